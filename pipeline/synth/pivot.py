"""Where the studio's head turns (its pivot, the middle of the skull) and how far a height-field
head's neck must reach below the frame for a pinhole to see it leave the bottom: shared by the
live clip (:mod:`.live`) and a capture through a pinhole (:mod:`.studio` with ``fov``)."""

from __future__ import annotations

import numpy as np

from .head import Head
from .pinhole import Pinhole

#: Pivot depth behind the face's frontmost point, in head units (``Head.scale`` pixels each).
PIVOT_DEPTH = 0.5


def pivot_point(head: Head) -> np.ndarray:
    """Camera-space pivot ``C`` = (cx, -cy, z): the head centre, :data:`PIVOT_DEPTH` head units
    behind the face's frontmost point."""
    cx, cy = head.center
    z = float(head.height[head.mask].max()) - PIVOT_DEPTH * head.scale
    return np.array([cx, -cy, z], dtype=np.float64)


def mesh_pivot(head: Head, points: np.ndarray) -> np.ndarray:
    """Camera-space pivot of a head mesh: the head centre, halfway in depth between the face's
    frontmost point and the mesh's back (a real head's middle, where the neck turns it)."""
    cx, cy = head.center
    front = float(head.height[head.mask].max())
    return np.array([cx, -cy, 0.5 * (front + float(points[:, 2].min()))], dtype=np.float64)


def neck_reach(reach: float, height: int, head_scale: float, camera: Pinhole) -> float:
    """How far (reference pixels) a height-field head's neck must reach below the frame's
    ``height`` for a pinhole ``camera`` to see it leave the frame's bottom, where the orthographic
    camera needs ``reach``: a camera that shows the neck's plane smaller than the reference (a
    wide lens) needs it longer. The neck is taken a head unit behind the pivot (its farthest)."""
    s = camera.focal / (camera.distance_px + head_scale)
    below = height - camera.center[1]  # the frame's bottom below the principal point
    return reach if s >= 1.0 else (below + reach) / s - below
