"""The synthetic head rendered turned and moved: its height field as a triangle mesh shaded by
spherical-harmonic light ratios, rasterised on a supersampled grid (a fragment rasteriser
grouped by triangle size)."""

from __future__ import annotations

import cv2
import numpy as np
from scipy.ndimage import distance_transform_edt

from relight.directions import fibonacci_sphere
from relight.numerics import EPS, FLOAT
from relight.spherical_harmonics import MONOMIALS, SPHERE_POINTS, environment_sh9, sh9_irradiance, sh9_irradiance_matrix

from ..raster import rasterise
from .head import Head, height_units, inside
from .pinhole import Pinhole, image_points

#: Irradiance-ratio guards: the reference irradiance is floored at this share of the brightest
#: direction's, and the ratio is capped.
IRRADIANCE_FLOOR = 0.02
MAX_SHADING_RATIO = 8.0


class LiveHead:
    """The head as a triangle mesh that renders at any pose (see the module docstring).

    head : the studio's head; radiance : (P, 3) linear radiance at the head's mask pixels
    (``np.flatnonzero(head.mask)`` order) at the reference pose; room : the room environment
    (lat-long, linear) whose irradiance re-shades turned normals; pivot : camera-space pivot
    ``C`` (x, -y, z) - see :func:`.pivot.pivot_point`; reach_px : how far (pixels) the head may move
    down, to extend the neck below the frame; camera : the frames' :class:`.pinhole.Pinhole`
    (None: orthographic).
    """

    def __init__(self, head: Head, radiance: np.ndarray, room: np.ndarray, pivot: np.ndarray, *,
                 reach_px: float, camera: Pinhole | None = None):
        h_img, w_img = head.mask.shape
        self.size = (w_img, h_img)
        self.camera = camera
        self.pivot = np.asarray(pivot, dtype=np.float64)
        x0, y0, x1, _ = head.bbox(pad=2)
        mask = head.mask[y0:, x0:x1]
        rad_img = np.zeros((h_img, w_img, 3), dtype=np.float64)
        rad_img.reshape(-1, 3)[np.flatnonzero(head.mask)] = radiance
        # Rim vertices: the pixels just outside the silhouette, moved onto it (where the segment to
        # the nearest head pixel leaves the head, found on the analytic outline), at the surface's
        # height there. They carry the nearest head pixel's colour and normal.
        ring = cv2.dilate(mask.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool) & ~mask
        _, (iy, ix) = distance_transform_edt(~mask, return_indices=True)
        src_y, src_x = iy + y0, ix + x0  # image pixel each vertex takes its colour from
        rows, cols = mask.shape
        gy, gx = np.mgrid[y0:y0 + rows, x0:x0 + cols].astype(np.float64)
        px, py = gx.copy(), gy.copy()
        z = np.where(mask, head.height[y0:, x0:x1], 0.0).astype(np.float64)
        ry, rx = np.nonzero(ring)
        rim_x, rim_y, rim_z = _rim_points(head, src_x[ry, rx], src_y[ry, rx], gx[ry, rx], gy[ry, rx])
        px[ry, rx], py[ry, rx], z[ry, rx] = rim_x, rim_y, rim_z
        vert = mask | ring
        # Extend the neck below the frame: repeat the last row (pure neck there), one pixel lower each time.
        extra = int(np.ceil(reach_px)) + 2
        if mask[-1].any():
            def ext(a):
                return np.concatenate([a, np.repeat(a[-1:], extra, axis=0)], axis=0)
            vert, z, px, src_y, src_x, mask = ext(vert), ext(z), ext(px), ext(src_y), ext(src_x), ext(mask)
            py = np.concatenate([py, py[-1:] + np.arange(1, extra + 1)[:, None]], axis=0)
        index = -np.ones(vert.shape, dtype=np.int64)
        vy, vx = np.nonzero(vert)
        index[vy, vx] = np.arange(vy.size)
        #: Reference image position (x, y) of each vertex, and its camera-space point (x, -y, height).
        self.ref_xy = np.stack([px[vy, vx], py[vy, vx]], axis=1)
        self.points = np.stack([self.ref_xy[:, 0], -self.ref_xy[:, 1], z[vy, vx]], axis=1)
        self._src = (src_y[vy, vx], src_x[vy, vx])
        self.radiance = rad_img[self._src]
        self.normal = head.normal[self._src].astype(np.float64)
        # Two triangles per quad of four vertices with at least one head pixel among them.
        a, b, c, d = index[:-1, :-1], index[:-1, 1:], index[1:, :-1], index[1:, 1:]
        quad = (a >= 0) & (b >= 0) & (c >= 0) & (d >= 0)
        quad &= mask[:-1, :-1] | mask[:-1, 1:] | mask[1:, :-1] | mask[1:, 1:]
        self.triangles = np.concatenate([np.stack([a[quad], c[quad], b[quad]], axis=1),
                                         np.stack([b[quad], c[quad], d[quad]], axis=1)]).astype(np.int32)
        self._corners = np.ascontiguousarray(self.triangles.T)  # (3, T): rows of first, second, third corners
        # Room irradiance (SH) at the reference normals, for the shading ratio.
        self.sh = environment_sh9(room)
        self._irradiance_form = sh9_irradiance_matrix(self.sh)
        e_max = sh9_irradiance(self.sh, fibonacci_sphere(SPHERE_POINTS)).max(axis=0)
        self._e_floor = IRRADIANCE_FLOOR * np.maximum(e_max, EPS)
        self._e_ref = np.maximum(sh9_irradiance(self.sh, self.normal), self._e_floor)
        n = self.normal
        self._monomials = np.stack([n[:, i] * n[:, j] if j < 3 else n[:, i] for i, j in zip(*MONOMIALS, strict=True)
                                    if i < 3])  # (9, V): the monomials except the constant
        self._relative = np.ascontiguousarray((self.points - self.pivot).T)  # (3, V)

    # -- per-vertex values
    def vertex_values(self, image: np.ndarray) -> np.ndarray:
        """Per-vertex values (V, C) of a reference-pose image (H, W) or (H, W, C): each head
        pixel's own; rim and below-frame neck vertices take their nearest head pixel's (as the
        colours do)."""
        img = np.asarray(image, dtype=np.float64)
        if img.ndim == 2:
            img = img[..., None]
        return img[self._src]

    def colours(self, rotation: np.ndarray) -> np.ndarray:
        """(V, 3) vertex radiance with the head turned by ``rotation`` (room light, SH irradiance ratio)."""
        # E(R n) = n~^T (R~^T M R~) n~ with n~ = (n, 1), R~ = diag(R, 1): rotate the form, not the
        # normals, and evaluate it on the normals' ten quadratic monomials. (Per-frame work avoids
        # BLAS: its threads spin on small products and slow the rest down.)
        r4 = np.eye(4)
        r4[:3, :3] = rotation
        form = np.einsum("ji,cjk,kl->cil", r4, self._irradiance_form, r4)  # (3, 4, 4)
        iu, ju = MONOMIALS
        weight = np.where(iu == ju, 1.0, 2.0)
        out = np.empty_like(self.radiance, dtype=FLOAT)
        for ch in range(3):
            coef = form[ch][iu, ju] * weight
            e = np.full(self._monomials.shape[1], coef[-1], dtype=np.float64)
            for k in range(len(coef) - 1):
                e += coef[k] * self._monomials[k]
            ratio = np.minimum(np.maximum(e, 0.0) / self._e_ref[:, ch], MAX_SHADING_RATIO)
            out[:, ch] = self.radiance[:, ch] * ratio
        return out

    def project(self, rotation: np.ndarray, translation=(0.0, 0.0), points: np.ndarray | None = None) -> np.ndarray:
        """Camera-space points (N, 3) (default: the mesh vertices) moved by the pose -> (N, 3):
        ``R (P - C) + C + (tx, -ty, 0)``."""
        r = np.asarray(rotation, dtype=np.float64)
        q = self._relative if points is None else (np.asarray(points, dtype=np.float64) - self.pivot).T
        tx, ty = translation
        shift = self.pivot + np.array([tx, -ty, 0.0])
        return np.stack([r[i, 0] * q[0] + r[i, 1] * q[1] + r[i, 2] * q[2] + shift[i] for i in range(3)], axis=1)

    # -- rasterisation
    def render(self, rotation: np.ndarray, translation=(0.0, 0.0), values: np.ndarray | None = None
               ) -> tuple[tuple[int, int, int, int], np.ndarray, np.ndarray]:
        """Rasterise the head at a pose.

        Returns ``box`` (x0, y0, x1, y1) in the image, the premultiplied head values
        (y1-y0, x1-x0, C) (mean over 2x2 samples per pixel; 0 where uncovered) and the coverage
        (y1-y0, x1-x0) in [0, 1]. ``values`` (V, C) replaces the shaded vertex colours.
        """
        rotation = np.asarray(rotation, dtype=np.float64)
        vals = self.colours(rotation) if values is None else np.asarray(values, dtype=FLOAT)
        p = self.project(rotation, translation)
        x_img, y_img = image_points(self.camera, p)
        box = screen_box(x_img, y_img, self.size)
        bx0, by0, bx1, by1 = box
        nch = vals.shape[1]
        if bx1 <= bx0 or by1 <= by0:
            return empty_render(box, nch)
        gw, gh = 2 * (bx1 - bx0), 2 * (by1 - by0)
        # Sample (I, J) of the 2x grid sits at pixel coordinate box0 + (I - 0.5) / 2.
        sx = 2.0 * (x_img - bx0) + 0.5
        sy = 2.0 * (y_img - by0) + 0.5
        sz = p[:, 2].astype(np.float32)
        cells, depth, tri, w0, w1 = rasterise(self._corners, sx, sy, sz, gw, gh)
        t = self._corners[:, tri]
        # Z-buffer: the nearest fragment (largest z: toward the camera) of each sample wins.
        zbuf = np.full(gw * gh, -np.inf, dtype=np.float32)
        np.maximum.at(zbuf, cells, depth)
        win = depth >= zbuf[cells]
        cells, w0, w1 = cells[win], w0[win], w1[win]
        t0, t1, t2 = t[0, win], t[1, win], t[2, win]
        w2 = 1.0 - w0 - w1
        planes = np.ascontiguousarray(vals.T)
        out, cov = box_filter_samples(cells, [w0 * v[t0] + w1 * v[t1] + w2 * v[t2] for v in planes], gw, gh)
        return box, out, cov


