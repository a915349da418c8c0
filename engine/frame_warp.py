"""The face's warp in one frame: where the rig's points sit in the frame (the head pose's
projection plus what the tracked landmarks add beyond the tracking noise,
:func:`regularised_points`), the warp they give (:func:`face_warp`: a :class:`FaceWarp`, its
coarse map of frame pixels to reference positions made when asked, :mod:`.warp`), and the live
frame read through it at the live light's sample pixels (:func:`sample_live`).

``rig`` is the path's :class:`relight.engine.rig.FaceRig`; points are (N, 2) float32 pixels (x
right, y down); boxes are (x0, y0, x1, y1).
"""
from __future__ import annotations

import cv2
import numpy as np

from relight.colour import decode_srgb8
from relight.kernels.work_groups import OUTSIDE
from relight.numerics import EPS, px_at

from .warp import GRID_STEP, coarse_map, mesh_coarse_map, points_box

#: Tracked points within this distance (px at 540 rows) of where the head pose puts them are taken
#: as its noise (:func:`regularised_points`).
POINT_NOISE_AT_540 = 2.0


def regularised_points(base: np.ndarray, xy: np.ndarray, size) -> np.ndarray:
    """Tracked points ``xy`` (N, 2) as ``base`` (where the head pose puts them) plus what the
    pose leaves of each, shrunk toward zero where it is within the tracking noise
    (``POINT_NOISE_AT_540`` px, scaled): noise does not bend the warp, a real departure from
    the pose (an expression, the bundle's depth error) does."""
    e = xy - base
    noise = px_at(POINT_NOISE_AT_540, size[1])
    n2 = (e * e).sum(axis=1, keepdims=True)
    shrink = np.clip(1.0 - noise * noise / np.maximum(n2, EPS), 0.0, 1.0)
    return (base + shrink * e).astype(np.float32)


def _affine_ring(src: np.ndarray, dst: np.ndarray, ring: np.ndarray) -> np.ndarray:
    """The ring around the face carried by the least-squares affine map of the tracked points
    (robust where the bundle's depth is poor; the ring only anchors the mask's feathered edge)."""
    a = np.c_[src, np.ones(len(src))].astype(np.float64)
    m, *_ = np.linalg.lstsq(a, dst.astype(np.float64), rcond=None)
    return (np.c_[ring, np.ones(len(ring))] @ m).astype(np.float32)


def _mesh_positions(rig, est, pose, ref_idx: np.ndarray, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The warp mesh's corners in this frame ((N, 2) float32) and their distance along the
    view ((N,) camera z): where the head ``pose`` (``est``'s) puts them, the tracked landmarks
    ``ref_idx`` at ``xy`` (the pose's projection plus what it leaves of each beyond the tracking
    noise)."""
    model = rig.mesh_model
    cur = est.project_points(pose, model).astype(np.float32)
    cur[ref_idx] = xy
    r, _ = cv2.Rodrigues(pose.rvec)
    depth = model @ r[2] + float(pose.tvec[2, 0])
    return cur, depth


class FaceWarp:
    """The face's warp in one frame (:func:`face_warp`): ``cur`` and ``ref`` where its points sit
    in the frame (N, 2) and in the reference, ``box`` the frame's box they span (None: the face
    is outside the frame) and :meth:`coarse` the coarse map over it - made when first asked (a
    frame that carries the last light field needs the points alone: 2-3 ms saved at 720p)."""

    def __init__(self, rig, cur: np.ndarray, ref: np.ndarray, box, depth: np.ndarray | None):
        self._rig, self.cur, self.ref, self.box, self._depth = rig, cur, ref, box, depth
        self._coarse = None
        self._made = box is None

    def coarse(self) -> np.ndarray | None:
        """The coarse map of frame pixels to reference positions over :attr:`box`
        (:mod:`.warp`; None: the face is outside the frame or its points do not triangulate)."""
        if not self._made:
            self._made = True
            if self._depth is not None:
                self._coarse = mesh_coarse_map(self.cur, self.ref, self._rig.mesh_triangles, self.box, self._depth)
            else:
                self._coarse = coarse_map(self.cur, self.ref, self.box)
        return self._coarse


def face_warp(rig, est, pose, size, ref_idx: np.ndarray, xy: np.ndarray, rigid: bool) -> FaceWarp:
    """The face's :class:`FaceWarp` in this frame. ``est``: the frame's
    :class:`relight.engine.pose.PoseEstimator` (``size`` (w, h)) and ``pose`` its head pose;
    ``ref_idx``, ``xy``: the tracked landmarks and where they sit (:func:`regularised_points`);
    ``rigid``: the rig's mesh moved by the pose and the landmarks, else the landmarks and an
    affine ring (FramePath's ``rigid_warp``)."""
    if rigid:
        cur, depth = _mesh_positions(rig, est, pose, ref_idx, xy)
        return FaceWarp(rig, cur, rig.mesh_ref, points_box(cur, size), depth)
    ring = rig.control_ref[rig.ring_index]
    cur = np.concatenate([xy, _affine_ring(rig.control_ref[ref_idx], xy, ring)])
    ref = np.concatenate([rig.control_ref[ref_idx], ring])
    return FaceWarp(rig, cur, ref, points_box(cur, size), None)


def sample_live(rig, rgb, cur: np.ndarray, ref: np.ndarray, rotation: np.ndarray, rigid: bool):
    """The live frame at the light estimator's sample pixels: ((S, 3) float32 linear, (S,) bool
    where the frame shows them - inside it, the warp and facing the camera). ``rgb``: (H, W, 3)
    uint8 sRGB or a :class:`relight.video_yuv.YuvFrame` (read in its planes); ``cur``, ``ref``,
    ``rigid``: the warp's points in the frame and the reference (:func:`face_warp`);
    ``rotation``: the head's (3x3)."""
    from relight.video_yuv import sample_codes

    n = rig.live_ref.shape[0]
    if rigid:  # frame positions of a grid over the reference
        grid = mesh_coarse_map(ref, cur, rig.mesh_triangles, rig.live_box)
    else:
        grid = coarse_map(ref, cur, rig.live_box)
    if grid is None or n == 0:
        return np.zeros((n, 3), np.float32), np.zeros(n, dtype=bool)
    x0, y0 = rig.live_box[:2]
    gx = ((rig.live_ref[:, 0] - x0 + 0.5) / GRID_STEP + 0.5).astype(np.float32)[None]
    gy = ((rig.live_ref[:, 1] - y0 + 0.5) / GRID_STEP + 0.5).astype(np.float32)[None]
    pos = cv2.remap(grid, gx, gy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=(OUTSIDE, OUTSIDE))[0]
    h, w = rgb.shape[:2]
    valid = (pos[:, 0] >= 0) & (pos[:, 1] >= 0) & (pos[:, 0] <= w - 1) & (pos[:, 1] <= h - 1)
    valid &= rig.live_normal @ np.asarray(rotation, np.float32)[2] > 0.3
    return decode_srgb8(sample_codes(rgb, pos)).reshape(-1, 3), valid
