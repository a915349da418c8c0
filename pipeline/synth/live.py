"""A synthetic live video: the studio's procedural head turning and moving under the room light.

:func:`synthesize_live` writes ``OUT/live.mp4`` (H.264 with an AAC audio track) and the exact
per-frame head pose in ``OUT/truth/meta.json``, for measuring head-pose tracking.

Geometry. The head is the static studio's (:func:`.head.build_head`, same seed and size, so a
bundle captured from ``relight synth --seed S --size WxH`` matches this video's reference
pose): a height field seen by an orthographic camera looking along -Z. A head pixel at image
column ``x``, row ``y`` with height ``h`` (pixels toward the camera) is the camera-space point
``P = (x, -y, h)`` (+X right, +Y up, +Z toward the camera). At frame ``i`` it moves to::

    P' = R (P - C) + C + (tx, -ty, 0),    R = Ry(yaw) @ Rx(pitch) @ Rz(roll)

(:func:`relight.directions.rotation_matrix`: degrees, right-handed rotations about camera +Y,
+X, +Z) and is seen at column ``P'x``, row ``-P'y``. ``[tx, ty]`` is in image pixels (``ty``
down). The pivot ``C`` is the head centre (:attr:`.head.Head.center`, between the eyes in the
image) at a depth of :data:`PIVOT_DEPTH` head units (half the crown-to-chin height = ``0.5 *
Head.scale`` pixels) behind the face's frontmost point - about the middle of the skull, where
a neck turns a head. The reference pose (``R = I``, no translation) is the head as built: the
pose of the static capture's reference frame.

Rendering. The height field is a triangle mesh with a vertex at every head pixel centre (its
height from ``Head.height``) plus rim vertices: each pixel just outside the silhouette is moved
onto the head's analytic outline (:func:`.head.inside`, bisected to 1e-6 px) at the surface's
height there, so the outline stays smooth however the head turns. Frames rasterise the moved
mesh with a z-buffer (nearest surface wins; watertight, so no holes; a steep side turning toward
the camera shows as stretched triangles) at 2x2 samples per pixel, box-filtered. The neck is
extended below the frame (its last row repeated) so it never lifts off the bottom edge.

Shading. Each vertex starts from the studio's reference radiance under the room light
(:meth:`.studio.Studio.ambient_head`: ``builtin:room`` times ``ambient``, cast shadows and
specular at the reference pose) and is multiplied by the ratio of the diffuse irradiance at its
rotated normal to that at its reference normal, both from a 9-coefficient spherical-harmonics
projection of the room (Ramamoorthi & Hanrahan 2001). Cast shadows and highlights therefore
stay where they were at the reference pose (they move with the head); the change of overall
brightness of each part as it turns toward or away from the ceiling light and the window is
modelled. The background is the studio's wall under the room light (no mirror sphere, no
flash); the camera is the studio's sensor (gain 1, neutral white balance, counter-based noise).

Limits. A height field has no far side: the back of the skull is not modelled, so on the side
turning away the outline is the face's own profile (narrower than a real head's), and on the
side turning toward the camera the steep band next to the rim - a pixel or two of the reference
- is stretched over several pixels. Shadows and highlights are baked at the reference pose (see
above). Frames are instants (no motion blur, no rolling shutter). The neck turns with the head.
"""

from __future__ import annotations

import json
import os
import time
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, field
from pathlib import Path

import cv2
import numpy as np
from scipy.ndimage import distance_transform_edt
from tqdm import tqdm

from relight.directions import equirect_directions, equirect_solid_angles, fibonacci_sphere, rotation_matrix
from relight.errors import InputError
from relight.imageio import atomic_path, write_image
from relight.numerics import EPS, EPS_NORM, FLOAT
from relight.video import AUDIO_RATE, VideoWriter

from .head import Head, height_units, inside
from .studio import MAX_SIZE, MIN_SIZE, Studio, SynthConfig

