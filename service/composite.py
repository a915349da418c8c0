"""Putting the relit face into the frame: ``paste`` (the paper) and ``transfer`` (the default).

The settings of the two modes; the compositing itself runs in ``kernels/composite.cl``
(:mod:`relight.kernels.compositor`, with its NumPy twin). ``a`` is the warped, feathered face
mask in 0-1, all colours linear RGB.

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

#: Regulariser of the lighting ratio, as a share of the face's median ambient luminance.
RATIO_EPS = 0.05
#: Largest lighting ratio applied (after normalisation).
RATIO_MAX = 6.0
#: Smallest luminance a median may have before a gain is taken from it.
TINY = 1e-6
MODES = ("transfer", "paste")
