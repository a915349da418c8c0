"""The acquisition rig of the synthetic studio: flash timing, the hand's path, head motion, camera drift.

Everything here is a pure function of a :class:`numpy.random.Generator` and the capture
settings, so the same seed gives the same capture.

Timing model: frame ``i`` integrates light over ``[i / fps, i / fps + exposure)``. The flash
blinks at ``flash_hz`` with a random phase, a jittered period and occasional lags (a phone
app is no metronome), lit for ``duty`` of each period; a frame's *flash fraction* is how much
of its exposure the flash was on, so frames straddling a flash edge are partially lit.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from relight.directions import rigid_matrix
from relight.numerics import EPS, px_at

#: Flash hand-path extent (degrees): azimuth +-AZ, elevation from EL_LOW to EL_HIGH.
AZIMUTH_MAX = 80.0
ELEVATION_LOW = -35.0
ELEVATION_HIGH = 70.0
#: Head motion limits at 960x540 (the paper: translation below 3 px, rotation below 0.35 deg).
MAX_SHIFT_PX_AT_540 = 3.0
MAX_ROT_DEG = 0.35


@dataclass(frozen=True)
class Pulse:
    """One flash: on from ``start`` to ``end`` (seconds), toward ``direction`` (camera space).

    ``strength`` is how much of the flash reaches the face (1 = aimed at it): a hand-held
    phone's beam sometimes points away, and the paper drops such ill-positioned flashes.
    """

    start: float
    end: float
    direction: tuple[float, float, float]
    strength: float = 1.0


def flash_pulses(rng: np.random.Generator, duration: float, flash_hz: float, *, duty: float = 0.5,
                 jitter: float = 0.04, lag_probability: float = 0.04) -> list[tuple[float, float]]:
    """Flash on-intervals over ``duration`` seconds: random phase, jittered period, occasional lags."""
    period = 1.0 / flash_hz
    t = -rng.uniform(0.0, period)
    out = []
    while t < duration:
        on = duty * period * (1.0 + 0.05 * rng.standard_normal())
        if t + on > 0:
            out.append((max(t, 0.0), t + on))
        step = period * (1.0 + jitter * rng.standard_normal())
        if rng.uniform() < lag_probability:
            step += period * rng.uniform(0.3, 0.8)
        t += max(step, 1.2 * on)
    return out


def hand_direction(t: np.ndarray, duration: float, rng_phase: np.ndarray, *,
                   sparse_sides: bool = False) -> np.ndarray:
    """Direction of the hand-held flash at times ``t``: a zig-zag over the frontal hemisphere.

    Azimuth sweeps back and forth about 9 times per capture while the elevation climbs from
    low to high and back down once (the passes down fall between those up), with a slow hand
    wobble; as in the paper's Fig. 12 the samples cover the front in zig-zag rows.
    ``sparse_sides``: the hand hurries through the sides instead of dwelling there (the
    paper's Fig. 14 sampling pattern): samples at the widest azimuths are about 6x sparser
    than in front.
    """
    t = np.asarray(t, dtype=np.float64)
    sweeps = 9.0

    def triangle(x):  # period 1, values in [-1, 1]
        return 2.0 * np.abs(2.0 * (x - np.floor(x + 0.5))) - 1.0

    # A hand slows down to turn: sin() of the triangle wave dwells at the ends of each row.
    tri = triangle(t / duration * sweeps + rng_phase[0])
    if sparse_sides:  # slope 0.35 in front, 2.3 at the ends: the sides are crossed quickly
        az = AZIMUTH_MAX * (0.35 * tri + 0.65 * tri ** 3)
    else:
        az = AZIMUTH_MAX * np.sin(0.5 * np.pi * tri)
    el_t = 0.5 - 0.5 * triangle(t / duration + 0.5 + 0.1 * rng_phase[1])
    el = ELEVATION_LOW + (ELEVATION_HIGH - ELEVATION_LOW) * el_t
    wobble = (3.0 * np.sin(2 * np.pi * (0.31 * t + rng_phase[2]))
              + 2.0 * np.sin(2 * np.pi * (0.73 * t + rng_phase[3])))
    az = az + wobble
    el = el + 0.7 * wobble
    az, el = np.radians(az), np.radians(el)
    return np.stack([np.cos(el) * np.sin(az), np.sin(el), np.cos(el) * np.cos(az)], axis=-1)


#: Share of flashes that miss the face (the hand or the head blocks the beam, or it points away),
#: and the little light they still bring.
MISAIM_PROBABILITY = 0.2
MISAIM_STRENGTH = (0.0, 0.003)
#: Strength range of well-aimed flashes (the hand is not steady).
AIM_STRENGTH = (0.85, 1.0)


def make_pulses(rng: np.random.Generator, duration: float, flash_hz: float, *,
                sparse_sides: bool = False) -> list[Pulse]:
    """Flash pulses with their directions (taken at each pulse's middle) and strengths."""
    intervals = flash_pulses(rng, duration, flash_hz)
    phase = rng.uniform(0.0, 1.0, size=4)
    mids = np.array([(a + b) / 2 for a, b in intervals])
    dirs = hand_direction(mids, duration, phase, sparse_sides=sparse_sides) if intervals else np.zeros((0, 3))
    misaimed = rng.uniform(size=len(intervals)) < MISAIM_PROBABILITY
    strength = np.where(misaimed, rng.uniform(*MISAIM_STRENGTH, size=len(intervals)),
                        rng.uniform(*AIM_STRENGTH, size=len(intervals)))
    return [Pulse(a, b, tuple(float(x) for x in d), float(st))
            for (a, b), d, st in zip(intervals, dirs, strength, strict=True)]


def flash_fractions(pulses: list[Pulse], frame_count: int, fps: float,
                    exposure: float) -> list[list[tuple[int, float]]]:
    """Per frame, the pulses lighting it and the fraction of the exposure each was on.

    Returns a list (one entry per frame) of ``(pulse index, fraction)`` pairs.
    """
    out: list[list[tuple[int, float]]] = [[] for _ in range(frame_count)]
    for k, p in enumerate(pulses):
        first = max(int(np.floor((p.start - exposure) * fps)), 0)
        last = min(int(np.ceil(p.end * fps)), frame_count - 1)
        for i in range(first, last + 1):
            t0 = i / fps
            overlap = min(p.end, t0 + exposure) - max(p.start, t0)
            if overlap > 0:
                out[i].append((k, overlap / exposure))
    return out


def _ou_walk(rng: np.random.Generator, n: int, fps: float, tau_s: float = 2.0) -> np.ndarray:
    """A smooth zero-mean random walk (Ornstein-Uhlenbeck, then smoothed), unit max amplitude."""
    theta = 1.0 / max(tau_s * fps, 1.0)
    x = np.zeros(n)
    noise = rng.standard_normal(n)
    for i in range(1, n):
        x[i] = x[i - 1] * (1.0 - theta) + noise[i] * np.sqrt(2 * theta)
    k = max(int(0.25 * fps), 1)
    x = np.convolve(np.pad(x, k, mode="edge"), np.ones(2 * k + 1) / (2 * k + 1), mode="same")[k:-k]
    x -= x.mean()
    return x / max(float(np.abs(x).max()), EPS)


def head_motion(rng: np.random.Generator, n: int, fps: float, height: int, amount: float,
                reference: int) -> np.ndarray:
    """(n, 3) rigid image motion [tx, ty, rot_deg] per frame, identity at ``reference``.

    A smooth random walk scaled so the largest excursion from the reference frame reaches
    ``amount`` times the paper's limits (3 px at 540 rows, scaled with the frame height;
    0.35 degrees).
    """
    raw = np.stack([_ou_walk(rng, n, fps) for _ in range(3)], axis=1)
    # Re-base on the reference frame: motion relative to its pose (rotations share a centre).
    rot = raw[:, 2] - raw[reference, 2]
    a = np.radians(rot)
    c, s = np.cos(a), np.sin(a)
    tx0, ty0 = raw[reference, 0], raw[reference, 1]
    # t_rel = t_i - R(rot) t_ref with R = [[c, s], [-s, c]] (see relight.directions.rigid_matrix).
    tx = raw[:, 0] - (c * tx0 + s * ty0)
    ty = raw[:, 1] - (-s * tx0 + c * ty0)
    rel = np.stack([tx, ty, rot], axis=1)
    shift_max = px_at(MAX_SHIFT_PX_AT_540, height) * amount * rng.uniform(0.7, 1.0)
    rot_max = MAX_ROT_DEG * amount * rng.uniform(0.7, 1.0)
    tmag = np.hypot(rel[:, 0], rel[:, 1]).max()
    rel[:, :2] *= shift_max / max(tmag, EPS) if amount > 0 else 0.0
    rel[:, 2] *= rot_max / max(np.abs(rel[:, 2]).max(), EPS) if amount > 0 else 0.0
    rel[reference] = 0.0
    return rel


def motion_matrices(motion: np.ndarray, center: tuple[float, float]) -> np.ndarray:
    """(n, 2, 3) image-space matrices of per-frame motions (see :func:`relight.directions.rigid_matrix`)."""
    return np.stack([rigid_matrix(tx, ty, r, center) for tx, ty, r in motion])


def camera_drift(rng: np.random.Generator, flash: np.ndarray, fps: float,
                 enabled: bool) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame exposure gain (n,) and white-balance gains (n, 3) of a phone camera.

    Disabled: all ones. Enabled: auto-exposure that meters a running average of the scene
    brightness (and so pumps with the flash, late), a slow exposure wander of a few percent,
    and white balance drifting a few percent per channel (green fixed).
    """
    n = len(flash)
    if not enabled:
        return np.ones(n), np.ones((n, 3))
    brightness = 1.0 + 4.0 * np.asarray(flash, dtype=np.float64)
    alpha = 1.0 - np.exp(-1.0 / (0.5 * fps))
    ema = np.empty(n)
    acc = brightness[:max(int(fps), 1)].mean()
    for i in range(n):
        ema[i] = acc  # the camera meters what it saw before this frame
        acc += alpha * (brightness[i] - acc)
    wander = 0.04 * _ou_walk(rng, n, fps, tau_s=4.0)
    gain = (ema[0] / ema) ** 0.35 * np.exp(wander)
    wb = np.ones((n, 3))
    wb[:, 0] = np.exp(0.03 * _ou_walk(rng, n, fps, tau_s=5.0))
    wb[:, 2] = np.exp(0.03 * _ou_walk(rng, n, fps, tau_s=5.0))
    return gain, wb
