"""The capture's fits for its reflectance maps (stage 5 fitting, paper section 3.2 and the
shading model that ``full`` adds to it): per pixel the shading model ((albedo x cosine + a broad
specular lobe) x visibility, :func:`shading_model`), fitted to the samples and rounded as a
bundle stores it; the texels the maps keep beyond the captured hull; the spline's weight
(:mod:`.stacking`). :func:`model_maps` makes the maps from them through
:func:`relight.kernels.reflectance.maps_from_fit` - what the relight side also runs, from the
fits a bundle stores, to make them again."""

from __future__ import annotations

import numpy as np

from relight.errors import InputError
from relight.kernels.interpolation import PIXEL_CHUNK, lobe, visibility_at
from relight.kernels.reflectance import ShadingModel, carried, carry_weights, maps_from_fit, vertex_model
from relight.kernels.triangulation import Triangulation
from relight.numerics import EPS_NORM, EPS_VALUE, TINY_SCALE

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


def shading_model(samples: np.ndarray, normals: np.ndarray, tri: Triangulation,
                  vertex_vis: np.ndarray) -> ShadingModel:
    """Per pixel the shading model ``(albedo x max(n . l, 0) + spec x lobe(l)) x visibility(l)``
    (visibility: the smoothed visibility maps of the horizon table, as the interpolation reads
    them; 1 without one; lobe: :func:`relight.kernels.interpolation.lobe`).

    Albedo and spec are fitted by least squares to the samples that light the pixel well (cosine >
    ``MODEL_MIN_COS``, visibility > ``MODEL_MIN_VIS``), per channel, spec >= 0 (a channel whose
    lobe would come out negative is refitted with albedo alone), the lobe only where those samples
    saw it (``MODEL_LOBE_SEEN``) and its peak stays within what they bound (spec at most the
    brightest of them / ``MODEL_LOBE_SEEN``; else albedo alone); 0 where no sample lights the
    pixel. The trust ramps from 0 to 1 as the fit's R^2 over those samples goes from
    ``MODEL_R2_NONE`` to ``MODEL_R2_FULL`` (0 with fewer than 4 of them). vertex_vis : (P, >= K)
    visibility at the vertices' texels (:func:`relight.kernels.interpolation.visibility_at` of
    ``tri.vertex_texel``; ones without a horizon table)."""
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
    this is :func:`relight.kernels.interpolation.compute_maps` without adaptation. The
    interpolation (visibility-aware with a horizon table) is a convex combination of vertex
    values, so residuals are interpolated offset to be non-negative and the offset taken off
    again. paper_adaptation (no trend): the
    paper's light adaptation (``compute_maps``' ``adaptation``) over samples + model lights.
    spline : inside the captured directions each pixel blends this path with the thin-plate
    spline of its samples (:mod:`relight.kernels.spline`; capped at the brightest sample of the
    texel's triangle), by the weight that best predicts left-out samples (stacking, fitted over
    a window of neighbouring pixels when ``grid``, the (H, W) mask of the P pixels, is given).
    reach_deg : with ``extrapolate``, model light is kept only this far from a captured direction.
    fit_out : a dict that receives the fits (``model``: the
    :class:`relight.kernels.reflectance.ShadingModel`, ``blend``) - with the samples, normals,
    horizon and triangulation, all :func:`relight.kernels.reflectance.maps_from_fit` (and
    :mod:`relight.kernels.recipe`) needs to make the maps again.
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
        from .stacking import leave_one_out, stacking_terms, stacking_weight

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
        model = vertex_model(fit, np.asarray(normals[ps], dtype=dt), verts_dt, vis, horizon)  # (V, p, 3)
        if loo is not None:
            num[ps], den[ps] = stacking_terms(samples[:, ps], model[:k], fit.trust, loo)
        if b:  # where the model (and what it leaves of the nearest samples) lights some pixel
            left = np.maximum(samples[:, ps].astype(dt) - model[:k], 0.0)
            carry = carried(left, carry_ids, carry_w.astype(dt))
            lit_vertex[k:] |= (model[k:] + carry).max(axis=(1, 2)) > MODEL_KEEP * peak
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
