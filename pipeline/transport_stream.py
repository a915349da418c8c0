"""The capture's compact light transport (stage 6), factored while the maps are made chunk by
chunk from the recipe, never all held: a basis from an even subsample of pixels, then every
pixel's maps projected on it and each rank's validation error measured on all of them. The
transport, its storage and the in-memory factorisation: :mod:`relight.kernels.transport`."""

from __future__ import annotations

import numpy as np

from relight.kernels.texel_lights import DIRECT_TEXELS, split_direct, validation_environments
from relight.kernels.transport import (
    MAX_RANK,
    STORE_MARGIN,
    STORE_TOLERANCE,
    Transport,
    leading_eigenpairs,
    stored_transport,
    syrk_sum,
)

#: Pixels whose maps make the basis of a streamed factorisation (:func:`factorize_stream`): a
#: face's maps are highly redundant across neighbouring pixels, and the ranks are then judged on
#: every pixel.
GRAM_PIXELS = 16384
#: Pixels per chunk of the streamed factorisation (each chunk's maps are made, used, dropped).
STREAM_CHUNK = 8192


def _chunk_maps(make, index: np.ndarray, n_t: int, chunk: int):
    """The texel-major maps (T, 3, n) float32 of the pixels ``index``, made ``chunk`` at a time."""
    for c0 in range(0, index.size, chunk):
        yield np.asarray(make(index[c0:c0 + chunk])[:n_t], dtype=np.float32)  # (T, 3, n)


def _kept_gram_blocks(make, sub: np.ndarray, n_t: int, chunk: int, sub_maps: np.ndarray):
    """The Gram blocks (3n, T) of the subsample ``sub``'s maps, each kept in ``sub_maps``
    (T, 3, len(sub)) float16 on the way (for the second pass)."""
    for c0, m in zip(range(0, sub.size, chunk), _chunk_maps(make, sub, n_t, chunk), strict=True):
        sub_maps[:, :, c0:c0 + m.shape[2]] = m
        yield m.reshape(n_t, -1).T  # (3n, T) Fortran-ordered: no copy for BLAS


def _subsample_cap(g: np.ndarray, sig2: np.ndarray, vecs: np.ndarray, envs, rests, k_all: int,
                   store_tolerance: float) -> int:
    """How many ranks are worth projecting on: the subsample's own errors (its Gram ``g``, its
    eigenpairs) bound them, with room (16 more: the whole face may need more than its subsample)."""
    est = np.zeros(k_all)
    for lp, rest in zip(envs, rests, strict=True):
        total = float(np.sum(lp * (g @ lp)))
        if total > 0:
            a2 = np.sum(sig2[:, None] * (vecs.T @ rest) ** 2, axis=1)
            tail = max(float(np.sum(rest * (g @ rest))), 0.0) - np.cumsum(a2)
            est = np.maximum(est, np.sqrt(np.clip(tail, 0.0, None) / total))
    met = np.flatnonzero(est <= STORE_MARGIN * store_tolerance)
    return min(k_all, (int(met[0]) + 1 if met.size else k_all) + 16)


def _second_pass_maps(make, sub: np.ndarray, sub_maps: np.ndarray, rest_pix: np.ndarray, n_t: int, chunk: int):
    """(pixel ids (n,), their maps (T, 3, n) float32) of every pixel: the subsample's kept maps
    first, then the other pixels' made again."""
    for c0 in range(0, sub.size, chunk):
        yield sub[c0:c0 + chunk], np.asarray(sub_maps[:, :, c0:c0 + chunk], dtype=np.float32)
    for c0, m in zip(range(0, rest_pix.size, chunk), _chunk_maps(make, rest_pix, n_t, chunk), strict=True):
        yield rest_pix[c0:c0 + m.shape[2]], m


def _project_all(chunks, u: np.ndarray, lights: np.ndarray, rest_l: np.ndarray, n_pix: int, progress):
    """Every pixel's maps (``chunks`` of (ids, maps (T, 3, n))) projected on the basis u (T, cap),
    and the validation relights' energies: (v (P, 3, cap) float32; per environment the exact
    relights' energy total (E,), the rank part's target energy rr (3, E), V^T r (cap, 3, E) and
    V^T V (3, cap, cap), float64 sums). lights / rest_l : (T, 3, E) the environments and what
    the rank part relights of them."""
    n_t, cap = u.shape
    n_env = lights.shape[2]
    v = np.zeros((n_pix, 3, cap), dtype=np.float32)
    total = np.zeros(n_env)
    rr = np.zeros((3, n_env))
    vtr = np.zeros((cap, 3, n_env))
    vtv = np.zeros((3, cap, cap))
    ut = np.ascontiguousarray(u.T)
    lights_t = np.ascontiguousarray(lights.transpose(1, 2, 0))  # (3, E, T)
    rest_t = np.ascontiguousarray(rest_l.transpose(1, 2, 0))
    for index, m in chunks:
        n = m.shape[2]
        vc = (ut @ m.reshape(n_t, 3 * n)).reshape(cap, 3, n)
        v[index] = vc.transpose(2, 1, 0)
        for c in range(3):  # per channel, as BLAS products (m[:, c] a strided view BLAS reads)
            mc = m[:, c]  # (T, n)
            full = lights_t[c] @ mc  # (E, n) the exact relights of this chunk
            total += np.einsum("ep,ep->e", full, full, dtype=np.float64)
            r = rest_t[c] @ mc  # what the rank part must relight
            rr[c] += np.einsum("ep,ep->e", r, r, dtype=np.float64)
            vcc = vc[:, c]  # (cap, n)
            vtr[:, c] += vcc @ r.T
            vtv[c] += vcc @ vcc.T
        if progress is not None:
            progress(n)
    return v, total, rr, vtr, vtv


