"""Smooth interpolation of light samples (a thin-plate spline over directions), for the pixels
the shading model does not explain.

Plain barycentric interpolation is linear inside each triangle of light directions and bends at
its edges: between two rings of a light dome 20 degrees apart it draws a moving highlight or
shadow edge as two half-bright ghosts. A thin-plate spline (:class:`scipy.interpolate.
RBFInterpolator`, kernel ``r^2 log r`` of the chord between unit directions, plus a linear
polynomial) passes through every sample with the least bending energy, so it follows the
samples' trend across the triangles' edges. It interpolates ``value ** SPLINE_GAMMA``, where a
highlight or shadow blends more like the light moving than like two exposures mixed.

Measured on the real held-out set (``../shared/data/rti-dome``: 49 lights predict 20 held-out
photos; sRGB PSNR directly at the held-out directions, every third pixel of the mask):
barycentric 23.67 dB; this spline of the linear values 23.43, of ``value ** 0.4`` 24.87 (0.3:
24.76, 0.5: 24.83); Clough-Tocher cubics over a projection of the directions 24.70 at best,
Gaussian and multiquadric kernels 24.2-24.75. Alone it loses on faces (the quick synthetic
scene: 27.2 dB against 29.5 with the shading model), hence the per-pixel blend: the weight of
each path is the one that best predicts samples left out of the interpolation, pooled over a
window of neighbouring pixels (fitted by the capture: :mod:`relight.pipeline.stacking`; a bundle
stores it).

The spline is linear in the (transformed) values, so it is computed once as a weight matrix
(query x sample) and applied to every pixel as one matrix product. This module holds the
spline's weights and their application (exactly, to a bundle's 8-bit sample codes): what the
maps kernel and a bundle's recipe run, in the capture and on the relight side alike.
"""

from __future__ import annotations

import numpy as np

from relight.errors import InputError, NumericalError

#: Power applied to the (non-negative, linear) values before interpolating, undone after.
SPLINE_GAMMA = 0.4


def spline_weights(dirs: np.ndarray, query: np.ndarray) -> np.ndarray | None:
    """(Q, K) float64 weights of the thin-plate spline through K unit light directions at Q
    query directions (rows sum to 1; weights may be negative). None when the directions do not
    determine one (fewer than 4, or all on one plane) - callers keep linear interpolation."""
    dirs = np.asarray(dirs, dtype=np.float64)
    query = np.asarray(query, dtype=np.float64).reshape(-1, 3)
    k = len(dirs)
    if k < 4:
        return None
    # The interpolant scipy's RBFInterpolator(kernel="thin_plate_spline", degree=1) builds,
    # written out (scipy.interpolate takes ~0.4 s to import; a bundle's first frame needs this):
    # [[Phi, P], [P^T, 0]] [c; a] = [I; 0], the polynomial's domain shifted and scaled to [-1, 1].
    lo, hi = dirs.min(axis=0), dirs.max(axis=0)
    shift, scale = (hi + lo) / 2, (hi - lo) / 2
    scale[scale == 0.0] = 1.0

    def poly(x):
        return np.hstack([np.ones((len(x), 1)), (x - shift) / scale])

    system = np.zeros((k + 4, k + 4))
    system[:k, :k] = _tps(np.linalg.norm(dirs[:, None] - dirs[None], axis=2))
    system[:k, k:] = poly(dirs)
    system[k:, :k] = system[:k, k:].T
    basis = np.hstack([_tps(np.linalg.norm(query[:, None] - dirs[None], axis=2)), poly(query)])  # (Q, K + 4)
    try:  # the system is symmetric: w = (S^-1 basis^T)^T, one right-hand side per query
        w = np.linalg.solve(system, basis.T)[:k].T
    except np.linalg.LinAlgError:
        return None
    return w if np.isfinite(w).all() else None


def _tps(r: np.ndarray) -> np.ndarray:
    """The thin-plate kernel r^2 log r (0 at r = 0)."""
    out = np.zeros_like(r)
    pos = r > 0
    out[pos] = r[pos] ** 2 * np.log(r[pos])
    return out


