"""Putting the relit face into the frame: ``paste`` (the paper) and ``transfer`` (the default).

All images here are linear RGB float32 (H, W, 3) over the face's box; ``alpha`` (H, W) is the
warped, feathered face mask in 0-1.

* paste: the relit reference face, scaled by an exposure gain so its median luminance matches
  the live face's, over the frame: ``out = frame (1 - a) + a g relit``.
* transfer: the live face keeps its eyes, mouth and expression and takes the new light as a
  per-pixel ratio ``(relit + eps) / (ambient + eps)`` of the relit face to the reference under
  the capture's room light; ``eps`` (a share of the face's median ambient) regularises dark
  pixels, the ratio is normalised to a median luminance of 1 (the face keeps its brightness,
  the light changes its distribution and colour; ``exposure`` scales it) and bounded to
  [0, RATIO_MAX]: ``out = frame (1 + a (g ratio - 1))``.

``strength`` (0-1) scales ``a``: 0 returns the frame unchanged.
"""

from __future__ import annotations

import numpy as np

from relight.colour import luminance

#: Regulariser of the lighting ratio, as a share of the face's median ambient luminance.
RATIO_EPS = 0.05
#: Largest lighting ratio applied (after normalisation).
RATIO_MAX = 6.0
#: Smallest luminance a median may have before a gain is taken from it.
TINY = 1e-6
MODES = ("transfer", "paste")


def ratio_image(relit: np.ndarray, ambient: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """(H, W, 3) float32 lighting ratio in the reference (before normalisation)."""
    lum = luminance(ambient)[mask]
    eps = np.float32(RATIO_EPS * max(float(np.median(lum)) if lum.size else 0.0, TINY))
    return (relit + eps) / (ambient + eps)


def median_gain(num: np.ndarray, den: np.ndarray, weight: np.ndarray) -> float:
    """Median luminance of ``num`` over that of ``den`` where ``weight`` > 0.5 (1.0 if undefined)."""
    sel = weight > 0.5
    if sel.sum() < 16:
        return 1.0
    a = float(np.median(luminance(num[sel])))
    b = float(np.median(luminance(den[sel])))
    if not (np.isfinite(a) and np.isfinite(b)) or a <= TINY or b <= TINY:
        return 1.0
    return a / b


def paste(frame: np.ndarray, relit: np.ndarray, alpha: np.ndarray, gain: float, strength: float) -> np.ndarray:
    a = (alpha * np.float32(strength))[..., None]
    return frame + a * (relit * np.float32(gain) - frame)


def transfer(frame: np.ndarray, ratio: np.ndarray, alpha: np.ndarray, gain: float, strength: float) -> np.ndarray:
    a = (alpha * np.float32(strength))[..., None]
    r = np.clip(ratio * np.float32(gain), 0.0, RATIO_MAX)
    return frame * (1.0 + a * (r - 1.0))
