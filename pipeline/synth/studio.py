"""The synthetic capture studio: the paper's acquisition (section 3.1) on a head whose truth is known.

``Studio`` holds one capture's scene (head, rig, sphere, wall, camera) and renders its frames;
:func:`synthesize` writes ``OUT/capture.mp4`` and ``OUT/truth/`` (see :data:`TRUTH_FILES`).

Radiometry (linear Rec.709 RGB throughout): a pixel is the radiance reflected toward the
camera times the camera's exposure gain. The flash is a directional light of power pi (a
white Lambertian surface facing it reads 1); truth images (``relit_*.exr``, ``olat_*.exr``)
are rendered at the reference pose with exposure gain 1, no noise, no clipping, ambient off,
so rendering a captured flash direction with a light as strong as the flash reproduces the
flash's share of that frame. Environment maps are integrated as directional lights on a
128x64 lat-long grid plus their bright texels (sun, lamps) at full resolution - finer than
the 64x32 maps the pipeline builds, and rendered by the shader itself, not interpolated.
"""

from __future__ import annotations

import hashlib
import json
import time
from dataclasses import asdict
from functools import cached_property
from pathlib import Path

import cv2
import numpy as np
from scipy.ndimage import distance_transform_edt
from tqdm import tqdm

from relight.directions import rotation_matrix
from relight.envmap import Lights, environment_stem, environment_to_lights, load_environment, rotate_environment
from relight.errors import InputError
from relight.imageio import atomic_path, write_image
from relight.kernels.shading import LightShader
from relight.numerics import EPS_NORM, FLOAT, px_at, require_finite
from relight.video_write import VideoWriter

from ..geometry import height_field_mesh
from . import acquisition
from .camera import Sensor
from .config import SynthConfig, SynthResult, head_info
from .head import Head, build_head
from .pinhole import ORTHOGRAPHIC_META, Pinhole
from .pinhole_view import capture_mesh, posed_layer, reference_view
from .pivot import mesh_pivot, neck_reach, pivot_point
from .scene import WALL_FLASH, MirrorSphere, sphere_placement, wall

AMBIENT_ENV = "builtin:room"
#: One-light truth images: name -> direction (camera space, toward the light).
OLAT_DIRECTIONS = {
    "front": (0.0, 0.0, 1.0),
    "left": (-0.8, 0.1, 0.6),
    "right": (0.8, 0.1, 0.6),
    "top": (0.0, 0.8, 0.6),
    "below": (0.0, -0.5, 0.87),
    "side": (1.0, 0.0, 0.05),
}
#: Grid (azimuth columns, polar rows) around the camera axis on which the truth integrates
#: environments, plus their bright texels at full resolution. Each column is one image-plane
#: direction, so the shader reads its visibility from a horizon table instead of marching.
TRUTH_GRID = (128, 64)
#: Texels brighter than this many times an environment's mean become lights of their own (a
#: sun, a lamp: exact directions, shadows marched); at most this many per environment.
TRUTH_PEAK_FACTOR = 500.0
TRUTH_MAX_PEAKS = 256
#: Lights per kernel launch in the truth pass (bounds one launch to about a second).
LIGHT_BATCH = 256
#: Outputs per shading pass (the kernel's MAX_OUT).
OUTPUTS_PER_PASS = 16
FLASH_STRENGTH = 1.0
TRUTH_FORMAT_VERSION = 1


