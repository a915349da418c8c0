"""The capture's weight of the thin-plate spline against the shading-model path, per pixel
(stage 5 fitting; the spline itself: :mod:`relight.kernels.spline`): the weight of each path is
the least-squares blend that best predicts samples left out of the interpolation (stacking),
pooled over a window of neighbouring pixels. The bundle stores the weight (``spline_blend``)."""

from __future__ import annotations

import numpy as np

from relight.kernels.spline import spline_values, spline_weights
from relight.numerics import EPS, TINY_SCALE

#: Leave-one-out: at most this many samples are left out (evenly spread) to weigh the spline
#: against the shading-model path per pixel.
LOO_MAX = 64
#: Stacking weights are fitted over a window of (2 x this + 1)^2 neighbouring pixels.
STACK_RADIUS = 3


def leave_one_out(dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Weights that predict samples from the others: (idx (L,) the left-out samples, linear
    (L, K) spherical barycentric weights, spline (L, K)
    :func:`relight.kernels.spline.spline_weights`), zero at the left-out sample. Only samples
    inside the others' hull are left out (at most ``LOO_MAX``, evenly spread); None when there
    is none."""
    from .triangulate import cap_faces, inside_hull, locate_in_faces

    dirs = np.asarray(dirs, dtype=np.float64)
    k = len(dirs)
    if k < 5:
        return None
    idx, lin, spl = [], [], []
    for j in np.linspace(0, k - 1, min(k, LOO_MAX * 3)).round().astype(int):
        others = np.r_[0:j, j + 1:k]
        if not inside_hull(dirs[others], dirs[j:j + 1])[0]:
            continue
        faces = cap_faces(dirs[others])
        sw = spline_weights(dirs[others], dirs[j:j + 1])
        if faces is None or sw is None:
            continue
        tv, tw = locate_in_faces(dirs[others], faces, dirs[j:j + 1])
        a, b = np.zeros(k), np.zeros(k)
        np.add.at(a, others[tv[0]], tw[0])
        b[others] = sw[0]
        idx.append(j)
        lin.append(a)
        spl.append(b)
        if len(idx) == LOO_MAX:
            break
    if not idx:
        return None
    return np.asarray(idx), np.asarray(lin), np.asarray(spl)


def stacking_terms(samples: np.ndarray, model: np.ndarray, trust: np.ndarray, loo) -> tuple[np.ndarray, np.ndarray]:
    """Per pixel the least-squares blend of the shading-model path and the spline from their
    leave-one-out predictions of the samples (stacking): (num (p,), den (p,)) with the weight of
    the model path ``num / den`` (clipped to 0-1 by :func:`stacking_weight`).

    samples : (K, p, 3) linear; model : (K, p, 3) the shading model at the sample directions;
    trust : (p,) the model's share in its path (the residual ``sample - trust x model``
    interpolated linearly, ``trust x model`` added back); loo : :func:`leave_one_out`."""
    idx, lin, spl = loo
    k, p, c = samples.shape
    s = samples.astype(np.float64)
    t = trust[None, :, None]
    resid = (s - t * model).reshape(k, p * c)
    path = (lin @ resid).reshape(len(idx), p, c) + t * model[idx]
    smooth = spline_values(s, spl)
    d = path - smooth
    return (d * (s[idx] - smooth)).sum(axis=(0, 2)), (d * d).sum(axis=(0, 2))


def stacking_weight(num: np.ndarray, den: np.ndarray, trust: np.ndarray, grid: np.ndarray | None = None,
                    radius: int = STACK_RADIUS) -> np.ndarray:
    """(p,) weight of the shading-model path against the spline, 0-1, from :func:`stacking_terms`
    summed over a (2 radius + 1)^2 window of neighbouring pixels when ``grid`` (the (H, W) mask
    whose True pixels, in raster order, are the p pixels) is given. Where the two paths predict
    alike (no evidence either way) the pixel keeps ``trust``."""
    if grid is not None and radius > 0:
        from scipy.ndimage import uniform_filter

        def window(v):
            img = np.zeros(grid.shape)
            img[grid] = v
            return uniform_filter(img, size=2 * radius + 1, mode="constant")[grid]

        num, den = window(num), window(den)
    ok = den > EPS * max(float(np.max(den)) if den.size else 0.0, TINY_SCALE)
    return np.where(ok, np.clip(num / np.where(ok, den, 1.0), 0.0, 1.0), trust)
