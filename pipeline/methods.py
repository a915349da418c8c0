"""Interpolation methods: name -> how sparse light samples become reflectance maps.

``full`` and ``barycentric`` are the paper's triangulation (with and without visibility and
light adaptation, :mod:`relight.kernels.reflectance`); the baselines people use for sparse
light relighting are fitted per pixel and evaluated on the same map, so a comparison is of the
representation only:

* ``ptm``: Polynomial Texture Maps (Malzbender et al. 2001), a biquadratic in the light's
  (x, y), least squares.
* ``hsh`` / ``hsh2``: hemispherical harmonics of order 3 (9 terms) / 2 (4 terms), the RTI
  tools' standard.
* ``rbf``: radial basis functions over light directions (Gaussian kernels, regularised), as in
  the RELIGHT web format.

Fitted methods cover the front hemisphere (z > 0) of the map and are clamped at zero.
"""

from __future__ import annotations

import numpy as np
from scipy.special import factorial, lpmv

from relight.errors import InputError

METHODS = ("full", "barycentric", "ptm", "hsh", "hsh2", "rbf")
FITTED = ("ptm", "hsh", "hsh2", "rbf")
#: RBF kernel width (radians) relative to the samples' typical spacing, and its ridge term.
RBF_WIDTH = 1.2
RBF_RIDGE = 1e-3


def validate_method(name: str) -> str:
    """Return ``name`` if it is a known method, else raise with the list of valid names."""
    if name not in METHODS:
        raise InputError(f"unknown method {name!r}; choose one of: {', '.join(METHODS)}")
    return name


def ptm_basis(d: np.ndarray) -> np.ndarray:
    """(K, 6) PTM's biquadratic basis in the directions' (x, y) (Malzbender et al. 2001)."""
    u, v = d[:, 0], d[:, 1]
    return np.stack([u * u, v * v, u * v, u, v, np.ones_like(u)], axis=1)


def hsh_basis(d: np.ndarray, order: int) -> np.ndarray:
    """Hemispherical harmonics (Gautron et al. 2004) up to ``order`` (order^2 terms) over z > 0."""
    z = np.clip(d[:, 2], -1.0, 1.0)
    theta = np.arccos(np.clip(z, 0.0, 1.0))
    phi = np.arctan2(d[:, 1], d[:, 0])
    x = np.cos(theta)
    # Shifted argument: the hemisphere's polar angle maps to [-1, 1].
    t = 2.0 * x - 1.0
    cols = []
    for l in range(order):
        for m in range(-l, l + 1):
            am = abs(m)
            k = np.sqrt((2 * l + 1) * factorial(l - am) / (2 * np.pi * factorial(l + am)))
            p = lpmv(am, l, t)
            if m > 0:
                cols.append(np.sqrt(2) * k * np.cos(m * phi) * p)
            elif m < 0:
                cols.append(np.sqrt(2) * k * np.sin(am * phi) * p)
            else:
                cols.append(k * p)
    return np.stack(cols, axis=1)


def rbf_width(dirs: np.ndarray):
    """The Gaussian RBF width (radians) for sample directions ``dirs``: from their median spacing."""
    cosm = dirs @ dirs.T
    np.fill_diagonal(cosm, -1.0)
    spacing = float(np.median(np.arccos(np.clip(cosm.max(axis=1), -1, 1))))
    width = max(RBF_WIDTH * spacing, np.radians(3.0))
    return width


def rbf_kernel(a: np.ndarray, b: np.ndarray, width: float) -> np.ndarray:
    """(len(a), len(b)) Gaussian of the angle between directions, of ``width`` radians."""
    ang = np.arccos(np.clip(a @ b.T, -1.0, 1.0))
    return np.exp(-0.5 * (ang / width) ** 2)


def fit_and_evaluate(method: str, dirs: np.ndarray, samples: np.ndarray, texel_dirs: np.ndarray) -> np.ndarray:
    """Fit ``method`` to samples (K, P, 3) at ``dirs`` (K, 3); evaluate at texel_dirs (T, 3).

    Returns pixel-major maps (P, 3, T_pad) float32 (the layout of
    :func:`relight.kernels.interpolation.compute_maps`).
    """
    dirs = np.asarray(dirs, dtype=np.float64)
    k = len(dirs)
    flat = samples.reshape(k, -1).astype(np.float64)
    if method == "ptm":
        a, e = ptm_basis(dirs), ptm_basis(texel_dirs)
    elif method in ("hsh", "hsh2"):
        order = 3 if method == "hsh" else 2
        a, e = hsh_basis(dirs, order), hsh_basis(texel_dirs, order)
    elif method == "rbf":
        width = rbf_width(dirs)
        kk = rbf_kernel(dirs, dirs, width)
        # Ridge-regularised interpolation: the weights solve (K + ridge I) w = samples.
        coef = np.linalg.solve(kk + RBF_RIDGE * np.eye(k) * np.trace(kk) / k, flat)
        out = rbf_kernel(texel_dirs, dirs, width) @ coef
        return _pixel_major(np.clip(out, 0.0, None).reshape(len(texel_dirs), *samples.shape[1:]))
    else:
        raise InputError(f"method {method!r} is not a fitted method")
    if a.shape[1] > k:
        raise InputError(f"{method} needs at least {a.shape[1]} light samples, got {k}")
    coef, *_ = np.linalg.lstsq(a, flat, rcond=None)
    out = e @ coef
    return _pixel_major(np.clip(out, 0.0, None).reshape(len(texel_dirs), *samples.shape[1:]))


def _pixel_major(maps: np.ndarray) -> np.ndarray:
    """(T, P, 3) -> (P, 3, T_pad) float32, zero padded."""
    from relight.kernels.layout import padded_texels

    t, p = maps.shape[:2]
    out = np.zeros((p, 3, padded_texels(t)), dtype=np.float32)
    out[:, :, :t] = maps.transpose(1, 2, 0)
    return out
