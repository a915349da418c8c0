"""Landmark-based warp from the reference into a frame: piecewise affine over a triangulation.

The control points are the tracked landmarks (reference position -> frame position) plus a ring
around the face whose frame positions come from the head pose (so the triangulation covers the
whole face, its outline included). The inverse map (frame pixel -> reference position) is
piecewise affine: exact at a coarse grid of ``GRID_STEP`` pixels, bilinear between (the
triangles are far larger than the grid), then one ``cv2.remap`` per image.

The rigid warp (the frame path's default) uses a mesh of fixed topology instead: the landmarks
and a grid over the face, triangulated once in the reference (:func:`reference_triangles`), its
corners moved every frame by the head pose and the tracked landmarks, drawn on the coarse grid
with depth (:func:`mesh_coarse_map`) - turned-away triangles left out, the nearer of two
overlapping ones kept.

Coordinates: (x right, y down) pixels; ``box`` = (x0, y0, x1, y1), x1/y1 exclusive.
"""

from __future__ import annotations

import cv2
import numpy as np
from scipy.spatial import Delaunay, QhullError

from relight.kernels.work_groups import OUTSIDE, OUTSIDE_HALF
from relight.numerics import EPS

#: Spacing (px) of the grid at which the piecewise-affine map is evaluated exactly.
GRID_STEP = 12


