"""Directions, the lat-long (equirectangular) layout, rotations and the mirror-sphere law.

Conventions (used everywhere in relight, documented in docs/conventions.md):

* Camera space: +X right in the image, +Y up, +Z toward the camera. A *light direction* is
  the unit vector from the face toward the light. Orthographic view direction (from the
  surface toward the camera) is +Z.
* Lat-long maps follow OpenEXR / Mitsuba: +Y is up (top row), the centre column is +Z,
  the column at 1/4 of the width is +X (so the left/right edges are -Z). For a texel
  coordinate ``u, v`` in [0, 1) (``u`` across, ``v`` down)::

      theta = pi * v            (polar angle from +Y)
      phi   = 2 * pi * u
      d     = (sin(phi) sin(theta), cos(theta), -cos(phi) sin(theta))

  Texel ``(i, j)`` (column, row) has its centre at ``u = (i + 0.5) / W``, ``v = (j + 0.5) / H``.
* Head rotation: ``R = Ry(yaw) @ Rx(pitch) @ Rz(roll)``, angles in degrees, right-handed
  rotations about camera +Y, +X, +Z.
* Image-space rigid motion ``[tx, ty, rot_deg]`` about a centre ``c``: a point ``p`` of the
  reference image moves to ``R(rot) (p - c) + c + t`` with ``rot`` counter-clockwise as seen
  on screen (OpenCV's ``getRotationMatrix2D`` sign), i.e. a roll about +Z.
"""

from __future__ import annotations

import numpy as np

from .numerics import ACCUM, EPS


def equirect_uv_to_direction(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Lat-long texture coordinates (u across, v down, in [0, 1]) -> unit directions (..., 3)."""
    u, v = np.broadcast_arrays(np.asarray(u, dtype=ACCUM), np.asarray(v, dtype=ACCUM))
    theta = np.pi * v
    phi = 2.0 * np.pi * u
    st = np.sin(theta)
    return np.stack([np.sin(phi) * st, np.cos(theta), -np.cos(phi) * st], axis=-1)


def direction_to_equirect_uv(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit directions (..., 3) -> lat-long (u, v), u in [0, 1), v in [0, 1]."""
    d = np.asarray(d, dtype=ACCUM)
    n = np.linalg.norm(d, axis=-1)
    n = np.where(n > EPS, n, 1.0)
    x, y, z = d[..., 0] / n, d[..., 1] / n, d[..., 2] / n
    theta = np.arccos(np.clip(y, -1.0, 1.0))
    phi = np.arctan2(x, -z)
    u = np.mod(phi / (2.0 * np.pi), 1.0)
    return u, theta / np.pi


def equirect_directions(width: int, height: int) -> np.ndarray:
    """Directions of the texel centres of a ``width x height`` lat-long map, (H, W, 3) float64."""
    u = (np.arange(width, dtype=ACCUM) + 0.5) / width
    v = (np.arange(height, dtype=ACCUM) + 0.5) / height
    return equirect_uv_to_direction(u[None, :], v[:, None])


def equirect_solid_angles(width: int, height: int) -> np.ndarray:
    """Exact solid angle (sr) of one texel in each row, (H,) float64; sums to 4 pi over the map."""
    edges = np.cos(np.pi * np.arange(height + 1, dtype=ACCUM) / height)
    return (2.0 * np.pi / width) * (edges[:-1] - edges[1:])


#: The environment's turn about the vertical (degrees) and its spin (degrees per second): one
#: convention everywhere - a turn of +D moves every light D degrees in azimuth toward +X (the
#: image's right): the environment rotated by ``rotation_matrix(D, 0, 0)`` (``relight.envmap.rotate_environment``;
#: what the HTTP API's rotation=D,0,0 does). Turning the environment by +D lights the face as
#: turning the head by -D (``render --rotate -D,0,0``) does.
ENV_TURN_RANGE_DEG = (-360.0, 360.0)
ENV_SPIN_RANGE_DEG_S = (-180.0, 180.0)

def with_env_turn(rotation: np.ndarray | None, env_rotation: np.ndarray | None) -> np.ndarray | None:
    """The rotation to relight with (a head turned by R sees the light from d at R^T d; None: not
    turned) when the environment itself is turned by ``env_rotation`` E (its lights at E d, seen
    at R^T E d): E^T R, E^T alone for no head rotation, ``rotation`` as it is for no turn."""
    if env_rotation is None:
        return rotation
    return env_rotation.T if rotation is None else env_rotation.T @ rotation


def rotation_matrix(yaw: float = 0.0, pitch: float = 0.0, roll: float = 0.0) -> np.ndarray:
    """``Ry(yaw) @ Rx(pitch) @ Rz(roll)`` from angles in degrees, (3, 3) float64."""
    a, b, c = np.radians([yaw, pitch, roll])
    ry = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    rx = np.array([[1, 0, 0], [0, np.cos(b), -np.sin(b)], [0, np.sin(b), np.cos(b)]])
    rz = np.array([[np.cos(c), -np.sin(c), 0], [np.sin(c), np.cos(c), 0], [0, 0, 1]])
    return ry @ rx @ rz


def rotation_angles(r: np.ndarray) -> tuple[float, float, float]:
    """Inverse of :func:`rotation_matrix`: (yaw, pitch, roll) in degrees, pitch in [-90, 90]."""
    r = np.asarray(r, dtype=ACCUM)
    pitch = np.arcsin(np.clip(-r[1, 2], -1.0, 1.0))
    yaw = np.arctan2(r[0, 2], r[2, 2])
    roll = np.arctan2(r[1, 0], r[1, 1])
    return tuple(float(x) for x in np.degrees([yaw, pitch, roll]))


def rigid_matrix(tx: float, ty: float, rot_deg: float, center: tuple[float, float]) -> np.ndarray:
    """The 2x3 image-space matrix of a rigid motion ``[tx, ty, rot_deg]`` about ``center``.

    Maps reference-image pixel coordinates (x right, y down) to the moved image; usable
    directly with ``cv2.warpAffine``.
    """
    cx, cy = center
    a = np.radians(rot_deg)
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, s, (1 - c) * cx - s * cy + tx], [-s, c, s * cx + (1 - c) * cy + ty]], dtype=ACCUM)


