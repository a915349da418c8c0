"""The capture's side of the maps' recipe (stage 6 writing): the light samples and horizons
quantised as a bundle stores them (the capture builds everything from the decoded values, so the
maps a bundle makes again are the maps its capture made), and the recipe's arrays for the bundle.
The recipe, its storage and its decoding: :mod:`relight.kernels.recipe`."""

from __future__ import annotations

import numpy as np

from relight.errors import InputError
from relight.kernels.bundle_format import Field
from relight.kernels.recipe import SAMPLE_GAMMA, Recipe, decode_horizon, encode_horizon
from relight.numerics import half_ceil

from .shading_fit import stored_precision


def encode_samples(samples: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(codes (K, P, 3) uint8, scale (P, 3) float16) of linear samples (K, P, 3); see
    :mod:`relight.kernels.recipe`."""
    x = np.asarray(samples, dtype=np.float32)
    if x.ndim != 3 or x.shape[2] != 3:
        raise InputError(f"samples of shape {x.shape}: expected (K, P, 3)")
    if not np.isfinite(x).all():
        raise InputError("light samples hold NaN or infinite values; check the input images")
    peak = np.maximum(x.max(axis=0), 0.0) if x.shape[0] else np.zeros(x.shape[1:], np.float32)
    if float(peak.max(initial=0.0)) > float(np.finfo(np.float16).max):
        raise InputError("light samples above the float16 range: scale them first "
                         "(relight.pipeline.bundle_write.storage_scale)")
    scale = half_ceil(peak)  # x / scale <= 1
    s = scale.astype(np.float32)
    inv = np.where(s > 0, 1.0 / np.where(s > 0, s, 1.0), 0.0).astype(np.float32)
    codes = np.empty(x.shape, dtype=np.uint8)
    for k0 in range(0, x.shape[0], 16):
        r = np.clip(x[k0:k0 + 16] * inv[None], 0.0, 1.0)
        np.power(r, np.float32(SAMPLE_GAMMA), out=r)
        codes[k0:k0 + 16] = np.rint(r * 255.0)
    return codes, scale


def quantise_horizon(elevations: np.ndarray | None) -> np.ndarray | None:
    """Horizon elevations as a bundle stores them, decoded (None stays None)."""
    return None if elevations is None else decode_horizon(encode_horizon(elevations))


def recipe_arrays(recipe: Recipe) -> tuple[dict, dict]:
    """(arrays, meta["recipe"]) a bundle stores for a recipe (inverse of
    :func:`relight.kernels.recipe.recipe_from_arrays`)."""
    arrays = {
        Field.SAMPLES_CODE: np.asarray(recipe.codes, dtype=np.uint8),
        Field.SAMPLES_SCALE: np.asarray(recipe.scale, dtype=np.float16),
        Field.MODEL_ALBEDO: stored_precision(np.asarray(recipe.albedo, np.float32)).astype(np.float16),
        Field.MODEL_SPEC: stored_precision(np.asarray(recipe.spec, np.float32)).astype(np.float16),
        Field.MODEL_TRUST: np.asarray(recipe.trust, np.float32).astype(np.float16),
        Field.SPLINE_BLEND: np.asarray(recipe.blend, np.float32).astype(np.float16),
        Field.TRI_VERTICES: np.asarray(recipe.tri.vertices, dtype=np.float64),
        Field.TRI_FACES: np.asarray(recipe.tri.faces, dtype=np.int32),
        Field.TRI_TEXEL_VERTICES: np.asarray(recipe.tri.texel_vertices, dtype=np.int32),
        Field.TRI_TEXEL_WEIGHTS: np.asarray(recipe.tri.texel_weights, dtype=np.float32),
    }
    if recipe.horizon is not None:
        h = np.asarray(recipe.horizon)
        arrays[Field.HORIZON_CODE] = h if h.dtype == np.uint8 else encode_horizon(h)
        if recipe.horizon_index is not None:
            arrays[Field.HORIZON_INDEX] = np.asarray(recipe.horizon_index, dtype=np.int32)
    meta = {"n_az": int(recipe.n_az), "trend": bool(recipe.trend), "extrapolate": bool(recipe.extrapolate),
            "spline": bool(recipe.spline), "sample_gamma": SAMPLE_GAMMA}
    return arrays, meta
