"""The maps' recipe: what a bundle keeps instead of its reflectance maps, read back from the
bundle and evaluated.

A pixel's reflectance map (64x32 texels, ~1000-2000 of them lit) is made by
:func:`relight.pipeline.shading_fit.model_maps` from the capture's light samples and a handful
of per-pixel fits: the shading model (albedo, specular weight, trust), the horizon table
(visibility), and the weight of the model path against the thin-plate spline. Those are what a
bundle stores - about K + 100 bytes per face pixel for K samples, against 2 x 3 x T bytes for
the maps themselves (12 KB at T = 2000) - and any texel of any pixel's map is evaluated from
them on demand, exactly as the capture made it:

* :func:`texel_rows` - a few texels for every pixel (a sun, a point light: the exact part of the
  compact relight), in NumPy, pixel chunk by pixel chunk;
* :func:`recipe_maps` - every texel for some or all pixels (the exact path, the live light
  estimate's pixels), through the same kernels as the capture.

Storage (the bundle's ``samples_code`` / ``samples_scale`` / ``horizon_code``):

* samples as 8-bit codes ``q = round(255 (x / s) ** SAMPLE_GAMMA)`` with ``s`` (per pixel and
  channel, float16, rounded up) the pixel's brightest sample: relative steps of ~1 % at mid
  code, ~0.4 % at the top; the spline's power domain is this gamma, so it works on the codes
  directly. Negative values (flash minus no-flash noise) are stored as 0: light is not
  negative, and the maps clip there anyway.
* horizons as 8-bit elevation angles, steps of 180/255 = 0.7 degrees (the visibility step is a
  texel, 5.6 degrees, wide).

The capture quantises first and builds everything from the decoded values, so the maps a
bundle evaluates are the maps its capture made (to float rounding); the capture's side -
encoding the samples, quantising the horizons, the recipe's arrays for the bundle - is
:mod:`relight.pipeline.recipe_write`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from relight.directions import equirect_directions
from relight.errors import InputError, NumericalError
from relight.numerics import EPS, EPS_NORM, EPS_VALUE

from . import interpolation as interp
from . import reflectance as rf
from . import triangulation
from .bundle_format import Field
from .maps import neighbourhoods
from .spline import SPLINE_GAMMA, spline_weights

#: Sample codes: x = scale * (q / 255) ** (1 / SAMPLE_GAMMA); the spline's own power domain.
SAMPLE_GAMMA = SPLINE_GAMMA
#: Pixels per chunk of the NumPy evaluation (bounds its scratch memory).
ROW_CHUNK = 16384


# ---------------------------------------------------------------------- quantisation
def _code_table(gamma: float) -> np.ndarray:
    return ((np.arange(256, dtype=np.float64) / 255.0) ** gamma).astype(np.float32)


_DECODE = _code_table(1.0 / SAMPLE_GAMMA)
_POWER = _code_table(1.0)  # the codes in the spline's power domain, per unit scale


def decode_samples(codes: np.ndarray, scale: np.ndarray, ids=slice(None), pixels=slice(None)) -> np.ndarray:
    """(k, p, 3) float32 linear samples of the codes ``ids`` (sample indices) and ``pixels``."""
    q = np.asarray(codes[ids])[:, pixels]
    return _DECODE[q] * np.asarray(scale[pixels], dtype=np.float32)[None]


def encode_horizon(elevations: np.ndarray) -> np.ndarray:
    """(P, n_az) uint8 codes of horizon elevations (radians, -pi/2..pi/2)."""
    e = np.asarray(elevations, dtype=np.float64)
    return np.rint((e / np.pi + 0.5) * 255.0).clip(0, 255).astype(np.uint8)


#: code -> elevation (radians)
_ELEVATION = ((np.arange(256) / 255.0 - 0.5) * np.pi).astype(np.float32)


def decode_horizon(codes: np.ndarray) -> np.ndarray:
    """(P, n_az) float32 horizon elevations (radians) of their codes."""
    return _ELEVATION[np.asarray(codes, dtype=np.uint8)]


# ---------------------------------------------------------------------- the recipe
@dataclass
class Recipe:
    """Everything :func:`relight.pipeline.shading_fit.model_maps` needs to make any texel again.

    codes (K, P, 3) uint8 / scale (P, 3): the samples
    (:func:`relight.pipeline.recipe_write.encode_samples`). normals (P, 3).
    horizon (P, n_az) float32 elevations (or their uint8 codes), or None (no visibility).
    albedo, spec (P, 3), trust (P,): the shading model
    (:class:`relight.kernels.reflectance.ShadingModel`). blend (P,): the model path's weight
    against the spline (1: no spline). tri: the samples' triangulation;
    active (T,) bool the map texels kept. trend / extrapolate / spline: model_maps' options.
    """

    codes: np.ndarray
    scale: np.ndarray
    normals: np.ndarray
    horizon: np.ndarray | None
    albedo: np.ndarray
    spec: np.ndarray
    trust: np.ndarray
    blend: np.ndarray
    tri: triangulation.Triangulation
    active: np.ndarray
    n_az: int
    trend: bool = True
    extrapolate: bool = True
    spline: bool = True
    horizon_index: np.ndarray | None = None  # (P,) row of ``horizon`` per pixel (None: a row each)

    @property
    def n_pixels(self) -> int:
        return int(self.normals.shape[0])

    @property
    def n_samples(self) -> int:
        return int(self.codes.shape[0])

    def samples(self, pixels=slice(None)) -> np.ndarray:
        return decode_samples(self.codes, self.scale, pixels=pixels)

    def horizon_elevations(self, pixels=slice(None)) -> np.ndarray | None:
        """(p, n_az) float32 horizon elevations (decoded when stored as codes), or None."""
        if self.horizon is None:
            return None
        rows = pixels if self.horizon_index is None else np.asarray(self.horizon_index)[pixels]
        h = np.asarray(self.horizon)[rows]
        return decode_horizon(h) if h.dtype == np.uint8 else h.astype(np.float32, copy=False)

    def subset(self, pixels: np.ndarray) -> Recipe:
        """The recipe of some pixels (an index array or slice)."""
        return Recipe(codes=np.asarray(self.codes)[:, pixels], scale=np.asarray(self.scale)[pixels],
                      normals=np.asarray(self.normals)[pixels],
                      horizon=(None if self.horizon is None else self.horizon if self.horizon_index is not None
                               else np.asarray(self.horizon)[pixels]),
                      horizon_index=(None if self.horizon_index is None
                                     else np.asarray(self.horizon_index)[pixels]),
                      albedo=np.asarray(self.albedo)[pixels], spec=np.asarray(self.spec)[pixels],
                      trust=np.asarray(self.trust)[pixels], blend=np.asarray(self.blend)[pixels], tri=self.tri,
                      active=self.active, n_az=self.n_az, trend=self.trend, extrapolate=self.extrapolate,
                      spline=self.spline)


def recipe_maps(recipe: Recipe, *, backend: str = "opencl", half: bool = True, texel_major: bool = False,
                progress=None) -> np.ndarray:
    """(P, 3, T_pad) maps of every active texel, as the capture made them (float16 with
    ``half``), or with ``texel_major`` (T_pad, 3, P) float32 (OpenCL)."""
    sm = rf.ShadingModel(albedo=np.asarray(recipe.albedo, np.float64), spec=np.asarray(recipe.spec, np.float64),
                         trust=np.asarray(recipe.trust, np.float64))
    maps, _ = rf.maps_from_fit(recipe.samples(), np.asarray(recipe.normals, np.float32), recipe.tri,
                               recipe.horizon_elevations(),
                               recipe.n_az, sm, np.asarray(recipe.blend, np.float64), recipe.active,
                               trend=recipe.trend, extrapolate=recipe.extrapolate, spline=recipe.spline,
                               backend=backend, half=half, texel_major=texel_major,
                               codes=(recipe.codes, recipe.scale), progress=progress)
    return maps


#: Most horizon azimuths a bundle's recipe may name (capture uses 64).
MAX_AZIMUTHS = 1024


def recipe_from_arrays(arrays: dict, meta: dict, map_size) -> Recipe:
    """The recipe a bundle stores (:mod:`relight.kernels.bundle`, fields marked (r))."""
    verts = np.asarray(arrays[Field.TRI_VERTICES], dtype=np.float64)
    codes = arrays[Field.SAMPLES_CODE]
    k = int(codes.shape[0])
    p = int(arrays[Field.PIXELS].shape[0])
    tv = np.asarray(arrays[Field.TRI_TEXEL_VERTICES], dtype=np.int64)
    tw = np.asarray(arrays[Field.TRI_TEXEL_WEIGHTS], dtype=np.float64)
    w, h = map_size
    if (codes.shape != (k, p, 3) or arrays[Field.SAMPLES_SCALE].shape != (p, 3) or tv.shape != (w * h, 3)
            or tw.shape != (w * h, 3) or verts.ndim != 2 or verts.shape[1:] != (3,) or len(verts) < k
            or (tv.size and (tv.min() < 0 or tv.max() >= len(verts)))):
        raise InputError("the bundle's recipe fields do not fit together (samples, pixels, triangulation); "
                         "the bundle is damaged - capture it again")
    active = np.zeros(w * h, dtype=bool)
    tex = np.asarray(arrays[Field.MAP_TEXELS], dtype=np.int64)
    if tex.size and (tex.min() < 0 or tex.max() >= w * h):
        raise InputError("the bundle's map_texels lie outside its map; capture it again")
    active[tex] = True
    tri = triangulation.Triangulation(vertices=verts, n_samples=k,
                                      faces=np.asarray(arrays[Field.TRI_FACES], dtype=np.int64), texel_vertices=tv,
                                      texel_weights=tw, active=(tv < k).any(axis=1), map_size=(w, h))
    opts = meta.get("recipe", {}) if isinstance(meta.get("recipe"), dict) else {}
    hz, hidx = arrays.get(Field.HORIZON_CODE), arrays.get(Field.HORIZON_INDEX)
    if hz is not None and not _horizon_fits(hz, hidx, p):
        raise InputError("the bundle's horizon fields do not fit its pixels; the bundle is damaged - capture it again")
    n_az = opts.get("n_az", 64 if hz is None else hz.shape[1])
    if isinstance(n_az, bool) or not isinstance(n_az, int) or not (1 <= n_az <= MAX_AZIMUTHS) \
            or (hz is not None and n_az != hz.shape[1]):
        raise InputError(f"the bundle's recipe says {n_az!r} horizon azimuths, its horizon_code holds "
                         f"{None if hz is None else hz.shape[1]}; the bundle is damaged - capture it again")
    return Recipe(codes=codes, scale=arrays[Field.SAMPLES_SCALE], normals=arrays[Field.NORMAL],
                  horizon=hz, horizon_index=None if hz is None else hidx, albedo=arrays[Field.MODEL_ALBEDO],
                  spec=arrays[Field.MODEL_SPEC],
                  trust=arrays[Field.MODEL_TRUST], blend=arrays[Field.SPLINE_BLEND], tri=tri, active=active,
                  n_az=n_az, trend=bool(opts.get("trend", True)),
                  extrapolate=bool(opts.get("extrapolate", True)), spline=bool(opts.get("spline", True)))


def _horizon_fits(hz: np.ndarray, hidx: np.ndarray | None, p: int) -> bool:
    if hz.ndim != 2:
        return False
    if hidx is None:
        return hz.shape[0] == p
    return hidx.shape == (p,) and (p == 0 or (int(np.min(hidx)) >= 0 and int(np.max(hidx)) < hz.shape[0]))


# ---------------------------------------------------------------------- a few texels
def smoothed_visibility(horizon: np.ndarray, n_az: int, map_size, texels: np.ndarray) -> np.ndarray:
    """(p, n) the smoothed visibility (:func:`relight.kernels.interpolation.visibility_maps`) of
    the map texels ``texels`` for each pixel of a horizon table (p, n_az) of elevations, float32."""
    w, h = map_size
    nb = neighbourhoods(map_size, texels)
    uniq, inv = np.unique(nb, return_inverse=True)
    d = equirect_directions(w, h).reshape(-1, 3)[uniq]
    s = np.hypot(d[:, 0], d[:, 1])
    beta = np.mod(np.arctan2(d[:, 1], d[:, 0]), 2 * np.pi)
    pos = beta / (2 * np.pi) * n_az - 0.5
    i0 = np.floor(pos).astype(np.int64) % n_az
    f = (pos - np.floor(pos)).astype(np.float32)
    hz = horizon[:, i0] * (1 - f) + horizon[:, (i0 + 1) % n_az] * f
    elev = np.arctan2(d[:, 2], np.maximum(s, EPS_NORM)).astype(np.float32)
    soft = np.float32(interp.VIS_SOFT_TEXELS * np.pi / h)
    vis = np.clip(0.5 + (elev[None] - hz) / soft, 0.0, 1.0).astype(np.float32)
    vis[:, s < EPS_VALUE] = 1.0
    return vis[:, inv.reshape(nb.shape)].mean(axis=2, dtype=np.float32)


def texel_rows(recipe: Recipe, texels: np.ndarray, *, pixels=None) -> np.ndarray:
    """(n, 3, P) float32 maps of the given map texels (ids into the map, all active) for every
    pixel (or the index array ``pixels``), evaluated from the recipe as
    :func:`relight.pipeline.shading_fit.model_maps` makes them."""
    texels = np.asarray(texels, dtype=np.int64).ravel()
    if texels.size and not recipe.active[texels].all():
        raise InputError("texel_rows: a requested texel is not among the bundle's map texels")
    p_all = recipe.n_pixels if pixels is None else len(pixels)
    out = np.zeros((texels.size, 3, p_all), dtype=np.float32)
    if texels.size == 0 or p_all == 0:
        return out
    tri, k = recipe.tri, recipe.n_samples
    verts = tri.vertices
    tv = tri.texel_vertices[texels]  # (n, 3)
    tw = tri.texel_weights[texels].astype(np.float32)
    need_v = np.unique(tv)
    virt = need_v[need_v >= k]
    carry_ids = carry_w = None
    if virt.size and recipe.extrapolate:
        carry_ids, carry_w = rf.carry_weights(verts, k)
        carry_ids, carry_w = carry_ids[virt - k], carry_w[virt - k].astype(np.float32)  # (b, 3)
    model_v = np.unique(np.concatenate([need_v, [] if carry_ids is None else carry_ids.ravel()]).astype(np.int64))
    samp_v = model_v[model_v < k]
    col = {int(v): i for i, v in enumerate(model_v)}
    vtex = tri.vertex_texel[model_v]
    tdirs = tri.texel_dirs[texels]
    # The spline part: texels inside the samples' hull, for pixels whose blend is below 1.
    spl_w = None
    if recipe.spline:
        inside = np.flatnonzero(rf.spline_texels(tv, k))
        if inside.size:
            w_ = spline_weights(verts[:k], tdirs[inside])
            if w_ is not None:
                spl_w = (inside, w_.astype(np.float32))
    pix_all = np.arange(recipe.n_pixels) if pixels is None else np.asarray(pixels, dtype=np.int64)
    for c0 in range(0, p_all, ROW_CHUNK):
        ps = pix_all[c0:c0 + ROW_CHUNK]
        out[:, :, c0:c0 + len(ps)] = _rows_chunk(recipe, ps, texels, tv, tw, model_v, samp_v, col, vtex, tdirs,
                                                 virt, carry_ids, carry_w, spl_w)
    if not np.isfinite(out).all():
        raise NumericalError("non-finite reflectance from the recipe; this is a bug, please report it")
    return out


def _chunk_visibility(r: Recipe, ps, texels: np.ndarray, vtex: np.ndarray, trust: np.ndarray):
    """The chunk's smoothed visibility, float32: (at the model's vertices' texels ``vtex``
    (p, m), at the requested ``texels`` (p, n), at the vertices' texels as the interpolation
    sees them (p, m) or None without a horizon)."""
    p, n_t = len(ps), texels.size
    if r.horizon is None:
        return np.ones((p, len(vtex)), np.float32), np.ones((p, n_t), np.float32), None
    hz = r.horizon_elevations(ps)
    open_sky = trust < 0.5
    # The model at the vertices sees the horizon itself (open-sky pixels: every light); the
    # interpolation and the trend see open-sky pixels' horizon as far below every light.
    vis_m = smoothed_visibility(hz, r.n_az, r.tri.map_size, vtex)
    vis_m[open_sky] = 1.0
    hz_i = np.where(open_sky[:, None], np.float32(interp.OPEN_SKY), hz)
    both = smoothed_visibility(hz_i, r.n_az, r.tri.map_size, np.concatenate([texels, vtex]))
    return vis_m, both[:, :n_t], both[:, n_t:]


def _vertex_rows(r: Recipe, x: np.ndarray, model: np.ndarray, trust: np.ndarray, model_v: np.ndarray,
                 samp_v: np.ndarray, col: dict, virt: np.ndarray, carry_ids, carry_w) -> np.ndarray:
    """(m, p, 3) float32 the values the interpolation reads at the vertices ``model_v``: the
    samples ``x`` (s, p, 3) less the trusted model (with the trend), the virtual lights' model
    and what it leaves of their nearest samples (with extrapolation; else black)."""
    k = r.n_samples
    p = x.shape[1]
    xi = {int(v): i for i, v in enumerate(samp_v)}
    tw_ = trust[None, :, None] if r.trend else None
    vals = np.zeros((len(model_v), p, 3), np.float32)
    for v in model_v:
        i = col[int(v)]
        if v < k:
            vals[i] = x[xi[int(v)]] - (tw_[0] * model[i] if r.trend else 0.0)
    if virt.size and r.extrapolate:
        for b, v in enumerate(virt):
            i = col[int(v)]
            base = (1.0 - tw_[0]) * model[i] if r.trend else model[i]
            carried = np.zeros((p, 3), np.float32)
            for j in range(carry_ids.shape[1]):
                c = int(carry_ids[b, j])
                carried += carry_w[b, j] * np.maximum(x[xi[c]] - model[col[c]], 0.0)
            vals[i] = base + carried
    # (virtual vertices without extrapolation are black: their vals stay 0)
    return vals


def _subset_mix(tw: np.ndarray, use: np.ndarray, cv: np.ndarray) -> np.ndarray:
    """(n, p, 3) the texels' interpolation over a subset of their vertices: the barycentric
    weights tw (n, 3) times ``use`` (n, 3, p), renormalised, over the vertex values cv (n, 3, p, 3)."""
    wgt = tw[:, :, None] * use
    wgt = wgt / np.maximum(wgt.sum(axis=1, keepdims=True), EPS)
    return np.einsum("tvp,tvpc->tpc", wgt, cv)


def _interpolate_rows(tw: np.ndarray, cv: np.ndarray, ci: np.ndarray, vis_t: np.ndarray, vis_iv) -> np.ndarray:
    """(n, p, 3) the texels' interpolation of their vertices' values cv (n, 3, p, 3) with
    barycentric weights tw (n, 3), visibility-aware with a horizon (vis_t (p, n) at the texels,
    vis_iv (p, m) at the vertices, ci (n, 3) their columns)."""
    regular = np.einsum("tv,tvpc->tpc", tw, cv)
    if vis_iv is None:
        return regular
    vv = vis_iv[:, ci].transpose(1, 2, 0)  # (n, 3v, p)
    vp = vis_t.T  # (n, p)
    vmin, vmax = vv.min(axis=1), vv.max(axis=1)
    spread = vmax - vmin
    sp = np.maximum(spread, EPS_VALUE)
    lit = np.clip((vv - vmin[:, None]) / sp[:, None], 0.0, 1.0)
    t_lit = np.clip((vp - vmin) / sp, 0.0, 1.0)[..., None]
    aware = t_lit * _subset_mix(tw, lit, cv) + (1 - t_lit) * _subset_mix(tw, 1.0 - lit, cv)
    return (1 - spread[..., None]) * regular + spread[..., None] * aware


def _blend_rows_spline(r: Recipe, ps, texels: np.ndarray, m: np.ndarray, spl_w) -> None:
    """In place: the rows m (n, p, 3) at the texels inside the hull (``spl_w``: their columns,
    spline weights (Q, K)) blended with the spline of the codes, capped at the brightest sample
    of each texel's triangle, for the pixels whose blend is below 1."""
    k = r.n_samples
    blend = np.asarray(r.blend[ps], dtype=np.float32)
    sel = np.flatnonzero(blend < 1.0)
    if sel.size:
        inside, w_ = spl_w
        q = _POWER[np.asarray(r.codes)[:, ps[sel]]]  # (K, s, 3): (x / scale) ** gamma
        spl = (w_ @ q.reshape(k, -1)).reshape(len(inside), sel.size, 3)
        np.clip(spl, 0.0, None, out=spl)
        sc = np.asarray(r.scale[ps[sel]], dtype=np.float32)
        spl = spl ** np.float32(1.0 / SAMPLE_GAMMA) * sc[None]
        corners = r.tri.texel_vertices[texels[inside]]  # sample ids (inside the hull)
        cap = np.max(_DECODE[np.asarray(r.codes)[corners.ravel()][:, ps[sel]]].reshape(
            len(inside), 3, sel.size, 3), axis=1) * sc[None]
        np.minimum(spl, cap, out=spl)
        b = blend[sel][None, :, None]
        m[np.ix_(inside, sel)] = np.clip(b * m[np.ix_(inside, sel)] + (1 - b) * spl, 0.0, None)


