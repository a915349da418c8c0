"""What passes between the per-frame path's halves (STYLE 19: typed packets): a frame's
:class:`Front` - what tracking and the head pose found, all the second half reads - and the
:class:`FrameInfo` both halves fill (what happened to the frame, and which slow stages ran)."""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from relight.video_yuv import YuvFrame

from .frame_warp import FaceWarp
from .live_light import LiveLight
from .pose import Pose
from .tracking import Track


@dataclass
class FrameInfo:
    """What happened to one frame: ``face`` found, ``angles`` (yaw, pitch, roll) in degrees of
    the smoothed head rotation (None without a face), ``points`` tracked, ``timings`` ms,
    ``ran`` {stage: reason} of the slow stages that ran on it (:class:`.schedule.Plan`)."""

    face: bool = False
    angles: tuple[float, float, float] | None = None
    raw_angles: tuple[float, float, float] | None = None
    points: int = 0
    note: str = ""
    timings: dict = field(default_factory=dict)
    light: LiveLight | None = None
    reused: bool = False  # the last relight served this frame (the head turned < reuse_deg)
    ran: dict = field(default_factory=dict)


@dataclass(frozen=True)
class LayerLight:
    """The face layer's light for one frame (:meth:`.frame_light.LiveLightStage.transfer` and the
    other modes'): ``mode`` the layer's (:data:`.composite.LAYER_MODE`: 'live', or 'ambient' before
    any live light), ``gain`` the exposure gain (linear, before the path's smoothing),
    ``live_median`` the live face's median luminance (linear; 0 outside mode transfer), ``tau`` the
    detail threshold, ``eps`` the lighting ratio's floor, ``waited_ms`` the ms spent waiting for
    the relight (counted in the relight stage)."""

    mode: str
    gain: float
    live_median: float
    tau: float
    eps: float
    waited_ms: float


@dataclass
class Front:
    """What :meth:`FramePath.front` found in a frame - all :meth:`FramePath.back` reads of it.

    ``frame``: the frame as given ((H, W, 3) uint8 sRGB or a YuvFrame); ``t``: its time (s);
    ``t0``: perf_counter at the start of its path; ``info``: the FrameInfo both halves fill.
    The rest is None (or its default) when no head pose was found (``back`` then passes the frame through):
    ``track`` the tracked points, ``keep`` the pose's inliers among them and ``ref_idx`` their
    landmark indices, ``xy`` ((M, 2) float32) where the warp puts those landmarks, ``pose`` and
    ``rotation`` (3x3, smoothed) the head's, ``size`` (w, h), ``track_gain`` the tracking copy's
    brightening gain, ``warp`` the warp the pose gives (a :class:`.frame_warp.FaceWarp`: its
    coarse map made when the field is), ``brightness`` the face's mean grey code in the tracking
    copy (the scheduler's test of the room's light), ``thumb`` a grey thumbnail of the frame and
    ``thumb_scale`` its px per frame px (the scheduler's test of the scene: :mod:`.schedule`)."""

    frame: np.ndarray | YuvFrame
    t: float
    t0: float
    info: FrameInfo
    track: Track | None = None
    keep: np.ndarray | None = None
    ref_idx: np.ndarray | None = None
    xy: np.ndarray | None = None
    pose: Pose | None = None
    rotation: np.ndarray | None = None
    size: tuple[int, int] = (0, 0)
    track_gain: float = 1.0
    warp: FaceWarp | None = None
    brightness: float = 0.0
    thumb: np.ndarray | None = None
    thumb_scale: float = 1.0

    def outside(self):
        """(frame, info): the frame passed through, its info saying the face is outside it."""
        self.info.face = False
        self.info.note = "face outside the frame"
        self.info.timings["total"] = (time.perf_counter() - self.t0) * 1e3
        return self.frame, self.info
