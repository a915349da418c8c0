"""The stiff cases of the numerical stability suite (:mod:`relight.bench.stability`).

Every case is a small synthetic problem (a 16x13 head of about 120 pixels: a bump on a
slope, so some pixels have hard cast shadows; 3 to 60 sample directions; Lambert plus a
Blinn-Phong lobe; linear float32 samples): grazing lights and normals, slivers, duplicate
directions, the poles and the seam, degenerate hulls, saturation, an unseen specular lobe, a
sun 1e5 times the sky and extreme exposures. :data:`CASES` names them; each builds its
problems (:class:`~relight.bench.stability_reference.MapProblem`,
:class:`~relight.bench.stability_reference.RenderProblem`) from the :class:`Head`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from relight.directions import fibonacci_sphere

from .stability_reference import MapProblem, RenderProblem

#: The synthetic head: grid (rows, cols), bump height (pixels), Blinn-Phong lobe, seed.
HEAD_SHAPE = (13, 16)
BUMP_HEIGHT = 9.0
SPECULAR = 0.25
SHININESS = 40.0
SEED = 7


@dataclass
class Head:
    """The synthetic head every case starts from (arrays over its P mask pixels, row-major)."""

    depth: np.ndarray       # (h, w) float32 heights toward the camera, pixels
    mask: np.ndarray        # (h, w) bool
    normals: np.ndarray     # (P, 3) float64
    albedo: np.ndarray      # (P, 3) float64
    horizon: np.ndarray     # (P, HORIZON_DIRS) float32, from reflectance_maps.horizon_for
    _baseline: list = field(default_factory=list, repr=False)

    def baseline(self) -> MapProblem:
        """The ordinary well-conditioned problem (60 front lights), made once."""
        if not self._baseline:
            self._baseline.append(_problem(self, "60 front lights", front_dirs(60)))
        return self._baseline[0]


def make_head(seed: int = SEED) -> Head:
    """The bump-on-a-slope head of about 120 pixels, its analytic normals and its horizon table."""
    from relight.pipeline.reflectance_maps import horizon_for

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