def _rows_chunk(r: Recipe, ps, texels, tv, tw, model_v, samp_v, col, vtex, tdirs, virt, carry_ids, carry_w, spl_w):
    """(n, 3, p) float32 rows of the map texels ``texels`` for the pixels ``ps`` (see
    :func:`texel_rows`, which prepares the rest: the texels' triangles tv (n, 3) and weights tw,
    the vertices the model is evaluated at ``model_v`` (``col``: their rows, ``vtex``: their
    texels; ``samp_v`` the samples among them, ``virt`` the virtual ones with their carried
    samples), the texels' directions tdirs (n, 3), the spline part ``spl_w`` or None)."""
    normals = np.asarray(r.normals[ps], dtype=np.float32)
    trust = np.asarray(r.trust[ps], dtype=np.float32)
    albedo = np.asarray(r.albedo[ps], dtype=np.float32)
    spec = np.asarray(r.spec[ps], dtype=np.float32)
    vis_m, vis_t, vis_iv = _chunk_visibility(r, ps, texels, vtex, trust)
    sm = rf.ShadingModel(albedo=albedo, spec=spec, trust=trust)
    model = sm.at(normals, r.tri.vertices[model_v].astype(np.float32), vis_m)  # (m, p, 3)
    x = decode_samples(r.codes, r.scale, ids=samp_v, pixels=ps)  # (s, p, 3)
    vals = _vertex_rows(r, x, model, trust, model_v, samp_v, col, virt, carry_ids, carry_w)
    ci = np.vectorize(col.get, otypes=[np.int64])(tv)  # (n, 3) rows of vals
    cv = vals[ci]  # (n, 3v, p, 3c)
    regular = _interpolate_rows(tw, cv, ci, vis_t, vis_iv)
    if r.trend:
        coef = trust[:, None] * albedo
        spc = trust[:, None] * spec
        lit_t = np.clip(normals @ tdirs.T.astype(np.float32), 0.0, None) * vis_t  # (p, n)
        lobe_t = interp.lobe(normals, tdirs.astype(np.float32)) * vis_t
        regular = regular + lit_t.T[..., None] * coef[None] + lobe_t.T[..., None] * spc[None]
    m = np.clip(regular, 0.0, None)  # (n, p, 3)
    if spl_w is not None:
        _blend_rows_spline(r, ps, texels, m, spl_w)
    return m.transpose(0, 2, 1)