LIVE_FORMAT_VERSION = 1
#: Pivot depth behind the face's frontmost point, in head units (``Head.scale`` pixels each).
PIVOT_DEPTH = 0.5
#: ``shift = 1`` moves the head up to this fraction of the frame height each way (x and y).
SHIFT_FRACTION = 0.04
#: Largest rotation amplitudes (degrees) a height field can show without revealing what it lacks.
MAX_AMPLITUDE = {"yaw": 45.0, "pitch": 30.0, "roll": 45.0}
MAX_SHIFT = 5.0
#: Motion: each pose channel is a sum of three sines of incommensurate (random) frequencies near
#: these (Hz), weights :data:`MOTION_WEIGHTS`; the slowest one makes at least
#: :data:`MOTION_MIN_CYCLES` cycles per clip. The channel is then scaled so that it spans
#: :data:`MOTION_SPAN` of its range [-amplitude, amplitude] over the clip.
MOTION_HZ = (0.11, 0.23, 0.41)
MOTION_WEIGHTS = (1.0, 0.45, 0.2)
MOTION_MIN_CYCLES = 0.75
MOTION_SPAN = 0.97
#: Audio: a 440 Hz tone at -20 dBFS peak, or white noise at -26 dBFS RMS; 10 ms fades.
TONE_HZ = 440.0
TONE_PEAK = 0.1
NOISE_RMS = 0.05
AUDIO_FADE_S = 0.01
AUDIO_KINDS = ("tone", "noise", "none")
#: Irradiance-ratio guards: the reference irradiance is floored at this share of the brightest
#: direction's, and the ratio is capped.
IRRADIANCE_FLOOR = 0.02
MAX_SHADING_RATIO = 8.0
#: Triangles per rasterisation batch times candidate samples (bounds memory).
RASTER_BATCH = 2_000_000
#: Frames rendered at once on worker threads (at most one per CPU).
RENDER_THREADS = 4


@dataclass(frozen=True)
class LiveConfig:
    """Settings of one synthetic live video (``relight synth OUT --live``).

    yaw, pitch, roll : rotation amplitudes in degrees (the pose stays within +-amplitude).
    shift : translation amplitude, times :data:`SHIFT_FRACTION` of the frame height (x and y).
    ambient, noise : room light strength and sensor noise, times the studio's defaults.
    audio : ``tone`` (440 Hz), ``noise`` (white) or ``none`` (no audio stream).
    """

    width: int = 960
    height: int = 540
    fps: float = 30.0
    duration: float = 10.0
    seed: int = 0
    yaw: float = 30.0
    pitch: float = 15.0
    roll: float = 8.0
    shift: float = 1.0
    ambient: float = 1.0
    noise: float = 1.0
    crf: int = 18
    audio: str = "tone"

    def validate(self) -> LiveConfig:
        """Return self, or raise :class:`InputError` naming the setting to change."""
        w, h = self.width, self.height
        if not (MIN_SIZE[0] <= w <= MAX_SIZE[0] and MIN_SIZE[1] <= h <= MAX_SIZE[1]) or w % 2 or h % 2:
            raise InputError(f"--size {w}x{h}: use even numbers between {MIN_SIZE[0]}x{MIN_SIZE[1]} "
                             f"and {MAX_SIZE[0]}x{MAX_SIZE[1]}")
        if not (np.isfinite(self.fps) and 5.0 <= self.fps <= 240.0):
            raise InputError(f"--fps {self.fps}: use 5 to 240 frames per second")
        if not (np.isfinite(self.duration) and 1.0 <= self.duration <= 600.0):
            raise InputError(f"--duration {self.duration}: use 1 to 600 seconds")
        if not (isinstance(self.seed, int | np.integer) and 0 <= self.seed < 2**32):
            raise InputError(f"--seed {self.seed}: use a whole number from 0 to {2**32 - 1}")
        for name, top in MAX_AMPLITUDE.items():
            val = getattr(self, name)
            if not (np.isfinite(val) and 0.0 <= val <= top):
                raise InputError(f"{name} amplitude {val}: use 0 to {top:g} degrees (a height-field head "
                                 f"turned further shows the sides it does not have)")
        if not (np.isfinite(self.shift) and 0.0 <= self.shift <= MAX_SHIFT):
            raise InputError(f"shift {self.shift}: use 0 to {MAX_SHIFT:g} (times {SHIFT_FRACTION:g} of the frame "
                             f"height)")
        if not (np.isfinite(self.ambient) and 0.0 < self.ambient <= 20.0):
            raise InputError(f"--ambient {self.ambient}: use a number above 0 and up to 20 (the room light is "
                             f"the only light of a live video)")
        if not (np.isfinite(self.noise) and 0.0 <= self.noise <= 20.0):
            raise InputError(f"--noise {self.noise}: use a number from 0 to 20")
        if not (isinstance(self.crf, int | np.integer) and 0 <= self.crf <= 51):
            raise InputError(f"--crf {self.crf}: use a whole number from 0 (lossless) to 51")
        if self.audio not in AUDIO_KINDS:
            raise InputError(f"--audio {self.audio!r}: use one of {', '.join(AUDIO_KINDS)}")
        return self

    @property
    def frame_count(self) -> int:
        return int(round(self.duration * self.fps))

    @property
    def shift_px(self) -> float:
        """Translation amplitude in pixels (each of x and y)."""
        return self.shift * SHIFT_FRACTION * self.height


