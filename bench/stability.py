"""Numerical stability of the reflectance-map methods: stiff cases against float64 references.

Every case is a small synthetic problem (a 16x13 head of about 120 pixels: a bump on a
slope, so some pixels have hard cast shadows; 3 to 60 sample directions; Lambert plus a
Blinn-Phong lobe; linear float32 samples) run through every variant of :data:`VARIANTS` the
way production runs it, and compared with the same computation in float64:

* **Production maps** are built exactly as :func:`relight.pipeline.capture.finish` builds
  them: :func:`~relight.kernels.triangulation.triangulate`, then for the triangulated variants
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
* **Renders** (cases ``sun_1e5`` and ``exposure_extremes``): a tiny bundle is built per
  variant by :func:`~relight.pipeline.capture.finish` from a hand-made ``Prepared`` (given
  mask: photometric stereo geometry on the synthetic images), written with
  :func:`~relight.kernels.bundle.write_bundle` and loaded back; ``relight.Relighter`` renders
  it. The reference is the bundle's maps promoted to float64 times the float64 texel light
  (:meth:`Relighter.texel_light`, the light the kernels are given). ``max_rel_error`` is the
  exact path's (``exact=True``: the full sum in float32); the default compact path is a
  rank-k approximation chosen to meet a 1 % tolerance, so its error is a modelling error: it
  is listed in ``detail`` and counts towards ``finite``, not towards ``max_rel_error``.

Error measure of one output: ``max |production - reference| / max(max |reference|, TINY)``
over every pixel, channel and stored texel (over the head's pixels for renders), computed in
float64; a non-finite production value makes it ``inf``. A row's ``max_rel_error`` is the
largest over the case's outputs (NaN when none could be compared, or a reference failed).

Use: ``rows = run_stability()`` (about 30 s on 2 cores), ``print(table(rows))``.
"""

from __future__ import annotations

import tempfile
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from relight.directions import fibonacci_sphere
from relight.errors import InputError
from relight.kernels import interpolation, reflectance, triangulation
from relight.kernels.bundle import storage_scale
from relight.numerics import flush_subnormal_halves
from relight.pipeline import methods

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
#: Expected bound of the baseline case's error: float16 storage rounds to 2^-11 (4.9e-4)
#: relative, the OpenCL kernel adds at most 1e-4 (float32 and a fast arctangent in visibility).
BASELINE_MAX_REL = 1e-3
#: Expected bound of the exact render path against its float64 reference: float32 sums of a
#: few hundred float16 texels times float32 light (observed ~1e-7).
RENDER_MAX_REL = 1e-5

#: Bound of a map's largest value over its pixel's brightest sample (``max_gain``): the shading
#: model beyond the samples is at most albedo + spec, albedo alone at most the brightest sample
#: over the least cosine a fit uses (``MODEL_MIN_COS``), the lobe's weight at most it over
#: ``MODEL_LOBE_SEEN``; interpolation and the spline stay within the samples. (Before the lobe
#: had to be seen, ``unseen_lobe`` reached 8e3 and ``grazing`` 23.)
MAX_MAP_GAIN = 1.0 / reflectance.MODEL_MIN_COS + 1.0 / reflectance.MODEL_LOBE_SEEN

#: The synthetic head: grid (rows, cols), bump height (pixels), Blinn-Phong lobe, seed.
HEAD_SHAPE = (13, 16)
BUMP_HEIGHT = 9.0
SPECULAR = 0.25
SHININESS = 40.0
SEED = 7


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
                self._tri[key] = (triangulation.triangulate(self.dirs, key), time.perf_counter() - t0)
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


@dataclass
class Head:
    """The synthetic head every case starts from (arrays over its P mask pixels, row-major)."""

    depth: np.ndarray       # (h, w) float32 heights toward the camera, pixels
    mask: np.ndarray        # (h, w) bool
    normals: np.ndarray     # (P, 3) float64
    albedo: np.ndarray      # (P, 3) float64
    horizon: np.ndarray     # (P, HORIZON_DIRS) float32, from capture.horizon_for
    _baseline: list = field(default_factory=list, repr=False)

    def baseline(self) -> MapProblem:
        """The ordinary well-conditioned problem (60 front lights), made once."""
        if not self._baseline:
            self._baseline.append(_problem(self, "60 front lights", front_dirs(60)))
        return self._baseline[0]


