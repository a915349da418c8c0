"""Stage 5: per-pixel reflectance maps from sparse light samples (paper section 3.2).

A reflectance map (64x32 lat-long by default, the layout of :mod:`relight.directions`) holds,
per light direction, what the pixel shows under a flash-strength light from there. The samples
fill it in four steps:

1. **Triangulation**: the convex hull of the sample directions is their spherical Delaunay
   triangulation; virtual black lights are added outside the captured hull wherever no sample
   is near, so light fades out beyond it (holes inside the hull are interpolated, not
   darkened); each texel is interpolated with spherical barycentric weights (the planar
   weights of its ray through the triangle, normalised).
2. **Visibility**: from the height field, each pixel's horizon tells which directions it can
   see (soft over about a texel, then a 3x3 box filter as in the paper); inside a triangle
   whose vertices disagree, texels that are shadowed take the shadowed vertices' colours and
   lit ones the lit vertices', blended with plain interpolation by the vertices' spread.
3. **Light adaptation**: the cosine factor is divided out before interpolation and multiplied
   back at the texel, with the paper's three cases (Eq. 1-3) when vertices face away and only
   carry indirect light.
4. **Normalisation** for relighting is the texel's solid angle (stored beside the maps, applied
   to the environment when relighting): sin(latitude) weighting made exact.

``full`` (:func:`model_maps`) replaces step 3 by a per-pixel shading model ((albedo x cosine +
a broad specular lobe) x visibility, :func:`shading_model`) whose residual is interpolated,
extends the model beyond the hull (carrying what the model leaves of the nearest samples: skin's
indirect and subsurface light does not stop where the Lambert term does), and blends each pixel
with a thin-plate spline of its samples (:mod:`relight.kernels.spline`) by how well each
predicts left-out samples.

The NumPy implementation here is the reference; it works in chunks of pixels and texels so its
memory stays bounded.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from relight.directions import (
    direction_to_equirect_uv,
    equirect_directions,
)
from relight.errors import InputError, NumericalError
from relight.numerics import EPS, EPS_NORM, EPS_VALUE, TINY_SCALE

from .triangulation import (  # noqa: F401 (the triangulation's names, re-exported for the stages)
    DEFAULT_MAP_SIZE,
    MERGE_DEG,
    Triangulation,
    cap_faces,
    inside_hull,
    locate_in_faces,
    merge_close,
    triangulate,
)

#: Cosines below this count as facing away (no direct light): the guard of every division.
MIN_COS = 0.1
#: Soft width of the visibility step, in texels of elevation.
VIS_SOFT_TEXELS = 1.0
#: Pixels and texels per chunk of the NumPy reference (memory bound).
PIXEL_CHUNK = 4096
TEXEL_CHUNK = 256


#: Lambert fit of the shading model: samples used where the light is this far above the pixel's
#: tangent plane (cosine) and this visible; model-light texels kept where some pixel gets more
#: than ``MODEL_KEEP`` of the brightest sample.
MODEL_MIN_COS = 0.2
MODEL_MIN_VIS = 0.9
MODEL_KEEP = 0.01


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


#: How much of a pixel's trend the shading model gets: 0 below this coefficient of determination
#: (R^2) of its Lambert fit, 1 above ``MODEL_R2_FULL`` (shiny or badly modelled pixels - metal,
#: wrong normals - keep plain interpolation).
MODEL_R2_NONE = 0.3
MODEL_R2_FULL = 0.5
#: How far beyond the captured directions (degrees) the model's light is kept in the maps
#: (``relight capture --model-reach``). 60: on the base synthetic scene the studio environment
#: (key light from the side) gains 1.2 dB over 30 and 45; 180 adds 0.07 dB for 12 % more texels.
MODEL_REACH_DEG = 60.0
#: Horizon elevation (radians) of a pixel that nothing shadows: straight down, below any light.
OPEN_SKY = -0.5 * np.pi


#: The shading model's specular lobe: Blinn-Phong ``max(n . h, 0) ** SPEC_EXPONENT`` about the
#: half vector of the light and the view (+Z), where the light is above the surface. A broad
#: lobe (about 40 degrees wide at half height): the sheen of skin on the forehead, nose and
#: cheekbones, which moves with the light and which interpolation between samples 10-20 degrees
#: apart draws as two half-bright ghosts. Its weight is fitted per pixel (0 where the pixel shows
#: none); on the real faces of ../shared/data/faces-yale it is worth +0.15 dB over Lambert alone.
SPEC_EXPONENT = 8  # a whole number: the kernels raise to it by squaring
#: Beyond the captured hull the virtual lights carry, besides the model, the non-negative part of
#: the residual (what the model does not explain: indirect light, subsurface glow, the room's
#: light in an image set) of the nearest ``CARRY_NEAREST`` samples, weighted by a Gaussian of
#: ``CARRY_SIGMA_DEG`` of angle, fading with the nearest one's distance (1/e at
#: ``CARRY_FADE_DEG``): skin does not go black where the Lambert term does.
CARRY_NEAREST = 3
CARRY_SIGMA_DEG = 15.0
CARRY_FADE_DEG = 45.0


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


@dataclass
class ShadingModel:
    """Per pixel ``albedo x max(n . l, 0) x visibility(l) + spec x lobe(l) x visibility(l)``
    (:func:`shading_model`): albedo, spec (P, 3) float64 linear, trust (P,) 0-1."""

    albedo: np.ndarray
    spec: np.ndarray
    trust: np.ndarray

    def at(self, normals: np.ndarray, dirs: np.ndarray, vis: np.ndarray, rows=slice(None)) -> np.ndarray:
        """(D, p, 3) the model at directions (D, 3) for the pixels ``rows`` with normals (p, 3) and
        visibility (p, D), in the dtype of the normals."""
        dt = normals.dtype
        # C order (D, p): a transposed view here made the result - and every array computed
        # from it - strided, which slowed those NumPy passes ~20x.
        cos = np.ascontiguousarray((np.clip(normals @ dirs.T, 0.0, None) * vis).T)[..., None]  # (D, p, 1)
        spec = np.ascontiguousarray((lobe(normals, dirs) * vis).T)[..., None]
        return cos * self.albedo[rows].astype(dt)[None] + spec * self.spec[rows].astype(dt)[None]


def shading_model(samples: np.ndarray, normals: np.ndarray, tri: Triangulation,
                  vertex_vis: np.ndarray) -> ShadingModel:
    """Per pixel the shading model ``(albedo x max(n . l, 0) + spec x lobe(l)) x visibility(l)``
    (visibility: the smoothed visibility maps of the horizon table, as the interpolation reads
    them; 1 without one; lobe: :func:`lobe`).

    Albedo and spec are fitted by least squares to the samples that light the pixel well (cosine >
    ``MODEL_MIN_COS``, visibility > ``MODEL_MIN_VIS``), per channel, spec >= 0 (a channel whose
    lobe would come out negative is refitted with albedo alone); 0 where no sample lights the
    pixel. The trust ramps from 0 to 1 as the fit's R^2 over those samples goes from
    ``MODEL_R2_NONE`` to ``MODEL_R2_FULL`` (0 with fewer than 4 of them). vertex_vis : (P, >= K)
    visibility at the vertices' texels (:func:`visibility_at` of ``tri.vertex_texel``; ones without
    a horizon table)."""
    k, p = samples.shape[:2]
    dt = np.float64 if samples.dtype == np.float64 else np.float32  # float64 in: the stability reference
    n = np.asarray(normals, dtype=np.float64)
    albedo = np.zeros((p, 3))
    spec = np.zeros((p, 3))
    trust = np.zeros(p)
    dirs = tri.vertices[:k]
    for p0 in range(0, p, PIXEL_CHUNK):
        ps = slice(p0, min(p0 + PIXEL_CHUNK, p))
        cs = n[ps] @ dirs.T
        vk = vertex_vis[ps, :k]
        use = (cs > MODEL_MIN_COS) & (vk > MODEL_MIN_VIS)
        c = np.where(use, cs, 0.0)  # (p, K) regressors, float64
        s = np.where(use, lobe(n[ps], dirs), 0.0)
        y = samples[:, ps].astype(dt)  # (K, p, 3); sums over the K samples in float64
        cy = np.einsum("pk,kpc->pc", c, y, dtype=np.float64)
        sy = np.einsum("pk,kpc->pc", s, y, dtype=np.float64)
        cc, ss, cs_ = (c * c).sum(axis=1), (s * s).sum(axis=1), (c * s).sum(axis=1)
        det = cc * ss - cs_ * cs_
        ok = det > EPS_NORM * np.maximum(cc * ss, TINY_SCALE)  # the lobe is not a multiple of the cosine here
        safe = np.where(ok, det, 1.0)[:, None]
        a2 = (ss[:, None] * cy - cs_[:, None] * sy) / safe
        s2 = (cc[:, None] * sy - cs_[:, None] * cy) / safe
        a1 = cy / np.maximum(cc, EPS_VALUE)[:, None]  # albedo alone
        two = ok[:, None] & (s2 > 0.0)
        a = np.where(two, a2, a1)
        sp = np.where(two, s2, 0.0)
        albedo[ps], spec[ps] = a, sp
        cnt = use.sum(axis=1)
        # (K, p, 1) in C order: transposed views would make every (K, p, 3) pass below strided
        w = np.ascontiguousarray(use.T, dtype=dt)[..., None]
        mean = (y * w).sum(axis=0, dtype=np.float64) / np.maximum(cnt, 1)[:, None]
        pred = np.ascontiguousarray(c.T, dtype=dt)[..., None] * a[None].astype(dt) + \
            np.ascontiguousarray(s.T, dtype=dt)[..., None] * sp[None].astype(dt)
        ss_tot = (((y - mean[None].astype(dt)) ** 2) * w).sum(axis=(0, 2), dtype=np.float64)
        ss_res = (((y - pred) ** 2) * w).sum(axis=(0, 2), dtype=np.float64)
        r2 = 1.0 - ss_res / np.maximum(ss_tot, TINY_SCALE)
        t = np.clip((r2 - MODEL_R2_NONE) / (MODEL_R2_FULL - MODEL_R2_NONE), 0.0, 1.0)
        trust[ps] = np.where(cnt >= 4, t, 0.0)
    return ShadingModel(albedo=albedo, spec=spec, trust=trust)


def carry_weights(vertices: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """For each virtual light (vertices[k:]): (the ids (B, CARRY_NEAREST) of its nearest samples,
    their weights (B, CARRY_NEAREST), the Gaussian share times the fade with distance)."""
    near = min(CARRY_NEAREST, k)
    ang = np.degrees(np.arccos(np.clip(vertices[k:] @ vertices[:k].T, -1.0, 1.0)))  # (B, K)
    ids = np.argsort(ang, axis=1)[:, :near]
    a = np.take_along_axis(ang, ids, axis=1)
    w = np.exp(-(a / CARRY_SIGMA_DEG) ** 2)
    w /= np.maximum(w.sum(axis=1, keepdims=True), TINY_SCALE)
    return ids, w * np.exp(-a[:, :1] / CARRY_FADE_DEG)


def stored_precision(a: np.ndarray) -> np.ndarray:
    """``a`` rounded to float16 (clipped to its range), in its own dtype: a fit as bundles store it."""
    big = float(np.finfo(np.float16).max)
    return np.clip(a, -big, big).astype(np.float16).astype(a.dtype)


def model_maps(samples: np.ndarray, normals: np.ndarray, tri: Triangulation, horizon: np.ndarray | None,
               n_az: int, *, trend: bool = True, extrapolate: bool = True, paper_adaptation: bool = False,
               spline: bool = True, grid: np.ndarray | None = None, reach_deg: float = MODEL_REACH_DEG,
               backend: str = "opencl", half: bool = False, progress=None, fit_out: dict | None = None
               ) -> tuple[np.ndarray, Triangulation]:
    """Reflectance maps with the shading model (:func:`shading_model`): (maps (P, 3, T_pad)
    float32, or float16 with ``half``; the triangulation whose ``active`` texels they hold).

    trend : interpolate what the model does not explain - each sample minus the model's value
    for its light - and add the model back at every texel: the cosine falloff and the cast
    shadows then move with the light exactly instead of being interpolated between samples 10-20
    degrees apart (our light adaptation; the paper divides by the vertices' cosines instead).
    extrapolate : beyond the captured hull the virtual lights carry the model's value instead of
    black (residual 0), and texels are kept where the model lights some pixel. Without either
    this is :func:`compute_maps` without adaptation. The interpolation (visibility-aware with a
    horizon table) is a convex combination of vertex values, so residuals are interpolated
    offset to be non-negative and the offset taken off again. paper_adaptation (no trend): the
    paper's light adaptation (:func:`compute_maps` ``adaptation``) over samples + model lights.
    spline : inside the captured directions each pixel blends this path with the thin-plate
    spline of its samples (:mod:`relight.kernels.spline`; capped at the brightest sample of the
    texel's triangle), by the weight that best predicts left-out samples (stacking, fitted over
    a window of neighbouring pixels when ``grid``, the (H, W) mask of the P pixels, is given).
    reach_deg : with ``extrapolate``, model light is kept only this far from a captured direction.
    fit_out : a dict that receives the fits (``model``: the :class:`ShadingModel`, ``blend``) -
    with the samples, normals, horizon and triangulation, all
    :func:`maps_from_fit` (and :mod:`relight.kernels.recipe`) needs to make the maps again.
    """
    if trend and paper_adaptation:
        raise InputError("the shading-model trend and the paper's light adaptation exclude each other")
    sm, blend, active = fit_model(samples, normals, tri, horizon, n_az, extrapolate=extrapolate, spline=spline,
                                  grid=grid, reach_deg=reach_deg, backend=backend)
    if fit_out is not None:
        fit_out.update(model=sm, blend=blend, active=active)
    return maps_from_fit(samples, normals, tri, horizon, n_az, sm, blend, active, trend=trend,
                         extrapolate=extrapolate, paper_adaptation=paper_adaptation, spline=spline,
                         backend=backend, half=half, progress=progress)


def _vertex_model(sm: ShadingModel, normals: np.ndarray, verts: np.ndarray, vis: np.ndarray,
                  horizon: np.ndarray | None) -> np.ndarray:
    """(V, p, 3) the shading model at the vertices for a chunk of pixels (sm, normals, vis of the
    chunk): open-sky pixels (trust < 0.5) see every vertex."""
    if horizon is not None:
        open_sky = sm.trust < 0.5
        if open_sky.any():
            vis = np.where(open_sky[:, None], np.float32(1.0), vis)
    return sm.at(normals, verts, vis)


def fit_model(samples: np.ndarray, normals: np.ndarray, tri: Triangulation, horizon: np.ndarray | None,
              n_az: int, *, extrapolate: bool = True, spline: bool = True, grid: np.ndarray | None = None,
              reach_deg: float = MODEL_REACH_DEG, backend: str = "opencl"
              ) -> tuple[ShadingModel, np.ndarray, np.ndarray]:
    """The fits of :func:`model_maps`, pixel chunk by chunk (no array of all pixels x vertices):
    (the shading model, at the precision a bundle stores it; the model path's weight against the
    spline (P,) (stacking; the trust without a spline); the kept map texels (T,) bool)."""
    k, p = samples.shape[:2]
    if grid is not None and int(np.count_nonzero(grid)) != p:
        raise InputError(f"the pixel grid marks {int(np.count_nonzero(grid))} pixels for {p} pixels of samples")
    verts = tri.vertices
    b = len(verts) - k
    dt = np.float64 if samples.dtype == np.float64 else np.float32  # float64 in: the stability reference
    verts_dt = verts.astype(dt)
    loo = None
    if spline:
        from .spline import leave_one_out, stacking_terms, stacking_weight

        loo = leave_one_out(verts[:k])
    carry_ids, carry_w = carry_weights(verts, k) if b else (None, None)
    albedo, spec, trust = np.zeros((p, 3)), np.zeros((p, 3)), np.zeros(p)
    num, den = np.zeros(p), np.zeros(p)
    lit_vertex = np.zeros(len(verts), dtype=bool)
    lit_vertex[:k] = True
    peak = max(float(np.max(samples)) if samples.size else 0.0, TINY_SCALE)
    for p0 in range(0, p, PIXEL_CHUNK):
        ps = slice(p0, min(p0 + PIXEL_CHUNK, p))
        vis = (np.ones((ps.stop - p0, len(verts)), dtype=np.float32) if horizon is None else
               visibility_at(horizon[ps], n_az, tri.map_size, tri.vertex_texel, backend=backend))
        fit = shading_model(samples[:, ps], normals[ps], tri, vis)
        # The fits at the precision a bundle stores them (float16), so its maps can be made again.
        fit = ShadingModel(albedo=stored_precision(fit.albedo), spec=stored_precision(fit.spec),
                           trust=stored_precision(fit.trust))
        albedo[ps], spec[ps], trust[ps] = fit.albedo, fit.spec, fit.trust
        if loo is None and not b:
            continue
        model = _vertex_model(fit, np.asarray(normals[ps], dtype=dt), verts_dt, vis, horizon)  # (V, p, 3)
        if loo is not None:
            num[ps], den[ps] = stacking_terms(samples[:, ps], model[:k], fit.trust, loo)
        if b:  # where the model (and what it leaves of the nearest samples) lights some pixel
            left = np.maximum(samples[:, ps].astype(dt) - model[:k], 0.0)
            carried = _carried(left, carry_ids, carry_w.astype(dt))
            lit_vertex[k:] |= (model[k:] + carried).max(axis=(1, 2)) > MODEL_KEEP * peak
    sm = ShadingModel(albedo=albedo, spec=spec, trust=trust)
    blend = stored_precision(stacking_weight(num, den, trust, grid)) if loo is not None else trust.copy()
    if extrapolate:
        # Model light is kept where it lights some pixel, within reach_deg of a captured direction:
        # farther out (behind the head) it would cost map texels for light that reaches little.
        near = (tri.texel_dirs @ verts[:k].T).max(axis=1) >= np.cos(np.radians(reach_deg))
        active = (lit_vertex[tri.texel_vertices].any(axis=1) & near) | tri.active
    else:
        active = tri.active.copy()
    return sm, blend, active


def maps_from_fit(samples: np.ndarray, normals: np.ndarray, tri: Triangulation, horizon: np.ndarray | None,
                  n_az: int, sm: ShadingModel, blend: np.ndarray, active: np.ndarray, *,
                  trend: bool = True, extrapolate: bool = True, paper_adaptation: bool = False,
                  spline: bool = True, backend: str = "opencl", half: bool = False, texel_major: bool = False,
                  progress=None):
    """The maps of :func:`model_maps` from its fits (:func:`fit_model`: the shading model ``sm``,
    the spline ``blend`` (P,), the kept texels ``active`` (T,) bool), for these pixels (any
    subset of the fitted ones, with their fits). Returns (maps, the triangulation whose
    ``active`` texels they hold); maps (P, 3, T_pad), or with ``texel_major`` (T_pad, 3, P)
    float32 (what the transport's projections read; OpenCL only)."""
    k, p = samples.shape[:2]
    verts = tri.vertices
    b = len(verts) - k
    trust = sm.trust
    dt = np.float64 if samples.dtype == np.float64 else np.float32  # float64 in: the stability reference
    n = np.asarray(normals, dtype=dt)
    verts_dt = verts.astype(dt)
    carry_ids, carry_w = carry_weights(verts, k) if b else (None, None)
    n_vals = len(verts) if extrapolate else k
    vals = np.zeros((n_vals, p, 3), dtype=dt)
    offset = np.zeros((p, 3), dtype=np.float64)
    for p0 in range(0, p, PIXEL_CHUNK):
        ps = slice(p0, min(p0 + PIXEL_CHUNK, p))
        vis = (np.ones((ps.stop - p0, len(verts)), dtype=np.float32) if horizon is None else
               visibility_at(horizon[ps], n_az, tri.map_size, tri.vertex_texel, backend=backend))
        chunk_sm = ShadingModel(albedo=sm.albedo[ps], spec=sm.spec[ps], trust=trust[ps])
        model = _vertex_model(chunk_sm, n[ps], verts_dt, vis, horizon)  # (V, p, 3)
        chunk = samples[:, ps].astype(dt)
        tw = trust[ps][None, :, None].astype(dt)
        if trend:  # the trusted share of the model is taken out and added back at each texel
            both = chunk - tw * model[:k]
        else:
            both = chunk
        if extrapolate and b:
            # beyond the hull: the model (its untrusted share with the trend) plus what it leaves
            # of the nearest samples
            left = np.maximum(chunk - model[:k], 0.0)
            carried = _carried(left, carry_ids, carry_w.astype(dt))
            virt = ((1.0 - tw) * model[k:] if trend else model[k:]) + carried
            both = np.concatenate([both, virt])
        off = np.maximum(-both.min(axis=0), 0.0)  # (p, 3)
        offset[ps] = off
        vals[:, ps] = both + off[None]
    if horizon is not None and (trust < 0.5).any():
        # Where the model does not explain the samples, neither does its geometry's shadowing:
        # those pixels interpolate without visibility (an open sky: every light visible).
        horizon = np.where((trust < 0.5)[:, None], np.float32(OPEN_SKY), horizon).astype(np.float32)
    if extrapolate:
        map_tri = Triangulation(vertices=verts, n_samples=len(verts), faces=tri.faces,
                                texel_vertices=tri.texel_vertices, texel_weights=tri.texel_weights,
                                active=np.asarray(active, dtype=bool), map_size=tri.map_size)
    else:
        map_tri = Triangulation(vertices=verts, n_samples=k, faces=tri.faces, texel_vertices=tri.texel_vertices,
                                texel_weights=tri.texel_weights, active=np.asarray(active, dtype=bool),
                                map_size=tri.map_size)
    # The kernel takes the offset off and adds the trusted model back at each texel in float32,
    # then stores float16 with ``half`` (the bundle's storage; keeps large captures' memory down).
    coef = trust[:, None] * sm.albedo if trend else np.zeros_like(sm.albedo)
    spec = trust[:, None] * sm.spec if trend else np.zeros_like(sm.spec)
    if texel_major and backend != "opencl":
        raise InputError("texel-major maps are made by the OpenCL backend only")
    act = np.flatnonzero(map_tri.active)
    smooth = None
    if spline and (blend < 1.0).any():
        from .spline import spline_weights

        inside = np.flatnonzero(spline_texels(map_tri.texel_vertices[act], k))
        sw = spline_weights(verts[:k], map_tri.texel_dirs[act][inside]) if inside.size else None
        if sw is not None:
            smooth = (inside, sw, map_tri.texel_vertices[act[inside]])
    # The OpenCL kernel blends the spline in itself (its values from BLAS, chunk by chunk).
    blend_in = None
    if smooth is not None and backend == "opencl":
        blend_in = (samples, smooth[0], smooth[1], np.asarray(blend, dtype=np.float32))
    maps = compute_maps(vals, normals, map_tri, horizon=horizon, n_az=n_az, adaptation=paper_adaptation,
                        backend=backend, half=half and not texel_major, trend=(offset, coef, spec),
                        texel_major=texel_major, spline=blend_in, progress=progress)
    if smooth is not None and blend_in is None:
        for p0 in range(0, p, PIXEL_CHUNK):
            ps = slice(p0, min(p0 + PIXEL_CHUNK, p))
            if (blend[ps] < 1.0).any():
                m = maps[ps, :, :act.size].astype(dt)
                _blend_spline(m, samples[:, ps], blend[ps], *smooth)
                maps[ps, :, :act.size] = np.clip(m, 0.0, None)
    # The OpenCL maps are finite when their inputs are (guarded divisions, outputs clipped to
    # [0, inf) by selects): the vertex values are checked, ~10x fewer than the maps.
    checked = vals if backend == "opencl" else maps
    if not np.isfinite(np.sum(checked, dtype=np.float64)):
        raise NumericalError("non-finite reflectance from the shading model; this is a bug, please report it")
    return maps, map_tri


def _carried(left: np.ndarray, ids: np.ndarray, w: np.ndarray) -> np.ndarray:
    """(B, p, 3) what each virtual light carries of its nearest samples: sum over n of
    w[b, n] x left[ids[b, n]] (left (K, p, 3); one gather per neighbour, not one array of all)."""
    out = w[:, 0, None, None] * left[ids[:, 0]]
    for j in range(1, ids.shape[1]):
        out += w[:, j, None, None] * left[ids[:, j]]
    return out


def spline_texels(texel_vertices: np.ndarray, k: int) -> np.ndarray:
    """(n,) bool: the texels the spline blends into - those whose triangle is made of samples
    (vertex ids < k), i.e. inside the samples' hull (:func:`triangulate` gives those texels the
    samples' own cap triangles; a triangle of three samples lies inside their hull)."""
    return (np.asarray(texel_vertices) < k).all(axis=1)


def _blend_spline(m: np.ndarray, samples: np.ndarray, weight: np.ndarray, inside: np.ndarray,
                  weights: np.ndarray, corners: np.ndarray) -> None:
    """In place: maps m (p, 3, T) at texel columns ``inside`` become ``weight x m + (1 - weight) x
    spline`` for the pixels with weight < 1 (samples (K, p, 3); spline weights (len(inside), K)).
    The spline is capped at the brightest of the three samples around each texel (``corners``
    (len(inside), 3) sample ids): its power domain turns a small overshoot into a large one."""
    from .spline import spline_values

    sel = np.flatnonzero(weight < 1.0)
    if sel.size == 0:
        return
    part = samples[:, sel]
    spl = spline_values(part, weights)  # (len(inside), s, 3)
    np.minimum(spl, part[corners].max(axis=1).astype(spl.dtype), out=spl)
    w = weight[sel, None, None].astype(m.dtype)
    rows = np.ix_(sel, np.arange(3), inside)
    m[rows] = w * m[rows] + (1 - w) * spl.transpose(1, 2, 0).astype(m.dtype)


def visibility_maps(horizon: np.ndarray, n_az: int, map_size: tuple[int, int], *, smooth: bool = True) -> np.ndarray:
    """(P, h, w) float32 soft visibility of each map texel for each pixel.

    horizon : (P, n_az) horizon elevation (radians above the image plane: the arctangent of the
    largest rise per pixel of image-plane travel, :func:`relight.pipeline.capture.horizon_for`)
    toward each of ``n_az`` image-plane directions (see
    :func:`relight.kernels.shading.grid_directions`), interpolated linearly between them.
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
    spec x lobe(l)) x visibility(l)`` (the shading model added back, :func:`model_maps`;
    :func:`lobe`), then clipped at 0.
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
    from .maps import padded_texels

    pm = np.zeros((p, 3, padded_texels(act.size)), dtype=np.float32)
    pm[:, :, :act.size] = out.transpose(1, 2, 0)
    return pm


def _subset(c, wv, use):
    w = wv * use
    w = w / np.maximum(w.sum(axis=-1, keepdims=True), EPS)
    return np.einsum("...v,...vc->...c", w, c)


def sample_map(maps: np.ndarray, tri_active: np.ndarray, map_size: tuple[int, int], direction) -> np.ndarray:
    """Bilinear lookup of pixel-major reflectance maps (P, 3, T_pad) toward one direction: (P, 3)."""
    w, h = map_size
    u, v = direction_to_equirect_uv(np.asarray(direction, dtype=np.float64))
    x = float(u) * w - 0.5
    y = min(max(float(v) * h - 0.5, 0.0), h - 1.0)
    x0 = int(np.floor(x))
    y0 = int(np.floor(y))
    fx, fy = x - x0, y - y0
    lut = -np.ones(w * h, dtype=np.int64)
    lut[np.flatnonzero(tri_active)] = np.arange(int(tri_active.sum()))
    out = np.zeros(maps.shape[:2], dtype=np.float64)
    for dy, wy in ((0, 1 - fy), (1, fy)):
        for dx, wx in ((0, 1 - fx), (1, fx)):
            yy = min(y0 + dy, h - 1)
            xx = (x0 + dx) % w
            t = lut[yy * w + xx]
            if t >= 0 and wx * wy > 0:
                out += wx * wy * np.asarray(maps[:, :, t], dtype=np.float64)
    return out.astype(np.float32)


def compute_maps(samples: np.ndarray, normals: np.ndarray, tri: Triangulation, *, horizon: np.ndarray | None,
                 n_az: int, adaptation: bool = True, backend: str = "opencl", half: bool = False,
                 trend=None, texel_major: bool = False, spline=None, progress=None) -> np.ndarray:
    """Reflectance maps (P, 3, T_pad) of P pixels, pixel-major: OpenCL, or the NumPy reference (float32).

    horizon : (P, n_az) horizon elevations for visibility, or None for none. half : OpenCL output
    in float16 (the bundle's storage; halves the peak memory of large captures). trend : see
    :func:`build_maps`. spline (OpenCL): see :func:`relight.kernels.maps.build_maps_cl` (the
    NumPy path blends it afterwards, :func:`_blend_spline`).
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
