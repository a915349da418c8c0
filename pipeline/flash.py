"""Stage 1: separate flash frames from no-flash frames (paper section 3.1).

Input is a brightness trace: the mean linear luminance (0-1) of each frame over the face
region (or the whole frame before the face is known). With ``s = fps / (2 * flash_hz)``
frames between a flash and the next dark frame:

1. local maxima of the trace in a window of +-s frames are flash candidates, local minima are
   dark (no-flash) frames;
2. a candidate whose brightness exceeds the dark level around it (the mean of the neighbouring
   minima) by less than ``threshold`` is dropped (the flash did not reach the face); beyond the
   paper, so is one below ``min_share`` of the median flash's contrast (a phone's exposure
   wander alone can lift a dark frame by more than 0.002);
3. a candidate whose spacing to both neighbouring candidates deviates from ``2 s`` (or a whole
   multiple of it: a dropped flash in between doubles the gap) by more than ``s / 2`` is dropped
   as a spurious extremum; a single lag of the flash app only disturbs one side. (Beyond the
   paper, a flash's time is the centre of the frames it lit, not its brightest frame.)

Beyond the paper, each kept flash is extended to every frame around its peak that the flash lit
for most of its exposure (brightness above the dark level by at least half the peak's
contrast): a flash lights two to three frames at 5 Hz and 30 fps, and each is a sample of the
same light direction. ``level`` is that share per frame (1 at the peak). Frames around a dark
minimum whose own flash share is tiny join the no-flash frames, so registration sees more.

The flash rate is estimated from the trace (its dominant period) when not given.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.ndimage import maximum_filter1d, minimum_filter1d

from relight.errors import InputError
from relight.numerics import EPS

#: Default minimum flash contrast over the dark level (linear luminance, 0-1), as in the paper,
#: and the least share of the median flash's contrast a flash must reach (beyond the paper).
DEFAULT_THRESHOLD = 0.002
DEFAULT_MIN_SHARE = 0.1
DEFAULT_FLASH_HZ = 5.0
#: A frame belongs to a flash when it shows at least this share of the flash's peak contrast.
LIT_SHARE = 0.5
#: A frame next to a dark minimum is a no-flash frame too when it shows less than this share.
DARK_SHARE = 0.03


@dataclass
class FlashFrames:
    """Result of the separation; every index refers to the video's frame order.

    peaks : (F,) the brightest frame of each kept flash.
    flash_frames : sorted frames lit by a kept flash for most of their exposure.
    pulse_of : frame -> index into ``peaks`` of the flash that lit it.
    level : (N,) per frame, the share of its flash's peak contrast (0 for dark frames).
    dark : sorted no-flash frames (local minima and near-dark neighbours).
    flash_hz : the flash rate used (given or estimated). estimated : True when estimated.
    rejected : reason -> count of dropped flash candidates.
    """

    peaks: np.ndarray
    flash_frames: np.ndarray
    pulse_of: dict
    level: np.ndarray
    dark: np.ndarray
    flash_hz: float
    estimated: bool
    rejected: dict = field(default_factory=dict)


#: Relative difference between the stated frame rate and the frames' mean rate above which the
#: mean rate is used (below it the stated one: the frames are evenly spaced).
RATE_TOLERANCE = 1e-3
#: A brightness trace whose standard deviation is below this is flat (nothing blinks), and the
#: floor of the spectrum's power before its logarithm.
FLAT_STD = 1e-7
LOG_FLOOR = 1e-300


def estimate_flash_hz(trace: np.ndarray, fps: float, times: np.ndarray | None = None) -> float | None:
    """The dominant blink rate of a brightness trace (Hz), or None if there is no clear one.

    Looks for the strongest spectral peak between 0.5 Hz and fps / 4 and refines it by
    parabolic interpolation; "clear" means at least 4 times the median spectral power.
    ``times``: the frames' times in seconds (variable frame rate: the trace is resampled
    linearly onto an even grid at ``fps`` first).
    """
    x = np.asarray(trace, dtype=np.float64)
    if times is not None and x.size > 1:
        t = np.asarray(times, dtype=np.float64)
        grid = t[0] + np.arange(int(np.floor((t[-1] - t[0]) * fps)) + 1) / fps
        x = np.interp(grid, t, x)
    n = x.size
    if n < 16:
        return None
    x = x - x.mean()
    if x.std() < FLAT_STD:  # a flat trace: nothing blinks
        return None
    window = np.hanning(n)
    pad = 1 << int(np.ceil(np.log2(n * 4)))
    power = np.abs(np.fft.rfft(x * window, pad)) ** 2
    freqs = np.fft.rfftfreq(pad, 1.0 / fps)
    band = (freqs >= 0.5) & (freqs <= fps / 4.0)
    if not band.any():
        return None
    idx = np.flatnonzero(band)
    k = idx[np.argmax(power[idx])]
    if power[k] < 4.0 * np.median(power[idx]) or power[k] <= 0:
        return None
    if 0 < k < power.size - 1:
        a, b, c = np.log(power[k - 1:k + 2] + LOG_FLOOR)
        denom = a - 2 * b + c
        offset = 0.5 * (a - c) / denom if abs(denom) > EPS else 0.0
        return float((k + np.clip(offset, -0.5, 0.5)) * fps / pad)
    return float(freqs[k])


def separate(trace: np.ndarray, fps: float, flash_hz: float | None = None,
             threshold: float = DEFAULT_THRESHOLD, min_share: float = DEFAULT_MIN_SHARE,
             times: np.ndarray | None = None) -> FlashFrames:
    """Classify frames from a brightness trace (N,) of linear mean luminance.

    ``times``: (N,) each frame's time in seconds (phones record at a variable frame rate); the
    blink rate and the period check use them, and ``fps`` becomes their mean rate. None: frames
    evenly spaced at ``fps``.

    Raises :class:`InputError` when the trace is too short or not finite, or when no flash
    survives the filters (the message says which filter removed them).
    """
    trace = np.asarray(trace, dtype=np.float64)
    n = trace.size
    if n < 8:
        raise InputError(f"the video has {n} frames; a capture needs at least a few seconds of video")
    if not np.isfinite(trace).all():
        raise InputError("the brightness trace holds non-finite values; the video is corrupt")
    if fps <= 0 or not np.isfinite(fps):
        raise InputError(f"frame rate {fps}: the video must state a positive frame rate")
    times, fps = _frame_times(times, n, fps)
    estimated = flash_hz is None
    if estimated:
        flash_hz = estimate_flash_hz(trace, fps, times) or DEFAULT_FLASH_HZ
    if not (0 < flash_hz <= fps / 2):
        raise InputError(f"--flash-hz {flash_hz}: must be above 0 and at most half the frame rate ({fps / 2:g})")
    s = fps / (2.0 * flash_hz)
    half = max(int(np.floor(s)), 1)
    maxima, minima = _extrema(trace, half)
    rejected = {"low_contrast": 0, "period": 0, "no_dark_neighbour": 0}
    if minima.size == 0:
        raise InputError("no dark (no-flash) frames found: the flash must blink slower than the camera "
                         "films (check --flash-hz) and the room must be dark between flashes")
    cand, cand_dark, cand_contrast = _contrast_filter(trace, maxima, minima, threshold, min_share, rejected)
    if cand.size >= 3:
        cand, cand_dark, cand_contrast = _period_filter(trace, times, cand, cand_dark, cand_contrast, half, minima,
                                                        flash_hz, rejected)
    if cand.size == 0:
        reasons = ", ".join(f"{k}: {v}" for k, v in rejected.items() if v)
        raise InputError(f"no usable flash found ({reasons or 'no bright frames'}); check that the flash "
                         "lights the face, or lower --flash-threshold")
    level, pulse_of = _lit_frames(trace, cand, cand_dark, cand_contrast, half, minima)
    flash_frames = np.array(sorted(pulse_of), dtype=np.int64)
    dark = _dark_frames(trace, minima, cand, cand_contrast, pulse_of)
    return FlashFrames(peaks=cand.astype(np.int64), flash_frames=flash_frames, pulse_of=pulse_of, level=level,
                       dark=dark, flash_hz=float(flash_hz), estimated=estimated, rejected=rejected)


def _frame_times(times, n: int, fps: float) -> tuple[np.ndarray, float]:
    """Each frame's time (N,) in seconds and the frame rate to use (Hz): the frames' mean rate when
    it differs from the stated one. Raises :class:`InputError` on unusable ``times``."""
    if times is None:
        return np.arange(n) / fps, fps
    times = np.asarray(times, dtype=np.float64)
    if times.shape != (n,) or not np.isfinite(times).all() or (np.diff(times) <= 0).any():
        raise InputError("frame times must be finite and increasing, one per frame of the trace")
    rate = (n - 1) / (times[-1] - times[0])
    if abs(rate - fps) > RATE_TOLERANCE * fps:
        fps = rate  # the stated rate is not what the frames show (variable frame rate)
    return times, fps


def _extrema(trace: np.ndarray, half: int) -> tuple[np.ndarray, np.ndarray]:
    """Frame indices of the trace's local maxima and minima in a window of +-``half`` frames."""
    size = 2 * half + 1
    is_max = (trace == maximum_filter1d(trace, size, mode="nearest"))
    is_min = (trace == minimum_filter1d(trace, size, mode="nearest"))
    # Plateaus (equal neighbours) count once: keep the first frame of a run.
    is_max &= np.r_[True, trace[1:] != trace[:-1]] | ~np.r_[False, is_max[:-1]]
    is_min &= np.r_[True, trace[1:] != trace[:-1]] | ~np.r_[False, is_min[:-1]]
    maxima = np.flatnonzero(is_max & ~is_min)
    minima = np.flatnonzero(is_min & ~is_max)
    return maxima, minima