def make_head(seed: int = SEED) -> Head:
    """The bump-on-a-slope head of about 120 pixels, its analytic normals and its horizon table."""
    from relight.pipeline.capture import horizon_for

    h, w = HEAD_SHAPE
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    mask = ((x - (w - 1) / 2) / (w / 2 - 1)) ** 2 + ((y - (h - 1) / 2) / (h / 2 - 1)) ** 2 < 1.0
    depth = BUMP_HEIGHT * np.exp(-((x - w / 2) ** 2 + (y - h / 2) ** 2) / 18.0) + 0.15 * x
    gy, gx = np.gradient(depth)  # rows grow downward, +Y is up
    n = np.stack([-gx, gy, np.ones_like(depth)], axis=-1)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    depth = np.where(mask, depth, 0.0).astype(np.float32)
    rng = np.random.default_rng(seed)
    p = int(mask.sum())
    albedo = rng.uniform(0.2, 0.8, (p, 3)) * np.array([1.0, 0.8, 0.65])
    return Head(depth=depth, mask=mask, normals=n.reshape(-1, 3)[np.flatnonzero(mask)], albedo=albedo,
                horizon=horizon_for(depth, mask))


def shade(head: Head, dirs: np.ndarray, normals: np.ndarray | None = None, *, shadows: bool = True) -> np.ndarray:
    """(K, P, 3) float32 flash-unit samples: albedo x max(n.l, 0) plus a Blinn-Phong lobe, with
    hard cast shadows from the head's height field (the capture's own shadow-ray march)."""
    from relight.kernels.heightfield import NO_SURFACE, MarchSettings, visibility_numpy

    n = head.normals if normals is None else normals
    d = np.asarray(dirs, dtype=np.float64)
    cos = n @ d.T  # (P, K)
    half = d + np.array([0.0, 0.0, 1.0])
    half /= np.maximum(np.linalg.norm(half, axis=1, keepdims=True), 1e-12)
    spec = SPECULAR * np.clip(n @ half.T, 0.0, None) ** SHININESS * (cos > 0)
    val = head.albedo[:, None, :] * np.clip(cos, 0.0, None)[..., None] + spec[..., None]
    if shadows:
        hgt = np.where(head.mask, head.depth, NO_SURFACE).astype(np.float32)
        ys, xs = np.nonzero(head.mask)
        px, py, pz = xs.astype(np.float32), ys.astype(np.float32), head.depth[ys, xs]
        march = MarchSettings()
        lit = np.stack([visibility_numpy(hgt, px, py, pz, li, march) for li in d], axis=1)
        val *= lit[..., None]
    return np.ascontiguousarray(val.transpose(1, 0, 2), dtype=np.float32)


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def front_dirs(k: int, seed: int = 0, min_z: float = 0.2) -> np.ndarray:
    """(k, 3) well-spread directions in front of the face (a capture's typical cover)."""
    d = fibonacci_sphere(6 * k)
    d = d[d[:, 2] > min_z]
    return d[np.random.default_rng(seed).choice(len(d), k, replace=False)]


# ---------------------------------------------------------------------------------- cases
def _problem(head: Head, label: str, dirs, normals=None, samples=None) -> MapProblem:
    dirs = _unit(dirs)
    n = head.normals if normals is None else normals
    s = shade(head, dirs, n) if samples is None else samples
    return MapProblem(label=label, dirs=dirs, samples=s, normals=n, horizon=head.horizon)


def _baseline(head: Head) -> list:
    return [head.baseline()]


def _grazing(head: Head) -> list:
    k = 36
    elev = np.radians(np.linspace(0.5, 3.0, k))
    az = np.linspace(0.0, 2 * np.pi, k, endpoint=False)
    ring = np.stack([np.cos(az) * np.cos(elev), np.sin(az) * np.cos(elev), np.sin(elev)], axis=1)
    dirs = np.concatenate([ring, front_dirs(20, seed=1)])
    rng = np.random.default_rng(1)
    n = head.normals.copy()
    edge = rng.random(len(n)) < 0.5  # half the pixels on the silhouette: view cosine ~1e-3
    a = rng.uniform(0, 2 * np.pi, int(edge.sum()))
    n[edge] = _unit(np.stack([np.cos(a), np.sin(a), np.full_like(a, 1e-3)], axis=1))
    return [_problem(head, "lights 0.5-3 deg above the image plane, normals at 1e-3", dirs, normals=n)]


def _slivers(head: Head) -> list:
    a = np.linspace(-0.6, 0.6, 14)
    off = 1e-4 * (-1.0) ** np.arange(a.size)  # zig-zag 1e-4 rad across a great circle
    line = np.stack([np.sin(a), off, np.cos(a)], axis=1)
    return [_problem(head, "14 almost collinear + 30 regular", np.concatenate([front_dirs(30, seed=2), line]))]