@dataclass
class LiveResult:
    """What :func:`synthesize_live` wrote and how long each part took (seconds)."""

    out: Path
    video: Path
    truth: Path
    meta: Path
    reference: Path
    mask: Path
    frame_count: int
    timings: dict = field(default_factory=dict)


# ---------------------------------------------------------------------- lighting
def sh9_basis(d: np.ndarray) -> np.ndarray:
    """Real spherical harmonics up to order 2 at unit directions (..., 3) -> (..., 9), float64.

    Order: Y00, Y1-1 (y), Y10 (z), Y11 (x), Y2-2 (xy), Y2-1 (yz), Y20, Y21 (xz), Y22.
    """
    d = np.asarray(d, dtype=np.float64)
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    return np.stack([
        np.full_like(x, 0.282095),
        0.488603 * y, 0.488603 * z, 0.488603 * x,
        1.092548 * x * y, 1.092548 * y * z, 0.315392 * (3.0 * z * z - 1.0),
        1.092548 * x * z, 0.546274 * (x * x - y * y),
    ], axis=-1)


#: Lambertian convolution weights per SH band: pi, 2 pi / 3, pi / 4.
_SH_LAMBERT = np.array([np.pi] + [2.0 * np.pi / 3.0] * 3 + [np.pi / 4.0] * 5)


def environment_sh9(env: np.ndarray) -> np.ndarray:
    """(9, 3) SH coefficients of a lat-long environment's radiance (float64, exact texel solid angles)."""
    h, w = env.shape[:2]
    y = sh9_basis(equirect_directions(w, h))
    weight = equirect_solid_angles(w, h)[:, None, None]
    return np.einsum("hwk,hwc->kc", y * weight, env.astype(np.float64))