def _contrast_filter(trace, maxima, minima, threshold: float, min_share: float, rejected: dict):
    """Flash candidates that stand out of the dark level around them: (peaks, dark levels,
    contrasts), each (F,); counts the dropped ones in ``rejected``."""
    # Dark level around each candidate: mean of the nearest minimum before and after.
    pos = np.searchsorted(minima, maxima)
    before = np.where(pos > 0, minima[np.maximum(pos - 1, 0)], -1)
    after = np.where(pos < minima.size, minima[np.minimum(pos, minima.size - 1)], -1)
    dark_level = np.full(maxima.size, np.nan)
    both = (before >= 0) & (after >= 0)
    dark_level[both] = 0.5 * (trace[before[both]] + trace[after[both]])
    only_b = (before >= 0) & (after < 0)
    only_a = (after >= 0) & (before < 0)
    dark_level[only_b] = trace[before[only_b]]
    dark_level[only_a] = trace[after[only_a]]
    ok = np.isfinite(dark_level)
    rejected["no_dark_neighbour"] = int((~ok).sum())
    contrast = np.where(ok, trace[maxima] - np.nan_to_num(dark_level), 0.0)
    # The paper's absolute threshold, and (beyond it) a share of the typical flash's contrast:
    # a phone's exposure wander alone can lift a dark frame by more than 0.002.
    typical = float(np.median(contrast[ok & (contrast >= threshold)])) if (ok & (contrast >= threshold)).any() else 0.0
    low = ok & (contrast < max(threshold, min_share * typical))
    rejected["low_contrast"] = int(low.sum())
    keep = ok & ~low
    return maxima[keep], dark_level[keep], contrast[keep]


