"""A capture's head seen through a pinhole (``relight synth --fov`` without ``--live``).

The orthographic studio moves its head image in the image plane (:func:`.rig.motion_matrices`);
through a pinhole the same rigid motion is a motion of the head in space - a roll about the
camera's axis through the head's pivot and a shift in the pivot's plane, the live clip's
convention (:mod:`.live`: ``P' = R (P - C) + C + (tx, -ty, 0)``, ``R`` the roll) - and the head
is the live clip's mesh (:class:`.render.LiveHead`, or :class:`.mesh_render.MeshLiveHead`)
rasterised through the camera. Its values are the capture's own radiance at the reference pose
(the studio's shader: cast shadows, specular, the flash turned into the head's frame), carried
by each vertex. The truth's images (relit, one-light, normals, albedo, depth, the mask) go
through the same projection at the reference pose, so they lie on the capture's reference frame
pixel for pixel.

With a camera of None every function here is orthographic (the tests' check that the mesh path
reproduces the image-plane warp).
"""

from __future__ import annotations

import numpy as np

from relight.directions import rotation_matrix
from relight.numerics import EPS_VALUE, FLOAT

from .head import Head
from .mesh_head import HeadMesh, Placement
from .mesh_render import MeshLiveHead
from .pinhole import Pinhole
from .render import LiveHead

#: A pixel of a truth image through the pinhole is on the head when at least this share of its
#: samples sees the head (the orthographic truth's mask: the pixel's centre on the head).
MASK_SHARE = 0.5


def capture_mesh(head: Head, radiance: np.ndarray, room: np.ndarray, pivot: np.ndarray, *, reach_px: float,
                 camera: Pinhole | None, mesh: HeadMesh | None = None, placement: Placement | None = None
                 ) -> LiveHead | MeshLiveHead:
    """The capture's head as a mesh that renders at any pose through ``camera``: the live
    clip's (a height field's or ``mesh``'s). ``radiance`` (P, 3): the room's light at the
    reference pose (what it shades by when given no values); ``reach_px``: how far the
    height field's neck reaches below the frame."""
    if mesh is None:
        return LiveHead(head, radiance, room, pivot, reach_px=reach_px, camera=camera)
    return MeshLiveHead(mesh, placement, head, radiance, room, pivot, camera=camera)


def motion_pose(motion_row) -> tuple[np.ndarray, tuple[float, float]]:
    """A capture frame's ``[tx, ty, rot_deg]`` (the truth's ``head_motion``) as the mesh's pose:
    the roll's rotation matrix (counter-clockwise on screen, as the image-plane warp's) and the
    shift (pixels of the pivot's plane, ty down)."""
    tx, ty, rot = (float(v) for v in motion_row)
    return rotation_matrix(roll=rot), (tx, ty)


def posed_layer(head_mesh: LiveHead | MeshLiveHead, image: np.ndarray, motion_row
                ) -> tuple[tuple[int, int, int, int], np.ndarray, np.ndarray]:
    """The head at a capture frame's motion carrying ``image`` ((H, W, 3) linear radiance at the
    reference pose's pixels): its box (x0, y0, x1, y1), premultiplied radiance and coverage.
    A mesh head's parts the reference pose did not see (a scan's body continued below the
    frame) take its colour map under the room's diffuse light."""
    rotation, shift = motion_pose(motion_row)
    if isinstance(head_mesh, MeshLiveHead):
        return head_mesh.render(rotation, shift, lit=(image, head_mesh.sh))
    return head_mesh.render(rotation, shift, head_mesh.vertex_values(image))


def reference_view(head_mesh: LiveHead | MeshLiveHead, images: list[np.ndarray], mask: np.ndarray
                   ) -> tuple[list[np.ndarray], np.ndarray]:
    """Reference-pose images (each (H, W) or (H, W, C), the orthographic reference's pixels)
    as the camera sees them at the reference pose, and the head's mask there.

    Each is rendered with the ``mask`` (H, W) (the orthographic reference's head pixels) as one
    more channel, and divided by that channel's mean: a pixel's value is the mean over its
    samples on the head. Returns the images (float32, the same channels, 0 off the mask) and
    the mask (bool: at least :data:`MASK_SHARE` of the pixel's samples on the head).
    """
    chans = [np.asarray(img, dtype=np.float64).reshape(*mask.shape, -1) for img in images]
    stack = np.concatenate([*chans, mask[..., None].astype(np.float64)], axis=2)
    box, values, _ = head_mesh.render(np.eye(3), (0.0, 0.0), head_mesh.vertex_values(stack))
    x0, y0, x1, y1 = box
    full = np.zeros((*mask.shape, stack.shape[2]), dtype=np.float64)
    full[y0:y1, x0:x1] = values
    weight = full[..., -1]
    seen = weight >= MASK_SHARE
    full = np.where(seen[..., None], full / np.maximum(weight, EPS_VALUE)[..., None], 0.0)
    out, k = [], 0
    for img, ch in zip(images, chans, strict=True):
        n = ch.shape[2]
        part = full[..., k:k + n].astype(FLOAT)
        out.append(part if np.ndim(img) == 3 else part[..., 0])
        k += n
    return out, seen
