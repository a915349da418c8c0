"""The compact light transport: the reflectance maps factored in direction space.

Relighting a pixel is ``sum_t maps[p, :, t] * Lp[t]`` over the maps' texels (``Lp``: the
environment as texel powers, :mod:`relight.kernels.texel_lights`). The maps' texel-space Gram
matrix gives an orthonormal basis U (texels x rank) and ``V = U^T maps``; a relight is then
``V^T (U^T Lp)`` plus, exactly, the few brightest texels of the environment (a sun): a low-rank
basis is poor at deltas, the maps' own rows are exact. The rank is chosen at capture time from
measured errors on a validation set of environments (sky, studio, window, uniform, room,
rotated, and small suns all over the hull). The basis is stored in 8 and 4 bits
(:func:`quantise_basis`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from relight.errors import InputError, NumericalError
from relight.numerics import flush_subnormal_halves, half_ceil, read_halves

from .texel_lights import (
    DIRECT_TEXELS,
    split_direct,
    validation_environments,
)

#: Pixels per block of the compact transport's layout (one work item each).
PIXEL_BLOCK = 16
#: Largest rank considered.
MAX_RANK = 256
#: The finest relight tolerance a bundle serves from its compact transport (``relight capture
#: --store-tolerance``; the Relighter's default tolerance): ranks are stored up to the first whose
#: validation error, the storage's rounding noise included, meets it. Finer tolerances use the exact maps.
STORE_TOLERANCE = 0.01
#: Ranks are projected up to the one meeting this share of the tolerance (plus 16) before the
#: rounding noise is measured and only the ranks the tolerance needs are kept.
STORE_MARGIN = 0.5
#: Steps of the 8-bit basis: values are stored as round(127 v / max|v|) per pixel and channel.
V_LEVELS = 127
#: The leading ranks stored in 8 bits; the rest in 4 bits (steps of +-V4_LEVELS) with a step of
#: their own per pixel and channel. The later ranks are small next to the first (the light's
#: large-scale shading): one 8-bit step for all ranks rounded them as coarsely as 4 bits with
#: their own step do. Measured on a 960x540 capture against its exact maps: at every rank from
#: 32 to 96 the relight error with 16 ranks in 8 bits and the rest in 4 was at or below that of
#: all ranks in 8 bits with one step (rank 46: 0.93 % vs 0.96 %), in 33-40 % fewer bytes.
HEAD_RANKS = 16
V4_LEVELS = 7
#: Largest basis-image value kept in float16 on the way to storage (half of float16's 65504,
#: room for the peak's rounding up): brighter projections are scaled by a power of two, which the
#: basis u takes back (:func:`stored_transport`).
V_HALF_PEAK = 2.0 ** 15


def syrk_sum(blocks, t: int) -> np.ndarray:
    """(t, t) float64 sum of ``b.T @ b`` over float32 blocks ``b`` (n, t) by BLAS's symmetric
    rank-k update (half the multiplications of a product). BLAS takes Fortran order: a block in
    either order is handed over without a copy (C-ordered as its transpose)."""
    from scipy.linalg.blas import ssyrk

    g = np.zeros((t, t))
    for b in blocks:
        # Upper triangle of b.T @ b: trans=1 on b itself, or trans=0 on b.T (Fortran-ordered).
        g += ssyrk(1.0, b, trans=1, lower=0) if b.flags.f_contiguous else ssyrk(1.0, b.T, trans=0, lower=0)
    upper = np.triu(g)
    return upper + np.triu(upper, 1).T


def gram(maps: np.ndarray, chunk: int = 4096, n_texels: int | None = None) -> np.ndarray:
    """(T, T) float64 texel Gram matrix of pixel-major maps (P, 3, Tp) over their first
    ``n_texels`` texels (default all Tp), accumulated in float32 pixel blocks."""
    p, _, t_pad = maps.shape
    t = t_pad if n_texels is None else int(n_texels)
    return syrk_sum((np.asarray(maps[p0:p0 + chunk, :, :t], dtype=np.float32).reshape(-1, t)
                      for p0 in range(0, p, chunk)), t)


def gram_rows(rows: np.ndarray, chunk: int = 4096) -> np.ndarray:
    """(T, T) float64 texel Gram matrix of texel-major maps (T, 3, P) (the same as :func:`gram`
    of their pixel-major form), accumulated in float32 pixel blocks."""
    t, _, p = rows.shape
    return syrk_sum((np.asarray(rows[:, :, p0:p0 + chunk], dtype=np.float32).reshape(t, -1).T
                      for p0 in range(0, p, chunk)), t)


@dataclass
class Transport:
    """The compact light transport of a bundle.

    u : (T, K) float32 orthonormal texel basis. v : (P / 16, 3, Kp, 16) float16, the maps
    projected on it in blocks of 16 pixels (pixels and ranks zero padded to multiples of 16), or
    None when only their storage is held (:meth:`basis` makes v): ``q`` / ``q_scale`` the first
    ranks (at most HEAD_RANKS) in 8 bits, ``q4`` / ``q4_scale`` the rest in 4 bits
    (:func:`quantise_basis`; None for a bundle of format 3, which holds every rank in 8 bits).
    rank_errors : (K,) float32, the largest relative L2 error over the validation environments at
    each rank (with ``direct`` exact texels), the storage's rounding included. sigma : (K,)
    singular values.
    """

    u: np.ndarray
    v: np.ndarray | None  # None: only the storage is held (see basis())
    rank_errors: np.ndarray
    sigma: np.ndarray
    direct: int = DIRECT_TEXELS
    q: np.ndarray | None = None  # 8-bit storage of v's first ranks (quantise_basis), when made so
    q_scale: np.ndarray | None = None
    q4: np.ndarray | None = None  # 4-bit storage of the rest (two pixels a byte)
    q4_scale: np.ndarray | None = None

    def basis(self) -> np.ndarray:
        """v, dequantised from the storage on first use (a Relighter packs its kernel's layout
        straight from that storage: :func:`relight.kernels.relight_packing.pack_quantised`)."""
        if self.v is None:
            self.v = dequantise_basis(self.q, self.q_scale, self.q4, self.q4_scale)
        return self.v

    def rank_for(self, tolerance: float) -> int | None:
        """Smallest stored rank meeting ``tolerance`` on the validation set, or None."""
        ok = np.flatnonzero(self.rank_errors <= tolerance)
        return int(ok[0]) + 1 if ok.size else None


def _quantise(vf: np.ndarray, levels: int) -> tuple[np.ndarray, np.ndarray]:
    """(int8 steps (nb, 3, k, 16) in [-levels, levels], step scale (nb, 3, 16) float16: the peak
    |v| over the ranks per pixel and channel, rounded up to a half)."""
    nb, _, k, blk = vf.shape
    peak = np.abs(vf).max(axis=2) if k else np.zeros((nb, 3, blk), np.float32)
    scale = half_ceil(peak)
    s = scale.astype(np.float32)
    inv = np.where(s > 0, levels / np.where(s > 0, s, 1.0), 0.0).astype(np.float32)
    return np.clip(np.rint(vf * inv[:, :, None, :]), -levels, levels).astype(np.int8), scale


def quantise_basis(v: np.ndarray, rank: int, head: int = HEAD_RANKS):
    """Storage of blocked basis images v (P / 16, 3, Kp, 16), first ``rank`` used: (q int8
    (P / 16, 3, min(rank, head), 16), scale (P, 3) float16, q4 uint8 (P / 16, 3, rank - head, 8)
    or None, scale4 (P, 3) float16 or None) with ``v ~ q x scale / V_LEVELS`` for the first
    ``head`` ranks and ``v ~ q4 x scale4 / V4_LEVELS`` for the rest; q4 holds pixel s of a block
    in the low four bits of byte s and pixel s + 8 in the high four (two's complement)."""
    nb, _, kp, blk = v.shape
    vf = read_halves(v[:, :, :rank]) if v.dtype == np.float16 else np.asarray(v[:, :, :rank], np.float32)
    k8 = min(rank, head)
    q, scale = _quantise(vf[:, :, :k8], V_LEVELS)
    per_pixel = lambda sc: np.ascontiguousarray(sc.transpose(0, 2, 1).reshape(nb * blk, 3))  # noqa: E731
    if rank <= k8:
        return q, per_pixel(scale), None, None
    q4, scale4 = _quantise(vf[:, :, k8:], V4_LEVELS)
    half = blk // 2
    packed = ((q4[..., :half].view(np.uint8) & 0x0F) | (q4[..., half:].view(np.uint8) << 4)).astype(np.uint8)
    return q, per_pixel(scale), packed, per_pixel(scale4)


def unpack_nibbles(q4: np.ndarray) -> np.ndarray:
    """(P / 16, 3, k, 16) int8 steps of :func:`quantise_basis`'s 4-bit storage."""
    b = np.asarray(q4).view(np.int8)
    lo = np.left_shift(b, 4).astype(np.int8) >> 4  # sign-extend the low four bits
    return np.concatenate([lo, b >> 4], axis=-1)


def basis_scale(q: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """(P / 16, 3, 16) float16 stored peak |v| (the step times the levels) of the basis ``q``
    (P / 16, 3, K, 16), or (P / 16, 3, K, 8) for 4 bits, per pixel and channel, from its
    ``scale`` (P, 3) (checked against q's shape)."""
    nb = q.shape[0]
    blk = PIXEL_BLOCK
    if scale.shape != (nb * blk, 3):
        raise InputError(f"transport basis scale of shape {scale.shape}: expected ({nb * blk}, 3); capture the "
                         "bundle again")
    return np.asarray(scale, np.float16).reshape(nb, blk, 3).transpose(0, 2, 1)


def basis_units(q: np.ndarray, scale: np.ndarray, levels: int = V_LEVELS) -> np.ndarray:
    """(P / 16, 3, 16) float32 value of one step of the stored basis ``q`` per pixel and
    channel (:func:`basis_scale` / ``levels``)."""
    return basis_scale(q, scale).astype(np.float32) / levels


def dequantise_basis(q: np.ndarray, scale: np.ndarray, q4: np.ndarray | None = None,
                     scale4: np.ndarray | None = None) -> np.ndarray:
    """float16 blocked basis images (P / 16, 3, Kp, 16) (ranks zero padded to a multiple of 16)
    of :func:`quantise_basis` storage."""
    from .layout import padded_texels

    nb, _, k8, blk = q.shape
    k4 = 0 if q4 is None else q4.shape[2]
    s = basis_units(q, scale)
    s4 = None if q4 is None else basis_units(q4, scale4, V4_LEVELS)
    out = np.zeros((nb, 3, padded_texels(k8 + k4), blk), dtype=np.float16)
    for b0 in range(0, nb, 4096):
        out[b0:b0 + 4096, :, :k8] = np.asarray(q[b0:b0 + 4096], np.float32) * s[b0:b0 + 4096, :, None, :]
        if k4:
            out[b0:b0 + 4096, :, k8:k8 + k4] = (unpack_nibbles(q4[b0:b0 + 4096]).astype(np.float32)
                                                 * s4[b0:b0 + 4096, :, None, :])
    return flush_subnormal_halves(out)


def leading_eigenpairs(g: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """The ``k`` largest eigenvalues of the symmetric (T, T) Gram matrix ``g``, largest first and
    clipped at 0 (rounding leaves tiny negatives), and their (T, k) eigenvectors. Only those are
    computed (LAPACK's MRRR driver), the rest are never used."""
    from scipy.linalg import eigh

    n = g.shape[0]
    w, vecs = eigh(g, subset_by_index=[n - k, n - 1], driver="evr")
    order = np.argsort(w)[::-1]
    return np.clip(w[order], 0.0, None), vecs[:, order]


def factorize(maps: np.ndarray, map_size, texels: np.ndarray, *, max_rank: int = MAX_RANK,
              direct: int = DIRECT_TEXELS, store_tolerance: float = STORE_TOLERANCE,
              texel_major: bool = False) -> Transport:
    """The compact transport of pixel-major maps (P, 3, Tp) over ``texels`` (T <= Tp), or of
    texel-major maps (T, 3, P) with ``texel_major`` (a capture holds only those).

    Ranks are kept up to the first meeting ``store_tolerance`` on the validation set (at most
    ``max_rank``). The basis images are rounded as a bundle stores them (8 bits for the first
    HEAD_RANKS, 4 for the rest: :func:`quantise_basis`; ``Transport.q`` ... hold that form) and
    ``rank_errors`` include that rounding's noise (its expected energy added to the
    truncation's), so a rank meeting a tolerance meets it as stored.
    """
    n_t = texels.size
    g = gram_rows(maps) if texel_major else gram(maps, n_texels=n_t)
    k_all = min(max_rank, n_t)
    sig2, vecs = leading_eigenpairs(g, k_all)
    envs = [lp for _, lp in validation_environments(map_size, texels)]
    total = np.zeros(len(envs))
    resid = np.zeros((k_all, len(envs)))
    coef = np.zeros((k_all, 3, len(envs)))
    for e, lp in enumerate(envs):
        # Energies from the Gram itself (sum over channels of lp^T G lp): the components beyond
        # k_all need not be known, the tail past k is the whole minus the first k.
        total[e] = float(np.sum(lp * (g @ lp)))
        _, rest = split_direct(lp, direct)
        coef[:, :, e] = vecs.T @ rest
        a2 = np.sum(sig2[:, None] * coef[:, :, e] ** 2, axis=1)  # energy per leading component
        resid[:, e] = max(float(np.sum(rest * (g @ rest))), 0.0) - np.cumsum(a2)  # left after k+1 components
    ok = total > 0
    errors = (np.sqrt(np.clip(resid[:, ok], 0.0, None) / total[ok]).max(axis=1) if ok.any()
              else np.zeros(k_all))
    met = np.flatnonzero(errors <= STORE_MARGIN * store_tolerance)
    cap = min(k_all, (int(met[0]) + 1 if met.size else k_all) + 16)  # room for the rounding noise
    u = vecs[:, :cap].astype(np.float32)
    p = maps.shape[2] if texel_major else maps.shape[0]
    v = np.zeros((p, 3, cap), dtype=np.float32)
    for p0 in range(0, p, 4096):
        if texel_major:
            blk = np.asarray(maps[:, :, p0:p0 + 4096], dtype=np.float32)  # (T, 3, n)
            v[p0:p0 + blk.shape[2]] = np.einsum("tcn,tk->nck", blk, u, optimize=True)
        else:
            blk = np.asarray(maps[p0:p0 + 4096, :, :n_t], dtype=np.float32)
            # One GEMM over (pixels x channels) rows (a 3-D matmul would be 4096 small ones).
            v[p0:p0 + blk.shape[0]] = (blk.reshape(-1, n_t) @ u).reshape(blk.shape[0], 3, cap)
    tr = stored_transport(v, u, cap, sig2, resid, total, coef, direct)
    k = tr.rank_for(store_tolerance)
    if k is None or k == cap:
        return tr
    return stored_transport(v, u, k, sig2, resid, total, coef, direct)


def stored_transport(v_all: np.ndarray, u: np.ndarray, k: int, sig2, resid, total, coef, direct) -> Transport:
    """The transport of rank k as a bundle stores it, from projections v_all (P, 3, >= k) on the
    basis u (T, >= k): basis images in 8 and 4 bits, and each rank's error with their rounding noise
    (resid (ranks, E) the truncation's residual energy, total (E,) each validation relight's
    energy, coef (ranks, 3, E) its coefficients; see :func:`factorize`)."""
    from .layout import padded_texels

    p = v_all.shape[0]
    kp = padded_texels(k)
    nb = -(-p // PIXEL_BLOCK)
    # The projections go through float16 (each pixel's peak is stored as a half): a power of two
    # taken off them and put on the basis u keeps every peak in range and every product v u
    # exactly as it was (bright maps project to ~sqrt(T) times their brightest texel).
    peak = float(np.abs(v_all[:, :, :k]).max(initial=0.0)) if k else 0.0
    if not np.isfinite(peak):
        raise NumericalError("non-finite transport projections; this is a bug, please report it")
    shift = int(np.ceil(np.log2(peak / V_HALF_PEAK))) if peak > V_HALF_PEAK else 0
    v = np.zeros((nb * PIXEL_BLOCK, 3, kp), dtype=np.float16)
    v[:p, :, :k] = v_all[:, :, :k] * np.float32(2.0 ** -shift) if shift else v_all[:, :, :k]
    if shift:
        u = u * np.float32(2.0 ** shift)
        coef = coef * 2.0 ** shift  # the validation lights' coefficients on the scaled basis
    flush_subnormal_halves(v)
    v = np.ascontiguousarray(v.reshape(nb, PIXEL_BLOCK, 3, kp).transpose(0, 2, 3, 1))
    q, q_scale, q4, q4_scale = quantise_basis(v, k)
    # The rounding's expected energy per unit coefficient, per rank and channel: a step s
    # rounds with variance s^2 / 12, summed over the pixels (see factorize).
    noise_unit = np.zeros((k, 3))
    noise_unit[:q.shape[2]] = ((np.asarray(q_scale, np.float64) / V_LEVELS) ** 2 / 12.0).sum(axis=0)
    if q4 is not None:
        noise_unit[q.shape[2]:] = ((np.asarray(q4_scale, np.float64) / V4_LEVELS) ** 2 / 12.0).sum(axis=0)
    errors = np.zeros(k)
    for e in np.flatnonzero(total > 0):
        noise = np.cumsum(np.sum(coef[:k, :, e] ** 2 * noise_unit, axis=1))
        errors = np.maximum(errors, np.sqrt(np.clip(resid[:k, e], 0.0, None) / total[e] + noise / total[e]))
    # Only the storage: the basis images are dequantised where something reads them (basis()).
    return Transport(u=np.ascontiguousarray(u[:, :k]), v=None, rank_errors=errors.astype(np.float32),
                     sigma=np.sqrt(sig2[:k]).astype(np.float32), direct=direct, q=q, q_scale=q_scale,
                     q4=q4, q4_scale=q4_scale)