def _period_filter(trace, times, cand, cand_dark, cand_contrast, half: int, minima, flash_hz: float,
                   rejected: dict):
    """Drop candidates whose gaps to both neighbours are off the blink period; returns the kept
    (peaks, dark levels, contrasts) and counts the dropped ones in ``rejected``."""
    # Period filter: both gaps far from a whole number of blink periods -> a spurious extremum.
    # Whole multiples, because a dropped flash between two good ones doubles their gap. In
    # seconds, from the frames' times (evenly spaced frames: 2 s frames a period, s / 2 off).
    gaps = np.diff(_pulse_times(trace, times, cand, cand_dark, cand_contrast, half, minima))
    period = 1.0 / flash_hz
    periods = np.maximum(np.round(gaps / period), 1.0)
    off = np.abs(gaps - periods * period) > period / 4
    prev_bad = np.r_[True, off]
    next_bad = np.r_[off, True]
    bad = prev_bad & next_bad
    rejected["period"] = int(bad.sum())
    return cand[~bad], cand_dark[~bad], cand_contrast[~bad]


def _lit_frames(trace, cand, cand_dark, cand_contrast, half: int, minima) -> tuple[np.ndarray, dict]:
    """Each frame's share of its flash's peak contrast, level (N,), and frame -> flash index for
    the frames a kept flash lit for most of their exposure."""
    n = trace.size
    level = np.zeros(n)
    pulse_of: dict[int, int] = {}
    for k, (peak, dark, con) in enumerate(zip(cand, cand_dark, cand_contrast, strict=True)):
        lo, hi = max(peak - half, 0), min(peak + half, n - 1)
        for j in range(lo, hi + 1):
            share = (trace[j] - dark) / con
            if share >= LIT_SHARE and (j == peak or j not in pulse_of or share > level[j]):
                if not _between_minima(j, peak, minima):
                    continue
                pulse_of[j] = k
                level[j] = min(share, 1.0) if j != peak else 1.0
    return level, pulse_of


