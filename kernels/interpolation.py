"""The paper's interpolation of reflectance maps from sparse light samples (section 3.2, steps
2-3): each pixel's visibility from its horizon (soft over about a texel, then a 3x3 box as in
the paper), the samples interpolated over the triangulation's texels with visibility-aware
vertex choice and the paper's light adaptation (cosine divided out and multiplied back, its
three cases when vertices face away), optionally around a trend (the shading model, whose
specular lobe is defined here). The NumPy reference works in chunks of pixels and texels so its
memory stays bounded; :func:`compute_maps` runs it or the OpenCL kernel
(:mod:`relight.kernels.maps`)."""

from __future__ import annotations

import numpy as np

from relight.directions import equirect_directions
from relight.errors import InputError, NumericalError
from relight.numerics import EPS, EPS_NORM, EPS_VALUE

from .triangulation import Triangulation

#: Cosines below this count as facing away (no direct light): the guard of every division.
MIN_COS = 0.1
#: Soft width of the visibility step, in texels of elevation.
VIS_SOFT_TEXELS = 1.0
#: Pixels and texels per chunk of the NumPy reference (memory bound).
PIXEL_CHUNK = 4096
TEXEL_CHUNK = 256
#: Horizon elevation (radians) of a pixel that nothing shadows: straight down, below any light.
OPEN_SKY = -0.5 * np.pi
#: The shading model's specular lobe: Blinn-Phong ``max(n . h, 0) ** SPEC_EXPONENT`` about the
#: half vector of the light and the view (+Z), where the light is above the surface. A broad
#: lobe (about 40 degrees wide at half height): the sheen of skin on the forehead, nose and
#: cheekbones, which moves with the light and which interpolation between samples 10-20 degrees
#: apart draws as two half-bright ghosts. Its weight is fitted per pixel (0 where the pixel shows
#: none); on the real faces of ../shared/data/faces-yale it is worth +0.15 dB over Lambert alone.
SPEC_EXPONENT = 8  # a whole number: the kernels raise to it by squaring


def visibility_at(horizon: np.ndarray, n_az: int, map_size: tuple[int, int], columns: np.ndarray, *,
                  backend: str = "opencl") -> np.ndarray:
    """(P, len(columns)) float32 smoothed visibility (:func:`visibility_maps`) of the given map
    texels for each pixel of a horizon table (P, n_az). ``backend`` "opencl"
    (:func:`relight.kernels.maps.visibility_at_cl`) or "numpy" (in pixel chunks)."""
    columns = np.asarray(columns, dtype=np.int64)
    if backend == "opencl":
        from .maps import visibility_at_cl

        w, h = map_size
        return visibility_at_cl(horizon, n_az, map_size, equirect_directions(w, h).reshape(-1, 3), columns,
                                VIS_SOFT_TEXELS * np.pi / h)
    p = horizon.shape[0]
    out = np.empty((p, columns.size), dtype=np.float32)
    for p0 in range(0, p, PIXEL_CHUNK):
        ps = slice(p0, min(p0 + PIXEL_CHUNK, p))
        out[ps] = visibility_maps(horizon[ps], n_az, map_size).reshape(ps.stop - p0, -1)[:, columns]
    return out