def mirror_normal(light: np.ndarray, view: np.ndarray = (0.0, 0.0, 1.0)) -> np.ndarray:
    """Normal of a mirror that reflects the view ray into ``light``: the half vector."""
    h = np.asarray(light, dtype=ACCUM) + np.asarray(view, dtype=ACCUM)
    n = np.linalg.norm(h, axis=-1, keepdims=True)
    return h / np.where(n > EPS, n, 1.0)


def reflect(view: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Mirror reflection of ``view`` (pointing away from the surface) about ``normal``."""
    view = np.asarray(view, dtype=ACCUM)
    normal = np.asarray(normal, dtype=ACCUM)
    return 2.0 * np.sum(view * normal, axis=-1, keepdims=True) * normal - view


def sphere_point_for_light(light: np.ndarray, sphere: tuple[float, float, float]) -> np.ndarray:
    """Image position (x, y) of the highlight of ``light`` on a mirror sphere (orthographic).

    sphere : (cx, cy, r) in pixels. light : (..., 3) unit direction(s) in camera space.
    """
    cx, cy, r = sphere
    n = mirror_normal(light)
    return np.stack([cx + r * n[..., 0], cy - r * n[..., 1]], axis=-1)


def light_for_sphere_point(xy: np.ndarray, sphere: tuple[float, float, float]) -> np.ndarray:
    """Inverse of :func:`sphere_point_for_light`: light direction(s) (..., 3) for image point(s)."""
    cx, cy, r = sphere
    xy = np.asarray(xy, dtype=ACCUM)
    nx = (xy[..., 0] - cx) / r
    ny = -(xy[..., 1] - cy) / r
    nz = np.sqrt(np.clip(1.0 - nx * nx - ny * ny, 0.0, 1.0))
    return reflect(np.array([0.0, 0.0, 1.0]), np.stack([nx, ny, nz], axis=-1))


def fibonacci_sphere(n: int) -> np.ndarray:
    """(n, 3) nearly uniform unit directions (a Fibonacci lattice: equal-area z bands, the
    azimuth turned by the golden angle), +Z at the first point's pole."""
    i = np.arange(n) + 0.5
    phi = np.arccos(1 - 2 * i / n)
    theta = np.pi * (1 + 5**0.5) * i
    return np.stack([np.cos(theta) * np.sin(phi), np.sin(theta) * np.sin(phi), np.cos(phi)], axis=1)


def angle_between_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle in degrees between direction arrays (..., 3) (not necessarily unit)."""
    a = np.asarray(a, dtype=ACCUM)
    b = np.asarray(b, dtype=ACCUM)
    # atan2(|a x b|, a . b) is accurate at every angle, unlike acos of a dot product.
    return np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1)))
