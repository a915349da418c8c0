"""Everything in the synthetic frame that is not the head: the wall and the mirror sphere.

The mirror sphere (an orthographic view, or a pinhole's: :class:`MirrorSphere` ``camera``)
reflects the room and, during a flash, shows the flash as a small disc whose light the lens
spreads into a saturated blob (glare), as phone cameras do; its centre obeys the mirror law
exactly.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from relight.envmap import sample_environment
from relight.numerics import EPS_NORM, EPS_VALUE, FLOAT

#: Angular radius of the flash as seen from the face (degrees) and the sphere's reflectance.
FLASH_RADIUS_DEG = 1.5
MIRROR_REFLECTANCE = 0.6
#: Sub-samples per pixel side when rendering the sphere, and around the flash's reflection.
SPHERE_SUPERSAMPLE = 4
FLASH_SUPERSAMPLE = 32
#: The wall sits behind the head: it gets this fraction of the flash (inverse-square falloff).
WALL_FLASH = 0.3
WALL_ALBEDO = 0.45


def sphere_placement(width: int, height: int) -> tuple[float, float, float]:
    """(cx, cy, r) of the mirror sphere in pixels: right of the head, radius 1/10 of the height."""
    return 0.80 * width, 0.64 * height, 0.10 * height


#: A pinhole's sphere (:class:`MirrorSphere` ``camera``): its outline (an ellipse off the axis,
#: stretched away from it) is found by projecting this many of its rays.
OUTLINE_RAYS = 64


@dataclass(frozen=True)
class MirrorSphere:
    """A chrome ball of radius ``r`` pixels centred at (cx, cy) - seen by an orthographic camera,
    or with ``camera`` (a :class:`.pinhole.Pinhole`) through that pinhole: then a ball whose centre
    lies on the ray through (cx, cy) at the camera's ``distance_px`` from the eye, of radius
    ``r * distance_px / focal`` (its outline ~``r`` px in radius on the axis; an ellipse off it),
    each sub-sample's view ray from the eye."""

    cx: float
    cy: float
    r: float
    glare_sigma: float
    camera: object = None

    @property
    def bbox(self) -> tuple[int, int, int, int]:
        """(x0, y0, x1, y1) region holding the sphere and its glare."""
        pad = int(np.ceil(4 * self.glare_sigma)) + 2
        if self.camera is None:
            lo_x, lo_y, hi_x, hi_y = self.cx - self.r, self.cy - self.r, self.cx + self.r, self.cy + self.r
        else:
            xs, ys = self._outline()
            lo_x, lo_y, hi_x, hi_y = xs.min(), ys.min(), xs.max(), ys.max()
        return (int(np.floor(lo_x)) - pad, int(np.floor(lo_y)) - pad,
                int(np.ceil(hi_x)) + pad + 1, int(np.ceil(hi_y)) + pad + 1)

    def _outline(self) -> tuple[np.ndarray, np.ndarray]:
        """A pinhole's ball: image columns and rows of :data:`OUTLINE_RAYS` points of its outline
        (the rays from the eye that graze it)."""
        from .pinhole import image_points

        eye, centre, radius = self._ball()
        axis = centre - eye
        dist = float(np.linalg.norm(axis))
        axis /= dist
        e1 = np.cross(axis, [0.0, 1.0, 0.0])
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(axis, e1)
        sin_a = radius / dist
        cos_a = np.sqrt(max(1.0 - sin_a * sin_a, 0.0))
        t = np.linspace(0.0, 2.0 * np.pi, OUTLINE_RAYS, endpoint=False)[:, None]
        rays = cos_a * axis + sin_a * (np.cos(t) * e1 + np.sin(t) * e2)
        return image_points(self.camera, eye + dist * cos_a * rays)

    def _ball(self) -> tuple[np.ndarray, np.ndarray, float]:
        """(the eye (3,), the ball's centre (3,), its radius) in the pinhole's camera space."""
        cam = self.camera
        ppx, ppy = cam.center
        eye = np.array([ppx, -ppy, cam.eye_z])
        return eye, eye + cam.distance_px * cam.view_rays(self.cx, self.cy), self.r * cam.distance_px / cam.focal

    def _reflections(self, xs: np.ndarray, ys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(inside (len(ys), len(xs)) bool, the view ray's reflection (..., 3), unit) at the image
        points of columns ``xs`` and rows ``ys``: where the ray from the camera through each meets
        the ball, the direction a light must come from to be seen there."""
        if self.camera is None:
            nx = (xs[None, :] - self.cx) / self.r
            ny = -(ys[:, None] - self.cy) / self.r
            rr = nx**2 + ny**2
            nz = np.sqrt(np.clip(1.0 - rr, 0.0, 1.0))
            # Reflection of the view ray (0, 0, 1) about n: 2 nz n - v.
            return rr < 1.0, np.stack(np.broadcast_arrays(2 * nz * nx, 2 * nz * ny, 2 * nz * nz - 1.0), axis=-1)
        eye, centre, radius = self._ball()
        d = self.camera.view_rays(xs[None, :], ys[:, None])
        oc = eye - centre
        b = d @ oc
        disc = b * b - (oc @ oc - radius * radius)
        inside = disc > 0.0
        t = -b - np.sqrt(np.maximum(disc, 0.0))
        n = (eye + t[..., None] * d - centre) / radius
        refl = d - 2.0 * (n * d).sum(axis=-1, keepdims=True) * n
        refl /= np.maximum(np.linalg.norm(refl, axis=-1, keepdims=True), EPS_NORM)
        return inside, refl

    def _subsamples(self):
        x0, y0, x1, y1 = self.bbox
        k = SPHERE_SUPERSAMPLE
        xs = x0 + (np.arange((x1 - x0) * k) + 0.5) / k - 0.5
        ys = y0 + (np.arange((y1 - y0) * k) + 0.5) / k - 0.5
        return self._reflections(xs, ys)

    def _box(self, a: np.ndarray) -> np.ndarray:
        k = SPHERE_SUPERSAMPLE
        h, w = a.shape[0] // k, a.shape[1] // k
        return a.reshape(h, k, w, k, *a.shape[2:]).mean(axis=(1, 3))

    def ambient_layer(self, env: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(premultiplied radiance (h, w, 3), coverage (h, w)) of the sphere reflecting ``env``."""
        inside, refl = self._subsamples()
        rad = sample_environment(env, refl) * (MIRROR_REFLECTANCE * inside[..., None])
        return self._box(rad).astype(FLOAT), self._box(inside.astype(np.float64)).astype(FLOAT)

    def flash_layer(self, direction: np.ndarray, strength: float = 1.0) -> np.ndarray:
        """(h, w, 3) radiance the flash adds (its reflection seen through the lens), full exposure.

        The flash's reflection is a spot far smaller than a pixel at phone resolutions, so it
        is found on a fine grid of sub-samples (each reflects the view ray off the sphere on its
        own), spread by the lens's point-spread function (a Gaussian, the glare that makes a
        phone's flash highlight a saturated blob) and only then integrated over the pixels, as
        optics and sensor do; the blob's position therefore keeps its sub-pixel accuracy.
        """
        from scipy.special import erf

        d = np.asarray(direction, dtype=np.float64)
        d = d / np.linalg.norm(d)
        x0, y0, x1, y1 = self.bbox
        img = np.zeros((y1 - y0, x1 - x0), dtype=np.float64)
        if self.camera is None:
            to_camera, centre, radius = np.array([0.0, 0.0, 1.0]), None, self.r
        else:
            eye, centre, radius = self._ball()
            to_camera = (eye - centre) / np.linalg.norm(eye - centre)
        half = d + to_camera
        if np.linalg.norm(half) < EPS_NORM:
            return np.zeros((*img.shape, 3), dtype=FLOAT)
        # Where to look: around the mirror point of the half vector (the sub-samples below do
        # their own reflection, so the result does not rest on this guess).
        n = half / np.linalg.norm(half)
        if centre is None:
            gx, gy = int(round(self.cx + self.r * n[0])), int(round(self.cy - self.r * n[1]))
            win = int(np.ceil(self.r * np.radians(FLASH_RADIUS_DEG))) + 2
        else:
            from .pinhole import image_points

            px_, py_ = image_points(self.camera, (centre + radius * n)[None])
            gx, gy = int(round(float(px_[0]))), int(round(float(py_[0])))
            xs_, ys_ = self._outline()  # the flash's spot is as stretched as the outline
            reach = 0.5 * max(np.ptp(xs_), np.ptp(ys_))
            win = int(np.ceil(reach * np.radians(FLASH_RADIUS_DEG))) + 2
        k = FLASH_SUPERSAMPLE
        xs = gx - win + (np.arange((2 * win + 1) * k) + 0.5) / k - 0.5
        ys = gy - win + (np.arange((2 * win + 1) * k) + 0.5) / k - 0.5
        inside, refl = self._reflections(xs, ys)
        cosang = refl[..., 0] * d[0] + refl[..., 1] * d[1] + refl[..., 2] * d[2]
        row, col = np.nonzero(inside & (cosang > np.cos(np.radians(FLASH_RADIUS_DEG))))
        if row.size == 0:
            return np.zeros((*img.shape, 3), dtype=FLOAT)
        radiance = strength * np.pi / (2 * np.pi * (1 - np.cos(np.radians(FLASH_RADIUS_DEG))))
        energy = MIRROR_REFLECTANCE * radiance / (k * k)  # per sub-sample (area 1/k^2 pixel)
        # Gaussian PSF integrated over each pixel: separable, one erf difference per axis.
        s2 = self.glare_sigma * np.sqrt(2.0)
        px = np.arange(x0, x1, dtype=np.float64)
        py = np.arange(y0, y1, dtype=np.float64)
        wx = 0.5 * (erf((px[None, :] + 0.5 - xs[col][:, None]) / s2) - erf((px[None, :] - 0.5 - xs[col][:, None]) / s2))
        wy = 0.5 * (erf((py[None, :] + 0.5 - ys[row][:, None]) / s2) - erf((py[None, :] - 0.5 - ys[row][:, None]) / s2))
        img = energy * (wy.T @ wx)
        return np.repeat(img.astype(FLOAT)[..., None], 3, axis=2)


def wall(width: int, height: int, rng: np.random.Generator) -> np.ndarray:
    """(H, W) wall albedo: a faint vertical gradient and a soft plaster texture."""
    y = np.linspace(0.0, 1.0, height)[:, None]
    n = rng.standard_normal((height, width)).astype(np.float32)
    n = cv2.GaussianBlur(n, (0, 0), max(2.0, width / 200))
    n /= max(float(n.std()), EPS_VALUE)
    return (WALL_ALBEDO * (1.05 - 0.1 * y) * (1 + 0.03 * n)).astype(FLOAT)
