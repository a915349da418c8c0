"""Putting the relit face into the frame: ``transfer`` (the default), ``ambient`` and ``paste``.

The settings of the modes; the compositing itself runs in ``kernels/composite.cl``
(:mod:`relight.kernels.compositor`, with its NumPy twin). ``a`` is the warped, feathered face
mask in 0-1, ``f`` the live frame's pixel, all colours linear RGB.

* transfer: the light on the live face is measured from the live face (:mod:`relight.service.
  live_light`: the bundle relit by a fitted non-negative light explains the frame), and the face
  is relit for real: the bundle's own prediction ``relit(target)`` (exposure-matched to the live
  face) carries the new light, and the live frame's own detail - what the bundle's prediction
  of the live frame does not explain, beyond the fit's scatter (``DETAIL_SHRINK``): eyes, mouth,
  expression - is carried over by the ratio ``f x relit(target) / relit(live light)`` where the
  live pixel has signal (not in deep shadow relative to what the target wants, not near black,
  not clipped); ``eps`` (a share of the face's median) regularises the ratio, bounded to
  [0, RATIO_MAX].
* ambient: the ratio ``(relit + eps) / (ambient + eps)`` of the relit face to the reference under
  the capture room's light (the face under even light for bundles without a usable one),
  normalised to a median luminance of 1 - the live frame's own light stays in the output (the
  face is tinted, not relit): kept to compare with, and for a live room that is the capture's.
* paste: the relit reference face, scaled by an exposure gain so its median luminance matches
  the live face's, over the frame (the paper).

``strength`` (0-1) scales ``a``: 0 returns the frame unchanged.
"""

from __future__ import annotations

#: Regulariser of the lighting ratio, as a share of the face's median luminance (the ambient
#: reference's in mode ambient, the live light's in mode transfer).
RATIO_EPS = 0.05
#: Largest lighting ratio applied (after normalisation).
RATIO_MAX = 6.0
#: Smallest luminance a median may have before a gain is taken from it.
TINY = 1e-6
MODES = ("transfer", "ambient", "paste")
#: The mode every entry point starts in (filter, serve, the frame path).
DEFAULT_MODE = "transfer"
#: The compositing kernel's mode for each (relight.kernels.compositor.LAYER_MODES).
LAYER_MODE = {"transfer": "live", "ambient": "ambient", "paste": "paste"}
#: What mode transfer relights: the whole person (the face from the bundle, hair, ears, neck and
#: shoulders by the face's change of light carried over them: :mod:`.head_light`) or the face alone
#: (the bundle's face mask; the rest of the frame as it came).
REGIONS = ("person", "face")
#: The region every entry point starts with: the person - measured against the live frame's truth
#: under sunset it gains 6.7 / 4.9 dB over the person and 5.7 / 4.0 dB over the face (procedural /
#: scanned head) with the background's mean change under 0.2 codes, and 0.1-1.3 dB on each of the
#: ten real Yale faces (the face's turned-away and feathered edge gets the face's change of light
#: instead of the room's); at 720p the per-frame path then costs 62 ms of CPU a frame against 37 for
#: the face alone (the segmentation, its colour check and the ratio then every 2nd frame; the
#: face's and the person's composite in one kernel pass every frame).
DEFAULT_REGION = "person"
#: Mode transfer: a live pixel passes its own detail into the output only where it differs from
#: what the fitted live light predicts by more than this many times the fit's scatter (relative,
#: soft-thresholded): eyes, mouth, expression pass; the model's error and the camera's noise
#: do not (on a still real face, the output then equals the bundle's prediction to 0.03 dB).
DETAIL_SHRINK = 2.0
#: Mode transfer: the target is brought to the live face's exposure by its mean luminance, but
#: never so far that its EXPOSURE_PERCENTILE-th percentile exceeds the live face's (a light that
#: leaves half the face dark must not blow out the other half to keep the mean).
EXPOSURE_PERCENTILE = 95.0


def exposure_match(live, target) -> float:
    """The gain that brings ``target`` (luminance of face pixels under the target light) to the
    exposure of ``live`` (the same pixels under the live light): 1 when either is empty or black."""
    import numpy as np

    live = np.asarray(live, dtype=np.float64)
    target = np.asarray(target, dtype=np.float64)
    if live.size == 0 or target.size == 0:
        return 1.0
    ml, mt = float(live.mean()), float(target.mean())
    pl, pt = (float(np.percentile(v, EXPOSURE_PERCENTILE)) for v in (live, target))
    if not (ml > TINY and mt > TINY and pt > TINY):
        return 1.0
    return min(ml / mt, pl / pt)
