"""Everything in the synthetic frame that is not the head: the wall and the mirror sphere.

The mirror sphere (orthographic view) reflects the room and, during a flash, shows the flash
as a small disc whose light the lens spreads into a saturated blob (glare), as phone
cameras do; its centre obeys the mirror law exactly.
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


@dataclass(frozen=True)
class MirrorSphere:
    """A chrome ball of radius ``r`` pixels centred at (cx, cy)."""

    cx: float
    cy: float
    r: float
    glare_sigma: float

    @property
    def bbox(self) -> tuple[int, int, int, int]:
        """(x0, y0, x1, y1) region holding the sphere and its glare."""
        pad = int(np.ceil(4 * self.glare_sigma)) + 2
        return (int(np.floor(self.cx - self.r)) - pad, int(np.floor(self.cy - self.r)) - pad,
                int(np.ceil(self.cx + self.r)) + pad + 1, int(np.ceil(self.cy + self.r)) + pad + 1)

    def _subsamples(self):
        x0, y0, x1, y1 = self.bbox
        k = SPHERE_SUPERSAMPLE
        xs = x0 + (np.arange((x1 - x0) * k) + 0.5) / k - 0.5
        ys = y0 + (np.arange((y1 - y0) * k) + 0.5) / k - 0.5
        nx = (xs[None, :] - self.cx) / self.r
        ny = -(ys[:, None] - self.cy) / self.r
        rr = nx**2 + ny**2
        inside = rr < 1.0
        nz = np.sqrt(np.clip(1.0 - rr, 0.0, 1.0))
        # Reflection of the view ray (0, 0, 1) about n: 2 nz n - v.
        refl = np.stack(np.broadcast_arrays(2 * nz * nx, 2 * nz * ny, 2 * nz * nz - 1.0), axis=-1)
        return inside, refl

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
        half = d + np.array([0.0, 0.0, 1.0])
        if np.linalg.norm(half) < EPS_NORM:
            return np.zeros((*img.shape, 3), dtype=FLOAT)
        # Where to look: around the mirror point of the half vector (the sub-samples below do
        # their own reflection, so the result does not rest on this guess).
        n = half / np.linalg.norm(half)
        gx, gy = int(round(self.cx + self.r * n[0])), int(round(self.cy - self.r * n[1]))
        k = FLASH_SUPERSAMPLE
        win = int(np.ceil(self.r * np.radians(FLASH_RADIUS_DEG))) + 2
        xs = gx - win + (np.arange((2 * win + 1) * k) + 0.5) / k - 0.5
        ys = gy - win + (np.arange((2 * win + 1) * k) + 0.5) / k - 0.5
        nx = (xs[None, :] - self.cx) / self.r
        ny = -(ys[:, None] - self.cy) / self.r
        rr = nx**2 + ny**2
        nz = np.sqrt(np.clip(1.0 - rr, 0.0, 1.0))
        cosang = (2 * nz * nx) * d[0] + (2 * nz * ny) * d[1] + (2 * nz * nz - 1.0) * d[2]
        row, col = np.nonzero((rr < 1.0) & (cosang > np.cos(np.radians(FLASH_RADIUS_DEG))))
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