class Studio:
    """One synthetic capture: the scene, the rig's schedule, and frame rendering."""

    def __init__(self, config: SynthConfig, *, progress: bool = False):
        self.config = config.validate()
        self.progress = progress
        c = self.config
        seeds = np.random.SeedSequence([c.seed, 0x5EED]).spawn(5)
        rng_rig, rng_motion, rng_drift, rng_scene, noise = seeds
        self.noise_seed = int(noise.generate_state(1)[0])
        self.n = c.frame_count
        self.exposure_time = 0.9 / c.fps
        t0 = time.perf_counter()
        self.mesh = self.placement = None
        if c.head_mesh is not None:
            from .mesh_head import build_mesh_head, load_head_mesh, place_mesh, resolve_head

            self.mesh = load_head_mesh(**resolve_head(c.head_mesh, texture=c.head_texture,
                                                      normal_map=c.head_normal_map, specular_map=c.head_specular_map,
                                                      flip_textures=c.head_texture_flip))
            self.placement = place_mesh(self.mesh, c.width, c.height)
            self.head: Head = build_mesh_head(self.mesh, c.width, c.height, placement=self.placement)
        else:
            self.head = build_head(c.width, c.height, c.seed)
        self.timings = {"head": time.perf_counter() - t0}
        self.surface = self.head.surface()
        self.shader = LightShader(self.surface)

        self.pulses = acquisition.make_pulses(np.random.default_rng(rng_rig), c.duration, c.flash_hz,
                                     sparse_sides=c.sparse_sides)
        self.lit = acquisition.flash_fractions(self.pulses, self.n, c.fps, self.exposure_time)
        self.fraction = np.array([sum(f for _, f in lst) for lst in self.lit])
        self.level = np.array([sum(f * self.pulses[k].strength for k, f in lst) for lst in self.lit])
        dark = np.flatnonzero(self.fraction == 0.0)
        self.reference_frame = int(dark[0]) if dark.size else int(np.argmin(self.fraction))
        self.motion = acquisition.head_motion(np.random.default_rng(rng_motion), self.n, c.fps, c.height,
                                      c.head_motion, self.reference_frame)
        self.matrices = acquisition.motion_matrices(self.motion, self.head.center)
        self.gain, self.white_balance = acquisition.camera_drift(np.random.default_rng(rng_drift), self.level,
                                                         c.fps, c.camera_drift)
        self.sensor = Sensor().scaled(c.noise)

        #: The camera: None (orthographic, the head image moved in the image plane) or a pinhole
        #: (``fov``: the head a mesh moved in space and seen through it, :mod:`.pinhole_view`).
        #: The head's pivot (:mod:`.pivot`: where a neck turns it), camera-space (x, -y, z).
        self.pivot = pivot_point(self.head) if self.mesh is None else \
            mesh_pivot(self.head, self.placement.project(self.mesh.vertices))
        self.camera: Pinhole | None = None if c.fov is None else \
            Pinhole.from_fov((c.width, c.height), c.fov, c.distance, self.head.scale, self.pivot[2])
        self._head_mesh = None
        cx, cy, r = sphere_placement(c.width, c.height)
        self.sphere = MirrorSphere(cx, cy, r, glare_sigma=max(0.8, px_at(1.2, c.height)), camera=self.camera)
        self.room = load_environment(AMBIENT_ENV) * np.float32(c.ambient)
        self.wall_albedo = wall(c.width, c.height, np.random.default_rng(rng_scene))

        # Pixels partly covered by the head but whose centre is off it take the colour of the
        # nearest shaded pixel (so the anti-aliased silhouette has no dark fringe).
        mask = self.head.mask
        _, (iy, ix) = distance_transform_edt(~mask, return_indices=True)
        flat_pos = -np.ones(mask.size, dtype=np.int64)
        flat_pos[self.surface.pix] = np.arange(self.surface.pix.size)
        edge = (self.head.alpha > 0) & ~mask
        self._edge_dst = np.flatnonzero(edge)
        self._edge_src = flat_pos[(iy * c.width + ix)[edge]]
        # Frames move the head within this crop (its bounding box plus the largest motion).
        reach = px_at(acquisition.MAX_SHIFT_PX_AT_540, c.height) * max(c.head_motion, 1.0)
        self._reach = reach + np.radians(acquisition.MAX_ROT_DEG * max(c.head_motion, 1.0)) * max(c.width, c.height)
        x0, y0, x1, y1 = self.head.bbox(pad=int(np.ceil(self._reach)) + 4)
        self._crop = (x0, y0, x1, y1)
        cw = x1 - x0

        def to_crop(flat):
            return (flat // c.width - y0) * cw + (flat % c.width - x0)

        self._crop_pix = to_crop(self.surface.pix.astype(np.int64))
        self._crop_edge = to_crop(self._edge_dst)
        crop_alpha = self.head.alpha[y0:y1, x0:x1]
        self._crop_rgba = np.zeros((y1 - y0, cw, 4), dtype=FLOAT)
        self._crop_rgba[..., 3] = crop_alpha
        self._ambient_head: np.ndarray | None = None
        self._flash_layers: dict[int, np.ndarray] = {}

    # ------------------------------------------------------------------ truth
    def _truth_lights(self, env: np.ndarray) -> Lights:
        return environment_to_lights(env, grid=TRUTH_GRID, pole="z", keep_grid=True,
                                     peak_factor=TRUTH_PEAK_FACTOR, max_peaks=TRUTH_MAX_PEAKS)

    def render_truth(self) -> dict[str, np.ndarray]:
        """Truth at the reference pose: name -> (P, 3) radiance at the head's shaded pixels.

        Names: each truth environment's stem, ``olat_<name>`` for :data:`OLAT_DIRECTIONS`,
        and ``ambient`` (the room light of the no-flash frames, ambient strength applied).
        """
        c = self.config
        outputs: list[tuple[str, Lights]] = []
        for src in c.truth_envs:
            outputs.append((environment_stem(src), self._truth_lights(load_environment(src))))
        outputs.append(("ambient", self._truth_lights(self.room)))
        for name, direction in OLAT_DIRECTIONS.items():
            v = np.asarray(direction, dtype=np.float64)
            outputs.append((f"olat_{name}", Lights(dirs=(v / np.linalg.norm(v))[None],
                                                   power=np.full((1, 3), np.pi * FLASH_STRENGTH),
                                                   column=np.array([-1]), n_grid=0)))
        groups = [outputs[i:i + OUTPUTS_PER_PASS] for i in range(0, len(outputs), OUTPUTS_PER_PASS)]
        passes = [_union([lights for _, lights in g]) for g in groups]
        with tqdm(total=self.surface.pix.size, desc="shadow horizons", unit="px", disable=not self.progress,
                  leave=False) as hbar:
            self.shader.prepare_horizons(TRUTH_GRID[0], progress=hbar)
        bar = tqdm(total=sum(d.shape[0] for d, _, _ in passes), desc="truth lights", unit="light",
                   disable=not self.progress, leave=False)
        results: dict[str, np.ndarray] = {}
        for group, (dirs, power, column) in zip(groups, passes, strict=True):
            acc = self._shade_batched(dirs, power, column, bar=bar)
            for (name, _), img in zip(group, acc, strict=True):
                results[name] = require_finite(f"truth {name}", img.astype(FLOAT))
        bar.close()
        self._ambient_head = results["ambient"]
        return results

    # ------------------------------------------------------------------ frames
    def ambient_head(self) -> np.ndarray:
        """(P, 3) head radiance under the room light at the reference pose."""
        if self._ambient_head is None:
            lights = self._truth_lights(self.room)
            self._ambient_head = self._shade_batched(lights.dirs, lights.power, lights.column)[0].astype(FLOAT)
        return self._ambient_head

    def _shade_batched(self, dirs: np.ndarray, power: np.ndarray, column: np.ndarray, *, view=(0.0, 0.0, 1.0),
                       bar=None) -> np.ndarray:
        """(E, P, 3) float64: the shader's outputs for lights ``dirs`` (L, 3) with ``power`` (L, E, 3)
        or (L, 3) and horizon ``column`` (L,), summed over batches of LIGHT_BATCH lights (the
        horizon table at TRUTH_GRID prepared first if it is not). ``bar``: a tqdm bar told of
        each batch's lights."""
        if self.shader.n_dir != TRUTH_GRID[0]:
            self.shader.prepare_horizons(TRUTH_GRID[0])
        n_out = 1 if np.ndim(power) == 2 else power.shape[1]
        acc = np.zeros((n_out, self.surface.pix.size, 3), dtype=np.float64)
        for a in range(0, dirs.shape[0], LIGHT_BATCH):
            sl = slice(a, a + LIGHT_BATCH)
            acc += self.shader.shade(dirs[sl], power[sl], direction_index=column[sl], view=view)
            if bar is not None:
                bar.update(dirs[sl].shape[0])
        return acc

    def turned_head_radiance(self, envs: list[np.ndarray], rotation: np.ndarray) -> list[np.ndarray]:
        """(P, 3) radiance of the head's shaded pixels under each environment (lat-long, linear,
        camera frame) with the head turned by ``rotation`` (3, 3): the full shading of the
        truth (cast shadows, specular), computed in the head's own frame - the environments
        turned into it (what the camera frame sees toward ``d``, the head sees toward
        ``R^T d``) and the camera seen from ``R^T z``. The head is rigid, so its self-shadowing
        turns with it; radiance is per reference-pose pixel (move it with the live head's mesh).
        """
        r = np.asarray(rotation, dtype=np.float64)
        if r.shape != (3, 3) or not np.isfinite(r).all():
            raise InputError("rotation must be a finite 3x3 matrix")
        view = r.T @ np.array([0.0, 0.0, 1.0])
        out: list[np.ndarray] = []
        for start in range(0, len(envs), OUTPUTS_PER_PASS):
            group = [self._truth_lights(rotate_environment(env, r.T)) for env in envs[start:start + OUTPUTS_PER_PASS]]
            acc = self._shade_batched(*_union(group), view=view)
            out.extend(require_finite("turned head radiance", img.astype(FLOAT)) for img in acc)
        return out

    def head_image(self, radiance: np.ndarray) -> np.ndarray:
        """(P, 3) radiance at shaded pixels -> (H, W, 3) image, silhouette fringe filled, 0 elsewhere."""
        c = self.config
        img = np.zeros((c.height * c.width, 3), dtype=FLOAT)
        img[self.surface.pix] = radiance
        img[self._edge_dst] = radiance[self._edge_src]
        return img.reshape(c.height, c.width, 3)

    def flash_radiance(self, frame: int) -> np.ndarray:
        """(P, 3) head radiance added by the flash(es) during ``frame`` (head-frame light directions)."""
        lit = self.lit[frame]
        if not lit:
            return np.zeros((self.surface.pix.size, 3), dtype=FLOAT)
        # The head is rolled by rot about +Z; in its own frame the light is rolled back.
        to_head = rotation_matrix(roll=-self.motion[frame, 2])
        dirs = np.array([to_head @ np.asarray(self.pulses[k].direction) for k, _ in lit])
        power = np.array([[np.full(3, np.pi * FLASH_STRENGTH * f * self.pulses[k].strength)] for k, f in lit])
        return self.shader.shade(dirs, power)[0]

    def _flash_layer(self, k: int) -> np.ndarray:
        layer = self._flash_layers.get(k)
        if layer is None:
            p = self.pulses[k]
            layer = self.sphere.flash_layer(np.asarray(p.direction), FLASH_STRENGTH * p.strength)
            self._flash_layers[k] = layer
        return layer

    @cached_property
    def _static_layers(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The wall under the room light (H, W, 3), the sphere's reflection of the room and its coverage."""
        room = environment_to_lights(self.room, grid=(64, 32))
        e_front = float((room.power.mean(axis=1) * np.clip(room.dirs[:, 2], 0, None)).sum())
        wall_amb = (self.wall_albedo * (e_front / np.pi))[..., None] * np.ones(3, dtype=FLOAT)
        s_rad, s_cov = self.sphere.ambient_layer(self.room)
        return wall_amb.astype(FLOAT), s_rad, s_cov

    def render_frame(self, frame: int, *, flash: np.ndarray | None = None) -> np.ndarray:
        """Linear frame ``frame`` as the scene presents it to the sensor (before gain, noise, sRGB).

        (H, W, 3) float32, linear Rec.709. ``flash`` overrides the head's flash radiance
        (P, 3) - the truth test re-renders frames from the recorded light directions.
        """
        wall_amb, s_rad, s_cov = self._static_layers
        lit = self.lit[frame]
        head = self.ambient_head() + (self.flash_radiance(frame) if flash is None else flash)
        # Background: the wall (ambient + its share of the flash), then the sphere over it.
        wall_flash = sum(f * self.pulses[k].strength * max(self.pulses[k].direction[2], 0.0)
                         for k, f in lit) * WALL_FLASH * FLASH_STRENGTH
        out = wall_amb.copy() if wall_flash == 0 else wall_amb + (self.wall_albedo * np.float32(wall_flash))[..., None]
        x0, y0, x1, y1 = self.sphere.bbox
        region = out[y0:y1, x0:x1]
        region[:] = s_rad + (1.0 - s_cov[..., None]) * region
        for k, f in lit:
            region += np.float32(f) * self._flash_layer(k)
        if self.camera is not None:  # the head moved in space, seen through the pinhole
            (hx0, hy0, hx1, hy1), moved, cov = posed_layer(self.head_mesh, self.head_image(head), self.motion[frame])
            dst = out[hy0:hy1, hx0:hx1]
            dst[:] = moved + (1.0 - cov[..., None]) * dst
            return out
        # The head: premultiplied by coverage, moved by this frame's rigid motion.
        hx0, hy0, hx1, hy1 = self._crop
        rgba = self._crop_rgba.copy()
        flat = rgba.reshape(-1, 4)
        flat[self._crop_pix, :3] = head
        flat[self._crop_edge, :3] = head[self._edge_src]
        rgba[..., :3] *= rgba[..., 3:]
        m = self.matrices[frame].copy()
        m[:, 2] += m[:, :2] @ np.array([hx0, hy0]) - np.array([hx0, hy0])
        moved = cv2.warpAffine(rgba, m, (hx1 - hx0, hy1 - hy0), flags=cv2.INTER_LINEAR,
                               borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        dst = out[hy0:hy1, hx0:hx1]
        dst[:] = moved[..., :3] + (1.0 - moved[..., 3:]) * dst
        return out

    @property
    def head_mesh(self):
        """The head as a mesh that renders through :attr:`camera` (:func:`.pinhole_view.capture_mesh`),
        built on first use (it needs :meth:`ambient_head`)."""
        if self._head_mesh is None:
            c = self.config
            reach = self._reach if self.camera is None else \
                neck_reach(self._reach, c.height, self.head.scale, self.camera)
            self._head_mesh = capture_mesh(self.head, self.ambient_head(), self.room, self.pivot,
                                           reach_px=reach, camera=self.camera, mesh=self.mesh,
                                           placement=self.placement)
        return self._head_mesh

    def pinhole_truth(self, images: list[np.ndarray]) -> tuple[list[np.ndarray], np.ndarray]:
        """Reference-pose images (the orthographic reference's pixels, (H, W) or (H, W, C)) as
        the capture's reference frame shows them through the pinhole
        (:func:`.pinhole_view.reference_view`: 0 off the head), and the head's mask there."""
        if self.camera is None:
            raise InputError("an orthographic capture's truth is its reference images as they are")
        return reference_view(self.head_mesh, images, self.head.mask)

    def camera_frame(self, frame: int, *, noisy: bool = True, flash: np.ndarray | None = None) -> np.ndarray:
        """(H, W, 3) uint8 sRGB frame as the phone records it (``flash``: see :meth:`render_frame`)."""
        key = (self.noise_seed, frame) if noisy else None
        return self.sensor.expose(self.render_frame(frame, flash=flash), self.gain[frame],
                                  self.white_balance[frame], key)

    # ------------------------------------------------------------------ metadata
    def meta(self) -> dict:
        """The truth's ``meta.json`` content."""
        c = self.config
        # Frames an aimed flash (one that reaches the face) lit for most of their exposure.
        aimed = [sum(f for k, f in self.lit[i] if self.pulses[k].strength >= 0.5) for i in range(self.n)]
        flash_frames = [i for i in range(self.n) if aimed[i] > 0.5]
        light_dirs = {}
        for i in flash_frames:
            k = max(self.lit[i], key=lambda kf: kf[1] * self.pulses[kf[0]].strength)[0]
            light_dirs[str(i)] = [round(x, 7) for x in self.pulses[k].direction]
        cx, cy, r = self.sphere.cx, self.sphere.cy, self.sphere.r
        cfg = asdict(c)
        cfg["truth_envs"] = list(c.truth_envs)
        return {
            "format": "relight-synth-truth",
            "version": TRUTH_FORMAT_VERSION,
            "config": cfg,
            "fps": c.fps,
            "size": [c.width, c.height],
            "frame_count": self.n,
            "flash_hz": c.flash_hz,
            "exposure_time": self.exposure_time,
            "flash_frames": flash_frames,
            "light_dirs": light_dirs,
            "flash_fraction": [round(float(f), 5) for f in self.fraction],
            "flash_level": [round(float(f), 5) for f in self.level],
            "pulses": [{"start": round(p.start, 6), "end": round(p.end, 6), "strength": round(p.strength, 5),
                        "direction": [round(x, 7) for x in p.direction]} for p in self.pulses],
            "sphere": [cx, cy, r],
            "head_center": list(self.head.center),
            "head_scale": self.head.scale,
            "head": head_info(c.head_mesh),
            "head_motion": [[round(float(x), 6) for x in row] for row in self.motion],
            "reference_frame": self.reference_frame,
            "exposure_gain": [round(float(g), 6) for g in self.gain],
            "white_balance": [[round(float(x), 6) for x in row] for row in self.white_balance],
            "sensor": {"read_noise": self.sensor.read_noise, "shot_gain": self.sensor.shot_gain},
            "flash_strength": FLASH_STRENGTH,
            "conventions": {
                "camera": "+X right in the image, +Y up, +Z toward the camera; light_dirs point from the face "
                          "toward the light",
                "head_motion": "[tx, ty, rot_deg] per frame: reference pixel p moves to R(rot)(p - c) + c + t, "
                               "c = head_center, rot counter-clockwise on screen (cv2.getRotationMatrix2D sign)",
                "flash_frames": "frames an aimed flash (strength >= 0.5: it reached the face) lit for more than "
                                "half of their exposure",
                "flash_level": "per frame, share of the exposure with the flash on times the pulse's strength",
                "flash_fraction": "per frame, share of the exposure during which a flash was on",
                "radiometry": "linear Rec.709; the flash is a directional light of power pi (a white Lambertian "
                              "surface facing it reads 1); relit_*/olat_* at the reference pose, gain 1, no noise, "
                              "ambient off; frame = sRGB(clip(gain * white_balance * scene + noise))",
                "depth": "height toward the camera in pixels (orthographic camera), 0 off the mask",
                "mesh": "head.ply vertices are (column, -row, height) in pixels",
            } | ({} if self.camera is None else PINHOLE_CONVENTIONS),
            "camera": ORTHOGRAPHIC_META if self.camera is None else self.camera.meta(),
        } | ({} if self.camera is None else {"pivot": [float(self.pivot[0]), float(-self.pivot[1]),
                                                       float(self.pivot[2])]})


#: A capture through a pinhole (``fov``): the conventions that differ from the orthographic one's.
PINHOLE_CONVENTIONS = {
    "head_motion": "[tx, ty, rot_deg] per frame, a motion of the head in space: a head point P = (x, -y, h) "
                   "(column x, row y, height h of the orthographic reference, pixels) moves to "
                   "Rz(rot) (P - C) + C + (tx, -ty, 0), C = (pivot[0], -pivot[1], pivot[2]), rot counter-clockwise "
                   "on screen, and is seen through the pinhole (camera): column cx + f (P'x - cx) / (eye_z - P'z), "
                   "row cy + f (-P'y - cy) / (eye_z - P'z)",
    "truth_images": "relit_*, olat_*, normals, albedo, depth and mask are the reference pose through the pinhole: "
                    "each pixel the mean over its samples on the head (2x2 a pixel), the mask where at least half "
                    "of them are",
    "depth": "height toward the camera (camera-space Z, pixels of the orthographic reference) of the surface "
             "seen at each pixel through the pinhole, 0 off the mask",
    "mesh": "head.ply vertices are camera-space points (column, -row, height) of the orthographic reference, in "
            "pixels: project them through the camera to meet the images",
    "sphere": "the ball's centre lies on the ray through image point (sphere[0], sphere[1]) at the camera's "
              "distance_px from the eye, its radius sphere[2] * distance_px / focal_px",
}


def _union(group: list[Lights]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Lights of several outputs as one list: the shared grid cells first, then each output's own.

    Returns dirs (L, 3), power (L, E, 3) and grid column (L,) (-1: march this light); lights
    with no power in any output are dropped.
    """
    n_out = len(group)
    grid = TRUTH_GRID[0] * TRUTH_GRID[1]
    base = next((lights for lights in group if lights.n_grid), None)
    dirs_parts, pow_parts, col_parts = [], [], []
    if base is not None:
        base_pow = np.zeros((grid, n_out, 3))
        for e, lights in enumerate(group):
            if lights.n_grid:
                base_pow[:, e] = lights.power[:grid]
        dirs_parts.append(base.dirs[:grid])
        pow_parts.append(base_pow)
        col_parts.append(base.column[:grid])
    for e, lights in enumerate(group):
        own = slice(lights.n_grid, None)
        pe = np.zeros((lights.dirs[own].shape[0], n_out, 3))
        pe[:, e] = lights.power[own]
        dirs_parts.append(lights.dirs[own])
        pow_parts.append(pe)
        col_parts.append(lights.column[own])
    dirs = np.concatenate(dirs_parts)
    power = np.concatenate(pow_parts)
    column = np.concatenate(col_parts)
    keep = power.sum(axis=(1, 2)) > 0
    return dirs[keep], power[keep], column[keep]


def synthesize(out: str | Path, config: SynthConfig | None = None, *, progress: bool = True) -> SynthResult:
    """Simulate a capture: write ``out/capture.mp4`` and the truth in ``out/truth/`` (``config``:
    the default :class:`SynthConfig` when None)."""
    config = SynthConfig() if config is None else config
    t_all = time.perf_counter()
    out = Path(out)
    truth = out / "truth"
    truth.mkdir(parents=True, exist_ok=True)
    studio = Studio(config, progress=progress)
    c = studio.config
    timings = dict(studio.timings)

    t0 = time.perf_counter()
    renders = studio.render_truth()
    timings["truth_render"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    head = studio.head
    names = [name for name in renders if name != "ambient"]
    if studio.camera is None:
        lit = [studio.head_image(renders[name]) * head.mask[..., None] for name in names]
        mask, normals, albedo = head.mask, head.normal, head.albedo
        depth = np.where(head.mask, head.height, 0.0).astype(FLOAT)
    else:  # the reference frame's view through the pinhole
        seen, mask = studio.pinhole_truth([studio.head_image(renders[name]) for name in names]
                                          + [head.normal, head.height, head.albedo])
        *lit, normals, depth, albedo = seen
        normals = normals / np.maximum(np.linalg.norm(normals, axis=2, keepdims=True), EPS_NORM)
    for name, img in zip(names, lit, strict=True):
        write_image(truth / (f"{name}.exr" if name.startswith("olat_") else f"relit_{name}.exr"), img)
    no_flash = np.zeros_like(renders["ambient"])
    write_image(truth / "ambient.exr", studio.render_frame(studio.reference_frame, flash=no_flash))
    write_image(truth / "mask.png", mask.astype(np.uint8) * 255)
    write_image(truth / "normals.exr", normals.astype(FLOAT))
    write_image(truth / "depth.exr", depth)
    write_image(truth / "albedo.exr", albedo)
    with atomic_path(truth / "head.ply") as tmp:
        if studio.mesh is not None:  # the mesh itself, posed as the reference frame shows it
            import trimesh

            trimesh.Trimesh(studio.placement.project(studio.mesh.vertices), studio.mesh.faces,
                            process=False).export(str(tmp), file_type="ply")
        else:
            height_field_mesh(head.height, head.mask).export(str(tmp), file_type="ply")
    timings["truth_write"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    video = out / "capture.mp4"
    t_render = 0.0
    with VideoWriter(video, c.fps, (c.width, c.height), crf=c.crf) as writer:
        for i in tqdm(range(studio.n), desc="frames", unit="frame", disable=not progress, leave=False):
            t1 = time.perf_counter()
            rgb = studio.camera_frame(i)
            t_render += time.perf_counter() - t1
            writer.write(rgb)
    timings["frames_render"] = t_render
    timings["frames_total"] = time.perf_counter() - t0

    meta = studio.meta()
    meta["files"] = {"video": "capture.mp4", "mask": "truth/mask.png", "normals": "truth/normals.exr",
                     "depth": "truth/depth.exr", "albedo": "truth/albedo.exr", "ambient": "truth/ambient.exr",
                     "mesh": "truth/head.ply",
                     "relit": {environment_stem(e): f"truth/relit_{environment_stem(e)}.exr" for e in c.truth_envs},
                     "olat": {f"olat_{k}": f"truth/olat_{k}.exr" for k in OLAT_DIRECTIONS}}
    meta["envs"] = {environment_stem(e): e for e in c.truth_envs}
    meta["olat_dirs"] = {f"olat_{k}": [float(x) for x in np.asarray(v) / np.linalg.norm(v)]
                         for k, v in OLAT_DIRECTIONS.items()}
    with atomic_path(truth / "meta.json") as tmp:
        tmp.write_text(json.dumps(meta, indent=1))
    timings["total"] = time.perf_counter() - t_all
    return SynthResult(out=out, video=video, truth=truth, frame_count=studio.n,
                       flash_frames=len(meta["flash_frames"]), timings=timings)


def cached_synthesis(out: str | Path, config: SynthConfig, *, label: str, progress: bool = True) -> Path:
    """``out/synth-<hash of the settings>``: synthesised the first time, reused while its truth
    is there (the benchmarks' cache; any change of a setting makes a new folder)."""
    settings = asdict(config)
    if config.fov is None:  # an orthographic capture keeps the folder it had before the camera's settings
        del settings["fov"], settings["distance"]
    key = hashlib.sha1(json.dumps(settings, sort_keys=True).encode()).hexdigest()[:10]
    cap = Path(out) / f"synth-{key}"
    if not (cap / "truth" / "meta.json").exists():
        if progress:
            print(f"synthesising {label} ...", flush=True)
        synthesize(cap, config, progress=progress)
    return cap
