"""The live studio's camera: orthographic (the default) or a webcam's pinhole (``--fov``).

Camera space is the studio's (:mod:`.live`): +X right, +Y up, +Z toward the camera, in pixels of
the orthographic reference - a point at image column ``x``, row ``y`` with height ``h`` is
``(x, -y, h)``. The orthographic camera sees a point ``P`` at column ``Px``, row ``-Py``.

A pinhole (:class:`Pinhole`) of horizontal field of view ``fov`` has the focal length
``f = (W / 2) / tan(fov / 2)`` pixels and its principal point at the frame's centre
``(cx, cy) = (W / 2, H / 2)``; its eye is on the axis through that centre, ``distance`` in front
of the head's pivot (the middle of the skull): ``E = (cx, -cy, pivot_z + D)``, looking along -Z.
It sees ``P`` at::

    column = cx + f (Px - cx) / (Ez - Pz),    row = cy + f (-Py - cy) / (Ez - Pz)

``D`` is the distance in the reference's pixels: the studio's head is a person's, its head unit
(half the crown-to-chin height, ``Head.scale`` pixels) :data:`HEAD_UNIT_CM` long, so
``D = distance_cm * Head.scale / HEAD_UNIT_CM``. The head at the pivot's depth is therefore
magnified by ``f / D`` against the orthographic view: a narrow lens shows it larger, a wide one
smaller, and its near parts (the nose) larger than its far ones (the ears) by ``D / (D - dz)``, as
a webcam at a call's distance does.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from relight.errors import InputError

#: Half an adult's crown-to-chin height (cm): the studio head's unit. (Adult crown-to-chin
#: heights are ~21-24 cm; anthropometric surveys' means are ~22-23.)
HEAD_UNIT_CM = 11.25
#: ``--distance``'s default: a video call's distance from the camera to the face, cm.
DEFAULT_DISTANCE_CM = 60.0
#: Accepted horizontal fields of view (degrees) and distances (cm).
FOV_RANGE = (20.0, 120.0)
DISTANCE_RANGE = (30.0, 300.0)
#: Nearest a projected point may come to the eye, as a share of the distance (a point at or
#: behind the eye has no image).
MIN_DEPTH_SHARE = 0.05


def check_camera(fov: float | None, distance: float) -> None:
    """Raise :class:`InputError` naming the flag to change when ``fov`` or ``distance`` is out of range."""
    if fov is not None and not (np.isfinite(fov) and FOV_RANGE[0] <= fov <= FOV_RANGE[1]):
        raise InputError(f"--fov {fov}: use a horizontal field of view from {FOV_RANGE[0]:g} to "
                         f"{FOV_RANGE[1]:g} degrees (a webcam's is 60-80), or leave it out for an orthographic camera")
    if not (np.isfinite(distance) and DISTANCE_RANGE[0] <= distance <= DISTANCE_RANGE[1]):
        raise InputError(f"--distance {distance}: use {DISTANCE_RANGE[0]:g} to {DISTANCE_RANGE[1]:g} cm "
                         f"(a video call's is ~{DEFAULT_DISTANCE_CM:g})")


@dataclass(frozen=True)
class Pinhole:
    """A pinhole camera in the studio's camera space (see the module docstring).

    focal : pixels; center : principal point (column, row); eye_z : the eye's camera-space Z;
    fov_deg, distance_cm : what it was made from; distance_px : ``eye_z`` minus the pivot's Z.
    """

    focal: float
    center: tuple[float, float]
    eye_z: float
    fov_deg: float
    distance_cm: float
    distance_px: float

    @classmethod
    def from_fov(cls, size: tuple[int, int], fov_deg: float, distance_cm: float, head_scale: float,
                 pivot_z: float) -> Pinhole:
        """The pinhole of a (width, height) frame with ``fov_deg`` across, ``distance_cm`` from a
        head whose unit is ``head_scale`` pixels and whose pivot is at camera-space Z ``pivot_z``."""
        check_camera(fov_deg, distance_cm)
        if not (np.isfinite(head_scale) and head_scale > 0):
            raise InputError(f"head scale {head_scale}: must be a positive number of pixels")
        w, h = size
        focal = 0.5 * w / math.tan(math.radians(0.5 * fov_deg))
        distance_px = distance_cm * head_scale / HEAD_UNIT_CM
        return cls(focal=focal, center=(0.5 * w, 0.5 * h), eye_z=float(pivot_z) + distance_px, fov_deg=float(fov_deg),
                   distance_cm=float(distance_cm), distance_px=distance_px)

    @property
    def magnification(self) -> float:
        """The image's scale at the pivot's depth against the orthographic view's."""
        return self.focal / self.distance_px

    def image_points(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Camera-space points (N, 3) -> their image columns and rows (N,) each.

        Raises :class:`InputError` when a point comes within :data:`MIN_DEPTH_SHARE` of the
        distance of the eye (or behind it): the head is too near the camera for its pose."""
        p = np.asarray(points, dtype=np.float64)
        depth = self.eye_z - p[:, 2]
        if depth.size and not depth.min() > MIN_DEPTH_SHARE * self.distance_px:
            raise InputError(f"the head comes within {self.eye_z - p[:, 2].max():.1f} px of the camera at "
                             f"--distance {self.distance_cm:g} cm: place it farther")
        s = self.focal / depth
        cx, cy = self.center
        return cx + s * (p[:, 0] - cx), cy + s * (-p[:, 1] - cy)

    def view_rays(self, xs, ys) -> np.ndarray:
        """Unit rays (..., 3) from the eye through image columns ``xs`` and rows ``ys`` (broadcast
        together): the directions :meth:`image_points` inverts."""
        x, y = np.broadcast_arrays(np.asarray(xs, np.float64), np.asarray(ys, np.float64))
        cx, cy = self.center
        d = np.stack([(x - cx) / self.focal, -(y - cy) / self.focal, -np.ones_like(x)], axis=-1)
        return d / np.linalg.norm(d, axis=-1, keepdims=True)

    def meta(self) -> dict:
        """The camera as the live clip's truth records it (``meta.json``'s ``camera``)."""
        return {"model": "pinhole", "fov_deg": self.fov_deg, "focal_px": self.focal,
                "principal_point": list(self.center), "distance_cm": self.distance_cm,
                "distance_px": self.distance_px, "eye_z": self.eye_z, "head_unit_cm": HEAD_UNIT_CM,
                "magnification": self.magnification}


def image_points(camera: Pinhole | None, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Image columns and rows of camera-space points (N, 3) through ``camera`` (None: orthographic)."""
    if camera is None:
        p = np.asarray(points)
        return p[:, 0], -p[:, 1]
    return camera.image_points(points)


ORTHOGRAPHIC_META = {"model": "orthographic"}