def _rank_residuals(coef: np.ndarray, rr: np.ndarray, vtr: np.ndarray, vtv: np.ndarray) -> np.ndarray:
    """(cap, E) residual energy of each rank: ||r||^2 - 2 c.(V^T r) + c^T (V^T V) c over the first
    k ranks (coef (cap, 3, E) the validation lights' coefficients; see :func:`_project_all`)."""
    cap, _, n_env = coef.shape
    resid = np.zeros((cap, n_env))
    for e in range(n_env):
        for c in range(3):
            cc = coef[:, c, e]
            cross = np.cumsum(cc * vtr[:, c, e])
            quad = np.diag(np.cumsum(np.cumsum(cc[:, None] * vtv[c] * cc[None, :], axis=0), axis=1))
            resid[:, e] += rr[c, e] - 2.0 * cross + quad
    return resid


def factorize_stream(make, n_pix: int, map_size, texels: np.ndarray, *, max_rank: int = MAX_RANK,
                     direct: int = DIRECT_TEXELS, store_tolerance: float = STORE_TOLERANCE,
                     gram_pixels: int = GRAM_PIXELS, chunk: int = STREAM_CHUNK, progress=None) -> Transport:
    """The compact transport of maps made chunk by chunk - ``make(index)`` returns the
    texel-major maps (Tp, 3, n) float32 of the pixels ``index`` (the layout the maps kernel
    writes and the projections read) - without ever holding all of them.

    The basis comes from the texel Gram matrix of an even subsample of at most ``gram_pixels``
    pixels; then every pixel's maps are projected on it, and each rank's validation error (the
    environments of :func:`relight.kernels.texel_lights.validation_environments`, ``direct`` texels
    exact) is measured on all
    pixels as the residual of the projection, the storage's rounding noise added as in
    :func:`relight.kernels.transport.factorize`. Ranks are stored up to the first meeting ``store_tolerance``.
    ``progress(n)`` is called with the pixels done in the second pass.
    """
    n_t = texels.size
    step = max(1, -(-n_pix // max(gram_pixels, 1)))
    sub = np.arange(0, n_pix, step)
    # The subsample's maps are kept (float16, at most gram_pixels of them) for the second pass.
    sub_maps = np.empty((n_t, 3, sub.size), dtype=np.float16)
    g = syrk_sum(_kept_gram_blocks(make, sub, n_t, chunk, sub_maps), n_t)
    k_all = min(max_rank, n_t)
    sig2, vecs = leading_eigenpairs(g, k_all)
    envs = [lp for _, lp in validation_environments(map_size, texels)]
    rests = [split_direct(lp, direct)[1] for lp in envs]
    cap = _subsample_cap(g, sig2, vecs, envs, rests, k_all, store_tolerance)
    u = vecs[:, :cap].astype(np.float32)
    lights = np.ascontiguousarray(np.stack(envs, axis=2).astype(np.float32))  # (T, 3, E)
    rest_l = np.ascontiguousarray(np.stack(rests, axis=2).astype(np.float32))
    coef = np.einsum("tk,tce->kce", u.astype(np.float64), rest_l.astype(np.float64))  # (cap, 3, E)
    rest_pix = np.setdiff1d(np.arange(n_pix), sub, assume_unique=True)
    v, total, rr, vtr, vtv = _project_all(_second_pass_maps(make, sub, sub_maps, rest_pix, n_t, chunk), u, lights,
                                          rest_l, n_pix, progress)
    resid = _rank_residuals(coef, rr, vtr, vtv)
    # Every projected rank stored, its rounding noise in the errors; then only the ranks the
    # tolerance needs (fewer ranks: a smaller step per pixel, so no more noise).
    tr = stored_transport(v, u, cap, sig2, resid, total, coef, direct)
    k = tr.rank_for(store_tolerance)
    if k is None or k == cap:
        return tr
    return stored_transport(v, u, k, sig2, resid, total, coef, direct)