def _duplicates(head: Head) -> list:
    base = front_dirs(40, seed=3)
    rng = np.random.default_rng(3)
    axis = _unit(np.cross(base[10:20], [0.0, 1.0, 0.0]))
    near = _unit(base[10:20] + 1e-7 * axis)  # 1e-7 rad apart
    dirs = np.concatenate([base, base[:10], near])
    s = shade(head, dirs)
    s[40:] *= rng.uniform(0.5, 1.5, (20, 1, 3)).astype(np.float32)  # same direction, different value
    return [_problem(head, "10 exact + 10 at 1e-7 rad, other values", dirs, samples=s)]


def _poles(head: Head) -> list:
    special = [[0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1], [1e-7, 0.3, -0.954], [-1e-7, 0.3, -0.954],
               [1e-7, -0.3, -0.954], [-1e-9, 0.0, -1.0]]
    return [_problem(head, "+Y, -Y, +Z, -Z and the seam", np.concatenate([front_dirs(30, seed=4), special]))]


def _degenerate_hull(head: Head) -> list:
    a = np.linspace(-1.4, 1.4, 40)
    circle = np.stack([np.sin(a), np.zeros_like(a), np.cos(a)], axis=1)
    three = [[0, 0, 1.0], [0.5, 0, 0.86], [0, 0.5, 0.86]]
    four = [*three, [-0.4, -0.3, 0.87]]
    return [_problem(head, "40 on one great circle", circle), _problem(head, "3 lights", three),
            _problem(head, "4 lights", four)]


def _saturated(head: Head) -> list:
    from relight.pipeline.geometry import photometric_stereo

    dirs = _unit(front_dirs(60, seed=5))
    raw = shade(head, dirs) * np.float32(8.0)
    raw[:, 0] = 10.0  # one pixel saturated in every sample
    clipped = raw >= 1.0
    s = np.minimum(raw, np.float32(1.0))
    # The geometry the capture would get: photometric stereo that skips the clipped samples.
    k, (h, w) = len(dirs), head.mask.shape
    pix = np.flatnonzero(head.mask)
    img = np.zeros((k, h * w, 3), dtype=np.float32)
    img[:, pix] = s
    clip = np.zeros((k, h * w), dtype=bool)
    clip[:, pix] = clipped.any(axis=2)
    normal, _, _ = photometric_stereo(img.reshape(k, h, w, 3), dirs, head.mask, clip.reshape(k, h, w))
    n = _unit(normal.reshape(-1, 3)[pix].astype(np.float64))
    share = float(clipped.any(axis=2).mean())
    return [_problem(head, f"{share:.0%} of samples clipped at 1, one pixel always", dirs, normals=n, samples=s)]


def _unseen_lobe(head: Head) -> list:
    """Yale B06 seen as sRGB, in small: pixels whose normal lies 0.6 degrees from the image
    plane (a cheek's silhouette) see their specular lobe only at ~1e-5 of its peak from the lights
    that light them, and their samples are noisy (the model's R^2 low: untrusted, so the model
    alone carries their maps beyond the captured hull). A lobe fitted there weighed 2e5 times the
    samples, and the capture's transport overflowed float16 (a bundle with NaN)."""
    rng = np.random.default_rng(11)
    n = head.normals.copy()
    edge = rng.random(len(n)) < 0.5
    a = rng.uniform(0, 2 * np.pi, int(edge.sum()))
    n[edge] = _unit(np.stack([np.cos(a), np.sin(a), np.full_like(a, 0.01)], axis=1))
    dirs = _unit(front_dirs(60, seed=6))
    s = shade(head, dirs, n)
    noise = np.where(edge[None, :, None], 0.6, 0.05) * rng.standard_normal(s.shape)
    s = np.clip(s * (1.0 + noise) + 0.003 * rng.random(s.shape), 0.0, None).astype(np.float32)
    return [_problem(head, "normals 0.6 deg from the image plane, noisy samples", dirs, normals=n, samples=s)]


def _sun_environment(sky: float = 1.0, ratio: float = 1e5, direction=(0.3, 0.4, 0.87)) -> np.ndarray:
    from relight.envmap import load_environment

    sun = load_environment("builtin:point:{},{},{}".format(*direction))
    sun = sun * np.float32(ratio * sky / float(sun.max()))
    return load_environment("builtin:uniform", width=sun.shape[1]) * np.float32(sky) + sun


