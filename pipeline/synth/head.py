"""A procedural human head: geometry and skin parameters, sampled on the image grid.

The head is a height field seen by an orthographic camera (the solid lies behind it, so
light from behind is blocked by the head itself): an egg-shaped skull narrowing to the jaw,
with brow ridge, eye sockets and eyeballs, a nose with tip and alae, lips, cheeks,
cheekbones, chin, temples, ears and a neck. Its albedo has skin with redder cheeks and
lips, eyes (sclera, iris, pupil, lashes), eyebrows, hair, nostrils, moles and a fine
blemish texture, so OpenCV's Haar frontal-face cascade finds it.

Head units: ``u`` right, ``v`` up, 1 unit = half the crown-to-chin height; eyes at v = 0.
``Head.scale`` is pixels per unit, ``Head.center`` the image position of (0, 0).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from relight.kernels.heightfield import NO_SURFACE
from relight.kernels.shading import Surface
from relight.numerics import EPS_NORM, EPS_VALUE

#: Subsamples per pixel side for the anti-aliased silhouette.
ALPHA_SUPERSAMPLE = 4
#: Steepest slope (dz/dx in pixels) kept in the normals at the silhouette.
MAX_SLOPE = 25.0


def _g(u, v, u0, v0, su, sv):
    return np.exp(-0.5 * (((u - u0) / su) ** 2 + ((v - v0) / sv) ** 2))


def _pair(u, v, u0, v0, su, sv):
    """A feature and its mirror image across the face's vertical axis."""
    return _g(u, v, u0, v0, su, sv) + _g(u, v, -u0, v0, su, sv)


