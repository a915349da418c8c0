"""Reflectance maps from their fits (``full``'s maps, paper section 3.2 with the shading model):
what the capture and the relight side both run - the capture once its fits are made, a bundle to
make its maps again from the fits it stores (:mod:`relight.kernels.recipe`).

A reflectance map (64x32 lat-long by default, the layout of :mod:`relight.directions`) holds,
per light direction, what the pixel shows under a flash-strength light from there. Here: the
shading model's form (:class:`ShadingModel`: (albedo x cosine + a broad specular lobe) x
visibility) and its value at the vertices; what the virtual lights beyond the captured hull
carry of their nearest samples (skin's indirect and subsurface light does not stop where the
Lambert term does: :func:`carry_weights`, :func:`carried`); and :func:`maps_from_fit`, which
interpolates the samples' residual over the triangulation (:mod:`relight.kernels.interpolation`),
adds the model back and blends each pixel with the thin-plate spline of its samples
(:mod:`relight.kernels.spline`, :func:`blend_spline`). The NumPy code is the reference; it works
in chunks of pixels so its memory stays bounded. The fits themselves are the capture's (stage 5
fitting): :mod:`relight.pipeline.shading_fit`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from relight.errors import InputError, NumericalError
from relight.numerics import TINY_SCALE

from .interpolation import OPEN_SKY, PIXEL_CHUNK, compute_maps, lobe, visibility_at
from .triangulation import Triangulation

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
    (:func:`relight.pipeline.shading_fit.shading_model`): albedo, spec (P, 3) float64 linear, trust
    (P,) 0-1."""

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


def vertex_model(sm: ShadingModel, normals: np.ndarray, verts: np.ndarray, vis: np.ndarray,
                  horizon: np.ndarray | None) -> np.ndarray:
    """(V, p, 3) the shading model at the vertices for a chunk of pixels (sm, normals, vis of the
    chunk): open-sky pixels (trust < 0.5) see every vertex."""
    if horizon is not None:
        open_sky = sm.trust < 0.5
        if open_sky.any():
            vis = np.where(open_sky[:, None], np.float32(1.0), vis)
    return sm.at(normals, verts, vis)


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
        model = vertex_model(chunk_sm, n[ps], verts_dt, vis, horizon)  # (V, p, 3)
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
            carry = carried(left, carry_ids, carry_w.astype(dt))
            virt = ((1.0 - tw) * model[k:] if trend else model[k:]) + carry
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
    """The maps of :func:`relight.pipeline.shading_fit.model_maps` from its fits
    (:func:`relight.pipeline.shading_fit.fit_model`: the shading model ``sm``, the spline
    ``blend`` (P,), the kept texels ``active`` (T,) bool), for these pixels (any subset of the
    fitted ones, with their fits). Returns (maps, the triangulation whose
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


def carried(left: np.ndarray, ids: np.ndarray, w: np.ndarray) -> np.ndarray:
    """(B, p, 3) what each virtual light carries of its nearest samples: sum over n of
    w[b, n] x left[ids[b, n]] (left (K, p, 3); one gather per neighbour, not one array of all)."""
    out = w[:, 0, None, None] * left[ids[:, 0]]
    for j in range(1, ids.shape[1]):
        out += w[:, j, None, None] * left[ids[:, j]]
    return out


def spline_texels(texel_vertices: np.ndarray, k: int) -> np.ndarray:
    """(n,) bool: the texels the spline blends into - those whose triangle is made of samples
    (vertex ids < k), i.e. inside the samples' hull (:func:`relight.pipeline.triangulate.triangulate`
    gives those texels the samples' own cap triangles; a triangle of three samples lies inside
    their hull)."""
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
