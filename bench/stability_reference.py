"""The two computations the numerical stability suite (:mod:`relight.bench.stability`) compares
for every problem: production, as the product runs it, and a float64 reference.

* **Production maps** are built exactly as :func:`relight.pipeline.bundle_arrays.finish` builds
  them: :func:`~relight.pipeline.triangulate.triangulate`, then for the triangulated variants
  :func:`~relight.kernels.interpolation.compute_maps` on the OpenCL device with float16 output
  (horizon from :func:`~relight.pipeline.capture.horizon_for` when visibility is on), for the
  fitted ones :func:`~relight.pipeline.methods.fit_and_evaluate` on the front texels; then
  stored as the bundle stores them (float16, subnormal halves flushed). ``detail`` also lists
  the builder's float32 result before that storage (the kernel run with float32 output): the
  arithmetic's own error, apart from the storage's.
* **Reference maps**, triangulated variants: the NumPy twin
  :func:`~relight.kernels.interpolation.build_maps` given float64 samples, normals and horizon.
  It interpolates and light-adapts in float64 when given float64 input; only its visibility
  maps (values in [0, 1]) and its returned array are float32, so the reference itself is
  exact to 2^-24 relative, far below the production's float16 storage (2^-11). Same
  triangulation (it is float64 in production too). Fitted variants: the same basis functions
  (imported from :mod:`relight.pipeline.methods`) solved here by ``np.linalg.lstsq`` in
  float64 and evaluated in float64, clamped at zero as the method defines.
* **Renders**: ``relight.Relighter`` renders the variant's tiny bundle (the exact path and the
  default compact one); the reference is the bundle's maps promoted to float64 times the
  float64 texel light (:meth:`Relighter.texel_light`, the light the kernels are given).

Also the problems themselves (:class:`MapProblem`, :class:`RenderProblem`), the variants as
the ``CaptureOptions`` that select them, and the error measure (:func:`relative_error`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from relight.errors import InputError
from relight.kernels import interpolation, triangulation
from relight.numerics import flush_subnormal_halves
from relight.pipeline import methods, recipe_write, shading_fit
from relight.pipeline.bundle_write import storage_scale
from relight.pipeline.triangulate import triangulate

from .variants import VARIANTS as CAPTURE_VARIANTS

#: The variants measured: the benchmark's (``relight.bench.variants.VARIANTS``), each as the
#: ``CaptureOptions`` fields that select it (visibility, light adaptation and extrapolation only
#: act on ``full``; the flags here are the effective ones).
VARIANTS: dict[str, dict] = {
    name: {"method": kw.get("method", "full"),
           "visibility": kw.get("visibility", True) and kw.get("method", "full") == "full",
           "adaptation": kw.get("adaptation", True) and kw.get("method", "full") == "full",
           "extrapolation": kw.get("extrapolation", True) and kw.get("method", "full") == "full",
           "paper_adaptation": kw.get("paper_adaptation", False),
           "spline": kw.get("spline", True) and kw.get("method", "full") == "full"}
    for name, kw in CAPTURE_VARIANTS.items()
}

#: Floor of the error's denominator (an all-zero reference compares as an absolute error).
TINY = float(np.finfo(np.float32).tiny)


@dataclass
class MapProblem:
    """One map-building input. dirs : (K, 3) float64 unit; samples : (K, P, 3) float32 linear;
    normals : (P, 3) float64 unit; horizon : (P, n_az) float32 elevations (used with visibility)."""

    label: str
    dirs: np.ndarray
    samples: np.ndarray
    normals: np.ndarray
    horizon: np.ndarray
    _tri: dict = field(default_factory=dict, repr=False)
    _ref: dict = field(default_factory=dict, repr=False)

    def triangulation(self, map_size) -> tuple[triangulation.Triangulation | InputError, float]:
        """(triangulation, or the InputError it raised; seconds it took): float64 and the same
        for every variant, so made once per map size."""
        key = tuple(map_size)
        if key not in self._tri:
            t0 = time.perf_counter()
            try:
                self._tri[key] = (triangulate(self.dirs, key), time.perf_counter() - t0)
            except InputError as exc:
                self._tri[key] = (exc, time.perf_counter() - t0)
        return self._tri[key]

    def reference(self, variant: str, tri: triangulation.Triangulation) -> np.ndarray:
        """:func:`reference_maps`, made once per distinct computation (``full -both`` and
        ``barycentric`` are the same one)."""
        opts = VARIANTS[variant]
        kind = opts["method"] if opts["method"] in methods.FITTED else "triangulated"
        key = (kind, opts["visibility"], opts["adaptation"], opts["extrapolation"], opts["paper_adaptation"],
               opts["spline"],
               tri.map_size)
        if key not in self._ref:
            self._ref[key] = reference_maps(variant, self, tri)
        return self._ref[key]


@dataclass
class RenderProblem:
    """One relight of the variant's bundle: env (H, 2H, 3) float32 radiance, a linear exposure."""

    label: str
    env: np.ndarray
    exposure: float = 1.0


def builder_maps(variant: str, problem: MapProblem, tri: triangulation.Triangulation, *,
                 half: bool) -> tuple[np.ndarray, float]:
    """(maps (P, 3, T_pad), scale) as :func:`relight.pipeline.capture.reflectance_maps` - the
    maps stage of ``bundle_arrays.finish`` - returns them (``tri``: the problem's
    :func:`~relight.pipeline.triangulate.triangulate`): the OpenCL kernel's float16 output with
    ``half`` (production) or its float32 output; a fitted method's float32. The maps hold the
    samples divided by ``scale``."""
    from relight.pipeline.capture_types import CaptureOptions
    from relight.pipeline.reflectance_maps import reflectance_maps

    opts = VARIANTS[variant]
    o = CaptureOptions(method=opts["method"], visibility=opts["visibility"], adaptation=opts["adaptation"],
                       extrapolation=opts["extrapolation"], paper_adaptation=opts["paper_adaptation"],
                       spline=opts["spline"],
                       map_size=tri.map_size)
    horizon = problem.horizon if opts["visibility"] else None
    maps, _, scale, _ = reflectance_maps(problem.samples, problem.normals, tri, o, horizon, half=half)
    return maps, scale