def _sun(head: Head) -> list:
    return [RenderProblem("sky + sun 1e5x", _sun_environment())]


def _exposure(head: Head) -> list:
    from relight.envmap import load_environment

    base = head.baseline()
    out = []
    for scale in (1e-6, 1e6):
        out.append(MapProblem(label=f"samples x{scale:g}", dirs=base.dirs, samples=base.samples * np.float32(scale),
                              normals=base.normals, horizon=base.horizon))
    studio = load_environment("builtin:studio")
    out += [RenderProblem(f"render exposure 2^{e:+d}", studio, 2.0 ** e) for e in (-20, 20)]
    return out


@dataclass(frozen=True)
class Case:
    """A named stiff case: a one-line description and the problems it runs (given the head)."""

    name: str
    description: str
    build: Callable[[Head], list]


CASES: dict[str, Case] = {c.name: c for c in [
    Case("float32_vs_float64", "baseline: 60 well-spread front lights, production vs float64", _baseline),
    Case("grazing", "lights 0.5-3 deg above the image plane; half the normals at view cosine 1e-3", _grazing),
    Case("slivers", "14 almost collinear directions (1e-4 rad zig-zag): thin Delaunay triangles", _slivers),
    Case("duplicates", "exact duplicate directions and near-duplicates 1e-7 rad apart, different values",
         _duplicates),
    Case("poles", "samples exactly at +Y, -Y, +Z, -Z and 1e-7 off the lat-long seam", _poles),
    Case("degenerate_hull", "all samples on one great circle; only 3 and 4 samples", _degenerate_hull),
    Case("saturated", "most samples clipped at 1.0 (clipped flags to geometry); a fully saturated pixel",
         _saturated),
    Case("unseen_lobe", "normals 0.6 deg from the image plane (specular lobe unseen), noisy samples", _unseen_lobe),
    Case("sun_1e5", "render: uniform sky + a 1-degree sun 1e5x brighter (exact and compact paths)", _sun),
    Case("exposure_extremes", "samples x1e-6 and x1e6 through the map builders; renders at exposure 2^-20, 2^+20",
         _exposure),
]}


# ---------------------------------------------------------------------------------- production
def builder_maps(variant: str, problem: MapProblem, tri: triangulation.Triangulation, *,
                 half: bool) -> tuple[np.ndarray, float]:
    """(maps (P, 3, T_pad), scale) as :func:`relight.pipeline.capture.reflectance_maps` - the
    maps stage of ``capture.finish`` - returns them (``tri``: the problem's
    :func:`~relight.kernels.triangulation.triangulate`): the OpenCL kernel's float16 output with
    ``half`` (production) or its float32 output; a fitted method's float32. The maps hold the
    samples divided by ``scale``."""
    from relight.pipeline.capture import CaptureOptions, reflectance_maps

    opts = VARIANTS[variant]
    o = CaptureOptions(method=opts["method"], visibility=opts["visibility"], adaptation=opts["adaptation"],
                       extrapolation=opts["extrapolation"], paper_adaptation=opts["paper_adaptation"],
                       spline=opts["spline"],
                       map_size=tri.map_size)
    horizon = problem.horizon if opts["visibility"] else None
    maps, _, scale, _ = reflectance_maps(problem.samples, problem.normals, tri, o, horizon, half=half)
    return maps, scale


