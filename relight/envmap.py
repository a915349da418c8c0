"""Environment maps: loading, built-in procedural environments, rotation, light sampling.

An environment map is a lat-long (equirectangular) array ``(H, W, 3)`` float32 of *linear*
RGB radiance with ``W == 2 * H`` (layout: see :mod:`relight.directions`). Radiance units are
chosen so that a uniform environment of radiance 1 makes a white Lambertian surface read 1,
and a light whose radiance integrates to pi over its solid angle (the ``point:`` built-in)
is as strong as one capture flash.

``load_environment`` accepts a file (``.exr``, ``.hdr``; ``.png``/``.jpg`` are decoded from
sRGB) or ``builtin:NAME`` with NAME one of :data:`BUILTINS`, ``point:x,y,z`` or a key light
``key:az=30,el=25,...`` (:mod:`relight.key_light`).
"""

from __future__ import annotations

import functools
import os
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .colour import luminance
from .directions import (
    direction_to_equirect_uv,
    equirect_directions,
    equirect_solid_angles,
    equirect_uv_to_direction,
)
from .env_draw import add_light, disc, grid, unit
from .errors import InputError
from .imageio import read_image
from .numerics import ACCUM, EPS, EPS_NORM, FLOAT, TINY_SCALE, require_finite

#: Width of the built-in maps unless asked otherwise (a 2-degree sun spans ~3 texels).
BUILTIN_WIDTH = 512
#: Limits for environment files (a 16K x 8K HDR probe still loads).
MAX_ENV_WIDTH = 16384
#: A source named ``photo:PATH`` is any picture made into an environment (:mod:`relight.photo_env`);
#: a plain path must be a 2:1 lat-long map (a square mirror-ball probe is not taken for a photo).
PHOTO_PREFIX = "photo:"


def builtin_studio(width: int = BUILTIN_WIDTH) -> np.ndarray:
    """Three-point studio: warm key (camera left, above), cool fill (right), rim (behind)."""
    dirs, dw, env = grid(width)
    env += 0.04 * np.where(dirs[..., 1:2] > 0, 1.0, 0.6)
    add_light(env, disc(dirs, dw, (-0.55, 0.45, 0.70), 14.0, 2.0), dw, (1.0, 0.94, 0.86), 0.9)
    add_light(env, disc(dirs, dw, (0.75, 0.10, 0.65), 24.0, 4.0), dw, (0.86, 0.92, 1.0), 0.3)
    add_light(env, disc(dirs, dw, (0.45, 0.50, -0.75), 8.0, 1.0), dw, (1.0, 1.0, 1.0), 0.5)
    return env.astype(FLOAT)


SUN_DIRECTION = unit((0.75, np.sin(np.radians(6.0)), 0.65))


def builtin_sunset(width: int = BUILTIN_WIDTH) -> np.ndarray:
    """Sky gradient + ground + a 2-degree sun low on the horizon (dynamic range > 1e4)."""
    dirs, dw, env = grid(width)
    y = dirs[..., 1:2]
    t = np.sqrt(np.clip(y, 0.0, 1.0))
    horizon = np.array([1.0, 0.55, 0.25]) * 0.35
    zenith = np.array([0.25, 0.40, 0.75]) * 0.12
    sky = horizon * (1 - t) + zenith * t
    glow_ang = np.arccos(np.clip(dirs @ SUN_DIRECTION, -1, 1))[..., None]
    sky = sky + 0.6 * np.array([1.0, 0.6, 0.3]) * np.exp(-0.5 * (glow_ang / np.radians(15.0)) ** 2)
    ground = np.array([0.05, 0.04, 0.03]) * 0.5
    blend = np.clip(y / np.sin(np.radians(1.0)) + 0.5, 0.0, 1.0)
    env += ground * (1 - blend) + sky * blend
    add_light(env, disc(dirs, dw, SUN_DIRECTION, 1.0), dw, (1.0, 0.75, 0.45), 0.9)
    return env.astype(FLOAT)


