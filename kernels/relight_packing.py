"""The relight kernels' operands, packed from a bundle's storage and from the light (host side,
moving bytes): what :class:`relight.kernels.relighter.Relighter` hands ``kernels/relight.cl``.

The compact kernel's: the bundle's stored transport read (:func:`read_transport`), its chosen
rank packed into the kernel's 32-pixel blocks (:func:`pack_basis`: the 8-bit leading ranks by
:func:`pack_quantised`, the 4-bit later ones by :func:`pack_nibbles`; :func:`unpack_basis`
reads them back for references) and the per-call coefficients (:func:`compact_coefficients`).
The exact kernel's: the maps padded to whole blocks of texels (:func:`exact_maps`) and the
light in its order (:func:`exact_light_blocks`).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from relight.errors import InputError
from relight.numerics import flush_subnormal_halves, read_halves

from . import texel_lights, transport
from .bundle_format import Field
from .runtime import aligned_zeros

#: Pixels per compact work item and texels per exact block (the kernels' 64-byte loads of 32 halves).
LANES = 32


def read_transport(bundle) -> transport.Transport:
    """The bundle's compact transport as it stores it (format 3 and later: the 8-bit basis and, format
    4, the 4-bit later ranks kept as stored, their shapes checked; format 1-2: the float16 basis),
    or factorised from its maps when it stores none."""
    arrays = bundle.arrays
    if Field.TRANSPORT_U in arrays:
        v = arrays[Field.TRANSPORT_V]
        q = q_scale = q4 = q4_scale = None
        if v.dtype == np.int8:  # 8-bit storage (format 3 and later): dequantised only where needed
            if Field.TRANSPORT_V_SCALE not in arrays:
                raise InputError("the bundle's 8-bit transport basis has no transport_v_scale: capture it again")
            q, q_scale = v, np.asarray(arrays[Field.TRANSPORT_V_SCALE])
            transport.basis_scale(q, q_scale)  # its shape checked now
            v = None
            if Field.TRANSPORT_V4 in arrays:  # format 4: the later ranks in 4 bits
                q4, q4_scale = arrays[Field.TRANSPORT_V4], np.asarray(arrays.get(Field.TRANSPORT_V4_SCALE, np.zeros(0)))
                if q4.dtype != np.uint8 or q4.ndim != 4 or q4.shape[:2] != q.shape[:2] or q4.shape[3] * 2 != 16:
                    raise InputError(f"the bundle's 4-bit transport basis has shape {q4.shape} ({q4.dtype}): "
                                     "capture it again")
                transport.basis_scale(q4, q4_scale)
        return transport.Transport(u=np.asarray(arrays[Field.TRANSPORT_U]), v=v,
                                   rank_errors=np.asarray(arrays[Field.TRANSPORT_ERRORS]),
                                   sigma=np.asarray(arrays.get(Field.TRANSPORT_SIGMA, np.zeros(1))),
                                   direct=int(bundle.meta.get("transport_direct", texel_lights.DIRECT_TEXELS)),
                                   q=q, q_scale=q_scale, q4=q4, q4_scale=q4_scale)
    return transport.factorize(bundle.pixel_maps(), bundle.map_size, np.asarray(bundle.map_texels))


def _kernel_blocks(steps: np.ndarray, kp: int, n_pix: int) -> np.ndarray:
    """(ceil(P / 32), kp, 3, 2, 16) int8, 64-byte aligned: stored steps (P / 16, 3, K, 16) in the
    compact kernel's 32-pixel blocks (ranks past K and pixels past P zero)."""
    nb, _, k, blk = steps.shape
    half = LANES // blk  # 16-pixel storage blocks per 32-pixel kernel block
    k = min(k, kp)
    blocks = -(-n_pix // LANES)
    if not n_pix <= nb * blk <= blocks * LANES:
        raise InputError(f"the stored basis holds {nb * blk} pixels for a face of {n_pix}: capture the bundle again")
    out = aligned_zeros((blocks, kp, 3, half, blk), np.int8)
    full, rem = divmod(nb, half)
    out[:full, :k] = np.asarray(steps[:full * half, :, :k]).reshape(full, half, 3, k, blk).transpose(0, 3, 2, 1, 4)
    if rem:  # a last kernel block with part of its storage
        out[full, :k, :, :rem] = np.asarray(steps[full * half:, :, :k]).transpose(2, 1, 0, 3)
    return out


def _kernel_units(scale16: np.ndarray, n_pix: int) -> np.ndarray:
    """(ceil(P / 32), 3, 32) float16, 64-byte aligned: the stored peak of each pixel and channel
    (``scale16`` (P / 16, 3, 16), :func:`relight.kernels.transport.basis_scale`) in the kernel's
    blocks; zero past P and for subnormal halves (the kernel reads those as zero)."""
    nb, _, blk = scale16.shape
    half = LANES // blk
    blocks = -(-n_pix // LANES)
    units = aligned_zeros((blocks, 3, LANES), np.float16)
    udest = units.reshape(blocks, 3, half, blk)
    full, rem = divmod(nb, half)
    udest[:full] = scale16[:full * half].reshape(full, half, 3, blk).transpose(0, 2, 1, 3)
    if rem:
        udest[full, :, :rem] = scale16[full * half:].transpose(1, 0, 2)
    if n_pix % LANES:  # the storage's padding pixels: zero (their bytes are zero too)
        units[-1, :, n_pix % LANES:] = 0
    if not np.isfinite(units).all():
        raise InputError("the bundle's transport basis has non-finite step sizes: capture the bundle again")
    return flush_subnormal_halves(units)


def pack_quantised(q: np.ndarray, scale: np.ndarray, kp: int, n_pix: int) -> tuple[np.ndarray, np.ndarray]:
    """The compact kernel's 8-bit operands from a bundle's storage of the leading ranks (q
    (P / 16, 3, K, 16) int8, scale (P, 3): :func:`relight.kernels.transport.quantise_basis`), by
    moving bytes only:

    q8 : (ceil(P / 32), kp, 3, 32) int8, 64-byte aligned - one work item's 32 pixels of one basis
    image contiguous, its whole block one stream (ranks past K and pixels past P zero);
    peaks : (ceil(P / 32), 3, 32) float16, each pixel's and channel's stored peak (a step is
    peak / V_LEVELS: the kernel's coefficients carry the division).
    """
    peaks = _kernel_units(transport.basis_scale(q, scale), n_pix)  # shape checked
    q8 = _kernel_blocks(q, kp, n_pix)
    return q8.reshape(q8.shape[0], kp, 3, LANES), peaks


def pack_nibbles(q4: np.ndarray, scale4: np.ndarray, kp: int, n_pix: int) -> tuple[np.ndarray, np.ndarray]:
    """The compact kernel's 4-bit operands from a bundle's storage of the later ranks (q4
    (P / 16, 3, K, 8) uint8, scale4 (P, 3)):

    q4k : (ceil(P / 32), kp, 3, 16) uint8 - byte i of a block's basis image holds pixel i in its
    low four bits and pixel i + 16 in its high four (two's complement);
    peaks : (ceil(P / 32), 3, 32) float16, each pixel's and channel's stored peak (a step is
    peak / V4_LEVELS).
    """
    peaks = _kernel_units(transport.basis_scale(q4, scale4), n_pix)
    steps = _kernel_blocks(transport.unpack_nibbles(q4), kp, n_pix)  # (B, kp, 3, 2, 16)
    out = aligned_zeros(steps.shape[:3] + (LANES // 2,), np.uint8)
    lo, hi = steps[:, :, :, 0].view(np.uint8), steps[:, :, :, 1].view(np.uint8)
    np.bitwise_or(lo & 0x0F, hi << 4, out=out)
    return out, peaks


class PackedBasis(NamedTuple):
    """The chosen rank of the basis as the compact kernel reads it (:func:`pack_basis`): ``rank8``
    leading ranks in 8 bits (``q8``, ``units``: :func:`pack_quantised`) and ``rank4`` later ranks
    in 4 bits (``q4``, ``units4``: :func:`pack_nibbles`; one zero block of each when rank4 is 0)."""

    rank8: int
    rank4: int
    q8: np.ndarray
    units: np.ndarray
    q4: np.ndarray
    units4: np.ndarray


def pack_basis(tr: transport.Transport, rank: int | None, n_pix: int) -> PackedBasis:
    """Only the chosen ``rank`` (None: the exact path, no rank) of the basis, in the kernel's
    32-pixel blocks (all ranks of one block in one run of memory: one stream per work item,
    measured 1.5x faster than a run per colour channel), as the bundle stores it - the leading
    ranks in 8 bits, the rest in 4, each with a step per pixel and channel: the kernel streams
    nothing it does not use. A bundle of format 1-2 (float16 basis) is rounded here as format 4
    stores it (its rank errors did not count that noise)."""
    q, q_scale, q4, q4_scale = tr.q, tr.q_scale, tr.q4, tr.q4_scale
    if q is None:
        q, q_scale, q4, q4_scale = transport.quantise_basis(tr.v, min(max(rank or 1, 1), tr.v.shape[2]))
    rank8 = min(rank or 0, q.shape[2])
    rank4 = (rank or 0) - rank8
    if q4 is None and rank4 or q4 is not None and rank4 > q4.shape[2]:
        raise InputError(f"the bundle stores fewer transport ranks than its errors ({rank}): capture it again")
    q8, units = pack_quantised(q, q_scale, max(rank8, 1), n_pix)
    if rank4:
        q4k, units4 = pack_nibbles(q4, q4_scale, rank4, n_pix)
    else:
        q4k = aligned_zeros((1, 1, 3, LANES // 2), np.uint8)
        units4 = aligned_zeros((1, 3, LANES), np.float16)
    return PackedBasis(rank8, rank4, q8, units, q4k, units4)


def unpack_basis(basis: PackedBasis, n_pix: int) -> np.ndarray:
    """(P, 3, rank8 + rank4) float32: the packed basis images as the kernel reads them (steps x
    their step size), for references and tests."""
    q8, units, q4, units4 = basis.q8, basis.units, basis.q4, basis.units4
    b = q8.shape[0]
    out = np.zeros((b, LANES, 3, basis.rank8 + basis.rank4), dtype=np.float32)
    k8 = basis.rank8
    step = read_halves(units)[:, None] / transport.V_LEVELS
    out[..., :k8] = (q8[:, :k8].astype(np.float32) * step).transpose(0, 3, 2, 1)
    if basis.rank4:
        steps = transport.unpack_nibbles(q4[:, :basis.rank4]).astype(np.float32)
        step = read_halves(units4)[:, None] / transport.V4_LEVELS
        out[..., k8:] = (steps * step).transpose(0, 3, 2, 1)
    return out.reshape(-1, 3, out.shape[3])[:n_pix]


def compact_coefficients(coef: np.ndarray, rank8: int, rank4: int) -> np.ndarray:
    """(rank8 + rank4, 3) float32: the basis coefficients as the compact kernel takes them -
    divided by the levels of their storage (a step is the stored peak over V_LEVELS, or over
    V4_LEVELS for the 4-bit ranks), so the kernel multiplies by the peak, a stored half, exactly."""
    c = np.asarray(coef[:rank8 + rank4], dtype=np.float64).copy()
    c[:rank8] /= transport.V_LEVELS
    c[rank8:] /= transport.V4_LEVELS
    return c.astype(np.float32)


def exact_maps(bundle, t_pad: int, t_exact: int) -> np.ndarray:
    """(P, 3, t_exact) float16, 64-byte aligned: the bundle's pixel-major maps (``t_pad`` stored
    texels) for the exact kernel, padded with zero texels to ``t_exact`` (a multiple of LANES) and
    checked finite on the way (subnormal halves flushed to zero, as the kernel reads them)."""
    n_pix = bundle.n_pixels
    maps = aligned_zeros((n_pix, 3, t_exact), np.float16)
    # A recipe bundle's maps are made once, all pixels together (the per-call set-up of
    # the maps - the spline's weights, the vertices' visibility - is not repeated).
    made = None if bundle.has_maps else bundle.pixel_maps()
    for p0 in range(0, n_pix, 8192):
        blk = made[p0:p0 + 8192] if made is not None else bundle.pixel_maps(slice(p0, p0 + 8192))
        if not np.isfinite(blk).all():
            raise InputError("the bundle's reflectance maps hold non-finite values: capture the bundle again")
        maps[p0:p0 + 8192, :, :t_pad] = flush_subnormal_halves(blk.copy())
    return maps


def exact_light_blocks(lp: np.ndarray, padded: int) -> tuple[np.ndarray, np.ndarray]:
    """(n, 3) texel light -> ((3 * padded,) float32 in the exact kernel's order, lit block indices).

    Per channel, per 32-texel block: the 16 even texels, then the 16 odd ones (the kernel's
    low and high halves of each packed pair).
    """
    out = np.zeros((3, padded), dtype=np.float32)
    out[:, :lp.shape[0]] = lp.T
    lit = np.flatnonzero(np.abs(out).reshape(3, -1, LANES).sum(axis=(0, 2)) > 0)
    return out.reshape(3, -1, LANES // 2, 2).transpose(0, 1, 3, 2).ravel(), lit
