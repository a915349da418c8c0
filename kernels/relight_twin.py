"""NumPy twin of relighting, from what a bundle stores: the reference the kernels are tested against.

:func:`relight_numpy` relights a bundle in float64 from its stored arrays alone - the maps (or,
for a recipe bundle, the maps its recipe makes: :meth:`relight.kernels.bundle.Bundle.pixel_maps`,
:meth:`~relight.kernels.bundle.Bundle.texel_rows`), the transport basis as stored
(``transport_u``, the 8-bit ``transport_v`` and the 4-bit ``transport_v4`` with their scales),
``transport_errors`` to choose the rank - and none of the Relighter's kernel-side forms: not its
32-pixel blocks, its repacked nibbles, its coefficients divided by the storage's levels
(:func:`relight.kernels.relight_packing.compact_coefficients`), its row cache or its frame buffers. A
bug in that packing shows in the kernel's result and not here.

Shared with the Relighter on purpose: the direction-space stage (the environment's lights turned
and splatted into the map's texels, :func:`relight.kernels.texel_lights.texel_light` - the light both
are given, with the same rotation and exposure conventions) and the storage's own definitions
(the levels V_LEVELS / V4_LEVELS, a half below ``HALF_TINY`` read as zero).
"""

from __future__ import annotations

import numpy as np

from relight.numerics import HALF_TINY

from . import texel_lights, transport
from .bundle_format import Field

#: The Relighter's default tolerance (relative L2 against the exact path) choosing the rank.
DEFAULT_TOLERANCE = transport.STORE_TOLERANCE
#: Pixels per chunk of the float64 products (bounds the scratch memory to ~40 MB at T = 2000).
CHUNK = 1024


def _halves(a) -> np.ndarray:
    """Stored float16 values as float64, a subnormal half as zero (the kernels' reading)."""
    out = np.asarray(a, dtype=np.float64)
    out[np.abs(out) < float(HALF_TINY)] = 0.0
    return out


def texel_light(bundle, env, rotation=None, exposure: float = 1.0) -> np.ndarray:
    """(T, 3) float64: the environment's power in the bundle's stored texels, over pi, for a head
    turned by ``rotation`` (camera from head), times ``exposure`` and the bundle's sample_scale."""
    lights = texel_lights.environment_lights(np.asarray(env))
    r = None if rotation is None else np.asarray(rotation, dtype=np.float64)
    scale = float(bundle.meta.get("sample_scale", 1.0))
    return texel_lights.texel_light(lights, r, bundle.map_size, np.asarray(bundle.map_texels, dtype=np.int64),
                                 exposure * scale)


def brightest_texels(lp: np.ndarray, n: int) -> np.ndarray:
    """Indices (ascending) of the ``n`` texels of ``lp`` with the largest luminance (rounded to
    float32, as the light the kernels take), ties to the lower index, lit ones only."""
    if n <= 0 or not lp.size:
        return np.zeros(0, dtype=np.int64)
    from relight.colour import LUMINANCE

    lum = lp.astype(np.float32) @ LUMINANCE.astype(np.float32)
    order = np.lexsort((np.arange(lum.size), -lum))[:n]  # by luminance, descending; then by index
    return np.sort(order[lum[order] > 0]).astype(np.int64)


def stored_rank(bundle, tolerance: float) -> int | None:
    """The smallest stored rank whose validation error (``transport_errors``) meets ``tolerance``;
    None when none does (the exact path)."""
    arrays = bundle.arrays
    errors = arrays[Field.TRANSPORT_ERRORS] if Field.TRANSPORT_U in arrays else _stored_transport(bundle)[0]
    ok = np.flatnonzero(np.asarray(errors) <= tolerance)
    return int(ok[0]) + 1 if ok.size else None


def _stored_transport(bundle, rank: int | None = None):
    """(errors, u (T, K), q, q_scale, q4, q4_scale) as the bundle stores its transport (a float16
    basis of format 1-2 rounded as format 4 stores it, for ``rank``; a bundle without one
    factorised as the Relighter does on load)."""
    arrays = bundle.arrays
    if Field.TRANSPORT_U not in arrays:
        tr = transport.factorize(bundle.pixel_maps(), bundle.map_size, np.asarray(bundle.map_texels))
        return tr.rank_errors, tr.u, tr.q, tr.q_scale, tr.q4, tr.q4_scale
    v = arrays[Field.TRANSPORT_V]
    if v.dtype == np.int8:
        q, q_scale = v, arrays[Field.TRANSPORT_V_SCALE]
        q4, q4_scale = arrays.get(Field.TRANSPORT_V4), arrays.get(Field.TRANSPORT_V4_SCALE)
    else:
        q, q_scale, q4, q4_scale = transport.quantise_basis(v, min(max(rank or 1, 1), v.shape[2]))
    return arrays[Field.TRANSPORT_ERRORS], arrays[Field.TRANSPORT_U], q, q_scale, q4, q4_scale


