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
image) at a depth of :data:`.pivot.PIVOT_DEPTH` head units (half the crown-to-chin height = ``0.5 *
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

import numpy as np
from tqdm import tqdm

from relight.directions import rotation_matrix
from relight.envmap import environment_stem, load_environment
from relight.errors import InputError
from relight.imageio import atomic_path, write_image
from relight.numerics import FLOAT
from relight.spherical_harmonics import environment_sh9
from relight.video_write import AUDIO_RATE, VideoWriter

from .config import MAX_SIZE, MIN_SIZE, SynthConfig, head_info
from .mesh_render import MeshLiveHead
from .motion import (
    AUDIO_KINDS,
    NOISE_RMS,
    START_EASE_S,
    TONE_HZ,
    TONE_PEAK,
    head_pose_track,
    make_audio,
    start_from,
)
from .pinhole import DEFAULT_DISTANCE_CM, ORTHOGRAPHIC_META, Pinhole, check_camera
from .pivot import neck_reach
from .render import LiveHead
from .studio import Studio

LIVE_FORMAT_VERSION = 1
#: ``shift = 1`` moves the head up to this fraction of the frame height each way (x and y).
SHIFT_FRACTION = 0.04
#: Largest rotation amplitudes (degrees) a height field can show without revealing what it lacks.
MAX_AMPLITUDE = {"yaw": 45.0, "pitch": 30.0, "roll": 45.0}
MAX_SHIFT = 5.0
#: Largest start pose (degrees, yaw and pitch) of a height-field head (its amplitudes' limits) and
#: of a mesh head (all of it is there: a webcam's turned heads, issue 49's -60..60 yaw).
START_LIMIT = {"yaw": MAX_AMPLITUDE["yaw"], "pitch": MAX_AMPLITUDE["pitch"]}
START_LIMIT_MESH = {"yaw": 75.0, "pitch": 45.0}
#: Frames rendered at once on worker threads (at most one per CPU).
RENDER_THREADS = 4


@dataclass(frozen=True)
class LiveConfig:
    """Settings of one synthetic live video (``relight synth OUT --live``).

    yaw, pitch, roll : rotation amplitudes in degrees (the pose stays within +-amplitude).
    start_yaw, start_pitch : the pose (degrees) the clip starts from, eased into its motion over
    :data:`.motion.START_EASE_S` (None: the motion's own start); up to :data:`START_LIMIT` (a
    height-field head) or :data:`START_LIMIT_MESH` (a mesh head).
    shift : translation amplitude, times :data:`SHIFT_FRACTION` of the frame height (x and y).
    ambient, noise : room light strength and sensor noise, times the studio's defaults.
    audio : ``tone`` (440 Hz), ``noise`` (white) or ``none`` (no audio stream).
    fov, distance : a pinhole camera of that horizontal field of view (degrees) at that distance
    (cm) from the head (:mod:`.pinhole`); ``fov`` None: the orthographic camera (``distance`` unused).
    """

    width: int = 960
    height: int = 540
    fps: float = 30.0
    duration: float = 10.0
    seed: int = 0
    yaw: float = 30.0
    pitch: float = 15.0
    roll: float = 8.0
    start_yaw: float | None = None
    start_pitch: float | None = None
    shift: float = 1.0
    ambient: float = 1.0
    noise: float = 1.0
    crf: int = 18
    audio: str = "tone"
    #: A textured head mesh instead of the procedural head (as :class:`.config.SynthConfig`'s).
    head_mesh: str | None = None
    head_texture: str | None = None
    head_normal_map: str | None = None
    head_specular_map: str | None = None
    head_texture_flip: bool = False
    #: Environments to render the person under at every frame's pose (the live frame's truth:
    #: ``truth/live_<stem>/NNNN.png`` and ``truth/silhouette/NNNN.png``); none by default.
    truth_envs: tuple[str, ...] = ()
    fov: float | None = None
    distance: float = DEFAULT_DISTANCE_CM

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
        limits = START_LIMIT_MESH if self.head_mesh else START_LIMIT
        for name, top in limits.items():
            val = getattr(self, f"start_{name}")
            if val is not None and not (np.isfinite(val) and -top <= val <= top):
                raise InputError(f"--start-{name} {val}: use -{top:g} to {top:g} degrees"
                                 + ("" if self.head_mesh else " for the procedural head (a height field turned "
                                    "further shows the sides it does not have; a --head-mesh head turns further)"))
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
        check_camera(self.fov, self.distance)
        stems = [environment_stem(e) for e in self.truth_envs]
        if len(set(stems)) != len(stems):
            raise InputError(f"--truth-env: environments must have distinct names, got {stems}")
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


class LiveScene:
    """One live video's scene: the studio's head, wall and sensor, the mesh head, the motion."""

    def __init__(self, config: LiveConfig):
        self.config = c = config.validate()
        t0 = time.perf_counter()
        # The static studio of the same seed and size: same head, same wall, same sensor model.
        self.studio = Studio(SynthConfig(width=c.width, height=c.height, seed=c.seed, ambient=c.ambient,
                                         noise=c.noise, duration=1.0, head_mesh=c.head_mesh,
                                         head_texture=c.head_texture, head_normal_map=c.head_normal_map,
                                         head_specular_map=c.head_specular_map,
                                         head_texture_flip=c.head_texture_flip))
        self.head = self.studio.head
        self.timings = {"head": time.perf_counter() - t0}
        seeds = np.random.SeedSequence([c.seed, 0x11FE]).spawn(3)
        rng_motion, rng_audio, noise = seeds
        self.noise_seed = int(noise.generate_state(1)[0])
        self.n = c.frame_count
        self.rotations, self.translations = head_pose_track(
            np.random.default_rng(rng_motion), self.n, c.fps, (c.yaw, c.pitch, c.roll), c.shift_px)
        if c.start_yaw is not None or c.start_pitch is not None:
            self.rotations = start_from(self.rotations, c.fps, (c.start_yaw, c.start_pitch, None))
        self.audio = make_audio(c.audio, int(round(self.n / c.fps * AUDIO_RATE)), np.random.default_rng(rng_audio))
        self.pivot = self.studio.pivot
        #: The frames' camera: a pinhole (``fov``) or None (orthographic).
        self.camera = None if c.fov is None else Pinhole.from_fov((c.width, c.height), c.fov, c.distance,
                                                                   self.head.scale, self.pivot[2])
        self.sensor = self.studio.sensor
        self._mesh: LiveHead | MeshLiveHead | None = None

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
        ang = np.radians(min(max(c.pitch, abs(c.start_pitch or 0.0)) + c.roll, 90.0))
        reach = drop * (1.0 - np.cos(ang)) + self.head.scale * np.sin(ang) + c.shift_px
        if self.camera is not None:  # a wide lens shows less of the neck below the pivot: reach farther
            reach = neck_reach(reach, self.head.mask.shape[0], self.head.scale, self.camera)
        if self.studio.mesh is not None:
            self._mesh = MeshLiveHead(self.studio.mesh, self.studio.placement, self.head, radiance, self.studio.room,
                                      self.pivot, camera=self.camera)
        else:
            self._mesh = LiveHead(self.head, radiance, self.studio.room, self.pivot, reach_px=reach, camera=self.camera)
        self.wall = self.studio._static_layers[0]
        self.timings["mesh"] = time.perf_counter() - t0

    @property
    def mesh(self) -> LiveHead | MeshLiveHead:
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

    def render_lit(self, rotation: np.ndarray, translation, envs: list[np.ndarray]
                   ) -> tuple[list[np.ndarray], np.ndarray]:
        """The person under each environment (lat-long, linear, camera frame) at a pose: linear
        frames (H, W, 3) float32 - the head with its full shading there (cast shadows and
        specular from the studio's shader, the light turned into the head's frame), the
        background the room-lit wall, untouched - and the head's coverage (H, W)."""
        radiance = self.studio.turned_head_radiance(envs, rotation)
        mesh = self.mesh
        frames, coverage = [], np.zeros(self.wall.shape[:2], dtype=FLOAT)
        for env, rad in zip(envs, radiance, strict=True):
            img = self.studio.head_image(rad)
            if isinstance(mesh, MeshLiveHead):
                (x0, y0, x1, y1), head, cov = mesh.render(rotation, translation, lit=(img, environment_sh9(env)))
            else:
                (x0, y0, x1, y1), head, cov = mesh.render(rotation, translation, mesh.vertex_values(img))
            out = self.wall.copy()
            dst = out[y0:y1, x0:x1]
            dst[:] = head + (1.0 - cov[..., None]) * dst
            coverage[y0:y1, x0:x1] = cov
            frames.append(out)
        return frames, coverage

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
            "start_pose": {"yaw": c.start_yaw, "pitch": c.start_pitch,
                           "ease_s": min(START_EASE_S, 0.5 * self.n / c.fps)}
            if c.start_yaw is not None or c.start_pitch is not None else None,
            "head_center": list(self.head.center),
            "head_scale": self.head.scale,
            "head": head_info(c.head_mesh),
            "camera": ORTHOGRAPHIC_META if self.camera is None else self.camera.meta(),
            "reference_pose": {"head_rotation": [0.0, 0.0, 0.0], "head_translation": [0.0, 0.0]},
            "sensor": {"read_noise": self.sensor.read_noise, "shot_gain": self.sensor.shot_gain,
                       "exposure_gain": 1.0, "white_balance": [1.0, 1.0, 1.0]},
            "audio": audio,
            "conventions": (
                "Camera space as in the README: +X right in the image, +Y up, +Z toward the camera, "
                + ("orthographic camera looking along -Z" if self.camera is None else
                   "pinhole camera looking along -Z (camera: its focal length and principal point in pixels, its "
                   "eye at camera-space (principal column, -principal row, eye_z))")
                + ". head_rotation is [yaw, pitch, roll] in degrees per frame, relative to "
                "the reference pose (the head as built, the pose of the static `relight synth` capture's "
                "reference frame, same seed and size): R = Ry(yaw) Rx(pitch) Rz(roll), right-handed rotations "
                "about camera +Y, +X, +Z (relight.directions.rotation_matrix). A head point at image column x, "
                "row y with height h (pixels toward the camera) is P = (x, -y, h); at a frame it moves to "
                "P' = R (P - C) + C + (tx, -ty, 0), where C = (pivot[0], "
                "-pivot[1], pivot[2]) with pivot = [column, row, height] in pixels and head_translation = "
                "[tx, ty] in pixels (ty down) of the reference plane"
                + (". It is seen at column P'x, row -P'y" if self.camera is None else
                   ". It is seen at column cx + f (P'x - cx) / (eye_z - P'z), row cy + f (-P'y - cy) / (eye_z - P'z) "
                   "(f = focal_px, (cx, cy) = principal_point; a head unit, head_scale px, is head_unit_cm)")
                + ". Frames are instants t = i / fps (no motion blur)."),
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
    if c.truth_envs:
        t0 = time.perf_counter()
        meta["files"].update(write_live_truth(scene, truth, progress=progress))
        meta["envs"] = {environment_stem(e): e for e in c.truth_envs}
        timings["truth_frames"] = time.perf_counter() - t0
    meta_path = truth / "meta.json"
    with atomic_path(meta_path) as tmp:
        tmp.write_text(json.dumps(meta, indent=1))
    timings["total"] = time.perf_counter() - t_all
    return LiveResult(out=out, video=video, truth=truth, meta=meta_path, reference=reference, mask=mask,
                      frame_count=scene.n, timings=timings)


def write_live_truth(scene: LiveScene, truth: Path, *, progress: bool = False) -> dict:
    """Every frame of the clip with the person under each of the scene's truth environments
    (``truth/live_<stem>/NNNN.png``: 8-bit sRGB, the camera's exposure, no sensor noise, the
    background untouched) and the person's pixels (``truth/silhouette/NNNN.png``: 0 or 255,
    coverage over one half). Returns the ``meta["files"]`` entries (printf patterns)."""
    c = scene.config
    stems = [environment_stem(e) for e in c.truth_envs]
    envs = [load_environment(e) for e in c.truth_envs]
    folders = {stem: truth / f"live_{stem}" for stem in stems}
    sil = truth / "silhouette"
    for folder in (*folders.values(), sil):
        folder.mkdir(parents=True, exist_ok=True)
    for i in tqdm(range(scene.n), desc="truth frames", unit="frame", disable=not progress, leave=False):
        frames, coverage = scene.render_lit(*scene.pose(i), envs)
        for stem, linear in zip(stems, frames, strict=True):
            write_image(folders[stem] / f"{i:04d}.png", scene.expose(linear, None))
        write_image(sil / f"{i:04d}.png", ((coverage > 0.5) * 255).astype(np.uint8))
    return {"live_truth": {stem: f"truth/live_{stem}/%04d.png" for stem in stems},
            "silhouette": "truth/silhouette/%04d.png"}
