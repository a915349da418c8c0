"""The capture's maps stage: the reflectance maps of the head's pixels from their stored
(quantised) samples, normals and visibility horizons - the shading-model fit, a fitted baseline
(:mod:`methods`) or plain interpolation - and the horizons themselves (half resolution for large
heads), and the maps' texel-major layout the bundle stores."""

from __future__ import annotations

import numpy as np

from relight.errors import InputError
from relight.kernels import interpolation, reflectance
from relight.kernels.heightfield import HORIZON_DIRS

from . import methods, recipe_write, shading_fit
from .bundle_write import storage_scale
from .capture_types import CaptureOptions

#: The head size (pixels) above which the horizon table (relight.kernels.heightfield.HORIZON_DIRS
#: directions) is computed at half resolution.
HALF_RES_PIXELS = 30000


def reflectance_maps(samples: np.ndarray, normals: np.ndarray, tri, opts: CaptureOptions, horizon, *,
                     half: bool = True, progress=None, grid: np.ndarray | None = None, recipe_out: dict | None = None,
                     recipe_only: bool = False):
    """The maps stage of :func:`relight.pipeline.bundle_arrays.finish`: (maps (P, 3, T_pad)
    float16 (float32 unless ``half``), texels (T,) map texel ids, scale, stored samples (K, P, 3)
    float32).

    The samples are divided by ``scale``, a power of two (1 for ordinary captures; see
    :func:`relight.pipeline.bundle_write.storage_scale`) so that maps and samples fit float16;
    the bundle records it as ``sample_scale`` and the renderer multiplies its light by it.
    ``horizon``: the pixels' horizon table for visibility (P, n_az), or (table, index) as
    :func:`horizon_rows` gives it, or None.

    Samples and horizons are quantised first, as the bundle stores them
    (:mod:`relight.kernels.recipe`), and everything is made from the stored values. With
    ``recipe_out`` (a dict) and the shading-model method, it receives the
    :class:`relight.kernels.recipe.Recipe` the maps can be made again from; with
    ``recipe_only`` too the maps are then not made here (None is returned for them: the caller
    makes them chunk by chunk, :func:`relight.kernels.recipe.recipe_maps`).
    """
    from relight.kernels import recipe as rcp

    if not np.isfinite(samples).all():
        raise InputError("light samples hold NaN or infinite values; check the input images")
    scale = storage_scale(samples)
    if scale != 1.0:
        samples = (samples / np.float32(scale)).astype(np.float32)
    codes, code_scale = recipe_write.encode_samples(samples)
    samples = rcp.decode_samples(codes, code_scale)
    horizon_index = None
    if isinstance(horizon, tuple):
        horizon, horizon_index = horizon
    horizon = recipe_write.quantise_horizon(horizon)
    horizon_table = horizon
    if horizon is not None and horizon_index is not None:
        horizon = horizon[horizon_index]  # a row per pixel for the fits and maps
    if opts.method in methods.FITTED:
        front = tri.texel_dirs[:, 2] > 0.0
        maps = methods.fit_and_evaluate(opts.method, tri.vertices[:tri.n_samples], samples, tri.texel_dirs[front])
        return maps, np.flatnonzero(front), scale, samples
    full = opts.method == "full"
    adapt = opts.adaptation and full
    trend = adapt and not opts.paper_adaptation
    if full and (trend or opts.extrapolation or opts.spline):
        sm, blend, active = shading_fit.fit_model(samples, normals, tri, horizon, HORIZON_DIRS,
                                                  extrapolate=opts.extrapolation, spline=opts.spline, grid=grid,
                                                  reach_deg=opts.model_reach, backend=opts.backend)
        recipe = None
        if recipe_out is not None and not (adapt and not trend):  # the paper's adaptation: maps kept
            recipe = recipe_out["recipe"] = rcp.Recipe(
                codes=codes, scale=code_scale, normals=np.asarray(normals, np.float32), horizon=horizon_table,
                horizon_index=horizon_index,
                albedo=sm.albedo.astype(np.float32), spec=sm.spec.astype(np.float32),
                trust=sm.trust.astype(np.float32), blend=np.asarray(blend, np.float32), tri=tri,
                active=active, n_az=HORIZON_DIRS, trend=bool(trend), extrapolate=bool(opts.extrapolation),
                spline=bool(opts.spline))
        if recipe is not None and recipe_only:
            return None, np.flatnonzero(active), scale, samples
        maps, map_tri = reflectance.maps_from_fit(samples, normals, tri, horizon, HORIZON_DIRS, sm, blend, active,
                                                  trend=trend, extrapolate=opts.extrapolation,
                                                  paper_adaptation=adapt and not trend, spline=opts.spline,
                                                  backend=opts.backend, half=half, codes=(codes, code_scale),
                                                  progress=progress)
        return maps, np.flatnonzero(map_tri.active), scale, samples
    maps = interpolation.compute_maps(samples, normals, tri, horizon=horizon, n_az=HORIZON_DIRS, adaptation=adapt,
                                    backend=opts.backend, half=half, progress=progress)
    return maps, np.flatnonzero(tri.active), scale, samples