def production_maps(variant: str, problem: MapProblem, tri: triangulation.Triangulation) -> np.ndarray:
    """(P, 3, T_pad) float64: the maps as ``capture.finish`` stores them (float16, subnormals
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
    codes, code_scale = recipe.encode_samples((problem.samples / unit).astype(np.float32))
    samples = (codes / 255.0) ** (1.0 / recipe.SAMPLE_GAMMA) * code_scale.astype(np.float64)[None]
    return unit * _reference_maps(opts, method, samples, problem, tri)


def _reference_maps(opts, method, samples, problem, tri):
    from relight.kernels import recipe
    from relight.kernels.heightfield import HORIZON_DIRS

    if method not in methods.FITTED:
        vis = None
        horizon = problem.horizon if opts["visibility"] else None
        if horizon is not None:
            horizon = recipe.quantise_horizon(horizon).astype(np.float64)
        if horizon is not None:
            vis = interpolation.visibility_maps(horizon.astype(np.float64), HORIZON_DIRS, tri.map_size)
        trend = opts["adaptation"] and not opts["paper_adaptation"]
        if opts["method"] == "full" and (trend or opts["extrapolation"] or opts["spline"]):
            maps, tri = reflectance.model_maps(samples, problem.normals.astype(np.float64), tri, horizon,
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


class BundleCache:
    """Per variant, one tiny bundle of the baseline scene (built on first use, files in a temp folder)."""

    def __init__(self, head: Head, map_size, folder: Path):
        self.head, self.map_size, self.folder = head, tuple(map_size), Path(folder)
        self.bundles: dict[str, object] = {}

    def get(self, variant: str):
        if variant not in self.bundles:
            self.bundles[variant] = self._build(variant)
        return self.bundles[variant]

    def _build(self, variant: str):
        from relight.kernels.bundle import load_bundle, write_bundle
        from relight.pipeline.capture import CaptureOptions, Prepared, Progress, finish

        head = self.head
        base = head.baseline()
        k, (h, w) = len(base.dirs), head.mask.shape
        pix = np.flatnonzero(head.mask)
        images = np.zeros((k, h * w, 3), dtype=np.float32)
        images[:, pix] = base.samples
        ambient = np.zeros((h, w, 3), dtype=np.float32)
        ambient.reshape(-1, 3)[pix] = 0.05 * head.albedo
        prep = Prepared(images=images.reshape(k, h, w, 3), dirs=base.dirs, clipped=np.zeros((k, h, w), dtype=bool),
                        ambient=ambient, background=np.zeros((h, w, 3), dtype=np.uint8), origin=(0, 0),
                        frame_size=(w, h), face_local=None, mask=head.mask.copy(), meta={"kind": "stability"})
        opts = CaptureOptions(**VARIANTS[variant], map_size=self.map_size)
        arrays, meta, _, _ = finish(prep, opts, Progress(False), {})
        path = self.folder / f"{variant.replace(' ', '_')}.bundle"
        write_bundle(path, meta, arrays)
        return load_bundle(path)


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


# ---------------------------------------------------------------------------------- rows
def _produce(prob, variant: str, map_size, bundles: BundleCache | None, clock: list[float]):
    """Production outputs of one problem: ({name: array}, callable giving the reference in the
    same layout); the first output is the one ``max_rel_error`` measures. The production's wall
    time is added to ``clock[0]``, also when it raises."""
    if isinstance(prob, RenderProblem):
        if bundles is None:
            raise ValueError("render problems need a BundleCache")
        bundle = bundles.get(variant)  # built once per variant: not timed
        t0 = time.perf_counter()
        try:
            frames, relighter = render_production(prob, bundle)
        finally:
            clock[0] += time.perf_counter() - t0
        m = bundle.mask
        return {name: f[m] for name, f in frames.items()}, lambda: render_reference(prob, relighter)[m]
    tri, seconds = prob.triangulation(map_size)
    clock[0] += seconds
    if isinstance(tri, InputError):
        raise tri
    t0 = time.perf_counter()
    try:
        maps = production_maps(variant, prob, tri)
    finally:
        clock[0] += time.perf_counter() - t0
    wide, scale = builder_maps(variant, prob, tri, half=False)  # before float16 storage: the arithmetic alone
    wide = wide.astype(np.float64) * scale

    def reference():
        ref = prob.reference(variant, tri)
        out = np.zeros(maps.shape, dtype=np.float64)  # production's layout: zero padded texels
        out[:, :, :ref.shape[2]] = ref
        return out

    return {"maps": maps, "float32": wide}, reference


def map_gain(maps: np.ndarray, samples: np.ndarray) -> float:
    """The largest map value over its pixel's brightest sample (pixels with a positive sample):
    how far the maps go beyond what was measured (extrapolation, adaptation, a fitted lobe)."""
    top = np.asarray(samples, dtype=np.float64).max(axis=(0, 2))  # (P,)
    lit = top > 0
    if not lit.any():
        return 0.0
    peak = np.asarray(maps, dtype=np.float64).max(axis=(1, 2))[lit]
    return float((peak / top[lit]).max())


def evaluate(case: str, description: str, problems: list, variant: str, *, map_size=triangulation.DEFAULT_MAP_SIZE,
             bundles: BundleCache | None = None) -> dict:
    """One row: the problems of a case through one variant, production against reference.

    Keys: case, description, variant, max_rel_error (float; NaN if nothing could be compared),
    finite (every production output finite), max_gain (the maps' largest value over their pixel's
    brightest sample, :func:`map_gain`; NaN for render-only cases), error (None, or ``"label: Type: message"`` of
    every production exception, joined by "; "), ok (every output finite and compared with a
    finite error, and every exception an :class:`InputError`: invalid input refused with a
    message - a handled case), seconds (wall time of the
    production path: the triangulation, made once per problem for all variants, is counted in
    each row; a render case's bundle is built once per variant and not counted), detail (the
    error of each output, warnings the production path raised, any reference failure).
    Nothing is raised: exceptions and warnings are recorded whatever the warning filters are.
    """
    errs, details, failures, gains = [], [], [], []
    finite, ok, clock = True, True, [0.0]
    for prob in problems:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                outputs, reference = _produce(prob, variant, map_size, bundles, clock)
            except Exception as exc:  # recorded, never raised: the report must list every crash
                ok &= isinstance(exc, InputError)
                failures.append(f"{prob.label}: {type(exc).__name__}: {exc}")
                continue
        finite &= all(bool(np.isfinite(o).all()) for o in outputs.values())
        if isinstance(prob, MapProblem):
            gains.append(map_gain(outputs["maps"], prob.samples))
        note = sorted({f"{w.category.__name__}: {w.message}" for w in caught})
        note = f" (warned: {'; '.join(note)})" if note else ""
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # a reference of a non-finite input may warn
                ref = reference()
            per = {name: relative_error(o, ref) for name, o in outputs.items()}
        except Exception as exc:  # the reference cannot be computed (e.g. a non-finite input)
            errs.append(float("nan"))
            details.append(f"{prob.label}: reference failed ({type(exc).__name__}: {exc}){note}")
            continue
        errs.append(next(iter(per.values())))
        details.append(f"{prob.label}: " + ", ".join(f"{k} {v:.2g}" for k, v in per.items()) + note)
    max_err = float("nan")
    if errs and not np.isnan(errs).any():
        max_err = float(max(errs))
    ok = ok and finite and bool(np.isfinite(errs).all())
    return {"case": case, "description": description, "variant": variant, "max_rel_error": max_err,
            "finite": bool(finite), "error": "; ".join(failures) or None, "ok": bool(ok),
            "max_gain": max(gains) if gains else float("nan"),
            "seconds": round(clock[0], 4), "detail": "; ".join(details + failures)}


def run_stability(variants=None, *, map_size=triangulation.DEFAULT_MAP_SIZE, cases=None) -> list[dict]:
    """Every case of :data:`CASES` (or the named ``cases``) through every variant of
    :data:`VARIANTS` (or the named ``variants``): one row per (case, variant), cases in order.

    See :func:`evaluate` for a row's keys and the module docstring for the references and the
    error measure (``max |production - reference| / max(max |reference|, TINY)``).
    """
    from threadpoolctl import threadpool_limits

    names = list(VARIANTS) if variants is None else list(variants)
    for v in names:
        if v not in VARIANTS:
            raise InputError(f"unknown variant {v!r}; choose from: {', '.join(VARIANTS)}")
    chosen = list(CASES) if cases is None else list(cases)
    for c in chosen:
        if c not in CASES:
            raise InputError(f"unknown case {c!r}; choose from: {', '.join(CASES)}")
    rows = []
    # Problems of a few hundred pixels gain nothing from BLAS threads, and on 2 cores they
    # fight PoCL's workers (measured: an eigh of 1024^2 took 10 s instead of 0.6 s).
    with threadpool_limits(limits=1, user_api="blas"), tempfile.TemporaryDirectory(prefix="relight-stab-") as tmp:
        head = make_head()
        bundles = BundleCache(head, map_size, Path(tmp))
        for name in chosen:
            case = CASES[name]
            problems = case.build(head)
            for v in names:
                rows.append(evaluate(case.name, case.description, problems, v, map_size=map_size, bundles=bundles))
        bundles.bundles.clear()  # release the memory maps before the folder goes
    return rows


def table(rows: list[dict]) -> str:
    """The rows as a plain-text table (case, variant, max relative error, finite, error)."""
    head = f"{'case':20s} {'variant':18s} {'max rel err':>11s} {'gain':>8s} {'finite':>6s} {'s':>6s}  error"
    lines = [head, "-" * len(head)]
    for r in rows:
        lines.append(f"{r['case']:20s} {r['variant']:18s} {r['max_rel_error']:11.2e} {r['max_gain']:8.3g} "
                     f"{'yes' if r['finite'] else 'no':>6s} {r['seconds']:6.2f}  {r['error'] or ''}")
    return "\n".join(lines)
