"""Head motion and sound of the synthetic live clips: smooth pseudo-random pose tracks, and the
audio track (a tone, noise, or none)."""

from __future__ import annotations

import numpy as np

from relight.numerics import EPS, EPS_NORM
from relight.video_write import AUDIO_RATE

#: Motion: each pose channel is a sum of three sines of incommensurate (random) frequencies near
#: these (Hz), weights :data:`MOTION_WEIGHTS`; the slowest one makes at least
#: :data:`MOTION_MIN_CYCLES` cycles per clip. The channel is then scaled so that it spans
#: :data:`MOTION_SPAN` of its range [-amplitude, amplitude] over the clip.
MOTION_HZ = (0.11, 0.23, 0.41)
MOTION_WEIGHTS = (1.0, 0.45, 0.2)
MOTION_MIN_CYCLES = 0.75
MOTION_SPAN = 0.97
#: Audio: a 440 Hz tone at -20 dBFS peak, or white noise at -26 dBFS RMS; 10 ms fades.
TONE_HZ = 440.0
TONE_PEAK = 0.1
NOISE_RMS = 0.05
AUDIO_FADE_S = 0.01
AUDIO_KINDS = ("tone", "noise", "none")


def _smooth_channel(rng: np.random.Generator, t: np.ndarray, duration: float) -> np.ndarray:
    """Sum of three sines (random, incommensurate frequencies and phases) scaled to span +-MOTION_SPAN."""
    base = max(MOTION_HZ[0] * rng.uniform(0.8, 1.25), MOTION_MIN_CYCLES / duration)
    ratios = np.array([1.0, MOTION_HZ[1] / MOTION_HZ[0], MOTION_HZ[2] / MOTION_HZ[0]])
    freqs = base * ratios * np.array([1.0, *rng.uniform(0.85, 1.15, size=2)])
    phases = rng.uniform(0.0, 2.0 * np.pi, size=3)
    x = sum(wt * np.sin(2.0 * np.pi * f * t + p) for wt, f, p in zip(MOTION_WEIGHTS, freqs, phases, strict=True))
    lo, hi = float(x.min()), float(x.max())
    if hi - lo < EPS:
        return np.zeros_like(t)
    return MOTION_SPAN * (2.0 * (x - lo) / (hi - lo) - 1.0)


def head_pose_track(rng: np.random.Generator, n: int, fps: float, amplitudes: tuple[float, float, float],
                    shift_px: float) -> tuple[np.ndarray, np.ndarray]:
    """Smooth head motion: rotations (n, 3) [yaw, pitch, roll] degrees and translations (n, 2) [tx, ty] px.

    Each channel is an independent smooth signal spanning :data:`MOTION_SPAN` of its range
    (+-amplitude, +-shift_px) over the clip, so the clip covers most of the range; frame 0 is
    not the reference pose. Values are rounded (6 decimals in degrees, 4 in pixels): the
    frames are rendered from exactly the rounded values that go into the truth.
    """
    t = np.arange(n) / fps
    duration = max(n / fps, EPS_NORM)
    rot = np.stack([a * _smooth_channel(rng, t, duration) for a in amplitudes], axis=1)
    trans = np.stack([shift_px * _smooth_channel(rng, t, duration) for _ in range(2)], axis=1)
    return np.round(rot, 6), np.round(trans, 4)


#: A clip told to start from a pose (``relight synth --live --start-yaw/--start-pitch``) eases from
#: it into its own motion over this many seconds (at most half the clip): a raised cosine, so the
#: head starts still at that pose and turns on smoothly.
START_EASE_S = 1.5


def start_from(rotations: np.ndarray, fps: float, start: tuple) -> np.ndarray:
    """``rotations`` (n, 3) [yaw, pitch, roll] degrees with each channel whose ``start`` entry is
    not None eased from that value at frame 0 into the track (:data:`START_EASE_S`): a blend of
    the two, so the pose stays between the start and the track (never beyond both); rounded as
    :func:`head_pose_track` rounds (the frames are rendered from the values in the truth)."""
    rot = np.asarray(rotations, dtype=np.float64).copy()
    n = rot.shape[0]
    t = np.arange(n) / fps
    ease = max(min(START_EASE_S, 0.5 * n / fps), EPS_NORM)
    w = np.where(t < ease, 0.5 * (1.0 + np.cos(np.pi * np.clip(t / ease, 0.0, 1.0))), 0.0)
    for k, value in enumerate(start):
        if value is not None:
            rot[:, k] = w * float(value) + (1.0 - w) * rot[:, k]
    return np.round(rot, 6)


def make_audio(kind: str, samples: int, rng: np.random.Generator) -> np.ndarray | None:
    """Mono float32 audio: a 440 Hz tone, seeded white noise, or None; faded in and out."""
    if kind == "none":
        return None
    if kind == "tone":
        t = np.arange(samples) / AUDIO_RATE
        a = TONE_PEAK * np.sin(2.0 * np.pi * TONE_HZ * t)
    else:
        a = np.clip(NOISE_RMS * rng.standard_normal(samples), -1.0, 1.0)
    fade = min(int(AUDIO_FADE_S * AUDIO_RATE), samples // 2)
    if fade:
        ramp = np.linspace(0.0, 1.0, fade)
        a[:fade] *= ramp
        a[samples - fade:] *= ramp[::-1]
    return a.astype(np.float32)
