"""The tracker's image of a frame: grey, scaled down to ``TRACK_ROWS`` rows, a dark frame
brightened (:func:`tracking_image`), and the tracker's reference with the face as the live light
shows it (:func:`lit_reference`, in the boxes :func:`aligned_box` gives).

Images are (H, W) uint8 grey codes unless a name says otherwise; boxes are (y0, y1, x0, x1).
"""
from __future__ import annotations

import cv2
import numpy as np

from relight.colour import LUMINANCE
from relight.video_yuv import downscale_area, downscale_fast

#: Rows of the frames the tracker sees (larger frames are scaled down for tracking only), and the
#: level (8-bit codes) a dark frame's brightest face tones are brought to for tracking.
TRACK_ROWS = 270
TRACK_BRIGHT = 200


def _percentile_u8(codes: np.ndarray, q: float) -> float:
    """``np.percentile(codes, q)`` (linear interpolation) of uint8 codes from their histogram
    (no sort: ~5x faster on a tracking frame)."""
    hist = cv2.calcHist([np.ascontiguousarray(codes)], [0], None, [256], [0, 256]).ravel()
    n = int(hist.sum())
    if n == 0:
        return 0.0
    pos = (n - 1) * q / 100.0
    lo = int(pos)
    cum = np.cumsum(hist)
    v0 = int(np.searchsorted(cum, lo + 1))  # the code of the lo-th smallest value (0-based)
    v1 = int(np.searchsorted(cum, min(lo + 2, n)))
    return v0 + (pos - lo) * (v1 - v0)


def track_exposure(grey: np.ndarray) -> tuple[np.ndarray, float]:
    """(the tracking image, the gain on its codes): a dark frame brightened (a gain in quarter stops, so it holds still
    while the exposure does): its 99th percentile brought to ``TRACK_BRIGHT`` codes. Tracking
    compares brightness gradients against fixed thresholds; a frame a twentieth as bright as the
    capture would otherwise lose the face."""
    top = _percentile_u8(grey[::4, ::4], 99.0)
    if top >= TRACK_BRIGHT / 2 or top <= 0:
        return grey, 1.0
    gain = float(2.0 ** (np.floor(4.0 * np.log2(TRACK_BRIGHT / top)) / 4.0))
    return cv2.convertScaleAbs(grey, alpha=gain), gain


def tracking_image(frame) -> tuple[np.ndarray, float, float]:
    """(the tracking image, its scale of the frame, the gain on its codes) of ``frame`` - (H, W, 3)
    uint8 sRGB or a :class:`relight.video_yuv.YuvFrame` (its planes scaled first, then made grey:
    :meth:`relight.video_yuv.YuvFrame.tracking_grey`): grey, scaled to
    at most ``TRACK_ROWS`` rows (LK's cost is its pyramids and windows; a third of a pixel at 1080
    rows is still far below the pose's noise; scaled by :func:`relight.video_yuv.downscale_fast`),
    a dark frame brightened (:func:`track_exposure`)."""
    h, w = frame.shape[:2]
    ts = min(1.0, TRACK_ROWS / h)
    if not isinstance(frame, np.ndarray):
        grey = frame.tracking_grey((round(w * ts), round(h * ts)) if ts < 1 else (w, h))
    else:
        grey = cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY)
        if ts < 1:
            grey = downscale_fast(grey, (round(w * ts), round(h * ts)))
    grey, gain = track_exposure(grey)
    return grey, ts, gain


def aligned_box(small_mask: np.ndarray, full_shape: tuple[int, int]):
    """The box of ``small_mask`` (a mask on a downscaled copy of a ``full_shape`` frame) and the
    full frame's box that INTER_AREA downscales to exactly those pixels: ((y0, y1, x0, x1) small,
    (y0, y1, x0, x1) full). The boxes start and end on the scales' periods (a scale p/q in lowest
    terms repeats every q full pixels), so resizing the full box gives the same pixels as resizing
    the whole frame; when a scale's period is long (> 64 px) or the mask is empty, the whole frames."""
    from fractions import Fraction

    sh, sw = small_mask.shape
    fh, fw = full_shape
    whole = ((0, sh, 0, sw), (0, fh, 0, fw))
    ys, xs = np.nonzero(small_mask)
    if ys.size == 0:
        return whole
    out_s, out_f = [], []
    for lo, hi, n_small, n_full in ((ys.min(), ys.max() + 1, sh, fh), (xs.min(), xs.max() + 1, sw, fw)):
        r = Fraction(n_small, n_full)
        if r.denominator > 64 or r > 1:
            return whole
        p = r.numerator  # small pixels per period
        s0 = (int(lo) - 1) // p * p if lo > 0 else 0
        s1 = min(-(-(int(hi) + 1) // p) * p, n_small)
        f0 = s0 * r.denominator // p
        f1 = n_full if s1 == n_small else s1 * r.denominator // p
        out_s += [max(s0, 0), s1]
        out_f += [max(f0, 0), f1]
    return (out_s[0], out_s[1], out_s[2], out_s[3]), (out_f[0], out_f[1], out_f[2], out_f[3])


def lit_reference(reference: np.ndarray, lit: np.ndarray, boxes, face: np.ndarray, gain: float) -> np.ndarray:
    """The tracker's ``reference`` (a copy) with the face as the live light shows it, so
    re-anchoring matches like with like. ``lit``: the reference frame relit by the live light
    ((H, W, 3) linear); ``boxes``: the tracking copy's box and the reference frame's box that
    downscales to it (:func:`aligned_box`); ``face``: the tracking copy's face pixels (bool, the
    reference's shape); ``gain``: the tracking gain of the frame the light was fitted to."""
    from relight.colour import encode_srgb8

    (sy0, sy1, sx0, sx1), (ry0, ry1, rx0, rx1) = boxes
    crop = np.ascontiguousarray(lit[ry0:ry1, rx0:rx1], dtype=np.float32) @ LUMINANCE
    if crop.shape != (sy1 - sy0, sx1 - sx0):
        crop = downscale_area(crop, (sx1 - sx0, sy1 - sy0))
    ref = reference.copy()
    pixels = encode_srgb8(np.clip(crop[face[sy0:sy1, sx0:sx1]], 0.0, 1.0))
    # in the codes the tracker sees (a dark frame's are brightened by the same gain)
    region = ref[sy0:sy1, sx0:sx1]
    region[face[sy0:sy1, sx0:sx1]] = pixels if gain == 1.0 else cv2.convertScaleAbs(pixels, alpha=gain).ravel()
    return ref