def lobe(normals: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """(p, D) the specular lobe ``max(n . h, 0) ** SPEC_EXPONENT`` where ``n . l > 0`` (else 0),
    h the unit half vector of each direction (D, 3) and the view +Z (0 straight behind)."""
    half = np.asarray(dirs, dtype=normals.dtype) + np.array([0.0, 0.0, 1.0], dtype=normals.dtype)
    norm = np.linalg.norm(half, axis=1)
    half = half / np.where(norm > EPS_VALUE, norm, np.inf)[:, None]
    nh = np.clip(normals @ half.T, 0.0, None)
    return np.where(normals @ np.asarray(dirs, dtype=normals.dtype).T > 0.0, _ipow(nh, SPEC_EXPONENT), 0.0)


def _ipow(x: np.ndarray, n: int) -> np.ndarray:
    """x ** n for a whole n >= 0 by squaring, as the kernels' ipow (a general power is ~10x slower)."""
    r = np.ones_like(x)
    x = x.copy()
    while n > 0:
        if n & 1:
            r *= x
        n >>= 1
        if n:
            x *= x
    return r


def visibility_maps(horizon: np.ndarray, n_az: int, map_size: tuple[int, int], *, smooth: bool = True) -> np.ndarray:
    """(P, h, w) float32 soft visibility of each map texel for each pixel.

    horizon : (P, n_az) horizon elevation (radians above the image plane: the arctangent of the
    largest rise per pixel of image-plane travel, :func:`relight.pipeline.reflectance_maps.horizon_for`)
    toward each of ``n_az`` image-plane directions (see
    :func:`relight.kernels.heightfield.grid_directions`), interpolated linearly between them.
    """
    w, h = map_size
    tdirs = equirect_directions(w, h).reshape(-1, 3)
    s = np.hypot(tdirs[:, 0], tdirs[:, 1])
    beta = np.mod(np.arctan2(tdirs[:, 1], tdirs[:, 0]), 2 * np.pi)
    pos = beta / (2 * np.pi) * n_az - 0.5
    i0 = np.floor(pos).astype(np.int64) % n_az
    i1 = (i0 + 1) % n_az
    f = (pos - np.floor(pos)).astype(np.float32)
    elev_h = horizon[:, i0] * (1 - f) + horizon[:, i1] * f  # (P, T)
    elev = np.arctan2(tdirs[:, 2], np.maximum(s, EPS_NORM))
    soft = VIS_SOFT_TEXELS * np.pi / h
    vis = np.clip(0.5 + (elev[None, :] - elev_h) / soft, 0.0, 1.0).astype(np.float32)
    vis[:, s < EPS_VALUE] = 1.0  # straight toward the camera: a height field cannot block it
    vis = vis.reshape(-1, h, w)
    if smooth:
        vis = box3(vis)
    return vis


def box3(maps: np.ndarray) -> np.ndarray:
    """3x3 box filter over (..., h, w) lat-long maps: wraps around in azimuth, clamps at the poles."""
    p = np.concatenate([maps[..., -1:], maps, maps[..., :1]], axis=-1)
    p = np.concatenate([p[..., :1, :], p, p[..., -1:, :]], axis=-2)
    acc = np.zeros_like(maps)
    h, w = maps.shape[-2:]
    for dy in range(3):
        for dx in range(3):
            acc += p[..., dy:dy + h, dx:dx + w]
    return acc / 9.0


def _adapt(c, wv, dv, dp, use):
    """Light-adapted interpolation with vertex weights ``wv * use`` (paper Eq. 1-3).

    c : (..., 3 vertices, 3 rgb) colours; wv : (..., 3) weights; dv : (..., 3) cosines at the
    vertices; dp : (...) cosine at the texel; use : (..., 3) share (0-1) of each vertex in this
    interpolation. Returns (..., 3 rgb).
    """
    w = wv * use
    wsum = w.sum(axis=-1, keepdims=True)
    w = w / np.maximum(wsum, EPS)
    inc = w > 0
    lit = inc & (dv > MIN_COS)
    unlit = inc & ~lit
    dvs = np.maximum(dv, MIN_COS)
    dps = np.maximum(dp, 0.0)[..., None]
    n_lit = lit.sum(axis=-1)
    wl = np.where(lit, w, 0.0)
    wu = np.where(unlit, w, 0.0)
    w_ind = wu.sum(axis=-1, keepdims=True)
    c_ind = np.einsum("...v,...vc->...c", wu, c) / np.maximum(w_ind, EPS)  # indirect estimate
    plain = np.einsum("...v,...vc->...c", w, c)
    # All lit: divide out the cosines, interpolate, multiply back.
    all_lit = np.einsum("...v,...vc->...c", wl / dvs, c) * dps
    # Some lit (Eq. 1-3 in one form): remove the unlit vertices' weighted indirect light from each
    # lit vertex, cosine-adapt the rest, add the indirect light back.
    sub = c - (w_ind * c_ind)[..., None, :]
    w_lit = wl.sum(axis=-1, keepdims=True)
    c_dir = np.einsum("...v,...vc->...c", wl / dvs, sub) * dps / np.maximum(w_lit, EPS) + w_ind * c_ind
    mixed = w_lit * c_dir + w_ind * c_ind
    out = np.where((n_lit == 0)[..., None], plain, np.where((n_lit == inc.sum(axis=-1))[..., None], all_lit, mixed))
    return out


def build_maps(samples: np.ndarray, normals: np.ndarray, tri: Triangulation, *,
               visibility: np.ndarray | None = None, adaptation: bool = True, trend=None) -> np.ndarray:
    """Reflectance maps of P pixels, pixel-major: (P, 3, T_pad) float32 over ``tri.active`` texels
    (T_pad: their count rounded up to 16, zero padded).

    samples : (K, P, 3) linear colours under each of the K sample lights (flash units).
    normals : (P, 3) unit normals (used by light adaptation). visibility : (P, h, w) smoothed
    visibility maps, or None to interpolate without them. trend : None, or (offset (P, 3), coef
    (P, 3)[, spec (P, 3)]): each texel becomes ``interpolation - offset + (coef x max(n . l, 0) +
    spec x lobe(l)) x visibility(l)`` (the shading model added back,
    :func:`relight.pipeline.shading_fit.model_maps`; :func:`lobe`), then clipped at 0.
    """
    k, p = samples.shape[:2]
    if k != tri.n_samples:
        raise InputError(f"{k} sample images for {tri.n_samples} light directions")
    act = np.flatnonzero(tri.active)
    out = np.zeros((act.size, p, 3), dtype=np.float32)
    verts = tri.vertices
    tdirs = tri.texel_dirs
    vtex = tri.vertex_texel
    padded = np.concatenate([samples, np.zeros((1, p, 3), dtype=samples.dtype)])  # black lights -> row k
    for p0 in range(0, p, PIXEL_CHUNK):
        ps = slice(p0, min(p0 + PIXEL_CHUNK, p))
        n = normals[ps].astype(np.float64)
        vis = None if visibility is None else visibility[ps].reshape(ps.stop - p0, -1)
        for t0 in range(0, act.size, TEXEL_CHUNK):
            ts = act[t0:t0 + TEXEL_CHUNK]
            tv = tri.texel_vertices[ts]  # (t, 3)
            wv = np.broadcast_to(tri.texel_weights[ts][None], (n.shape[0], len(ts), 3))
            cv = padded[np.minimum(tv, k)][:, :, ps].transpose(2, 0, 1, 3).astype(np.float64)  # (p, t, 3v, 3c)
            if adaptation:
                dv = np.einsum("pc,tvc->ptv", n, verts[tv])
                dp = n @ tdirs[ts].T
            else:
                dv = np.ones(wv.shape)
                dp = np.ones(wv.shape[:2])
            every = np.ones(wv.shape)
            regular = _adapt(cv, wv, dv, dp, every) if adaptation else np.einsum("ptv,ptvc->ptc", wv, cv)
            if vis is not None:
                vv = vis[:, vtex[tv]]  # (p, t, 3)
                vp = vis[:, ts]  # (p, t)
                vmin, vmax = vv.min(axis=-1), vv.max(axis=-1)
                spread = vmax - vmin
                # The vertex with the least visibility is shadowed, the one with the most lit, the
                # third in between by its value (a soft share, so tiny changes never flip a
                # vertex); the texel's own visibility chooses between the two interpolations.
                lit_share = np.clip((vv - vmin[..., None]) / np.maximum(spread, EPS_VALUE)[..., None], 0.0, 1.0)
                t_lit = np.clip((vp - vmin) / np.maximum(spread, EPS_VALUE), 0.0, 1.0)[..., None]
                if adaptation:
                    c_l = _adapt(cv, wv, dv, dp, lit_share)
                    c_s = _adapt(cv, wv, dv, dp, 1.0 - lit_share)
                else:
                    c_l = _subset(cv, wv, lit_share)
                    c_s = _subset(cv, wv, 1.0 - lit_share)
                aware = t_lit * c_l + (1 - t_lit) * c_s
                regular = (1 - spread[..., None]) * regular + spread[..., None] * aware
            if trend is not None:
                tv_ = 1.0 if vis is None else vis[:, ts]
                lit = np.clip(n @ tdirs[ts].T, 0.0, None) * tv_  # (p, t)
                regular = regular - np.asarray(trend[0][ps], np.float64)[:, None] + \
                    np.asarray(trend[1][ps], np.float64)[:, None] * lit[..., None]
                if len(trend) > 2:
                    regular = regular + np.asarray(trend[2][ps], np.float64)[:, None] * \
                        (lobe(n, tdirs[ts]) * tv_)[..., None]
            out[t0:t0 + len(ts), ps] = np.clip(regular, 0.0, None).transpose(1, 0, 2)
    if not np.isfinite(out).all():  # pragma: no cover - guarded above
        raise NumericalError("non-finite reflectance")
    from .layout import padded_texels

    pm = np.zeros((p, 3, padded_texels(act.size)), dtype=np.float32)
    pm[:, :, :act.size] = out.transpose(1, 2, 0)
    return pm


def _subset(c, wv, use):
    w = wv * use
    w = w / np.maximum(w.sum(axis=-1, keepdims=True), EPS)
    return np.einsum("...v,...vc->...c", w, c)


def compute_maps(samples: np.ndarray, normals: np.ndarray, tri: Triangulation, *, horizon: np.ndarray | None,
                 n_az: int, adaptation: bool = True, backend: str = "opencl", half: bool = False,
                 trend=None, texel_major: bool = False, spline=None, progress=None) -> np.ndarray:
    """Reflectance maps (P, 3, T_pad) of P pixels, pixel-major: OpenCL, or the NumPy reference (float32).

    horizon : (P, n_az) horizon elevations for visibility, or None for none. half : OpenCL output
    in float16 (the bundle's storage; halves the peak memory of large captures). trend : see
    :func:`build_maps`. spline (OpenCL): see :func:`relight.kernels.maps.build_maps_cl` (the
    NumPy path blends it afterwards, :func:`relight.kernels.reflectance.blend_spline`).
    """
    if backend == "numpy":
        vis = None if horizon is None else visibility_maps(horizon, n_az, tri.map_size)
        return build_maps(samples, normals, tri, visibility=vis, adaptation=adaptation, trend=trend)
    if backend != "opencl":
        raise InputError(f"backend {backend!r}: use 'opencl' or 'numpy'")
    from .maps import build_maps_cl

    return build_maps_cl(np.ascontiguousarray(samples, dtype=np.float32), normals, vertices=tri.vertices,
                         vertex_texel=tri.vertex_texel, texel_vertices=tri.texel_vertices,
                         texel_weights=tri.texel_weights, texel_dirs=tri.texel_dirs, active=tri.active,
                         map_size=tri.map_size, horizon=horizon, n_az=n_az,
                         vis_soft=VIS_SOFT_TEXELS * np.pi / tri.map_size[1], adaptation=adaptation,
                         half=half, trend=trend, spec_exponent=SPEC_EXPONENT, texel_major=texel_major,
                         spline=spline, progress=progress)