def screen_box(x_img: np.ndarray, y_img: np.ndarray, size: tuple[int, int]) -> tuple[int, int, int, int]:
    """The pixel box (x0, y0, x1, y1) of projected points at image columns ``x_img``, rows
    ``y_img``: a pixel's margin around them, clipped to the image ``size`` (w, h)."""
    w_img, h_img = size
    return (int(np.clip(np.floor(x_img.min()) - 1, 0, w_img)), int(np.clip(np.floor(y_img.min()) - 1, 0, h_img)),
            int(np.clip(np.ceil(x_img.max()) + 2, 0, w_img)), int(np.clip(np.ceil(y_img.max()) + 2, 0, h_img)))


def empty_render(box: tuple[int, int, int, int], nch: int) -> tuple[tuple[int, int, int, int], np.ndarray, np.ndarray]:
    """A render's result where the head covers no pixel: ``box`` and zero values and coverage."""
    x0, y0, x1, y1 = box
    shape = (max(y1 - y0, 0), max(x1 - x0, 0))
    return box, np.zeros((*shape, nch), FLOAT), np.zeros(shape, FLOAT)


def box_filter_samples(cells: np.ndarray, channels, gw: int, gh: int) -> tuple[np.ndarray, np.ndarray]:
    """Values and coverage of a 2x-per-pixel sample grid (gh, gw) box-filtered to pixels
    (INTER_AREA: exact 2x2 means): ``cells`` the flat indices of the covered samples, ``channels``
    one value array per channel over them. Returns ((gh/2, gw/2, C) values, (gh/2, gw/2) coverage),
    zero where no sample is covered."""
    out = np.empty((gh // 2, gw // 2, len(channels)), dtype=FLOAT)
    grid = np.zeros(gw * gh, dtype=FLOAT)
    for ch, v in enumerate(channels):
        grid[cells] = v
        out[..., ch] = cv2.resize(grid.reshape(gh, gw), (gw // 2, gh // 2), interpolation=cv2.INTER_AREA)
    grid[:] = 0.0
    grid[cells] = 1.0
    cov = cv2.resize(grid.reshape(gh, gw), (gw // 2, gh // 2), interpolation=cv2.INTER_AREA)
    return out, cov


#: Bisection steps locating the silhouette between a head pixel and a pixel off the head (2^-20 px).
RIM_BISECTIONS = 20


def _rim_points(head: Head, in_x, in_y, out_x, out_y) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where the segments from head pixels (in_x, in_y) to off-head pixels (out_x, out_y) cross the
    head's analytic outline (:func:`.head.inside`), and the surface height there (pixels)."""
    cx, cy = head.center
    s = head.scale
    ax, ay = np.asarray(in_x, dtype=np.float64), np.asarray(in_y, dtype=np.float64)
    bx, by = np.asarray(out_x, dtype=np.float64), np.asarray(out_y, dtype=np.float64)
    lo, hi = np.zeros(ax.shape), np.ones(ax.shape)
    for _ in range(RIM_BISECTIONS):
        mid = 0.5 * (lo + hi)
        inn = inside((ax + mid * (bx - ax) - cx) / s, (cy - (ay + mid * (by - ay))) / s)
        lo = np.where(inn, mid, lo)
        hi = np.where(inn, hi, mid)
    x, y = ax + lo * (bx - ax), ay + lo * (by - ay)
    z = height_units((x - cx) / s, (cy - y) / s) * s
    return x, y, z