def face_ring(mask: np.ndarray, count: int = 32, margin: float = 0.06) -> np.ndarray:
    """(count, 2) float32 points on a ring around the mask, ``margin`` x its size outside it."""
    ys, xs = np.nonzero(mask)
    size = max(float(np.ptp(xs)), float(np.ptp(ys)), 1.0)
    r = max(int(round(margin * size)), 2)
    # Padded, so a mask that reaches the crop's edge (a tight crop) gets its ring outside it.
    pad = r + 2
    m = np.pad(mask.astype(np.uint8), pad)
    grown = cv2.dilate(m, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1)))
    contours, _ = cv2.findContours(grown, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    c = max(contours, key=len).reshape(-1, 2).astype(np.float32) - np.float32(pad)
    step = len(c) / count
    return c[(np.arange(count) * step).astype(int)]


def coarse_map(cur: np.ndarray, ref: np.ndarray, box: tuple[int, int, int, int],
               step: int = GRID_STEP) -> np.ndarray | None:
    """(gh, gw, 2) float32 reference positions of a grid of frame points: grid point (i, j) sits
    at frame pixel (x0 + (i - 0.5) step - 0.5, y0 + (j - 0.5) step - 0.5) - pixel centres as
    bilinear upsampling by ``step`` places them, one extra point on each side of the box.
    ``OUTSIDE`` where a point is outside the triangulation. None when the control points
    cannot be triangulated (fewer than 3, or all on a line)."""
    x0, y0, x1, y1 = box
    w, h = x1 - x0, y1 - y0
    if w <= 0 or h <= 0 or len(cur) < 3:
        return None
    try:
        tri = Delaunay(np.asarray(cur, dtype=np.float64))
    except (QhullError, ValueError):
        return None
    gw, gh = -(-w // step) + 2, -(-h // step) + 2
    gx = x0 + (np.arange(gw) - 0.5) * step - 0.5
    gy = y0 + (np.arange(gh) - 0.5) * step - 0.5
    pts = np.stack(np.meshgrid(gx, gy), axis=-1).reshape(-1, 2)
    s = tri.find_simplex(pts)
    inside = s >= 0
    # Each triangle's affine map frame -> reference, solved directly (Qhull's ``transform``
    # property is several times slower for a few hundred triangles).
    p = tri.points[tri.simplices]  # (T, 3, 2) frame corners
    q = np.asarray(ref, dtype=np.float64)[tri.simplices]  # (T, 3, 2) reference corners
    e = p[:, 1:] - p[:, :1]  # (T, 2, 2) edge vectors (rows)
    det = e[:, 0, 0] * e[:, 1, 1] - e[:, 0, 1] * e[:, 1, 0]
    det = np.where(np.abs(det) > EPS, det, EPS)
    inv = np.empty_like(e)
    inv[:, 0, 0], inv[:, 0, 1] = e[:, 1, 1], -e[:, 0, 1]
    inv[:, 1, 0], inv[:, 1, 1] = -e[:, 1, 0], e[:, 0, 0]
    inv /= det[:, None, None]
    lin = np.einsum("tik,tkj->tij", inv, q[:, 1:] - q[:, :1])  # (T, 2, 2): frame offset -> reference offset
    si = s[inside]
    out = np.full((pts.shape[0], 2), OUTSIDE, dtype=np.float64)
    out[inside] = q[si, 0] + np.einsum("ni,nij->nj", pts[inside] - p[si, 0], lin[si])
    return out.reshape(gh, gw, 2).astype(np.float32)


def reference_triangles(ref: np.ndarray) -> np.ndarray:
    """(T, 3) int32 triangles over control points ``ref`` (N, 2) in the reference - a mesh whose
    topology is fixed once (:func:`mesh_coarse_map` moves its corners every frame), each turning
    from +x toward +y (positive :func:`signed_areas`)."""
    tri = Delaunay(np.asarray(ref, dtype=np.float64)).simplices.astype(np.int32)
    flip = signed_areas(np.asarray(ref, np.float64), tri) < 0
    tri[flip] = tri[flip][:, ::-1]
    return np.ascontiguousarray(tri)


def signed_areas(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Twice the signed area of each triangle of ``points`` (N, 2): positive when its corners turn
    from +x toward +y (clockwise as the image shows them, y down)."""
    p = np.asarray(points, np.float64)[triangles]
    e1, e2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    return e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]


def mesh_coarse_map(cur: np.ndarray, ref: np.ndarray, triangles: np.ndarray, box: tuple[int, int, int, int],
                    depth: np.ndarray | None = None, step: int = GRID_STEP) -> np.ndarray | None:
    """:func:`coarse_map` for a mesh of fixed topology: the same grid of frame points (layout and
    ``OUTSIDE`` as there), each mapped through the triangle of ``triangles`` (T, 3) that covers it
    where the control points sit in this frame (``cur``, N x 2) to the reference (``ref``).

    The mesh is drawn as a renderer draws a surface: triangles turned away (their corners'
    order reversed from the reference's, :func:`reference_triangles`) or collapsed are left
    out, and where turned triangles overlap (a cheek behind the nose) the one nearer the camera
    wins - ``depth`` (N,) the control points' distance along the view (smaller is nearer; None:
    any). Rasterised on the grid, no triangulation per frame: ~10x cheaper than Qhull's at
    500 control points. None when no triangle covers a grid point."""
    x0, y0, x1, y1 = box
    w, h = x1 - x0, y1 - y0
    if w <= 0 or h <= 0 or len(cur) < 3 or len(triangles) == 0:
        return None
    gw, gh = -(-w // step) + 2, -(-h // step) + 2
    cur = np.asarray(cur, np.float64)
    area = signed_areas(cur, triangles)
    keep = area > EPS * step * step
    tri = triangles[keep]
    p = cur[tri]  # (T, 3, 2)
    # grid coordinates of the corners: grid point (i, j) sits at x0 + (i - 0.5) step - 0.5
    gxy = (p - np.array([x0 - 0.5 - 0.5 * step, y0 - 0.5 - 0.5 * step])) / step
    lo = np.maximum(np.ceil(gxy.min(axis=1) - 1e-9), 0).astype(np.int64)  # (T, 2) first column/row
    hi = np.minimum(np.floor(gxy.max(axis=1) + 1e-9), [gw - 1, gh - 1]).astype(np.int64)
    ni, nj = hi[:, 0] - lo[:, 0] + 1, hi[:, 1] - lo[:, 1] + 1
    on = (ni > 0) & (nj > 0)
    if not on.any():
        return None
    tri, p, lo, ni, nj, area = tri[on], p[on], lo[on], ni[on], nj[on], area[keep][on]
    count = ni * nj
    t = np.repeat(np.arange(len(tri)), count)  # every (triangle, grid point of its box) pair
    k = np.arange(t.size) - np.repeat(np.cumsum(count) - count, count)
    gi, gj = lo[t, 0] + k % ni[t], lo[t, 1] + k // ni[t]
    px = x0 + (gi - 0.5) * step - 0.5
    py = y0 + (gj - 0.5) * step - 0.5
    a, b, c = p[t, 0], p[t, 1], p[t, 2]
    # barycentric weights of each pair's point in its triangle (areas of the opposite sub-triangles)
    w1 = ((px - a[:, 0]) * (c[:, 1] - a[:, 1]) - (py - a[:, 1]) * (c[:, 0] - a[:, 0])) / area[t]
    w2 = ((b[:, 0] - a[:, 0]) * (py - a[:, 1]) - (b[:, 1] - a[:, 1]) * (px - a[:, 0])) / area[t]
    w0 = 1.0 - w1 - w2
    tol = -1e-9
    inside = (w0 >= tol) & (w1 >= tol) & (w2 >= tol)
    t, gi, gj, w0, w1, w2 = t[inside], gi[inside], gj[inside], w0[inside], w1[inside], w2[inside]
    if t.size == 0:
        return None
    cell = gj * gw + gi
    if depth is not None:  # the nearest of the triangles over a grid point
        d = np.asarray(depth, np.float64)[tri[t]]
        z = w0 * d[:, 0] + w1 * d[:, 1] + w2 * d[:, 2]
        order = np.lexsort((z, cell))
    else:
        order = np.argsort(cell, kind="stable")
    cell = cell[order]
    first = np.ones(cell.size, dtype=bool)
    first[1:] = cell[1:] != cell[:-1]
    sel = order[first]
    q = np.asarray(ref, np.float64)[tri[t[sel]]]  # (M, 3, 2)
    out = np.full((gh * gw, 2), OUTSIDE, dtype=np.float64)
    out[cell[first]] = w0[sel, None] * q[:, 0] + w1[sel, None] * q[:, 1] + w2[sel, None] * q[:, 2]
    return out.reshape(gh, gw, 2).astype(np.float32)


def inverse_map(cur: np.ndarray, ref: np.ndarray, box: tuple[int, int, int, int],
                step: int = GRID_STEP) -> np.ndarray | None:
    """(H_box, W_box, 2) float32 reference positions of the frame pixels in ``box`` (the coarse
    map upsampled bilinearly; ``OUTSIDE`` unless all four grid points around a pixel are inside).
    cur, ref : (M, 2) control points in the frame and in the reference."""
    coarse = coarse_map(cur, ref, box, step)
    if coarse is None:
        return None
    x0, y0, x1, y1 = box
    w, h = x1 - x0, y1 - y0
    gh, gw = coarse.shape[:2]
    full = cv2.resize(coarse, (gw * step, gh * step), interpolation=cv2.INTER_LINEAR)[step:step + h, step:step + w]
    # Pixels between a grid point inside the triangulation and one outside would interpolate
    # toward OUTSIDE and land anywhere: they are outside too. A pixel is valid when the four
    # grid points around it are; the cells between grid points start half a step in.
    ok = coarse[..., 0] > OUTSIDE_HALF
    cell = ok[:-1, :-1] & ok[1:, :-1] & ok[:-1, 1:] & ok[1:, 1:]
    half = step // 2
    valid = np.repeat(np.repeat(cell, step, axis=0), step, axis=1)[half:half + h, half:half + w]
    full = np.ascontiguousarray(full)
    full[~valid] = OUTSIDE
    return full


def points_box(points: np.ndarray, size: tuple[int, int], pad: int = 2) -> tuple[int, int, int, int] | None:
    """Integer box around points, padded and clipped to a (width, height) frame; None if empty."""
    w, h = size
    x0 = max(int(np.floor(points[:, 0].min())) - pad, 0)
    y0 = max(int(np.floor(points[:, 1].min())) - pad, 0)
    x1 = min(int(np.ceil(points[:, 0].max())) + pad + 1, w)
    y1 = min(int(np.ceil(points[:, 1].max())) + pad + 1, h)
    return (x0, y0, x1, y1) if x1 > x0 and y1 > y0 else None