def texel_major(maps: np.ndarray, n_texels: int, chunk: int = 64) -> np.ndarray:
    """(T, 3, P) float16 copy of pixel-major maps (P, 3, T_pad), transposed in texel blocks."""
    p = maps.shape[0]
    out = np.empty((n_texels, 3, p), dtype=np.float16)
    for t0 in range(0, n_texels, chunk):
        t1 = min(t0 + chunk, n_texels)
        out[t0:t1] = np.asarray(maps[:, :, t0:t1], dtype=np.float16).transpose(2, 1, 0)
    return out


def horizon_for(depth: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """(P, HORIZON_DIRS) float32 horizon elevations (radians: the arctangent of the largest rise
    per pixel toward each direction) of the mask's pixels (row-major order).

    Large heads are done on a half-resolution height field (heights halved too, so slopes are
    unchanged): visibility varies slowly across a face and this is about 8x cheaper.
    """
    table, index = horizon_rows(depth, mask)
    return table if index is None else table[index]


def horizon_rows(depth: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """:func:`horizon_for` as (table (R, HORIZON_DIRS) float32, index (P,) int32 of each pixel's
    row, or None when there is a row per pixel): large heads share a row per 2x2 pixels (what a
    bundle stores: a quarter of the bytes)."""
    from relight.kernels.heightfield import NO_SURFACE, horizon_table

    pix = np.flatnonzero(mask)
    if pix.size <= HALF_RES_PIXELS:
        hgt = np.where(mask, depth, NO_SURFACE).astype(np.float32)
        return np.arctan(horizon_table(hgt, pix.astype(np.int32), HORIZON_DIRS)), None
    h, w = mask.shape
    h2, w2 = (h + 1) // 2, (w + 1) // 2
    m = np.zeros((h2 * 2, w2 * 2), dtype=np.float32)
    z = np.zeros_like(m)
    m[:h, :w] = mask
    z[:h, :w] = np.where(mask, depth, 0.0)
    cover = m.reshape(h2, 2, w2, 2).sum(axis=(1, 3))
    low = np.where(cover > 0, z.reshape(h2, 2, w2, 2).sum(axis=(1, 3)) / np.maximum(cover, 1) / 2.0, NO_SURFACE)
    low_pix = np.flatnonzero(cover > 0)
    table = horizon_table(low.astype(np.float32), low_pix.astype(np.int32), HORIZON_DIRS)
    row_of = -np.ones(h2 * w2, dtype=np.int64)
    row_of[low_pix] = np.arange(low_pix.size)
    ys, xs = pix // w, pix % w
    return np.arctan(table), row_of[(ys // 2) * w2 + xs // 2].astype(np.int32)
