"""A textured head mesh turned and moved in a live clip: the mesh itself rasterised with a depth
buffer at each pose (a turned head hides and shows parts of itself), shaded per sample.

The interface is :class:`.render.LiveHead`'s (``project``, ``render``, ``vertex_values``), so
:class:`.live.LiveScene` renders either head. The mesh's reference pose is the static studio's
(:mod:`.mesh_head`'s placement); a pose moves its camera-space points as the live clip's truth
documents: ``P' = R (P - C) + C + (tx, -ty, 0)``.

Shading, per sample of a 2x2 grid per pixel: the surface point's radiance under the room light
at the reference pose - the studio's own render (:meth:`.studio.Studio.ambient_head`: cast
shadows, specular) where the point was visible at the reference pose, else its colour map times
the room's diffuse irradiance at its normal (a hidden point: the back of an ear, under the jaw)
- times the ratio of the room's diffuse irradiance at its turned normal to that at its
reference normal (9-coefficient spherical harmonics, as :class:`.render.LiveHead`). Shadows and
highlights therefore move with the head; the far side, never seen at the reference pose, is
lit by the room's diffuse light alone. The whole mesh is rigid (a scan's shoulders turn with
its head).
"""

from __future__ import annotations

import numpy as np

from relight.directions import fibonacci_sphere
from relight.numerics import EPS
from relight.sampling import bilinear
from relight.spherical_harmonics import SPHERE_POINTS, environment_sh9, sh9_irradiance

from ..raster import rasterise
from .head import Head
from .mesh_head import HeadMesh, Placement, sample_map
from .pinhole import Pinhole, image_points
from .render import IRRADIANCE_FLOOR, MAX_SHADING_RATIO, box_filter_samples, empty_render, screen_box

#: A sample was visible at the reference pose when its depth is within this many pixels of the
#: reference's depth buffer there (the buffer is sampled bilinearly; steep sides need the slack).
VISIBLE_DEPTH_PX = 2.0


#: Below this many head units under the eyes a mesh's open boundary is the body's cut (a bust's
#: bottom, its arms' stumps), continued down by :func:`extend_below`.
BODY_BELOW_EYES = 1.5


def extend_below(points: np.ndarray, faces: np.ndarray, uv: np.ndarray, normals: np.ndarray, row: float,
                 length: float, albedo: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A bust continued straight down: each open edge of the mesh (an edge of one face) whose two
    vertices are below image ``row`` (camera-space points (V, 3), ``(x, -row, height)``) gets a
    wall of two triangles ``length`` pixels down. The walls have their own vertices: normals made
    level (:func:`wall_normals`) and one colour, the cut's skin (the texture coordinates of the
    edge vertex whose ``albedo`` is the cut's median colour). A wide lens sees past a scan's cut:
    the body goes on below it as a person's does, instead of a floating bust. Returns (points,
    faces, uv, normals), the mesh's first and the walls' after them."""
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    key = np.sort(e, axis=1)
    uniq, count = np.unique(key, axis=0, return_counts=True)
    edges = uniq[count == 1]
    low = -points[:, 1] > row
    edges = edges[low[edges[:, 0]] & low[edges[:, 1]]]
    if not len(edges):
        return points, faces, uv, normals
    # the wall's own vertices: a copy of each edge vertex (the same place: no crack) and one below
    # it, all with the skin's texture coordinates (the mesh's own at the top would sweep the wall
    # across the texture's atlas)
    ends, inverse = np.unique(edges, return_inverse=True)
    k = len(ends)
    top = len(points) + inverse.reshape(-1, 2)
    bottom = top + k
    a, b, a2, b2 = top[:, 0], top[:, 1], bottom[:, 0], bottom[:, 1]
    walls = np.concatenate([np.stack([a, b, b2], axis=1), np.stack([a, b2, a2], axis=1)]).astype(faces.dtype)
    colour = sample_map(albedo, uv[ends])
    skin = uv[ends][np.argmin(np.abs(colour - np.median(colour, axis=0)).sum(axis=1))]
    level = wall_normals(normals[ends])
    return (np.concatenate([points, points[ends], points[ends] - np.array([0.0, float(length), 0.0])]),
            np.concatenate([faces, walls]), np.concatenate([uv, np.repeat(skin[None], 2 * k, axis=0)]),
            np.concatenate([normals, level, level]))


def wall_normals(n: np.ndarray) -> np.ndarray:
    """Upright walls' normals (N, 3) below edge vertices of normals ``n``: theirs made level (a
    scan's cut bends its normals down), toward the camera where level leaves nothing."""
    level = np.asarray(n, dtype=np.float64) * np.array([1.0, 0.0, 1.0])
    norm = np.linalg.norm(level, axis=1, keepdims=True)
    return np.where(norm > 0.1, level / np.maximum(norm, EPS), np.array([0.0, 0.0, 1.0]))