def _smoothstep(e0, e1, x):
    t = np.clip((x - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3 - 2 * t)


def _skull_r2(u, v):
    """Squared 'radius' of the skull outline: < 1 inside. Narrows from the cheeks to the chin."""
    half_width = 0.74 - 0.30 * _smoothstep(-0.1, -1.05, v)
    return (u / half_width) ** 2 + v**2


def _ear_r2(u, v):
    return ((np.abs(u) - 0.75) / 0.085) ** 2 + ((v + 0.03) / 0.17) ** 2


NECK_HALF_WIDTH = 0.40
NECK_TOP = -0.55


def inside(u, v):
    """Boolean: is head-space point (u, v) on the head (skull, ears or neck)?"""
    neck = (np.abs(u) < NECK_HALF_WIDTH) & (v < NECK_TOP)
    return (_skull_r2(u, v) < 1.0) | (_ear_r2(u, v) < 1.0) | neck


def hairline(u):
    """v of the hair's lower edge at u (above it is hair), and the side-burn band."""
    return 0.56 + 0.05 * np.cos(4.0 * u) - 0.12 * _smoothstep(0.35, 0.62, np.abs(u))


def height_units(u, v):
    """Height toward the camera in head units; undefined (anything) outside :func:`inside`."""
    r2 = _skull_r2(u, v)
    z = 0.78 * np.clip(1.0 - r2, 0.0, None) ** 0.42
    # Brow ridge, eye sockets, eyeballs.
    z = z + 0.045 * _g(u, v, 0.0, 0.14, 0.34, 0.05) + 0.015 * _pair(u, v, 0.28, 0.15, 0.1, 0.04)
    z = z - 0.11 * _pair(u, v, 0.29, 0.01, 0.12, 0.075)
    for s in (-1.0, 1.0):
        d2 = ((u - s * 0.29) / 0.125) ** 2 + ((v - 0.0) / 0.125) ** 2
        z = z + 0.07 * np.clip(1.0 - d2, 0.0, None) ** 1.5
    # Nose: bridge rising to the tip, the tip's bulb and the alae; drops under the tip.
    t = np.clip((0.06 - v) / 0.40, 0.0, 1.0)
    ridge = (0.03 + 0.22 * t**1.3) * np.where(v < -0.34, np.exp(-(((v + 0.34) / 0.045) ** 2)), 1.0)
    ridge = ridge * _smoothstep(0.16, 0.06, v)
    width = 0.045 + 0.05 * t
    z = z + ridge * np.exp(-0.5 * (u / width) ** 2)
    z = z + 0.05 * _g(u, v, 0.0, -0.32, 0.06, 0.05) + 0.05 * _pair(u, v, 0.085, -0.345, 0.04, 0.035)
    # Lips and the line between them; philtrum.
    z = z + 0.045 * _g(u, v, 0.0, -0.50, 0.13, 0.03) + 0.05 * _g(u, v, 0.0, -0.585, 0.12, 0.035)
    z = z - 0.018 * _g(u, v, 0.0, -0.542, 0.13, 0.008)
    z = z + 0.01 * _g(u, v, 0.0, -0.44, 0.03, 0.04)
    # Cheeks, cheekbones, chin, temples.
    z = z + 0.05 * _pair(u, v, 0.36, -0.24, 0.14, 0.14) + 0.035 * _pair(u, v, 0.46, -0.05, 0.10, 0.07)
    z = z + 0.06 * _g(u, v, 0.0, -0.82, 0.13, 0.09)
    z = z - 0.03 * _pair(u, v, 0.62, 0.25, 0.07, 0.12)
    # Hair volume.
    z = z + 0.04 * _smoothstep(-0.05, 0.10, v - hairline(u)) * np.clip(1.0 - r2, 0.0, 1.0) ** 0.2
    ear = 0.16 * np.sqrt(np.clip(1.0 - _ear_r2(u, v), 0.0, None))
    neck = np.where(np.abs(u) < NECK_HALF_WIDTH,
                    0.34 * np.sqrt(np.clip(1.0 - (u / NECK_HALF_WIDTH) ** 2, 0.0, None)) + 0.05, 0.0)
    neck = np.where(v < NECK_TOP, neck, 0.0)
    skull = np.where(r2 < 1.0, z, 0.0)
    return np.maximum(np.maximum(skull, ear), neck)


@dataclass(frozen=True)
class Head:
    """The head at the reference pose on a (H, W) image grid.

    height : (H, W) float32 pixels toward the camera, ``NO_SURFACE`` off the head.
    alpha : (H, W) float32 coverage 0-1 (anti-aliased silhouette).
    mask : (H, W) bool, pixel centres on the head (the pixels that are shaded).
    normal : (H, W, 3) float32 unit normals (camera space), 0 off the head.
    albedo : (H, W, 3) float32 linear diffuse albedo. specular, roughness : (H, W) float32.
    wrap : (H, W, 3) float32 per-channel wrap (subsurface softening).
    regions : named (H, W) bool masks (eyes, hair, brows, lips) for tests and plots.
    """

    height: np.ndarray
    alpha: np.ndarray
    mask: np.ndarray
    normal: np.ndarray
    albedo: np.ndarray
    specular: np.ndarray
    roughness: np.ndarray
    wrap: np.ndarray
    center: tuple[float, float]
    scale: float
    regions: dict = field(default_factory=dict)

    def surface(self) -> Surface:
        """The shading input for :class:`relight.kernels.shading.LightShader`."""
        pix = np.flatnonzero(self.mask).astype(np.int32)
        flat = self.mask.ravel()
        return Surface(
            height=self.height, pix=pix,
            normal=self.normal.reshape(-1, 3)[flat], albedo=self.albedo.reshape(-1, 3)[flat],
            specular=self.specular.ravel()[flat], roughness=self.roughness.ravel()[flat],
            wrap=self.wrap.reshape(-1, 3)[flat],
        )

    def bbox(self, pad: int = 2) -> tuple[int, int, int, int]:
        """(x0, y0, x1, y1) of the covered pixels, padded, clipped to the image."""
        ys, xs = np.nonzero(self.alpha > 0)
        h, w = self.alpha.shape
        return (max(int(xs.min()) - pad, 0), max(int(ys.min()) - pad, 0),
                min(int(xs.max()) + pad + 1, w), min(int(ys.max()) + pad + 1, h))


def head_placement(width: int, height: int) -> tuple[tuple[float, float], float]:
    """Image position of the head origin and pixels per head unit for a frame size.

    The face (brows to chin) spans about a third of the frame height, as in the paper.
    """
    return (0.42 * width, 0.47 * height), 0.30 * height


def _noise(rng: np.random.Generator, shape, sigma_px: float) -> np.ndarray:
    n = rng.standard_normal(shape).astype(np.float32)
    if sigma_px > 0:
        n = cv2.GaussianBlur(n, (0, 0), sigma_px, borderType=cv2.BORDER_REFLECT)
        n /= max(float(n.std()), EPS_VALUE)
    return n


def build_head(width: int, height: int, seed: int = 0) -> Head:
    """Sample the procedural head on a ``width x height`` grid (skin tone and texture vary with ``seed``)."""
    (cx, cy), s = head_placement(width, height)
    rng = np.random.default_rng([seed, 0x4EAD])
    window, u, v = _window_grid(width, height, cx, cy, s)
    alpha, mask = _coverage(u, v, s)
    hz, nrm = _height_and_normals(u, v, s, rng)

    # ---- albedo and skin parameters -------------------------------------------------
    skin = _Skin(u, v, s, rng)
    lips = skin.paint_lips()
    brows = skin.paint_brows(rng)
    eyes = skin.paint_eyes()
    skin.paint_nostrils()
    skin.paint_moles(rng)
    hair_w = skin.paint_hair(rng)
    skin.paint_ears_and_neck()

    off = ~mask
    nrm[off] = 0.0
    skin.albedo[off] = 0.0

    def frame(a, fill=0.0):
        return _embed(a, window, (width, height), fill)

    regions = {"eyes": eyes & mask, "hair": (hair_w > 0.5) & mask, "brows": (brows > 0.5) & mask,
               "lips": (lips > 0.5) & mask}
    return Head(
        height=frame(np.where(mask, hz, NO_SURFACE), NO_SURFACE), alpha=frame(alpha), mask=frame(mask),
        normal=frame(nrm), albedo=frame(np.clip(skin.albedo, 0.0, 1.0)),
        specular=frame(np.where(mask, skin.spec, 0.0)), roughness=frame(np.clip(skin.rough, 0.05, 1.0), 1.0),
        wrap=frame(skin.wrap), center=(float(cx), float(cy)), scale=float(s),
        regions={k: frame(v) for k, v in regions.items()},
    )


def _window_grid(full_w: int, full_h: int, cx: float, cy: float, s: float):
    """The window the head can reach, ``(wx0, wx1, wy0)`` (frame px; it runs to the frame's
    bottom), and the head coordinates ``u``, ``v`` (h, w) float64 of its pixel centres."""
    # Work on the window the head can reach (ears at |u| < 0.84, crown at v = 1; the neck runs
    # to the bottom edge) and embed it in the frame at the end.
    wx0 = max(int(np.floor(cx - 0.9 * s)) - 2, 0)
    wx1 = min(int(np.ceil(cx + 0.9 * s)) + 3, full_w)
    wy0 = max(int(np.floor(cy - 1.02 * s)) - 2, 0)
    xs = np.arange(wx0, wx1, dtype=np.float64)
    ys = np.arange(wy0, full_h, dtype=np.float64)
    u = (xs[None, :] - cx) / s
    v = (cy - ys[:, None]) / s
    u, v = np.broadcast_arrays(u, v)
    return (wx0, wx1, wy0), u, v


def _coverage(u: np.ndarray, v: np.ndarray, s: float) -> tuple[np.ndarray, np.ndarray]:
    """(alpha (h, w) float32 0-1: the silhouette's coverage by supersampling, mask (h, w) bool:
    pixel centres on the head) at head coordinates ``u``, ``v`` (``s``: px per head unit)."""
    k = ALPHA_SUPERSAMPLE
    off = (np.arange(k) + 0.5) / k - 0.5
    alpha = np.zeros(u.shape, dtype=np.float64)
    for oy in off:
        for ox in off:
            alpha += inside(u + ox / s, v - oy / s)
    alpha = (alpha / (k * k)).astype(np.float32)
    return alpha, inside(u, v)


def _height_and_normals(u: np.ndarray, v: np.ndarray, s: float,
                        rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(height (h, w) float64 px toward the camera, unit normals (h, w, 3) float64 with the skin's
    micro-relief, slopes capped at MAX_SLOPE) at head coordinates ``u``, ``v``."""
    hz = height_units(u, v) * s
    # Normals from central differences of the continuous height (half a pixel each way).
    e = 0.5 / s
    gx = (height_units(u + e, v) - height_units(u - e, v)) * s  # dz/dx per pixel
    gy = (height_units(u, v + e) - height_units(u, v - e)) * s  # dz/d(up) per pixel
    # Micro-relief: pores and fine skin texture make the specular lobe break up a little.
    bump = _noise(rng, u.shape, 0.8) * (0.004 * s / 100.0)
    gx = gx + np.gradient(bump, axis=1)
    gy = gy - np.gradient(bump, axis=0)
    slope = np.hypot(gx, gy)
    limit = np.where(slope > MAX_SLOPE, MAX_SLOPE / np.maximum(slope, EPS_NORM), 1.0)
    nrm = np.stack([-gx * limit, -gy * limit, np.ones_like(gx)], axis=-1)
    nrm /= np.linalg.norm(nrm, axis=-1, keepdims=True)
    return hz, nrm


def _embed(a: np.ndarray, window: tuple[int, int, int], full_size: tuple[int, int], fill=0.0) -> np.ndarray:
    """The window's array ``a`` placed in a (H, W, ...) frame of ``fill`` (float32, or bool for a mask)."""
    wx0, wx1, wy0 = window
    full_w, full_h = full_size
    out = np.full((full_h, full_w, *a.shape[2:]), fill, dtype=np.float32 if a.dtype != bool else bool)
    out[wy0:, wx0:wx1] = a
    return out


class _Skin:
    """The skin maps painted on the head's window, float64: ``albedo`` (h, w, 3) linear,
    ``spec`` and ``rough`` (h, w), ``wrap`` (h, w, 3); each ``paint_*`` adds one feature at the
    head coordinates ``u``, ``v`` (h, w) in place (in the order :func:`build_head` calls them:
    the seeded draws follow it)."""

    def __init__(self, u: np.ndarray, v: np.ndarray, s: float, rng: np.random.Generator):
        self.u, self.v = u, v
        self.px = 1.0 / s  # one pixel in head units, for soft edges
        shape = u.shape
        tone = 1.0 + 0.06 * rng.standard_normal()
        self.skin = np.array([0.62, 0.42, 0.33]) * tone
        albedo = np.broadcast_to(self.skin, (*shape, 3)).copy()
        albedo *= (1.0 + 0.035 * _noise(rng, shape, 6.0 * s / 162))[..., None]
        albedo *= (1.0 + 0.03 * _noise(rng, shape, 0.7))[..., None]
        blush = _pair(u, v, 0.36, -0.25, 0.12, 0.10)
        albedo += blush[..., None] * np.array([0.06, -0.03, -0.02])
        self.albedo = albedo
        self.spec = np.full(shape, 0.35)
        self.rough = np.full(shape, 0.38)
        self.wrap = np.broadcast_to(np.array([0.30, 0.14, 0.09]), (*shape, 3)).copy()
        # Oily T-zone: forehead and nose.
        tzone = np.clip(_g(u, v, 0.0, 0.35, 0.25, 0.15) + _g(u, v, 0.0, -0.2, 0.06, 0.16), 0, 1)
        self.spec += 0.25 * tzone
        self.rough -= 0.06 * tzone

    def paint(self, weight, colour, ks=None, r=None, wr=None) -> None:
        """Blend ``colour`` (and specular ``ks``, roughness ``r``, wrap ``wr``) in by ``weight`` (h, w), clipped 0-1."""
        wgt = np.clip(weight, 0.0, 1.0)
        self.albedo[:] = self.albedo * (1 - wgt[..., None]) + wgt[..., None] * np.asarray(colour)
        if ks is not None:
            self.spec[:] = self.spec * (1 - wgt) + wgt * ks
        if r is not None:
            self.rough[:] = self.rough * (1 - wgt) + wgt * r
        if wr is not None:
            self.wrap[:] = self.wrap * (1 - wgt[..., None]) + wgt[..., None] * np.asarray(wr)

    def soft_inside(self, signed):
        """(h, w) 0-1: inside where ``signed`` < 0 (head units), with a ~1 px anti-aliased edge."""
        return np.clip(0.5 - signed / (1.5 * self.px), 0.0, 1.0)

    def paint_lips(self) -> np.ndarray:
        """Paint the lips and the line between them; returns the lips' weight (h, w)."""
        u, v = self.u, self.v
        lip_d = np.maximum(((u / 0.125) ** 2 + ((v + 0.545) / 0.07) ** 2), 0.0)
        lips = self.soft_inside((np.sqrt(lip_d) - 1.0) * 0.06)
        self.paint(lips * 0.85, (0.50, 0.20, 0.20), ks=0.5, r=0.3, wr=(0.35, 0.15, 0.1))
        self.paint(self.soft_inside(np.abs(v + 0.542) - 0.004) * (np.abs(u) < 0.11), (0.12, 0.05, 0.05))
        return lips

    def paint_brows(self, rng: np.random.Generator) -> np.ndarray:
        """Paint the eyebrows: arcs above the eyes, with strands; returns their weight (h, w)."""
        u, v = self.u, self.v
        strands = 0.9 + 0.15 * _noise(rng, u.shape, 0.6)
        brows = np.zeros(u.shape)
        for sgn in (-1.0, 1.0):
            du = (u - sgn * 0.29) / 0.17
            arc = 0.15 + 0.035 * (1 - du**2)
            band = self.soft_inside(np.abs(v - arc) - 0.03 * (1 - 0.5 * du**2)) * self.soft_inside(np.abs(du) - 1.0)
            brows = np.maximum(brows, band)
        self.paint(brows * np.clip(strands, 0, 1), (0.035, 0.025, 0.02), ks=0.1, r=0.5, wr=(0.05, 0.05, 0.05))
        return brows

    def paint_eyes(self) -> np.ndarray:
        """Paint the eyes: almond opening with sclera, iris, pupil; dark lash line on the upper lid.
        Returns the openings (h, w) bool."""
        u, v = self.u, self.v
        eyes = np.zeros(u.shape, dtype=bool)
        for sgn in (-1.0, 1.0):
            du = (u - sgn * 0.29) / 0.105
            lid = 0.042 * np.sqrt(np.clip(1 - du**2, 0, None))
            dv = v - 0.0
            opening = self.soft_inside(np.maximum(np.abs(dv) - lid, (np.abs(du) - 1.0) * 0.105))
            eyes |= opening > 0.5
            self.paint(opening, (0.74, 0.71, 0.67), ks=1.0, r=0.08, wr=(0.0, 0.0, 0.0))
            rr = np.hypot(u - sgn * 0.29, v)
            self.paint(opening * self.soft_inside(rr - 0.040), (0.20, 0.12, 0.06))
            self.paint(opening * self.soft_inside(rr - 0.017), (0.015, 0.012, 0.01))
            lash = self.soft_inside(np.abs(dv - lid) - 0.007) * self.soft_inside(np.abs(du) - 1.05) * (dv > -0.01)
            self.paint(lash, (0.03, 0.02, 0.02), ks=0.05, r=0.5)
        return eyes

    def paint_nostrils(self) -> None:
        """Paint the nostrils."""
        u, v = self.u, self.v
        for sgn in (-1.0, 1.0):
            self.paint(self.soft_inside(np.hypot((u - sgn * 0.042) / 0.028, (v + 0.385) / 0.013) * 0.013 - 0.013),
                       (0.06, 0.03, 0.03), ks=0.05)

    def paint_moles(self, rng: np.random.Generator) -> None:
        """Paint moles (seeded): a few small dark spots on the skin."""
        for _ in range(3):
            mu, mv = rng.uniform(-0.5, 0.5), rng.uniform(-0.7, 0.35)
            self.paint(0.8 * self.soft_inside(np.hypot(self.u - mu, self.v - mv) - 0.012), (0.25, 0.14, 0.1))

    def paint_hair(self, rng: np.random.Generator) -> np.ndarray:
        """Paint the hair (above the hairline, at the skull's sides) with strands; returns its weight (h, w)."""
        u, v = self.u, self.v
        hair_w = _smoothstep(-0.015, 0.015, v - hairline(u)) * (_skull_r2(u, v) < 1.05)
        hair_strands = np.clip(0.85 + 0.3 * _noise(rng, u.shape, 0.8), 0.3, 1.3)
        self.paint(hair_w, (0.075, 0.048, 0.032), ks=0.2, r=0.45, wr=(0.05, 0.05, 0.05))
        self.albedo *= np.where(hair_w > 0.5, hair_strands, 1.0)[..., None]
        return hair_w

    def paint_ears_and_neck(self) -> None:
        """Paint the ears a touch redder, the neck a touch darker."""
        u, v = self.u, self.v
        self.paint(0.5 * (_ear_r2(u, v) < 1.0) * (_skull_r2(u, v) >= 1.0), self.skin * np.array([1.05, 0.9, 0.88]))
        self.paint(0.4 * _smoothstep(-0.95, -1.2, v), self.skin * 0.85)