def _basis(q, scale, pixels: slice, levels: int, nibbles: bool) -> np.ndarray:
    """(n, 3, k) float64 basis images of the stored ``q`` for the pixels ``pixels`` (a slice of
    whole 16-pixel blocks): the steps times the pixel's and channel's stored peak over ``levels``.
    ``nibbles``: q (P / 16, 3, k, 8) uint8, byte s of a block holding pixel s in its low four bits
    and pixel s + 8 in its high four, two's complement; else q (P / 16, 3, k, 16) int8."""
    blk = transport.PIXEL_BLOCK
    b0, b1 = pixels.start // blk, -(-pixels.stop // blk)
    raw = np.asarray(q[b0:b1])
    if nibbles:
        lo = (raw & 0x0F).astype(np.int64)
        hi = (raw >> 4).astype(np.int64)
        steps = np.concatenate([np.where(lo >= 8, lo - 16, lo), np.where(hi >= 8, hi - 16, hi)], axis=-1)
    else:
        steps = raw.astype(np.int64)
    steps = steps.transpose(0, 3, 1, 2).reshape(-1, 3, steps.shape[2])  # (blocks x 16, 3, k) pixel-major
    n = pixels.stop - pixels.start
    steps = steps[pixels.start - b0 * blk:][:n]
    return steps * (_halves(scale[pixels]) / levels)[:, :, None]


def exact_sum(bundle, lp: np.ndarray) -> np.ndarray:
    """(P, 3) float64: the bundle's head pixels under the texel light ``lp`` (T, 3), the full sum
    over its maps."""
    maps = bundle.pixel_maps(padded=False)  # (P, 3, T) float16 (a recipe bundle's made once)
    out = np.zeros((bundle.n_pixels, 3))
    for p0 in range(0, out.shape[0], CHUNK):
        out[p0:p0 + CHUNK] = np.einsum("pct,tc->pc", _halves(maps[p0:p0 + CHUNK]), lp)
    return out


def compact_parts(bundle, lp: np.ndarray, rank: int) -> tuple[np.ndarray, np.ndarray]:
    """((P, 3), (P, 3)) float64: the compact transport's two parts as the bundle stores it - the
    light but for its ``transport_direct`` brightest texels through the first ``rank`` basis
    images (coefficients u^T lp), and those texels exactly (their maps: the bundle's
    ``texel_rows``, for a recipe bundle made from the recipe in NumPy)."""
    p = bundle.n_pixels
    _, u, q, q_scale, q4, q4_scale = _stored_transport(bundle, rank)
    direct = brightest_texels(lp, int(bundle.meta.get("transport_direct", texel_lights.DIRECT_TEXELS)))
    rest = lp.copy()
    rest[direct] = 0.0
    coef = np.asarray(u, dtype=np.float64)[:, :rank].T @ rest  # (rank, 3)
    k8 = min(rank, q.shape[2])
    k4 = rank - k8
    if k4 and (q4 is None or q4.shape[2] < k4):
        raise ValueError(f"the bundle stores fewer transport ranks than {rank}")
    low = np.zeros((p, 3))
    for p0 in range(0, p, CHUNK):  # (CHUNK a multiple of the storage's 16-pixel blocks)
        part = slice(p0, min(p0 + CHUNK, p))
        v = _basis(q[:, :, :k8], q_scale, part, transport.V_LEVELS, nibbles=False)
        low[part] = np.einsum("pck,kc->pc", v, coef[:k8])
        if k4:
            v4 = _basis(q4[:, :, :k4], q4_scale, part, transport.V4_LEVELS, nibbles=True)
            low[part] += np.einsum("pck,kc->pc", v4, coef[k8:])
    exact = np.zeros((p, 3))
    if direct.size:
        rows = _halves(bundle.texel_rows(direct))  # (n, 3, P)
        exact = np.einsum("ncp,nc->pc", rows, lp[direct])
    return low, exact


def in_frame(bundle, vals: np.ndarray) -> np.ndarray:
    """(H, W, 3) float32 reference frame holding the head pixels' ``vals`` (P, 3), zero elsewhere."""
    w, h = bundle.frame_size
    out = np.zeros((h, w, 3), dtype=np.float32)
    out.reshape(-1, 3)[np.asarray(bundle.frame_index)] = vals
    return out


def relight_numpy(bundle, env, rotation=None, *, exposure: float = 1.0, exact: bool | None = None,
                  tolerance: float = DEFAULT_TOLERANCE) -> np.ndarray:
    """The bundle's reference frame relit by ``env`` (``rotation``, ``exposure`` as
    :meth:`relight.Relighter.relight` takes them), computed in float64 from the stored arrays
    (module docstring): a new (H, W, 3) float32 array, zero outside the head. exact : the full
    sum over the maps (True), the compact transport at the rank meeting ``tolerance`` (False; the
    exact path when no stored rank does), or the compact one whenever a rank does (None)."""
    lp = texel_light(bundle, env, rotation, exposure)
    rank = None if exact else stored_rank(bundle, tolerance)
    if rank is None:
        return in_frame(bundle, exact_sum(bundle, lp))
    low, direct = compact_parts(bundle, lp, rank)
    return in_frame(bundle, low + direct)