class MeshLiveHead:
    """A head mesh that renders at any pose (see the module docstring).

    mesh, placement : the studio's (:mod:`.mesh_head`). head : the studio's head at the reference
    pose. radiance : (P, 3) its radiance under the room light at the mask's pixels. room : the
    room environment (lat-long, linear). pivot : camera-space pivot ``C``. camera : the frames'
    :class:`.pinhole.Pinhole` (None: orthographic).
    """

    def __init__(self, mesh: HeadMesh, placement: Placement, head: Head, radiance: np.ndarray, room: np.ndarray,
                 pivot: np.ndarray, *, camera: Pinhole | None = None):
        h_img, w_img = head.mask.shape
        self.size = (w_img, h_img)
        self.camera = camera
        self.mesh = mesh
        self.pivot = np.asarray(pivot, dtype=np.float64)
        #: Camera-space points (x, -y, height) of the vertices at the reference pose, and the
        #: faces, texture coordinates and normals rendered (the mesh's own, or with a pinhole
        #: camera the bust continued below the frame: :func:`extend_below`).
        self.points = placement.project(mesh.vertices)
        self.faces, self.uv, self.normals = mesh.faces, mesh.uv, mesh.normals
        if camera is not None:
            self.points, self.faces, self.uv, self.normals = extend_below(
                self.points, mesh.faces, mesh.uv, mesh.normals, placement.center[1] + BODY_BELOW_EYES * placement.scale,
                (h_img + camera.distance_px) / max(camera.magnification, 1e-3), mesh.albedo)
        self._corners = np.ascontiguousarray(self.faces.T)
        rad = np.zeros((h_img, w_img, 3), dtype=np.float64)
        rad.reshape(-1, 3)[np.flatnonzero(head.mask)] = radiance
        # The reference image (radiance and a weight: 1 on the mask) and its depth buffer.
        self._ref = np.concatenate([rad, head.mask[..., None].astype(np.float64)], axis=2)
        self._ref_depth = np.where(head.mask, head.height, -1e9).astype(np.float64)[..., None]
        self.sh = environment_sh9(room)
        e_max = sh9_irradiance(self.sh, fibonacci_sphere(SPHERE_POINTS)).max(axis=0)
        self._e_floor = IRRADIANCE_FLOOR * np.maximum(e_max, EPS)

    def vertex_values(self, image: np.ndarray) -> np.ndarray:
        """A reference-pose image (H, W) or (H, W, C) as ``render``'s ``values``: each sample
        takes the image's value where its surface point was at the reference pose (0 where that
        point was hidden then)."""
        img = np.asarray(image, dtype=np.float64)
        return img[..., None] if img.ndim == 2 else img

    def project(self, rotation: np.ndarray, translation=(0.0, 0.0), points: np.ndarray | None = None) -> np.ndarray:
        """Camera-space points (N, 3) (default: the mesh vertices) moved by the pose."""
        r = np.asarray(rotation, dtype=np.float64)
        q = (self.points if points is None else np.asarray(points, dtype=np.float64)) - self.pivot
        tx, ty = translation
        return q @ r.T + self.pivot + np.array([tx, -ty, 0.0])

    def render(self, rotation: np.ndarray, translation=(0.0, 0.0), values: np.ndarray | None = None, *,
               lit: tuple[np.ndarray, np.ndarray] | None = None
               ) -> tuple[tuple[int, int, int, int], np.ndarray, np.ndarray]:
        """Rasterise the head at a pose: ``box`` (x0, y0, x1, y1), the premultiplied radiance
        (or ``values``, a reference image from :meth:`vertex_values`) (y1-y0, x1-x0, C) as the
        mean over 2x2 samples a pixel, and the coverage (y1-y0, x1-x0).

        lit : ``(radiance, sh)`` - the head's radiance already shaded for this pose ((H, W, 3)
        at the reference pose's pixels, e.g. under another light with the light turned into the
        head's frame) and that light's 9 SH coefficients (9, 3): samples seen at the reference
        pose take the radiance as it is (no ratio), hidden ones their colour map under the
        light's diffuse irradiance at their turned normal (unshadowed).
        """
        rotation = np.asarray(rotation, dtype=np.float64)
        p = self.project(rotation, translation)
        x_img, y_img = image_points(self.camera, p)
        box = screen_box(x_img, y_img, self.size)
        bx0, by0, bx1, by1 = box
        nch = 3 if values is None else values.shape[2]
        if bx1 <= bx0 or by1 <= by0:
            return empty_render(box, nch)
        gw, gh = 2 * (bx1 - bx0), 2 * (by1 - by0)
        sx, sy = 2.0 * (x_img - bx0) + 0.5, 2.0 * (y_img - by0) + 0.5
        cells, depth, tri, w0, w1 = rasterise(self._corners, sx, sy, p[:, 2].astype(np.float32), gw, gh)
        zbuf = np.full(gw * gh, -np.inf, dtype=np.float32)
        np.maximum.at(zbuf, cells, depth)
        win = np.flatnonzero(depth >= zbuf[cells])
        _, first = np.unique(cells[win], return_index=True)  # one fragment a sample
        win = win[first]
        cells = cells[win]
        f = self.faces[tri[win]]
        wall = tri[win] >= len(self.mesh.faces)  # extend_below's: never in the reference's view
        w3 = np.stack([w0[win], w1[win], 1.0 - w0[win] - w1[win]], axis=1).astype(np.float64)

        def blend(attr):
            return w3[:, 0:1] * attr[f[:, 0]] + w3[:, 1:2] * attr[f[:, 1]] + w3[:, 2:3] * attr[f[:, 2]]

        ref = blend(self.points)  # where each sample's surface point was at the reference pose
        rx, ry, rz = ref[:, 0], -ref[:, 1], ref[:, 2]
        seen = (np.abs(bilinear(self._ref_depth, rx, ry)[:, 0] - rz) < VISIBLE_DEPTH_PX) & ~wall
        if values is not None:
            vals = np.where(seen[:, None], bilinear(values, rx, ry), 0.0)
        else:
            n_ref = blend(self.normals)
            n_ref /= np.maximum(np.linalg.norm(n_ref, axis=1, keepdims=True), EPS)
            # the reference render where it saw the point (its weight channel normalises the
            # bilinear blend at the mask's edge), else the colour map under the diffuse light
            if lit is None:
                ref, sh, n_hidden = self._ref, self.sh, n_ref
            else:
                ref = np.concatenate([np.asarray(lit[0], dtype=np.float64), self._ref[..., 3:]], axis=2)
                sh, n_hidden = np.asarray(lit[1], dtype=np.float64), n_ref @ rotation.T
            e_hidden = np.maximum(sh9_irradiance(sh, n_hidden), 0.0 if lit is not None else self._e_floor)
            ref_img = bilinear(ref, rx, ry)
            wgt = ref_img[:, 3:4]
            vals = np.where((seen[:, None] & (wgt > 0.5)), ref_img[:, :3] / np.maximum(wgt, EPS),
                            sample_map(self.mesh.albedo, blend(self.uv)) * e_hidden / np.pi)
            if lit is None:  # the room's light at the reference pose, re-shaded for the turn
                e_now = np.maximum(sh9_irradiance(self.sh, n_ref @ rotation.T), 0.0)
                vals = vals * np.minimum(e_now / e_hidden, MAX_SHADING_RATIO)
        out, cov = box_filter_samples(cells, [vals[:, ch] for ch in range(nch)], gw, gh)
        return box, out, cov
