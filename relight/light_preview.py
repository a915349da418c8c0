"""A small picture of a light: a grey ball and a skin-toned ball lit by an environment, seen from
the camera (what ``relight live``'s page shows and lets a user drag the key light on).

The balls are Lambertian: each pixel's irradiance is the environment's radiance over 32x16
texels times the cosine to the ball's normal there (camera space: +X the image's right, +Y up,
+Z toward the camera), so a key light placed toward (az, el) lights the ball where its normal
points there - dragging on the ball places the key where the bright spot goes.
"""

from __future__ import annotations

import functools

import cv2
import numpy as np

from .colour import LUMINANCE, encode_srgb8
from .directions import equirect_directions, equirect_solid_angles

#: The balls' albedos (linear Rec.709): a mid grey and a light skin tone.
GREY_ALBEDO = (0.45, 0.45, 0.45)
SKIN_ALBEDO = (0.62, 0.40, 0.30)
#: A light loaded only to be shown on the balls is drawn at this width (they read it at 32 x 16).
LOAD_WIDTH = 256
#: The background behind the balls (sRGB codes).
BACKGROUND = 28
#: The environment is summed over this many texels (columns x rows): 11-degree texels, finer than
#: a Lambertian ball shows.
TEXELS = (32, 16)


def ball_normals(size: int) -> tuple[np.ndarray, np.ndarray]:
    """((size, size, 3) float64 unit normals of a ball filling a size x size square, seen from
    +Z; (size, size) bool inside it)."""
    c = (np.arange(size) + 0.5) / size * 2.0 - 1.0
    x, y = np.meshgrid(c, -c)
    r2 = x * x + y * y
    inside = r2 <= 1.0
    z = np.sqrt(np.clip(1.0 - r2, 0.0, None))
    return np.stack([x, y, z], axis=-1), inside


def ball_direction(u: float, v: float) -> tuple[float, float]:
    """The light direction (azimuth, elevation in degrees) whose bright spot is at (u, v) on the
    ball (0-1 across its square, v down): the ball's normal there - a point outside the ball
    is taken to its rim. The page's drag uses this."""
    x, y = 2.0 * u - 1.0, 1.0 - 2.0 * v
    r = float(np.hypot(x, y))
    if r > 1.0:
        x, y = x / r, y / r
    z = float(np.sqrt(max(0.0, 1.0 - x * x - y * y)))
    return float(np.degrees(np.arctan2(x, z))), float(np.degrees(np.arcsin(np.clip(y, -1.0, 1.0))))


@functools.lru_cache(maxsize=4)
def _cosines(size: int) -> np.ndarray:
    """(size * size, texels) float32: each ball pixel's clamped cosine to each texel, times the
    texel's solid angle / pi (made once per size: a preview is then one product)."""
    cols, rows = TEXELS
    normals, _ = ball_normals(size)
    dirs = equirect_directions(cols, rows).reshape(-1, 3)
    omega = np.repeat(equirect_solid_angles(cols, rows), cols)
    return (np.clip(normals.reshape(-1, 3) @ dirs.T, 0.0, None) * omega / np.pi).astype(np.float32)


def irradiance(env: np.ndarray, size: int) -> np.ndarray:
    """(size, size, 3) irradiance / pi (what a white Lambertian surface reads) over a ball of
    ``size`` x ``size`` pixels (:func:`ball_normals`) under ``env`` ((H, 2H, 3) linear radiance)."""
    small = shrunk(env, TEXELS[0]).reshape(-1, 3)  # (TEXELS is 2:1)
    return (_cosines(size) @ small).reshape(size, size, 3)


def balls(env: np.ndarray, size: int = 96, exposure: float | None = None) -> np.ndarray:
    """(size, 2 size, 3) uint8 sRGB: the grey ball and the skin ball under ``env``. ``exposure``:
    a linear scale; None puts the grey ball's brightest point at 0.9 (each light seen at a
    readable brightness)."""
    _, inside = ball_normals(size)
    e = irradiance(env, size)
    if exposure is None:
        peak = float((e[inside] @ LUMINANCE).max()) * GREY_ALBEDO[0]
        exposure = 0.9 / peak if peak > 1e-12 else 1.0
    out = []
    for albedo in (GREY_ALBEDO, SKIN_ALBEDO):
        lit = np.clip(e * np.asarray(albedo) * exposure, 0.0, 1.0).astype(np.float32)
        img = encode_srgb8(lit)
        img[~inside] = BACKGROUND
        out.append(img)
    return np.hstack(out)


def shrunk(env: np.ndarray, width: int = 64) -> np.ndarray:
    """``env`` (H, 2H, 3) area-averaged to ``width`` x ``width / 2`` (what a preview needs)."""
    return cv2.resize(np.asarray(env, np.float32), (width, width // 2), interpolation=cv2.INTER_AREA)


def balls_png(env: np.ndarray, size: int = 96, turn_deg: float = 0.0) -> bytes:
    """:func:`balls` as PNG bytes, the environment turned by ``turn_deg`` first (the convention
    of :data:`relight.directions.ENV_TURN_RANGE_DEG`)."""
    small = shrunk(env)
    if turn_deg:
        from .directions import rotation_matrix
        from .envmap import rotate_environment

        small = rotate_environment(small, rotation_matrix(turn_deg, 0.0, 0.0))
    ok, buf = cv2.imencode(".png", cv2.cvtColor(balls(small, size), cv2.COLOR_RGB2BGR))
    return buf.tobytes()