def builtin_window(width: int = BUILTIN_WIDTH) -> np.ndarray:
    """A dim room with one large window (soft area light) to the camera's right, with muntins."""
    dirs, dw, env = grid(width)
    env += np.where(dirs[..., 1:2] > 0, 0.06, 0.04) * np.array([1.0, 0.97, 0.92])
    h = width // 2
    u = (np.arange(width) + 0.5) / width
    v = (np.arange(h) + 0.5) / h

    def box(x, lo, hi, soft):
        return np.clip((x - lo) / soft + 0.5, 0, 1) * np.clip((hi - x) / soft + 0.5, 0, 1)

    soft = 0.006
    win = box(u, 0.27, 0.40, soft)[None, :] * box(v, 0.28, 0.55, soft)[:, None]
    bars = 1.0 - box(u, 0.333, 0.337, 1.0 / width)[None, :] * np.ones((h, 1))
    bars = bars * (1.0 - box(v, 0.413, 0.417, 1.0 / h)[:, None] * np.ones((1, width)))
    env += (win * bars)[..., None] * 1.6 * np.array([0.95, 0.97, 1.0])
    return env.astype(FLOAT)


def builtin_uniform(width: int = BUILTIN_WIDTH) -> np.ndarray:
    """Radiance 1 from every direction (a white Lambertian surface reads 1)."""
    return np.ones((width // 2, width, 3), dtype=FLOAT)


def builtin_room(width: int = BUILTIN_WIDTH) -> np.ndarray:
    """Weak indoor ambient light: ceiling panel, a dim window on the left, walls and floor.

    The synthetic studio's room light (the no-flash frames are lit by it).
    """
    dirs, dw, env = grid(width)
    y = dirs[..., 1:2]
    env += np.where(y > 0, 0.07, 0.04) * np.array([1.0, 0.96, 0.9])
    add_light(env, disc(dirs, dw, (0.0, 0.85, 0.5), 20.0, 6.0), dw, (1.0, 0.97, 0.92), 0.14)
    add_light(env, disc(dirs, dw, (-0.9, 0.2, 0.3), 18.0, 8.0), dw, (0.9, 0.95, 1.0), 0.06)
    return env.astype(FLOAT)


#: Radius of the ``point:`` light (degrees): small, but a few texels wide at 512 x 256.
POINT_RADIUS_DEG = 1.0


def builtin_point(direction, width: int = BUILTIN_WIDTH) -> np.ndarray:
    """A single small light (1-degree radius disc) toward ``direction``, as strong as a flash.

    Its radiance integrates to pi over the map, so a white Lambertian surface facing it reads 1.
    """
    d = np.asarray(direction, dtype=ACCUM)
    if d.shape != (3,) or not np.isfinite(d).all() or np.linalg.norm(d) < EPS_NORM:
        raise InputError(f"point:{direction}: expected three finite numbers x,y,z not all zero")
    dirs, dw, env = grid(width)
    add_light(env, disc(dirs, dw, d, POINT_RADIUS_DEG), dw, (1.0, 1.0, 1.0), 1.0)
    return env.astype(FLOAT)


BUILTINS: dict[str, Callable[[int], np.ndarray]] = {
    "studio": builtin_studio,
    "sunset": builtin_sunset,
    "window": builtin_window,
    "uniform": builtin_uniform,
    "room": builtin_room,
}

_POINT = re.compile(r"^point:\s*([^,]+),([^,]+),([^,]+)$")


def parse_point(name: str) -> np.ndarray:
    """``point:x,y,z`` -> (3,) float64 direction (not normalised), or InputError."""
    m = _POINT.match(name)
    if not m:
        raise InputError(f"builtin:{name}: write a point light as builtin:point:x,y,z (e.g. point:0,0,1)")
    try:
        return np.array([float(g) for g in m.groups()])
    except ValueError:
        raise InputError(f"builtin:{name}: x, y and z must be numbers, e.g. point:0.5,0.2,1") from None


def builtin_names() -> list[str]:
    """Names accepted after ``builtin:`` (``point:x,y,z`` and ``key:...`` are parametrised: the
    key light's fields are :data:`relight.key_light.DEFAULTS`)."""
    from .presets import PRESETS

    return [*BUILTINS, *PRESETS, "point:x,y,z", "key:az=A,el=E,size=S,kelvin=K,fill=F,power=P"]


def environment_stem(source: str | os.PathLike) -> str:
    """A short file-name-safe name for an environment source (``builtin:studio`` -> ``studio``)."""
    s = str(source)
    if s.startswith("builtin:"):
        name = s[len("builtin:"):]
        return re.sub(r"[^A-Za-z0-9.+-]+", "_", name).strip("_")
    if s.startswith(PHOTO_PREFIX):
        return "photo_" + re.sub(r"[^A-Za-z0-9.+-]+", "_", Path(s[len(PHOTO_PREFIX):]).stem).strip("_")
    return Path(s).stem


def load_environment(source: str | os.PathLike, *, width: int | None = None) -> np.ndarray:
    """Load an environment map as linear float32 radiance, (H, W, 3) with W == 2 H, read-only.

    source : a path (.exr, .hdr, or an sRGB .png/.jpg: a 2:1 lat-long map), ``builtin:NAME`` (see
        :func:`builtin_names`), ``photo:PATH`` (any picture as the light: :mod:`relight.photo_env`)
        or a light saved by name, ``NAME.json`` (:mod:`relight.saved_light`).
        width : resolution of a built-in or a photo's map (default 512); ignored for map files.

    The map is returned read-only (:func:`freeze`): a :class:`relight.Relighter` given it again
    knows it by identity, so a loop relighting it under a new head rotation per call does not
    hash its 1.5 MB each time. To edit it, take a copy (``env * 2``, ``env.copy()``).

    Raises :class:`InputError` for a missing, hostile or corrupt file, a map that is not 2:1,
    non-finite or negative radiance, or an unknown built-in.
    """
    s = str(source)
    if s.startswith("builtin:"):
        name = s[len("builtin:"):]
        w = _drawn_width(width)
        if name.startswith("point:"):
            return freeze(builtin_point(parse_point(name), w))
        from .presets import PRESETS

        if name in PRESETS:
            return freeze(PRESETS[name](w))
        if name == "key" or name.startswith("key:"):
            from .key_light import KeyLight

            return freeze(KeyLight.parse(name[len("key:"):]).environment(w))
        if name not in BUILTINS:
            raise InputError(f"unknown built-in environment {name!r}; choose one of: {', '.join(builtin_names())}")
        return freeze(BUILTINS[name](w))
    if s.startswith(PHOTO_PREFIX):
        from .photo_env import load_photo_environment

        path = s[len(PHOTO_PREFIX):]
        if not path:
            raise InputError("photo: name a picture after it, e.g. photo:beach.jpg")
        return freeze(validate_environment(load_photo_environment(path, width=_drawn_width(width)), name=s))
    if s.lower().endswith(".json"):  # a light saved by name (relight live's page)
        return freeze(validate_environment(load_saved_light(s, width=width), name=s))
    env = read_image(s, max_dim=MAX_ENV_WIDTH, max_pixels=MAX_ENV_WIDTH * MAX_ENV_WIDTH // 2)
    return freeze(validate_environment(env, name=s))


def _drawn_width(width: int | None) -> int:
    """The width a built-in or a photo's map is drawn at (None: BUILTIN_WIDTH), checked."""
    w = BUILTIN_WIDTH if width is None else int(width)
    if w < 8 or w % 2 or w > MAX_ENV_WIDTH:
        raise InputError(f"built-in width {w}: use an even number between 8 and {MAX_ENV_WIDTH}")
    return w


def load_saved_light(path: str | os.PathLike, *, width: int | None = None) -> np.ndarray:
    """The map a light saved by name gives (:mod:`relight.saved_light`): its environment loaded,
    turned by its ``turn`` (the convention of :data:`relight.directions.ENV_TURN_RANGE_DEG`) and
    scaled by 2^``exposure``."""
    from .directions import rotation_matrix
    from .saved_light import environment_source, read_light

    doc = read_light(path)
    env = load_environment(environment_source(doc, Path(path).resolve().parent), width=width)
    turn, ev = float(doc.get("turn", 0.0)), float(doc.get("exposure", 0.0))
    if turn:
        env = rotate_environment(env, rotation_matrix(turn, 0.0, 0.0))
    if ev:
        env = env * np.float32(2.0 ** ev)
    return env


def freeze(env) -> np.ndarray:
    """A read-only C-contiguous float32 array that owns its data, with ``env``'s values (``env``
    itself when it already is one; else a copy): what :meth:`relight.Relighter.lights` recognises
    by identity instead of hashing its contents on every call."""
    a = np.asarray(env)
    if not (a.dtype == np.float32 and a.flags.c_contiguous and a.flags.owndata):
        a = np.array(a, dtype=np.float32, order="C")
    a.flags.writeable = False
    return a


def validate_environment(env: np.ndarray, *, name: str = "environment") -> np.ndarray:
    """Check an in-memory environment map; return it as contiguous float32.

    Raises :class:`InputError` unless it is (H, 2H, 3), finite and non-negative.
    """
    env = np.asarray(env)
    if env.ndim != 3 or env.shape[2] != 3:
        raise InputError(f"{name}: expected an (H, W, 3) RGB lat-long map, got shape {env.shape}")
    h, w = env.shape[:2]
    if w != 2 * h:
        raise InputError(f"{name}: a lat-long environment map must be twice as wide as high, got {w}x{h}; "
                         "resample it to 2:1 (e.g. 1024x512)")
    if h < 2:
        raise InputError(f"{name}: {w}x{h} is too small for an environment map")
    env = np.ascontiguousarray(env, dtype=FLOAT)
    require_finite(name, env, user_input=True)
    if (env < 0).any():
        raise InputError(f"{name}: holds negative radiance (min {float(env.min()):.3g}); "
                         "radiance must be >= 0, clamp the map")
    return env


def sample_environment(env: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """Bilinear lookup of a lat-long map (H, W, 3) toward directions (..., 3) -> (..., 3) float32.

    Wraps around in azimuth and clamps at the poles.
    """
    import cv2

    h, w = env.shape[:2]
    u, v = direction_to_equirect_uv(dirs)
    # Pad one column each side (wrap) and one row each side (replicate) so bilinear taps at
    # the seam and the poles read the right neighbours.
    padded = np.concatenate([env[:, -1:], env, env[:, :1]], axis=1)
    padded = np.concatenate([padded[:1], padded, padded[-1:]], axis=0).astype(np.float32)
    # cv2.remap wants maps under 32767 per side: lay the lookups out as rows of 1024.
    n = u.size
    cols = 1024
    rows = -(-n // cols)
    mx = np.zeros(rows * cols, dtype=np.float32)
    my = np.zeros(rows * cols, dtype=np.float32)
    mx[:n] = u.ravel() * w + 0.5
    my[:n] = v.ravel() * h + 0.5
    out = cv2.remap(padded, mx.reshape(rows, cols), my.reshape(rows, cols), cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_REPLICATE)
    return out.reshape(-1, 3)[:n].reshape(*np.shape(dirs)[:-1], 3)


def rotate_environment(env: np.ndarray, rotation: np.ndarray, *, supersample: int = 2) -> np.ndarray:
    """Rotate an environment map: what was seen toward ``d`` is seen toward ``rotation @ d``.

    Resampled on the sphere with ``supersample**2`` bilinear samples per output texel (a box
    prefilter), so a small sun is neither lost nor aliased; a pure yaw by a multiple of 90
    degrees is an exact column shift.
    """
    r = np.asarray(rotation, dtype=ACCUM)
    h, w = env.shape[:2]
    yaw_quarter = _quarter_yaw(r)
    if yaw_quarter is not None and w % 4 == 0:
        return np.ascontiguousarray(np.roll(env, -yaw_quarter * (w // 4), axis=1))
    s = max(1, int(supersample))
    u = (np.arange(w * s, dtype=ACCUM) + 0.5) / (w * s)
    v = (np.arange(h * s, dtype=ACCUM) + 0.5) / (h * s)
    out = sample_environment(env, equirect_uv_to_direction(u[None, :], v[:, None]) @ r)  # rows: R^T d
    if s > 1:
        out = out.reshape(h, s, w, s, 3).mean(axis=(1, 3))
    return np.ascontiguousarray(out, dtype=FLOAT)


def _quarter_yaw(r: np.ndarray) -> int | None:
    """k if ``r`` is a rotation about +Y by k*90 degrees (k in 0..3), else None."""
    for k in range(4):
        a = k * np.pi / 2
        ry = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
        if np.allclose(r, ry, atol=EPS):
            return k
    return None


@dataclass(frozen=True)
class Lights:
    """An environment as directional lights.

    dirs : (N, 3) float64 unit directions toward the lights. power : (N, 3) float64 radiance
    x solid angle (irradiance at normal incidence). column : (N,) int, the grid azimuth column of
    a grid-cell light, -1 for a light of its own (a bright texel). The first ``n_grid`` lights
    are the grid's cells in row-major order when the grid was kept whole.
    """

    dirs: np.ndarray
    power: np.ndarray
    column: np.ndarray
    n_grid: int


def grid_cell_directions(columns: int, rows: int, pole: str) -> np.ndarray:
    """(rows * columns, 3) centres of a lat-long grid's cells around ``pole`` ('y' or 'z').

    'y': the lat-long layout of :mod:`relight.directions`. 'z': azimuth ``beta`` around +Z
    (the camera axis) from +X toward +Y in columns, polar angle from +Z in rows - every cell of
    a column lies along one image-plane direction ``(cos beta, -sin beta)`` (x right, y down).
    """
    if pole == "y":
        return equirect_directions(columns, rows).reshape(-1, 3)
    beta = 2.0 * np.pi * (np.arange(columns) + 0.5) / columns
    alpha = np.pi * (np.arange(rows) + 0.5) / rows
    a, b = np.meshgrid(alpha, beta, indexing="ij")
    return np.stack([np.sin(a) * np.cos(b), np.sin(a) * np.sin(b), np.cos(a)], axis=-1).reshape(-1, 3)


def _grid_cells(dirs: np.ndarray, columns: int, rows: int, pole: str) -> tuple[np.ndarray, np.ndarray]:
    if pole == "y":
        u, v = direction_to_equirect_uv(dirs)
    else:
        u = np.mod(np.arctan2(dirs[..., 1], dirs[..., 0]) / (2 * np.pi), 1.0)
        v = np.arccos(np.clip(dirs[..., 2], -1.0, 1.0)) / np.pi
    col = np.minimum((u * columns).astype(np.int64), columns - 1)
    row = np.minimum((v * rows).astype(np.int64), rows - 1)
    return row, col


@functools.lru_cache(maxsize=8)
def _texel_cells(w: int, h: int, columns: int, rows: int, pole: str) -> tuple[np.ndarray, np.ndarray]:
    """(texel directions (h, w, 3), each texel's grid cell (h * w,)) of a w x h map, read-only and
    kept: an environment changed every frame (a key light dragged) re-uses them."""
    texel_dirs = equirect_directions(w, h)
    row, col = _grid_cells(texel_dirs, columns, rows, pole)
    cell = (row * columns + col).ravel()
    texel_dirs.flags.writeable = False
    cell.flags.writeable = False
    return texel_dirs, cell


def environment_to_lights(env: np.ndarray, *, grid: tuple[int, int] = (128, 64), pole: str = "y",
                          peak_factor: float = 30.0, max_peaks: int = 4096, keep_grid: bool = False) -> Lights:
    """Represent an environment map as directional lights, conserving its power exactly.

    Texels brighter than ``peak_factor`` times the mean luminance (a sun, a lamp) become
    lights of their own at their texel centres (at most ``max_peaks``, the brightest); the
    rest of each texel's power goes to the cell of a ``grid`` (columns, rows) lat-long grid
    around ``pole`` ('y': the map's own layout; 'z': the camera axis) that holds its centre,
    and the cell's light sits at the cell centre. Grid lights of different maps therefore share
    directions. Lights with zero power are dropped unless ``keep_grid`` (then the grid's cells
    come first, all of them, in row-major order).
    """
    if pole not in ("y", "z"):
        raise InputError(f"pole must be 'y' or 'z', got {pole!r}")
    columns, rows = grid
    h, w = env.shape[:2]
    dw = equirect_solid_angles(w, h)[:, None]
    power = env.astype(ACCUM) * dw[..., None]
    lum = luminance(env).astype(ACCUM)
    mean = float(np.sum(lum * dw) / (4 * np.pi))
    peak = lum > peak_factor * max(mean, TINY_SCALE)
    if peak.sum() > max_peaks:
        thresh = np.partition(lum.ravel(), -max_peaks)[-max_peaks]
        peak &= lum >= thresh
    texel_dirs, cell = _texel_cells(w, h, columns, rows, pole)
    rest = np.where(peak[..., None], 0.0, power).reshape(-1, 3)
    n_grid = rows * columns
    grid_power = np.stack([np.bincount(cell, rest[:, c], minlength=n_grid) for c in range(3)], axis=1)
    dirs = np.concatenate([grid_cell_directions(columns, rows, pole), texel_dirs[peak]])
    p = np.concatenate([grid_power, power[peak]])
    column = np.concatenate([np.tile(np.arange(columns), rows), np.full(int(peak.sum()), -1)])
    keep = p.sum(axis=1) > 0
    if keep_grid:
        keep[:n_grid] = True
    return Lights(dirs=dirs[keep], power=p[keep], column=column[keep],
                  n_grid=int(keep[:n_grid].sum()) if not keep_grid else n_grid)
