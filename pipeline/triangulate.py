"""The capture's triangulation of its light directions (paper section 3.2, step 1; stage 5):
virtual black lights added outside the captured hull, the spherical Delaunay triangulation (their
convex hull; directions that coincide where the hand paused are joggled apart by Qhull's ``QJ``
and their faces of no area never picked), and each map texel's triangle with its spherical
barycentric weights (the planar weights of its ray through the triangle, normalised). What it
makes, :class:`relight.kernels.triangulation.Triangulation`, is stored in the bundle and read
online."""

from __future__ import annotations

import numpy as np

from relight.directions import equirect_directions, fibonacci_sphere
from relight.errors import InputError
from relight.kernels.triangulation import Triangulation
from relight.numerics import EPS, EPS_NORM

DEFAULT_MAP_SIZE = (64, 32)
#: Virtual black lights sit where the nearest sample is farther than this many times the
#: samples' typical spacing (and at least BLACK_MIN_DEG).
BLACK_SPACING = 1.6
BLACK_MIN_DEG = 10.0
BLACK_CANDIDATES = 600


def _convex_hull(points: np.ndarray, **kw):
    """scipy's ConvexHull, imported on first use (scipy.spatial takes ~0.9 s to import: a
    bundle's first frame does not need it)."""
    from scipy.spatial import ConvexHull

    return ConvexHull(points, **kw)


def inside_hull(dirs: np.ndarray, query: np.ndarray) -> np.ndarray:
    """(Q,) bool: which query directions lie inside the spherical convex hull of ``dirs``.

    That hull is the convex cone of the sample directions: the faces of the 3D hull of the
    samples and the origin that meet at the origin bound it. When the origin is inside that
    hull (samples all around), every direction is inside; a degenerate set (all on one great
    circle) has no inside.
    """
    from scipy.spatial import QhullError

    pts = np.vstack([np.zeros(3), dirs])
    try:
        hull = _convex_hull(pts)
    except QhullError:
        return np.zeros(len(query), dtype=bool)
    at_origin = np.any(hull.simplices == 0, axis=1)
    if not at_origin.any():
        return np.ones(len(query), dtype=bool)
    planes = hull.equations[at_origin]  # outward normal n, offset ~0: inside where n . x <= 0
    return (query @ planes[:, :3].T + planes[:, 3] <= EPS_NORM).all(axis=1)


def triangulate(dirs: np.ndarray, map_size: tuple[int, int] = DEFAULT_MAP_SIZE) -> Triangulation:
    """Spherical Delaunay triangulation of the sample directions plus virtual black lights.

    Raises :class:`InputError` for fewer than 3 distinct directions or non-finite input.
    """
    dirs = np.asarray(dirs, dtype=np.float64)
    if dirs.ndim != 2 or dirs.shape[1] != 3 or not np.isfinite(dirs).all():
        raise InputError("light directions must be finite (K, 3) vectors")
    norm = np.linalg.norm(dirs, axis=1, keepdims=True)
    if (norm < EPS_NORM).any():
        raise InputError("a light direction has zero length")
    dirs = dirs / norm
    k = len(dirs)
    if k < 3:
        raise InputError(f"{k} light direction(s): at least 3 distinct directions are needed")
    # Typical spacing: median angle to the nearest other sample.
    cosm = dirs @ dirs.T
    np.fill_diagonal(cosm, -1.0)
    spacing = np.degrees(np.arccos(np.clip(cosm.max(axis=1), -1, 1)))
    gap = max(BLACK_SPACING * float(np.median(spacing)), BLACK_MIN_DEG)
    cand = fibonacci_sphere(BLACK_CANDIDATES)
    far = (cand @ dirs.T).max(axis=1) < np.cos(np.radians(gap))
    black = cand[far & ~inside_hull(dirs, cand)]
    verts = np.concatenate([dirs, black])
    if len(verts) < 4:
        raise InputError("the light directions cover the whole sphere too densely to triangulate; "
                         "this should not happen - report it")
    faces = _convex_hull(verts, qhull_options="Qt QJ").simplices.astype(np.int64)
    w, h = map_size
    tdirs = equirect_directions(w, h).reshape(-1, 3)
    tv, wts = locate_in_faces(verts, faces, tdirs)
    # Inside the samples' own hull, interpolate from samples only: the triangulation with the
    # black lights is Delaunay, not constrained to the hull's edges, so near them a black light
    # could otherwise reach in and darken a direction that was captured.
    cap = cap_faces(dirs)
    if cap is not None:
        inside = inside_hull(dirs, tdirs)
        if inside.any():
            tv_in, w_in = locate_in_faces(dirs, cap, tdirs[inside])
            tv[inside], wts[inside] = tv_in, w_in
            faces = np.concatenate([faces, cap])
    active = (tv < k).any(axis=1)
    return Triangulation(vertices=verts, n_samples=k, faces=faces, texel_vertices=tv, texel_weights=wts,
                         active=active, map_size=(w, h))


def cap_faces(dirs: np.ndarray) -> np.ndarray | None:
    """Spherical Delaunay faces of the samples alone (their cap), or None when they have no inside."""
    from scipy.spatial import QhullError

    try:
        hull = _convex_hull(np.vstack([np.zeros(3), dirs]), qhull_options="Qt QJ")
    except QhullError:
        return None
    keep = ~np.any(hull.simplices == 0, axis=1)
    if keep.all():  # the origin is inside: samples all around, no black lights were added
        return None
    return hull.simplices[keep].astype(np.int64) - 1


def locate_in_faces(verts: np.ndarray, faces: np.ndarray, query: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each query direction, the face its ray crosses and the normalised barycentric weights."""
    m = np.transpose(verts[faces], (0, 2, 1))  # (F, 3 coords, 3 vertices): columns are vertices
    det = np.linalg.det(m)
    ok = np.abs(det) > EPS  # joggled duplicates leave faces of no area: never pick them
    inv = np.zeros_like(m)
    inv[ok] = np.linalg.inv(m[ok])
    bary = np.einsum("fij,tj->tfi", inv, query)  # (T, F, 3)
    score = bary.min(axis=2)
    score[(bary.sum(axis=2) <= 0) | ~ok[None, :]] = -np.inf  # the ray must hit a real face in front
    best = np.argmax(score, axis=1)
    wts = np.clip(bary[np.arange(len(query)), best], 0.0, None)
    wts /= np.maximum(wts.sum(axis=1, keepdims=True), EPS)
    return faces[best], wts