def sh9_irradiance(coeffs: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Diffuse irradiance (..., 3) at unit normals (..., 3) from (9, 3) radiance coefficients.

    A uniform environment of radiance 1 gives pi (a white Lambertian surface reads 1).
    """
    return sh9_basis(normals) @ (_SH_LAMBERT[:, None] * coeffs)


def sh9_irradiance_matrix(coeffs: np.ndarray) -> np.ndarray:
    """(3, 4, 4) symmetric matrices M with E(n) = (n, 1)^T M (n, 1), equal to :func:`sh9_irradiance`
    (Ramamoorthi & Hanrahan 2001, eq. 12); a rotation of the normals is then a rotation of M."""
    c1, c2, c3, c4, c5 = 0.429043, 0.511664, 0.743125, 0.886227, 0.247708
    m = np.zeros((3, 4, 4))
    for ch in range(3):
        l00, l1m1, l10, l11, l2m2, l2m1, l20, l21, l22 = coeffs[:, ch]
        m[ch] = [[c1 * l22, c1 * l2m2, c1 * l21, c2 * l11],
                 [c1 * l2m2, -c1 * l22, c1 * l2m1, c2 * l1m1],
                 [c1 * l21, c1 * l2m1, c3 * l20, c2 * l10],
                 [c2 * l11, c2 * l1m1, c2 * l10, c4 * l00 - c5 * l20]]
    return m


#: Directions the SH light's brightest irradiance is searched over (a Fibonacci sphere).
SPHERE_POINTS = 2000

#: Upper-triangle entries (i, j) of a symmetric 4x4 form over (x, y, z, 1), the constant (3, 3) last.
_MONOMIALS = (np.array([0, 1, 2, 0, 0, 1, 0, 1, 2, 3]), np.array([0, 1, 2, 1, 2, 2, 3, 3, 3, 3]))


# ---------------------------------------------------------------------- motion
def _smooth_channel(rng: np.random.Generator, t: np.ndarray, duration: float) -> np.ndarray:
    """Sum of three sines (random, incommensurate frequencies and phases) scaled to span +-MOTION_SPAN."""
    base = max(MOTION_HZ[0] * rng.uniform(0.8, 1.25), MOTION_MIN_CYCLES / duration)
    ratios = np.array([1.0, MOTION_HZ[1] / MOTION_HZ[0], MOTION_HZ[2] / MOTION_HZ[0]])
    freqs = base * ratios * np.array([1.0, *rng.uniform(0.85, 1.15, size=2)])
    phases = rng.uniform(0.0, 2.0 * np.pi, size=3)
    x = sum(wt * np.sin(2.0 * np.pi * f * t + p) for wt, f, p in zip(MOTION_WEIGHTS, freqs, phases, strict=True))
    lo, hi = float(x.min()), float(x.max())
    if hi - lo < EPS:
        return np.zeros_like(t)
    return MOTION_SPAN * (2.0 * (x - lo) / (hi - lo) - 1.0)


def head_pose_track(rng: np.random.Generator, n: int, fps: float, amplitudes: tuple[float, float, float],
                    shift_px: float) -> tuple[np.ndarray, np.ndarray]:
    """Smooth head motion: rotations (n, 3) [yaw, pitch, roll] degrees and translations (n, 2) [tx, ty] px.

    Each channel is an independent smooth signal spanning :data:`MOTION_SPAN` of its range
    (+-amplitude, +-shift_px) over the clip, so the clip covers most of the range; frame 0 is
    not the reference pose. Values are rounded (6 decimals in degrees, 4 in pixels): the
    frames are rendered from exactly the rounded values that go into the truth.
    """
    t = np.arange(n) / fps
    duration = max(n / fps, EPS_NORM)
    rot = np.stack([a * _smooth_channel(rng, t, duration) for a in amplitudes], axis=1)
    trans = np.stack([shift_px * _smooth_channel(rng, t, duration) for _ in range(2)], axis=1)
    return np.round(rot, 6), np.round(trans, 4)


# ---------------------------------------------------------------------- audio
def make_audio(kind: str, samples: int, rng: np.random.Generator) -> np.ndarray | None:
    """Mono float32 audio: a 440 Hz tone, seeded white noise, or None; faded in and out."""
    if kind == "none":
        return None
    if kind == "tone":
        t = np.arange(samples) / AUDIO_RATE
        a = TONE_PEAK * np.sin(2.0 * np.pi * TONE_HZ * t)
    else:
        a = np.clip(NOISE_RMS * rng.standard_normal(samples), -1.0, 1.0)
    fade = min(int(AUDIO_FADE_S * AUDIO_RATE), samples // 2)
    if fade:
        ramp = np.linspace(0.0, 1.0, fade)
        a[:fade] *= ramp
        a[samples - fade:] *= ramp[::-1]
    return a.astype(np.float32)


# ---------------------------------------------------------------------- rendering
class LiveHead:
    """The head as a triangle mesh that renders at any pose (see the module docstring).

    head : the studio's head; radiance : (P, 3) linear radiance at the head's mask pixels
    (``np.flatnonzero(head.mask)`` order) at the reference pose; room : the room environment
    (lat-long, linear) whose irradiance re-shades turned normals; pivot : camera-space pivot
    ``C`` (x, -y, z) - see :func:`pivot_point`; reach_px : how far (pixels) the head may move
    down, to extend the neck below the frame.
    """

    def __init__(self, head: Head, radiance: np.ndarray, room: np.ndarray, pivot: np.ndarray, *,
                 reach_px: float):
        h_img, w_img = head.mask.shape
        self.size = (w_img, h_img)
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
        self._monomials = np.stack([n[:, i] * n[:, j] if j < 3 else n[:, i] for i, j in zip(*_MONOMIALS, strict=True)
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
        iu, ju = _MONOMIALS
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
        w_img, h_img = self.size
        p = self.project(rotation, translation)
        x_img, y_img = p[:, 0], -p[:, 1]
        bx0 = int(np.clip(np.floor(x_img.min()) - 1, 0, w_img))
        bx1 = int(np.clip(np.ceil(x_img.max()) + 2, 0, w_img))
        by0 = int(np.clip(np.floor(y_img.min()) - 1, 0, h_img))
        by1 = int(np.clip(np.ceil(y_img.max()) + 2, 0, h_img))
        box = (bx0, by0, bx1, by1)
        nch = vals.shape[1]
        if bx1 <= bx0 or by1 <= by0:
            return box, np.zeros((max(by1 - by0, 0), max(bx1 - bx0, 0), nch), FLOAT), \
                np.zeros((max(by1 - by0, 0), max(bx1 - bx0, 0)), FLOAT)
        gw, gh = 2 * (bx1 - bx0), 2 * (by1 - by0)
        # Sample (I, J) of the 2x grid sits at pixel coordinate box0 + (I - 0.5) / 2.
        sx = 2.0 * (x_img - bx0) + 0.5
        sy = 2.0 * (y_img - by0) + 0.5
        sz = p[:, 2].astype(np.float32)
        cells, depth, t, w0, w1 = self._rasterise(sx, sy, sz, gw, gh)
        # Z-buffer: the nearest fragment (largest z: toward the camera) of each sample wins.
        zbuf = np.full(gw * gh, -np.inf, dtype=np.float32)
        np.maximum.at(zbuf, cells, depth)
        win = depth >= zbuf[cells]
        cells, w0, w1 = cells[win], w0[win], w1[win]
        t0, t1, t2 = t[0, win], t[1, win], t[2, win]
        w2 = 1.0 - w0 - w1
        # Values and coverage on the 2x grid, box-filtered to pixels (INTER_AREA: exact 2x2 means).
        planes = np.ascontiguousarray(vals.T)
        out = np.empty((gh // 2, gw // 2, nch), dtype=FLOAT)
        grid = np.zeros(gw * gh, dtype=FLOAT)
        for ch in range(nch):
            v = planes[ch]
            grid[cells] = w0 * v[t0] + w1 * v[t1] + w2 * v[t2]
            out[..., ch] = cv2.resize(grid.reshape(gh, gw), (gw // 2, gh // 2), interpolation=cv2.INTER_AREA)
        grid[:] = 0.0
        grid[cells] = 1.0
        cov = cv2.resize(grid.reshape(gh, gw), (gw // 2, gh // 2), interpolation=cv2.INTER_AREA)
        return box, out, cov

    def _rasterise(self, sx: np.ndarray, sy: np.ndarray, sz: np.ndarray, gw: int, gh: int):
        """Fragments of all triangles on the integer sample grid [0, gw) x [0, gh).

        sx, sy : (V,) float64 vertex positions in samples; sz : (V,) depth. Returns sample index,
        depth, the triangle's vertices (3, F) and the barycentric weights of the first two. Edges
        are inclusive (a sample on an edge shared by two triangles is produced by both, never by
        neither). Triangles are grouped by bounding-box size; each is tested at every sample of
        its box (boxes larger than 4x4 samples are rounded up to squares).
        """
        ax, bx, cx = sx[self._corners]
        ay, by, cy = sy[self._corners]
        xmin = np.maximum(np.ceil(np.minimum(np.minimum(ax, bx), cx)), 0.0)
        xmax = np.minimum(np.floor(np.maximum(np.maximum(ax, bx), cx)), gw - 1.0)
        ymin = np.maximum(np.ceil(np.minimum(np.minimum(ay, by), cy)), 0.0)
        ymax = np.minimum(np.floor(np.maximum(np.maximum(ay, by), cy)), gh - 1.0)
        area = (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)
        live = (xmax >= xmin) & (ymax >= ymin) & (np.abs(area) > EPS_NORM)
        nx = (xmax - xmin).astype(np.int64) + 1
        ny = (ymax - ymin).astype(np.int64) + 1
        # Barycentric weights are affine in the sample position: l = base + A dx + B dy from the
        # bounding box's first sample (coefficients in float64, per-sample work in float32).
        inv = np.where(live, 1.0 / np.where(live, area, 1.0), 0.0)
        a0, b0 = (by - cy) * inv, (cx - bx) * inv
        a1, b1 = (cy - ay) * inv, (ax - cx) * inv
        base0 = a0 * xmin + b0 * ymin + (bx * cy - by * cx) * inv
        base1 = a1 * xmin + b1 * ymin + (cx * ay - cy * ax) * inv
        coef = np.stack([a0, b0, a1, b1, base0, base1]).astype(np.float32)
        xmin, ymin = xmin.astype(np.int32), ymin.astype(np.int32)
        # Group key: exact box size up to 4x4, else the power-of-two square that holds the box.
        small = (nx <= 4) & (ny <= 4)
        side = 2 ** np.ceil(np.log2(np.maximum(np.maximum(nx, ny), 1))).astype(np.int64)
        key = np.where(small, (nx - 1) * 4 + (ny - 1), 16 + side)
        sel = np.flatnonzero(live)
        order = sel[np.argsort(key[sel], kind="stable")]
        keys = key[order]
        # Per-triangle data in group order, so each group is a contiguous slice.
        coef, xmin, ymin = coef[:, order], xmin[order], ymin[order]
        starts = np.flatnonzero(np.r_[True, keys[1:] != keys[:-1]]) if order.size else np.zeros(0, np.int64)
        ends = np.r_[starts[1:], order.size]
        eps = np.float32(-1e-5)
        out = []
        for s0, s1 in zip(starts, ends, strict=True):
            kk = int(keys[s0])
            gx_n, gy_n = (kk // 4 + 1, kk % 4 + 1) if kk < 16 else (kk - 16, kk - 16)
            m = gx_n * gy_n
            dy, dx = np.divmod(np.arange(m, dtype=np.int32), np.int32(gx_n))
            fdx, fdy = dx.astype(np.float32), dy.astype(np.float32)
            step = max(RASTER_BATCH // m, 1)
            for c0 in range(s0, s1, step):
                c1 = min(c0 + step, s1)
                fa0, fb0, fa1, fb1, fc0, fc1 = coef[:, c0:c1, None]
                l0 = fa0 * fdx
                l0 += fc0
                l0 += fb0 * fdy
                l1 = fa1 * fdx
                l1 += fc1
                l1 += fb1 * fdy
                ok = (l0 >= eps) & (l1 >= eps) & (l0 + l1 <= 1.0 - eps)
                flat = np.flatnonzero(ok)
                r, q = np.divmod(flat, m)
                px = xmin[c0:c1][r] + dx[q]
                py = ymin[c0:c1][r] + dy[q]
                if kk >= 16:  # rounded-up boxes can reach past the grid's edge
                    inb = (px < gw) & (py < gh)
                    flat, r, px, py = flat[inb], r[inb], px[inb], py[inb]
                l0, l1 = l0.ravel()[flat], l1.ravel()[flat]
                ti = order[c0 + r]
                t = self._corners[:, ti]
                z0, z1, z2 = sz[t[0]], sz[t[1]], sz[t[2]]
                out.append((py * gw + px, z2 + l0 * (z0 - z2) + l1 * (z1 - z2), t, l0, l1))
        if not out:
            return (np.zeros(0, np.int32), np.zeros(0, np.float32), np.zeros((3, 0), np.int32),
                    np.zeros(0, np.float32), np.zeros(0, np.float32))
        cells, depth, t, l0, l1 = zip(*out, strict=True)
        return (np.concatenate(cells), np.concatenate(depth), np.concatenate(t, axis=1), np.concatenate(l0),
                np.concatenate(l1))


def pivot_point(head: Head) -> np.ndarray:
    """Camera-space pivot ``C`` = (cx, -cy, z): the head centre, :data:`PIVOT_DEPTH` head units
    behind the face's frontmost point."""
    cx, cy = head.center
    z = float(head.height[head.mask].max()) - PIVOT_DEPTH * head.scale
    return np.array([cx, -cy, z], dtype=np.float64)


class LiveScene:
    """One live video's scene: the studio's head, wall and sensor, the mesh head, the motion."""

    def __init__(self, config: LiveConfig):
        self.config = c = config.validate()
        t0 = time.perf_counter()
        # The static studio of the same seed and size: same head, same wall, same sensor model.
        self.studio = Studio(SynthConfig(width=c.width, height=c.height, seed=c.seed, ambient=c.ambient,
                                         noise=c.noise, duration=1.0))
        self.head = self.studio.head
        self.timings = {"head": time.perf_counter() - t0}
        seeds = np.random.SeedSequence([c.seed, 0x11FE]).spawn(3)
        rng_motion, rng_audio, noise = seeds
        self.noise_seed = int(noise.generate_state(1)[0])
        self.n = c.frame_count
        self.rotations, self.translations = head_pose_track(
            np.random.default_rng(rng_motion), self.n, c.fps, (c.yaw, c.pitch, c.roll), c.shift_px)
        self.audio = make_audio(c.audio, int(round(self.n / c.fps * AUDIO_RATE)), np.random.default_rng(rng_audio))
        self.pivot = pivot_point(self.head)
        self.sensor = self.studio.sensor
        self._mesh: LiveHead | None = None

    def prepare(self) -> None:
        """Shade the head under the room light at the reference pose and build the mesh (slow part)."""
        if self._mesh is not None:
            return
        t0 = time.perf_counter()
        radiance = self.studio.ambient_head()
        self.timings["room_shading"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        c = self.config
        # How far the bottom of the neck can rise: it hangs ``drop`` below the pivot, within a head
        # unit of it across and in depth; pitch and roll tilt it (yaw keeps heights), the shift lifts it.
        drop = self.head.mask.shape[0] - self.head.center[1]
        ang = np.radians(min(c.pitch + c.roll, 90.0))
        reach = drop * (1.0 - np.cos(ang)) + self.head.scale * np.sin(ang) + c.shift_px
        self._mesh = LiveHead(self.head, radiance, self.studio.room, self.pivot, reach_px=reach)
        self.wall = self.studio._static_layers[0]
        self.timings["mesh"] = time.perf_counter() - t0

    @property
    def mesh(self) -> LiveHead:
        self.prepare()
        return self._mesh

    def render(self, rotation: np.ndarray, translation=(0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
        """Linear frame (H, W, 3) float32 and head coverage (H, W) at a pose (rotation matrix, [tx, ty] px)."""
        mesh = self.mesh
        (x0, y0, x1, y1), head, cov = mesh.render(rotation, translation)
        out = self.wall.copy()
        coverage = np.zeros(out.shape[:2], dtype=FLOAT)
        dst = out[y0:y1, x0:x1]
        dst[:] = head + (1.0 - cov[..., None]) * dst
        coverage[y0:y1, x0:x1] = cov
        return out, coverage

    def pose(self, frame: int) -> tuple[np.ndarray, np.ndarray]:
        """Rotation matrix and translation [tx, ty] of ``frame``, exactly as recorded in the truth."""
        return rotation_matrix(*self.rotations[frame]), self.translations[frame]

    def camera_frame(self, frame: int, *, noisy: bool = True) -> np.ndarray:
        """(H, W, 3) uint8 sRGB frame ``frame`` as the camera records it."""
        linear, _ = self.render(*self.pose(frame))
        return self.expose(linear, frame if noisy else None)

    def expose(self, linear: np.ndarray, frame: int | None) -> np.ndarray:
        key = None if frame is None else (self.noise_seed, frame)
        return self.sensor.expose(linear, 1.0, np.ones(3), key)

    def meta(self) -> dict:
        c = self.config
        audio = None
        if self.audio is not None:
            audio = {"kind": c.audio, "codec": "aac", "sample_rate": AUDIO_RATE, "channels": 1,
                     "samples": int(self.audio.size), "duration": self.audio.size / AUDIO_RATE}
            audio.update({"frequency_hz": TONE_HZ, "peak": TONE_PEAK} if c.audio == "tone" else {"rms": NOISE_RMS})
        px, py, pz = self.pivot
        return {
            "format": "relight-synth-live",
            "version": LIVE_FORMAT_VERSION,
            "kind": "live",
            "config": asdict(c),
            "fps": c.fps,
            "size": [c.width, c.height],
            "frame_count": self.n,
            "seed": c.seed,
            "head_rotation": [[float(x) for x in row] for row in self.rotations],
            "head_translation": [[float(x) for x in row] for row in self.translations],
            "pivot": [float(px), float(-py), float(pz)],
            "amplitudes": {"yaw": c.yaw, "pitch": c.pitch, "roll": c.roll, "shift_px": c.shift_px},
            "head_center": list(self.head.center),
            "head_scale": self.head.scale,
            "reference_pose": {"head_rotation": [0.0, 0.0, 0.0], "head_translation": [0.0, 0.0]},
            "sensor": {"read_noise": self.sensor.read_noise, "shot_gain": self.sensor.shot_gain,
                       "exposure_gain": 1.0, "white_balance": [1.0, 1.0, 1.0]},
            "audio": audio,
            "conventions": (
                "Camera space as in the README: +X right in the image, +Y up, +Z toward the camera, orthographic "
                "camera looking along -Z. head_rotation is [yaw, pitch, roll] in degrees per frame, relative to "
                "the reference pose (the head as built, the pose of the static `relight synth` capture's "
                "reference frame, same seed and size): R = Ry(yaw) Rx(pitch) Rz(roll), right-handed rotations "
                "about camera +Y, +X, +Z (relight.directions.rotation_matrix). A head point at image column x, "
                "row y with height h (pixels toward the camera) is P = (x, -y, h); at a frame it moves to "
                "P' = R (P - C) + C + (tx, -ty, 0) and is seen at column P'x, row -P'y, where C = (pivot[0], "
                "-pivot[1], pivot[2]) with pivot = [column, row, height] in pixels and head_translation = "
                "[tx, ty] in image pixels (ty down). Frames are instants t = i / fps (no motion blur)."),
        }


def synthesize_live(out: str | Path, config: LiveConfig = LiveConfig(), *, progress: bool = True) -> LiveResult:
    """Write a live video of the head turning under room light: ``out/live.mp4`` and ``out/truth/``."""
    t_all = time.perf_counter()
    out = Path(out)
    truth = out / "truth"
    scene = LiveScene(config)
    c = scene.config
    with tqdm(total=1, desc="room light", unit="pass", disable=not progress, leave=False) as bar:
        scene.prepare()
        bar.update(1)
    timings = dict(scene.timings)
    truth.mkdir(parents=True, exist_ok=True)

    t0 = time.perf_counter()
    linear, coverage = scene.render(np.eye(3), (0.0, 0.0))
    reference = write_image(truth / "reference.png", scene.expose(linear, None))
    mask = write_image(truth / "mask_reference.png", ((coverage > 0.5) * 255).astype(np.uint8))
    timings["reference"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    video = out / "live.mp4"
    t_wait = 0.0
    # Frames render on worker threads (NumPy releases the GIL) a few frames ahead; the sensor and
    # the writer take them in order here, and H.264 encoding runs on the writer's own thread.
    threads = max(1, min(RENDER_THREADS, os.cpu_count() or 1))
    pool = ThreadPoolExecutor(threads, thread_name_prefix="relight-live")
    pending: deque = deque()
    try:
        with VideoWriter(video, c.fps, (c.width, c.height), crf=c.crf, audio=scene.audio) as writer:
            ahead = 0
            for i in tqdm(range(scene.n), desc="frames", unit="frame", disable=not progress, leave=False):
                while ahead < scene.n and len(pending) <= threads:
                    pending.append(pool.submit(scene.render, *scene.pose(ahead)))
                    ahead += 1
                t1 = time.perf_counter()
                linear, _ = pending.popleft().result()
                t_wait += time.perf_counter() - t1
                writer.write(scene.expose(linear, i))
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
    timings["frames_wait"] = t_wait
    timings["frames_total"] = time.perf_counter() - t0

    meta = scene.meta()
    meta["files"] = {"video": "live.mp4", "reference": "truth/reference.png",
                     "mask_reference": "truth/mask_reference.png"}
    meta_path = truth / "meta.json"
    with atomic_path(meta_path) as tmp:
        tmp.write_text(json.dumps(meta, indent=1))
    timings["total"] = time.perf_counter() - t_all
    return LiveResult(out=out, video=video, truth=truth, meta=meta_path, reference=reference, mask=mask,
                      frame_count=scene.n, timings=timings)


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
