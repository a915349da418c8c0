"""Stage 5: per-pixel reflectance maps from sparse light samples (paper section 3.2), and the
shading model that ``full`` adds to the paper's method.

A reflectance map (64x32 lat-long by default, the layout of :mod:`relight.directions`) holds,
per light direction, what the pixel shows under a flash-strength light from there. The paper's
steps live in their own modules: the **triangulation** of the sample directions
(:mod:`relight.kernels.triangulation`), the **interpolation** with visibility and light
adaptation (:mod:`relight.kernels.interpolation`); **normalisation** for relighting is the
texel's solid angle (applied to the environment when relighting: sin(latitude) weighting made
exact).

This module is ``full`` (:func:`model_maps`): a per-pixel shading model ((albedo x cosine + a
broad specular lobe) x visibility, :func:`shading_model`) replaces the paper's light adaptation
and its residual is interpolated; the model is extended beyond the hull (carrying what the model
leaves of the nearest samples: skin's indirect and subsurface light does not stop where the
Lambert term does), and each pixel is blended with a thin-plate spline of its samples
(:mod:`relight.kernels.spline`) by how well each predicts left-out samples. The NumPy code is
the reference; it works in chunks of pixels so its memory stays bounded.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from relight.errors import InputError, NumericalError
from relight.numerics import EPS_NORM, EPS_VALUE, TINY_SCALE

from .interpolation import OPEN_SKY, PIXEL_CHUNK, compute_maps, lobe, visibility_at
from .triangulation import Triangulation

#: Lambert fit of the shading model: samples used where the light is this far above the pixel's
#: tangent plane (cosine) and this visible; model-light texels kept where some pixel gets more
#: than ``MODEL_KEEP`` of the brightest sample.
MODEL_MIN_COS = 0.2
MODEL_MIN_VIS = 0.9
MODEL_KEEP = 0.01
#: The specular lobe is fitted only where the samples saw it: some used sample at a tenth of the
#: lobe's peak (its value 1, at the mirror direction) or more. A lobe seen only below that would
#: be extrapolated more than tenfold - at a grazing normal its values at the samples are ~1e-5
#: and its fitted weight ~1e5 times the samples (real faces: Yale B06 seen as sRGB gave maps
#: 40 000 times the brightest sample beyond the captured hull, and the transport overflowed).
MODEL_LOBE_SEEN = 0.1


#: How much of a pixel's trend the shading model gets: 0 below this coefficient of determination
#: (R^2) of its Lambert fit, 1 above ``MODEL_R2_FULL`` (shiny or badly modelled pixels - metal,
#: wrong normals - keep plain interpolation).
MODEL_R2_NONE = 0.3
MODEL_R2_FULL = 0.5
#: How far beyond the captured directions (degrees) the model's light is kept in the maps
#: (``relight capture --model-reach``). 60: on the base synthetic scene the studio environment
#: (key light from the side) gains 1.2 dB over 30 and 45; 180 adds 0.07 dB for 12 % more texels.
MODEL_REACH_DEG = 60.0


#: Beyond the captured hull the virtual lights carry, besides the model, the non-negative part of
#: the residual (what the model does not explain: indirect light, subsurface glow, the room's
#: light in an image set) of the nearest ``CARRY_NEAREST`` samples, weighted by a Gaussian of
#: ``CARRY_SIGMA_DEG`` of angle, fading with the nearest one's distance (1/e at
#: ``CARRY_FADE_DEG``): skin does not go black where the Lambert term does.
CARRY_NEAREST = 3
CARRY_SIGMA_DEG = 15.0
CARRY_FADE_DEG = 45.0


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
    lobe would come out negative is refitted with albedo alone), the lobe only where those samples
    saw it (``MODEL_LOBE_SEEN``) and its peak stays within what they bound (spec at most the
    brightest of them / ``MODEL_LOBE_SEEN``; else albedo alone); 0 where no sample lights the
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
        # the lobe where the samples measured it, its peak bounded by them (see MODEL_LOBE_SEEN)
        seen = s.max(axis=1, initial=0.0) >= MODEL_LOBE_SEEN
        y_top = np.where(use.T[..., None], y, 0).max(axis=0, initial=0.0).astype(np.float64)  # (p, 3)
        two = (ok & seen)[:, None] & (s2 > 0.0) & (s2 * MODEL_LOBE_SEEN <= y_top)
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


def _vertex_values(samples: np.ndarray, normals: np.ndarray, tri: Triangulation, horizon: np.ndarray | None,
                   n_az: int, sm: ShadingModel, *, trend: bool, extrapolate: bool, backend: str, dt
                   ) -> tuple[np.ndarray, np.ndarray]:
    """What :func:`maps_from_fit` interpolates, pixel chunk by pixel chunk: (vals (V, P, 3) in
    ``dt`` - the samples (less the trusted model with ``trend``), then with ``extrapolate`` the
    virtual lights' values - each pixel offset to be non-negative; that offset (P, 3) float64)."""
    k, p = samples.shape[:2]
    verts = tri.vertices
    b = len(verts) - k
    trust = sm.trust
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
    return vals, offset


def _map_triangulation(tri: Triangulation, k: int, active: np.ndarray, extrapolate: bool) -> Triangulation:
    """The triangulation the maps are made on: ``tri`` with the kept texels ``active``, its
    virtual lights counted as samples with ``extrapolate`` (they carry values, not black)."""
    verts = tri.vertices
    if extrapolate:
        return Triangulation(vertices=verts, n_samples=len(verts), faces=tri.faces,
                             texel_vertices=tri.texel_vertices, texel_weights=tri.texel_weights,
                             active=np.asarray(active, dtype=bool), map_size=tri.map_size)
    return Triangulation(vertices=verts, n_samples=k, faces=tri.faces, texel_vertices=tri.texel_vertices,
                         texel_weights=tri.texel_weights, active=np.asarray(active, dtype=bool),
                         map_size=tri.map_size)


def _spline_inputs(verts: np.ndarray, k: int, map_tri: Triangulation, act: np.ndarray):
    """(inside (Q,) columns of the active texels ``act`` inside the samples' hull, their spline
    weights (Q, K), their triangles' sample ids (Q, 3)), or None when no texel has spline weights."""
    from .spline import spline_weights

    inside = np.flatnonzero(spline_texels(map_tri.texel_vertices[act], k))
    sw = spline_weights(verts[:k], map_tri.texel_dirs[act][inside]) if inside.size else None
    if sw is None:
        return None
    return (inside, sw, map_tri.texel_vertices[act[inside]])


def _blend_spline_chunks(maps: np.ndarray, samples: np.ndarray, blend: np.ndarray, smooth, n_act: int, dt) -> None:
    """In place, NumPy's spline blend: pixel-major maps (P, 3, T_pad) blended with the spline of
    their samples (``smooth``: :func:`_spline_inputs`) where ``blend`` (P,) < 1, clipped at 0."""
    p = samples.shape[1]
    for p0 in range(0, p, PIXEL_CHUNK):
        ps = slice(p0, min(p0 + PIXEL_CHUNK, p))
        if (blend[ps] < 1.0).any():
            m = maps[ps, :, :n_act].astype(dt)
            blend_spline(m, samples[:, ps], blend[ps], *smooth)
            maps[ps, :, :n_act] = np.clip(m, 0.0, None)


def maps_from_fit(samples: np.ndarray, normals: np.ndarray, tri: Triangulation, horizon: np.ndarray | None,
                  n_az: int, sm: ShadingModel, blend: np.ndarray, active: np.ndarray, *,
                  trend: bool = True, extrapolate: bool = True, paper_adaptation: bool = False,
                  spline: bool = True, backend: str = "opencl", half: bool = False, texel_major: bool = False,
                  codes: tuple[np.ndarray, np.ndarray] | None = None, progress=None):
    """The maps of :func:`model_maps` from its fits (:func:`fit_model`: the shading model ``sm``,
    the spline ``blend`` (P,), the kept texels ``active`` (T,) bool), for these pixels (any
    subset of the fitted ones, with their fits). Returns (maps, the triangulation whose
    ``active`` texels they hold); maps (P, 3, T_pad), or with ``texel_major`` (T_pad, 3, P)
    float32 (what the transport's projections read; OpenCL only). ``codes``: the storage codes
    (codes (K, P, 3) uint8, scale (P, 3)) the samples were decoded from, when they were
    (:mod:`relight.kernels.recipe`): the OpenCL spline is then summed exactly from them, and a
    pixel's maps do not depend on which other pixels are made with it (or on the CPU)."""
    k, p = samples.shape[:2]
    trust = sm.trust
    dt = np.float64 if samples.dtype == np.float64 else np.float32  # float64 in: the stability reference
    vals, offset = _vertex_values(samples, normals, tri, horizon, n_az, sm, trend=trend, extrapolate=extrapolate,
                                  backend=backend, dt=dt)
    if horizon is not None and (trust < 0.5).any():
        # Where the model does not explain the samples, neither does its geometry's shadowing:
        # those pixels interpolate without visibility (an open sky: every light visible).
        horizon = np.where((trust < 0.5)[:, None], np.float32(OPEN_SKY), horizon).astype(np.float32)
    map_tri = _map_triangulation(tri, k, active, extrapolate)
    # The kernel takes the offset off and adds the trusted model back at each texel in float32,
    # then stores float16 with ``half`` (the bundle's storage; keeps large captures' memory down).
    coef = trust[:, None] * sm.albedo if trend else np.zeros_like(sm.albedo)
    spec = trust[:, None] * sm.spec if trend else np.zeros_like(sm.spec)
    if texel_major and backend != "opencl":
        raise InputError("texel-major maps are made by the OpenCL backend only")
    act = np.flatnonzero(map_tri.active)
    smooth = _spline_inputs(tri.vertices, k, map_tri, act) if spline and (blend < 1.0).any() else None
    # The OpenCL kernel blends the spline in itself (its values from BLAS, chunk by chunk).
    blend_in = None
    if smooth is not None and backend == "opencl":
        blend_in = (samples, smooth[0], smooth[1], np.asarray(blend, dtype=np.float32), codes)
    maps = compute_maps(vals, normals, map_tri, horizon=horizon, n_az=n_az, adaptation=paper_adaptation,
                        backend=backend, half=half and not texel_major, trend=(offset, coef, spec),
                        texel_major=texel_major, spline=blend_in, progress=progress)
    if smooth is not None and blend_in is None:
        _blend_spline_chunks(maps, samples, blend, smooth, act.size, dt)
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


def blend_spline(m: np.ndarray, samples: np.ndarray, weight: np.ndarray, inside: np.ndarray,
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


