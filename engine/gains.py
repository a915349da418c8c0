"""How bright the relit face goes into the frame: each mode's exposure gain on the relit
reference frame - mode transfer's matched to the live light's relight of the face
(:func:`live_gain`) and held once settled (:class:`ExposureLock`), mode ambient's from the ratio
to the reference light (:func:`ambient_gain`), mode paste's from the live face at the tracked
points (:func:`paste_gain`). See :mod:`.composite` for the modes.

``rig`` is the path's :class:`relight.engine.rig.FaceRig`; ``flat`` the relit reference frame,
(H x W, 3) float32 linear; frames are (H, W, 3) uint8 sRGB.
"""
from __future__ import annotations

import numpy as np

from relight.colour import LUMINANCE, decode_srgb8

from . import composite

#: Mode transfer: light fits whose exposure gains (their running median) set the exposure, then
#: held (:class:`ExposureLock`): 0.8 s of fits at :data:`.schedule.LIGHT_SETTLE_EVERY`.
EXPOSURE_LOCK_FITS = 8


def _sample_rgb(rgb, xy: np.ndarray) -> np.ndarray:
    """(N, 3) uint8 pixels of ``rgb`` ((H, W, 3) uint8 sRGB or a YuvFrame) nearest to points
    ``xy`` (clipped to the frame)."""
    from relight.video_yuv import sample_codes

    h, w = rgb.shape[:2]
    xi = np.clip(np.round(xy[:, 0]), 0, w - 1)
    yi = np.clip(np.round(xy[:, 1]), 0, h - 1)
    return sample_codes(rgb, np.stack([xi, yi], axis=1))


def _crop_index(xy: np.ndarray, origin, shape) -> np.ndarray:
    """Flat crop indices of the crop pixels nearest to reference points ``xy``."""
    h, w = shape
    xi = np.clip(np.round(xy[:, 0] - origin[0]).astype(np.int64), 0, w - 1)
    yi = np.clip(np.round(xy[:, 1] - origin[1]).astype(np.int64), 0, h - 1)
    return yi * w + xi


def live_gain(rig, live: np.ndarray, flat: np.ndarray) -> tuple[float, float]:
    """Mode transfer: (the median luminance of the face relit by the live light, the gain that
    brings the target's relight ``flat`` to its exposure: :func:`.composite.exposure_match`), over
    the live light's sample pixels. ``live``: the reference frame relit by the live light ((H, W, 3)
    float32 linear)."""
    le = live.reshape(-1, 3)[rig.live_full] @ LUMINANCE
    lt = flat[rig.live_full] @ LUMINANCE
    return (float(np.median(le)) if le.size else 0.0), composite.exposure_match(le, lt)


def ambient_gain(rig, flat: np.ndarray) -> float:
    """The gain that brings the median of the ratio to the reference light to 1."""
    ratio = (flat[rig.sample_full] + rig.ratio_eps) * rig.inv_ambient.reshape(-1, 3)[rig.sample_crop]
    med = float(np.median(ratio @ LUMINANCE)) if ratio.size else 1.0
    return 1.0 / med if med > composite.TINY else 1.0


def paste_gain(rig, rgb: np.ndarray, flat: np.ndarray, xy: np.ndarray, ref_idx: np.ndarray) -> float:
    """Mode paste: the gain that matches the relit face's median luminance to the live face's at
    the tracked points (``xy`` (N, 2) in ``rgb``, of the landmarks ``ref_idx``)."""
    live = decode_srgb8(_sample_rgb(rgb, xy)) @ LUMINANCE
    ref_px = rig.fill_flat[_crop_index(rig.control_ref[ref_idx], rig.origin, rig.mask_crop.shape)]
    relit_l = flat[ref_px[ref_px >= 0]] @ LUMINANCE
    num, den = float(np.median(live)) if live.size else 0.0, float(np.median(relit_l)) if relit_l.size else 0.0
    return num / den if num > composite.TINY and den > composite.TINY else 1.0


class ExposureLock:
    """Mode transfer's exposure: the target brought to the live face's exposure over the first
    EXPOSURE_LOCK_FITS light fits (their running median), then held - the relit person then
    brightens and darkens as the target light on it does when the head turns (a gain matched
    every frame would undo that, as an auto-exposure does), while the live light's own changes
    still cancel (it is fitted every frame). A new one for a new environment or a reset."""

    def __init__(self):
        self.lock: float | None = None
        self.fits: list[float] = []

    def __call__(self, gain: float) -> float:
        """The exposure gain to use, given this frame's matched ``gain``."""
        if self.lock is not None:
            return self.lock
        if np.isfinite(gain) and gain > 0:
            self.fits.append(float(np.log(gain)))
        if not self.fits:
            return gain
        med = float(np.exp(np.median(self.fits)))
        if len(self.fits) >= EXPOSURE_LOCK_FITS:
            self.lock = med
        return med