def _dark_frames(trace, minima, cand, cand_contrast, pulse_of: dict) -> np.ndarray:
    """Sorted no-flash frames: the minima plus neighbours with almost no flash light."""
    n = trace.size
    dark_set = set(int(m) for m in minima)
    for m in minima:
        k = int(np.searchsorted(cand, m))
        neigh = [c for c in (k - 1, k) if 0 <= c < cand.size]
        if not neigh:
            continue
        con = max(cand_contrast[c] for c in neigh)
        for j in (m - 1, m + 1):
            if 0 <= j < n and j not in pulse_of and trace[j] - trace[m] < DARK_SHARE * con:
                dark_set.add(j)
    return np.array(sorted(dark_set - set(pulse_of)), dtype=np.int64)


def _pulse_times(trace, times, peaks, dark, contrast, half: int, minima) -> np.ndarray:
    """When each flash happened (s): the centre of its lit frames (those showing at least
    LIT_SHARE of its contrast, no dark minimum between them and the peak), weighted by the share.
    A flash lights two to four frames nearly alike, and which of them is brightest is the noise's
    choice: the peak frame alone is up to a frame off its flash, which with a hand-held app's
    own lag made the period check drop good flashes."""
    out = np.empty(peaks.size)
    n = trace.size
    for k, (peak, d, con) in enumerate(zip(peaks, dark, contrast, strict=True)):
        lo, hi = max(int(peak) - half, 0), min(int(peak) + half, n - 1)
        js = np.array([j for j in range(lo, hi + 1) if _between_minima(j, int(peak), minima)])
        w = np.clip((trace[js] - d) / max(con, EPS), 0.0, 1.0)
        w = np.where(w >= LIT_SHARE, w, 0.0)
        out[k] = float(np.sum(w * times[js]) / np.sum(w)) if w.sum() > 0 else float(times[peak])
    return out


def _between_minima(j: int, peak: int, minima: np.ndarray) -> bool:
    """True when no dark minimum lies between frame j and its flash's peak."""
    lo, hi = (j, peak) if j < peak else (peak, j)
    i = np.searchsorted(minima, lo, side="right")
    return not (i < minima.size and minima[i] < hi)


def precision_recall(found: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """Precision and recall of a set of frame indices against the truth's."""
    f, t = set(int(x) for x in found), set(int(x) for x in truth)
    tp = len(f & t)
    return (tp / len(f) if f else 0.0), (tp / len(t) if t else 0.0)