def production_maps(variant: str, problem: MapProblem, tri: triangulation.Triangulation) -> np.ndarray:
    """(P, 3, T_pad) float64: the maps as ``bundle_arrays.finish`` stores them (float16, subnormals
    flushed) times the bundle's ``sample_scale`` - what the renderer reads."""
    maps, scale = builder_maps(variant, problem, tri, half=True)
    return flush_subnormal_halves(maps.astype(np.float16, copy=False)).astype(np.float64) * scale


def reference_maps(variant: str, problem: MapProblem, tri: triangulation.Triangulation) -> np.ndarray:
    """(P, 3, T) float64-computed maps of the same method (see the module docstring)."""
    from relight.kernels import recipe

    opts = VARIANTS[variant]
    method = opts["method"]
    # The samples and horizons as a bundle stores them (production makes its maps from those:
    # 8-bit codes are the measurement, not the arithmetic under test), in the production's
    # storage units (divided by its power-of-two scale, multiplied back at the end).
    unit = storage_scale(problem.samples)
    codes, code_scale = recipe_write.encode_samples((problem.samples / unit).astype(np.float32))
    samples = (codes / 255.0) ** (1.0 / recipe.SAMPLE_GAMMA) * code_scale.astype(np.float64)[None]
    return unit * _reference_maps(opts, method, samples, problem, tri)


def _reference_maps(opts, method, samples, problem, tri):
    from relight.kernels.heightfield import HORIZON_DIRS

    if method not in methods.FITTED:
        vis = None
        horizon = problem.horizon if opts["visibility"] else None
        if horizon is not None:
            horizon = recipe_write.quantise_horizon(horizon).astype(np.float64)
        if horizon is not None:
            vis = interpolation.visibility_maps(horizon.astype(np.float64), HORIZON_DIRS, tri.map_size)
        trend = opts["adaptation"] and not opts["paper_adaptation"]
        if opts["method"] == "full" and (trend or opts["extrapolation"] or opts["spline"]):
            maps, tri = shading_fit.model_maps(samples, problem.normals.astype(np.float64), tri, horizon,
                                               HORIZON_DIRS, trend=trend, extrapolate=opts["extrapolation"],
                                               paper_adaptation=opts["adaptation"] and not trend,
                                               spline=opts["spline"], backend="numpy")
            return maps[:, :, :int(tri.active.sum())].astype(np.float64)
        maps = interpolation.build_maps(samples, problem.normals.astype(np.float64), tri, visibility=vis,
                                      adaptation=opts["adaptation"])
        return maps[:, :, :int(tri.active.sum())].astype(np.float64)
    dirs = tri.vertices[:tri.n_samples]
    texels = tri.texel_dirs[tri.texel_dirs[:, 2] > 0.0]
    k = len(dirs)
    flat = samples.reshape(k, -1)
    if method == "rbf":
        width = methods.rbf_width(dirs)
        kk = methods.rbf_kernel(dirs, dirs, width)
        system = kk + methods.RBF_RIDGE * np.eye(k) * np.trace(kk) / k
        coef = np.linalg.lstsq(system, flat, rcond=None)[0]
        out = methods.rbf_kernel(texels, dirs, width) @ coef
    else:
        if method == "ptm":
            a, e = methods.ptm_basis(dirs), methods.ptm_basis(texels)
        else:
            order = 3 if method == "hsh" else 2
            a, e = methods.hsh_basis(dirs, order), methods.hsh_basis(texels, order)
        coef = np.linalg.lstsq(a, flat, rcond=None)[0]
        out = e @ coef
    out = np.clip(out, 0.0, None).reshape(len(texels), *problem.samples.shape[1:])
    return out.transpose(1, 2, 0)


def relative_error(production: np.ndarray, reference: np.ndarray) -> float:
    """max |production - reference| / max(max |reference|, TINY); inf if production is not finite."""
    prod = np.asarray(production, dtype=np.float64)
    ref = np.asarray(reference, dtype=np.float64)
    if not np.isfinite(prod).all():
        return float("inf")
    if prod.size == 0:
        return 0.0
    return float(np.abs(prod - ref).max() / max(float(np.abs(ref).max()), TINY))


def render_production(problem: RenderProblem, bundle) -> tuple[dict, object]:
    """(H, W, 3) float32 frames of the exact and the default compact path, and the exact Relighter."""
    from relight.kernels.relighter import Relighter

    exact, compact = Relighter(bundle, exact=True), Relighter(bundle)
    frames = {name: np.array(rl.relight(problem.env, exposure=problem.exposure))
              for name, rl in (("exact", exact), ("compact", compact))}
    return frames, exact


def render_reference(problem: RenderProblem, relighter) -> np.ndarray:
    """(H, W, 3) float64: the bundle's maps promoted to float64 times the float64 texel light
    (``relighter.texel_light``: the light its kernels are given)."""
    lp = relighter.texel_light(problem.env, None, problem.exposure)  # (T, 3) float64
    maps = np.asarray(relighter.maps[:, :, :lp.shape[0]], dtype=np.float64)
    ref = np.zeros(relighter.frame.shape, dtype=np.float64)
    ref.reshape(-1, 3)[relighter.frame_index] = np.einsum("pct,tc->pc", maps, lp)
    return ref