def spline_values(samples: np.ndarray, weights: np.ndarray, gamma: float = SPLINE_GAMMA) -> np.ndarray:
    """(Q, p, 3) spline interpolation of samples (K, p, 3), linear non-negative values, with
    weights (Q, K) from :func:`spline_weights`: ``(W @ s**gamma) ** (1/gamma)``, negative
    overshoot clipped to 0; float64 for float64 samples (the stability reference), else float32."""
    k, p, c = samples.shape
    out = spline_power_sum(samples.reshape(k, p * c), weights, gamma)
    return spline_root(out, gamma).reshape(len(weights), p, c)


def spline_power_sum(samples: np.ndarray, weights: np.ndarray, gamma: float = SPLINE_GAMMA, *,
                     out: np.ndarray | None = None) -> np.ndarray:
    """(Q, n) ``W @ max(s, 0) ** gamma`` for samples (K, n): the spline in its power domain (the
    maps kernel takes it so and applies :func:`spline_root` itself); float64 for float64 samples,
    else float32; into ``out`` when given."""
    dt = np.float64 if samples.dtype == np.float64 else np.float32
    s = np.clip(np.asarray(samples).astype(dt), 0.0, None)
    np.power(s, dt(gamma), out=s)
    return np.matmul(np.asarray(weights, dtype=dt), s, out=out)


#: Columns per BLAS call of :func:`exact_code_sums` (bounds its float64 scratch memory; the
#: sums are exact, so the blocking cannot change them).
EXACT_COLUMNS = 4096
#: Bits of float64's significand (53) less a factor 4 of headroom: every partial sum of
#: :func:`exact_code_sums` stays below 2 ** EXACT_BITS grid steps.
EXACT_BITS = 51


def fixed_point_weights(weights: np.ndarray, max_code: int = 255) -> np.ndarray:
    """(Q, K) float64 weights rounded to the finest grid 2^-s on which ``weights @ codes`` for
    codes in [0, max_code] is exact in float64: every product is a whole number of grid steps
    and every partial sum, in any order, stays below 2^EXACT_BITS of them. With row sums of
    |w| ~ 1-10 (a spline's) the grid is ~2^-40: far below float32's resolution of the result."""
    w = np.asarray(weights, dtype=np.float64)
    if not np.isfinite(w).all():
        raise NumericalError("non-finite spline weights; this is a bug, please report it")
    k = w.shape[-1] if w.ndim == 2 else 0
    bound = float(max_code) * max(float(np.abs(w).sum(axis=1).max(initial=0.0)), 1.0)
    bits = EXACT_BITS - int(np.ceil(np.log2(bound + 1.0)))
    # rounding moves each weight by at most half a step: the rounded sums grow by at most
    # max_code * K / 2 steps, which the "+ 1" above covers while this holds
    if max_code * k > 2.0 ** (bits + 1):
        raise NumericalError(f"spline weights too large for exact sums ({k} samples, |w| sum {bound / max_code:.3g})")
    return np.ldexp(np.rint(np.ldexp(w, bits)), -bits)


def exact_code_sums(codes: np.ndarray, weights: np.ndarray, *, out: np.ndarray | None = None) -> np.ndarray:
    """(Q, n) ``weights @ codes`` for uint8 codes (K, n) and weights from
    :func:`fixed_point_weights`, computed by BLAS in float64 where every operation is exact: the
    sums are the same bits whatever BLAS's blocking, threads, FMA or vector width, and so for
    any chunk of columns (the capture's streamed maps are exactly the whole's, on any CPU).
    Into ``out`` ((Q, n), any float dtype: rounded once from the exact sums) when given."""
    q = np.asarray(codes)
    if q.dtype != np.uint8:
        raise InputError(f"codes of dtype {q.dtype}: expected uint8")
    w = np.asarray(weights, dtype=np.float64)
    n = q.shape[1]
    if out is None:
        out = np.empty((len(w), n), dtype=np.float64)
    for c0 in range(0, n, EXACT_COLUMNS):
        c1 = min(c0 + EXACT_COLUMNS, n)
        out[:, c0:c1] = w @ q[:, c0:c1].astype(np.float64)
    return out


def spline_root(values: np.ndarray, gamma: float = SPLINE_GAMMA) -> np.ndarray:
    """In place: power-domain spline values clipped at 0 and raised to ``1 / gamma``; returns them."""
    np.clip(values, 0.0, None, out=values)
    if gamma == 0.4:  # x ** 2.5 as x * x * sqrt(x): ~10x faster than a general power
        root = np.sqrt(values)
        values *= values
        values *= root
    else:
        np.power(values, values.dtype.type(1.0 / gamma), out=values)
    return values
