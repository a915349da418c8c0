"""Environments as light in the maps' texels - the small, direction-space side of relighting.

Relighting a pixel is ``sum_t maps[p, :, t] * Lp[t]`` over the reflectance maps' texels, where
``Lp[t]`` is the power the environment sends from texel t's solid angle, over pi (maps are in
flash units: a flash has power pi). An environment becomes directional lights once (its lat-long
grid cells plus its bright texels at full resolution, power conserved exactly); a head rotation
only turns those lights, which are then splatted bilinearly into the map's texels - no
resampling of the map, so a 2-degree sun moves smoothly and keeps its power, and a yaw by a
multiple of 90 degrees equals rolling the map. Texels outside the captured hull are left out
(their maps are black). The compact transport that multiplies these (:mod:`relight.kernels.transport`)
takes the few brightest texels (:func:`split_direct`) exactly.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from relight.colour import luminance
from relight.directions import equirect_directions, rotation_matrix
from relight.envmap import BUILTINS, environment_to_lights, load_environment, validate_environment
from relight.numerics import RANK_REL

#: Lat-long grid (columns, rows) on which environments become lights; their bright texels
#: (over PEAK_FACTOR times the mean, at most MAX_PEAKS) stay lights of their own. The maps' own
#: 64x32: against the synthetic truth it relit the bench's five environments within 0.01 dB of a
#: 128x64 grid, with 2.7x fewer lights to turn and splat per frame.
LIGHT_GRID = (64, 32)
PEAK_FACTOR = 20.0
MAX_PEAKS = 1024
#: Brightest texels of an environment relit exactly, outside the low-rank part.
DIRECT_TEXELS = 8

@dataclass(frozen=True)
class EnvLights:
    """An environment as directional lights: dirs (N, 3) unit, power (N, 3) = radiance x solid angle."""

    dirs: np.ndarray
    power: np.ndarray


def environment_lights(env: np.ndarray) -> EnvLights:
    """Validate an environment map and turn it into lights (done once per environment)."""
    env = validate_environment(env)
    lights = environment_to_lights(env, grid=LIGHT_GRID, pole="y", peak_factor=PEAK_FACTOR, max_peaks=MAX_PEAKS)
    return EnvLights(dirs=lights.dirs, power=lights.power)


def splat(dirs: np.ndarray, power: np.ndarray, map_size: tuple[int, int]) -> np.ndarray:
    """(H_map * W_map, 3) power of lights spread bilinearly over a lat-long map's texel centres.

    Wraps around in azimuth, clamps at the poles; the total power is kept exactly. A weighted
    histogram per channel (np.bincount; a scipy.sparse matrix did it in one product but its
    import alone, 0.3 s, was a third of a bundle's first frame).
    """
    w, h = map_size
    n = dirs.shape[0]
    # Unit directions in, so no normalisation: the lat-long coordinates straight from the
    # convention of relight.directions (theta from +Y, phi = atan2(x, -z)), in texel units.
    x = np.arctan2(dirs[:, 0], -dirs[:, 2])
    x *= w / (2.0 * np.pi)
    x -= 0.5
    x[x < -0.5] += w
    y = np.arccos(np.clip(dirs[:, 1], -1.0, 1.0))
    y *= h / np.pi
    y -= 0.5
    np.clip(y, 0.0, h - 1.0, out=y)
    x0 = np.floor(x)
    y0 = np.minimum(np.floor(y), h - 2) if h > 1 else np.zeros_like(y)
    fx, fy = x - x0, y - y0
    gx, gy = 1.0 - fx, 1.0 - fy
    ix = x0.astype(np.int64) % w
    row = y0.astype(np.int64) * w
    idx = np.empty((n, 4), dtype=np.int64)
    idx[:, 0] = row + ix
    idx[:, 1] = row + (ix + 1) % w
    below = w if h > 1 else 0
    idx[:, 2] = idx[:, 0] + below
    idx[:, 3] = idx[:, 1] + below
    wt = np.empty((n, 4))
    wt[:, 0] = gx * gy
    wt[:, 1] = fx * gy
    wt[:, 2] = gx * fy
    wt[:, 3] = fx * fy
    p = np.asarray(power, dtype=np.float64).reshape(n, 3)
    flat = idx.ravel()
    out = np.empty((h * w, 3))
    for c in range(3):
        out[:, c] = np.bincount(flat, weights=(wt * p[:, c:c + 1]).ravel(), minlength=h * w)
    return out


def hull_cone(map_size, texels: np.ndarray) -> tuple[np.ndarray, float]:
    """(axis, cos of half-angle) of a cone holding every direction whose bilinear splat reaches
    one of ``texels``: the texel centres' cone widened by a cell's diagonal. Lights outside it
    land only on texels the capture never lit (their maps are black), so they are skipped."""
    w, h = map_size
    d = equirect_directions(w, h).reshape(-1, 3)[np.asarray(texels, dtype=np.int64)]
    axis = d.sum(axis=0)
    n = float(np.linalg.norm(axis))
    if not d.size or n < RANK_REL * max(len(d), 1):
        return np.array([0.0, 0.0, 1.0]), -1.0
    axis /= n
    spread = float(np.arccos(np.clip((d @ axis).min(), -1.0, 1.0)))
    margin = 1.05 * float(np.hypot(np.pi / h, 2.0 * np.pi / w))
    return axis, float(np.cos(min(spread + margin, np.pi)))


def texel_light(lights: EnvLights, rotation: np.ndarray | None, map_size, texels: np.ndarray,
                exposure: float = 1.0, cone: tuple[np.ndarray, float] | None = None) -> np.ndarray:
    """(T, 3) float64 ``Lp`` for the stored texels: the environment as the (static) face sees it
    when the head is turned by ``rotation`` (camera-from-head, 3x3), times ``exposure``.

    A head turned by R sees the camera-space light from d at R^T d. ``cone``: the bundle's
    :func:`hull_cone` (computed when not given); only the lights inside it are splatted.
    """
    r = np.eye(3) if rotation is None else np.asarray(rotation, dtype=np.float64)
    axis, cos_max = hull_cone(map_size, texels) if cone is None else cone
    dirs, power = lights.dirs, lights.power
    if cos_max > -1.0:
        keep = dirs @ (r @ axis) > cos_max
        # (np.compress: 2.5x faster than boolean indexing for these few-thousand-row arrays)
        dirs, power = np.compress(keep, dirs, axis=0), np.compress(keep, power, axis=0)
    if rotation is not None:
        dirs = dirs @ r
    return splat(dirs, power, map_size)[texels] * (exposure / np.pi)


def point_light(direction, map_size, texels: np.ndarray) -> np.ndarray:
    """(T, 3) ``Lp`` of one directional light as strong as a capture flash (``render --light``)."""
    d = np.asarray(direction, dtype=np.float64).reshape(1, 3)
    d = d / np.linalg.norm(d)
    return splat(d, np.full((1, 3), np.pi), map_size)[texels] / np.pi


def split_direct(lp: np.ndarray, n: int = DIRECT_TEXELS) -> tuple[np.ndarray, np.ndarray]:
    """(indices of the n brightest texels of Lp, ascending, Lp with them removed). Ties at the
    n-th brightest value go to the lower texel index: the choice (and so the result's rounding)
    is the same on every CPU - NumPy's partition breaks ties by its SIMD sort, which differs
    between AVX2 and AVX-512 machines (a uniform light is all ties)."""
    if n <= 0 or not lp.size:
        return np.zeros(0, dtype=np.int64), lp
    lum = luminance(lp.astype(np.float32))
    n = min(n, lp.shape[0])
    nth = lum[np.argpartition(lum, -n)[-n]]  # the n-th brightest value: one value, whatever the sort
    above = np.flatnonzero(lum > nth)
    top = np.union1d(above, np.flatnonzero(lum == nth)[:n - above.size])
    top = top[lum[top] > 0]
    rest = lp.copy()
    rest[top] = 0.0
    return top.astype(np.int64), rest


def validation_environments(map_size, texels: np.ndarray, seed: int = 0) -> list[tuple[str, np.ndarray]]:
    """(name, Lp) of the environments a rank must relight within tolerance.

    The built-ins (studio, sunset, window, uniform, room) as they are and turned by a few head
    rotations, and small lights at many directions across the captured texels.
    """
    rng = np.random.default_rng(seed)
    out = []
    for name in BUILTINS:
        lights = environment_lights(load_environment(f"builtin:{name}", width=256))
        out.append((name, texel_light(lights, None, map_size, texels)))
        for k in range(2):
            r = rotation_matrix(*rng.uniform([-40, -20, -15], [40, 20, 15]))
            out.append((f"{name}_rot{k}", texel_light(lights, r, map_size, texels)))
    # Small lights: at captured texel directions and between them.
    from relight.directions import equirect_directions

    w, h = map_size
    tdirs = equirect_directions(w, h).reshape(-1, 3)[texels]
    pick = rng.choice(len(tdirs), size=min(24, len(tdirs)), replace=False)
    for i, t in enumerate(pick):
        d = tdirs[t] + rng.normal(0, 0.03, 3)
        out.append((f"light{i}", point_light(d, map_size, texels)))
    return out
