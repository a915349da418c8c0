"""What one synthetic capture is asked for (:class:`SynthConfig`, the ``relight synth`` flags,
validated) and what it wrote (:class:`SynthResult`); :mod:`.studio` renders it."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from relight.envmap import environment_stem
from relight.errors import InputError

from .pinhole import DEFAULT_DISTANCE_CM, check_camera

#: The environments a capture's truth is rendered under unless told otherwise.
DEFAULT_TRUTH_ENVS = ("builtin:studio", "builtin:sunset", "builtin:window", "builtin:uniform")
#: Frame sizes a capture may have (width, height).
MAX_SIZE = (3840, 2160)
MIN_SIZE = (128, 72)


@dataclass(frozen=True)
class SynthConfig:
    """Settings of one synthetic capture (the ``relight synth`` flags)."""

    width: int = 960
    height: int = 540
    fps: float = 30.0
    flash_hz: float = 5.0
    duration: float = 60.0
    seed: int = 0
    head_motion: float = 1.0
    ambient: float = 1.0
    noise: float = 1.0
    camera_drift: bool = False
    sparse_sides: bool = False
    truth_envs: tuple[str, ...] = DEFAULT_TRUTH_ENVS
    crf: int = 16
    #: A textured head mesh instead of the procedural head (:mod:`.mesh_head`), its colour map when
    #: not embedded, optional normal and specular maps, and whether its images are stored the
    #: other way up from its texture coordinates.
    head_mesh: str | None = None
    head_texture: str | None = None
    head_normal_map: str | None = None
    head_specular_map: str | None = None
    head_texture_flip: bool = False
    #: A pinhole camera of that horizontal field of view (degrees) at that distance (cm) from the
    #: head (:mod:`.pinhole`, :mod:`.pinhole_view`); ``fov`` None: the orthographic camera.
    fov: float | None = None
    distance: float = DEFAULT_DISTANCE_CM

    def validate(self) -> SynthConfig:
        """Return self, or raise :class:`InputError` naming the setting to change."""
        w, h = self.width, self.height
        if not (MIN_SIZE[0] <= w <= MAX_SIZE[0] and MIN_SIZE[1] <= h <= MAX_SIZE[1]) or w % 2 or h % 2:
            raise InputError(f"--size {w}x{h}: use even numbers between {MIN_SIZE[0]}x{MIN_SIZE[1]} "
                             f"and {MAX_SIZE[0]}x{MAX_SIZE[1]}")
        if not (5.0 <= self.fps <= 240.0):
            raise InputError(f"--fps {self.fps}: use 5 to 240 frames per second")
        if not (0.5 <= self.flash_hz <= self.fps / 4):
            raise InputError(f"--flash-hz {self.flash_hz}: use 0.5 Hz up to a quarter of the frame rate "
                             f"({self.fps / 4:g} Hz) so dark frames exist between flashes")
        if not (1.0 <= self.duration <= 600.0):
            raise InputError(f"--duration {self.duration}: use 1 to 600 seconds")
        for name in ("head_motion", "ambient", "noise"):
            val = getattr(self, name)
            if not (np.isfinite(val) and 0.0 <= val <= 20.0):
                raise InputError(f"--{name.replace('_', '-')} {val}: use a number from 0 to 20")
        if self.ambient <= 0:
            raise InputError("--ambient must be > 0: the no-flash frames need some light to track the head")
        if not self.truth_envs:
            raise InputError("give at least one truth environment")
        if self.head_mesh is None and any((self.head_texture, self.head_normal_map, self.head_specular_map)):
            raise InputError("--head-texture, --head-normal-map and --head-specular-map go with --head-mesh FILE")
        check_camera(self.fov, self.distance)
        stems = [environment_stem(e) for e in self.truth_envs]
        if len(set(stems)) != len(stems):
            raise InputError(f"truth environments must have distinct names, got {stems}")
        return self

    @property
    def frame_count(self) -> int:
        return int(round(self.duration * self.fps))


@dataclass
class SynthResult:
    """What :func:`synthesize` wrote and how long each part took (seconds)."""

    out: Path
    video: Path
    truth: Path
    frame_count: int
    flash_frames: int
    timings: dict = field(default_factory=dict)


def head_info(mesh: str | None) -> dict:
    """What head a clip shows (its truth's ``head``): procedural, or a mesh with the credit its
    pictures must carry (a shipped head's; None for a user's mesh)."""
    if mesh is None:
        return {"kind": "procedural", "mesh": None, "credit": None}
    from .mesh_head import head_credit

    return {"kind": "mesh", "mesh": str(mesh), "credit": head_credit(mesh)}
