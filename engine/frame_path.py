"""The per-frame path shared by ``relight filter``, ``relight live`` and the service: track ->
pose -> relight -> live light -> warp -> composite.

One flow: a :class:`.rig.FaceRig` (everything the path needs of a bundle, prepared once, frozen),
then, per frame, :meth:`FramePath.front` (track, head pose: a :class:`Front`) and
:meth:`FramePath.back` (relight, live light, warp, composite). :class:`FramePath` is the one
stateful object: the rig, the relighter, the tracker, the pose estimators and filters, the live
light and the environment; its live light and its person are stage objects it owns, each
holding its own state (:class:`.frame_light.LiveLightStage`, :class:`.frame_person.PersonStage`,
``live_light`` and ``person``), the stages it calls are functions of their
own modules (:mod:`.tracking_image`, :mod:`.refind`, :mod:`.frame_warp`, :mod:`.gains`,
:mod:`.person_maps`). ``process(frame, t)`` takes an (H, W, 3) uint8 sRGB frame - or a
:class:`relight.video_yuv.YuvFrame`, a decoded frame kept in its planes (only the face's box -
and the person's, region person - is converted) - and its time in seconds, and returns the relit
frame (the same kind, same size; the input unchanged where no face is found) and a
:class:`FrameInfo`.

Frames of any size work: tracking finds the face wherever it is; the warp maps the bundle's
reference into the frame. Only the face's box is converted to linear light and back.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import cv2
import numpy as np

from relight.directions import ENV_SPIN_RANGE_DEG_S, ENV_TURN_RANGE_DEG, rotation_matrix, with_env_turn
from relight.errors import InputError
from relight.kernels.relighter import DEFAULT_TOLERANCE
from relight.numerics import EPS_VALUE

from . import composite
from .frame_light import LiveLightStage, sync_relight
from .frame_person import PersonStage
from .frame_warp import face_warp, regularised_points
from .gains import ambient_gain, paste_gain
from .live_light import LiveLight
from .person_maps import union_box
from .pose import OneEuroFilter, PoseEstimator
from .refind import refind_landmarks
from .rig import FaceRig
from .threads import Worker, limit_threads
from .tracking import FaceTracker
from .tracking_image import tracking_image
from .warp import GRID_STEP

#: Head turns (degrees) below which a frame reuses the last relight instead of relighting (the
#: environment and exposure unchanged): measured on a 960x540 capture, a turn of 0.1 deg changes
#: the relit face by at most 0.17 % (relative L2; a point light beside the face, the sharpest
#: case; 0.07-0.13 % under the built-in environments) - a sixth of the default tolerance. The
#: map's texels are 5.6 deg wide: the error grows linearly, ~1.7 % per degree at worst.
REUSE_DEG = 0.1
#: Region person: the person's matte and the light's ratio over it are made every this many
#: frames and reused between (the face's own alpha is every frame's).
PERSON_EVERY = 2
#: A YuvFrame relit with the person: its box converted to RGB is the face's and the last person's
#: grown by this share of the frame's larger side (the person moves between the maps; beyond the
#: box, the whole frame is converted).
YUV_PERSON_MARGIN = 0.04
#: Exposure a caller may add to the relit light, in stops (EV): the light scaled by 2^EV.
EXPOSURE_RANGE_EV = (-20.0, 20.0)

#: One Euro filter settings for the head angles (degrees) and the exposure gain (log).
ANGLE_MIN_CUTOFF = 1.5
ANGLE_BETA = 0.2
GAIN_MIN_CUTOFF = 0.5


@dataclass
class FrameInfo:
    """What happened to one frame: ``face`` found, ``angles`` (yaw, pitch, roll) in degrees of
    the smoothed head rotation (None without a face), ``points`` tracked, ``timings`` ms."""

    face: bool = False
    angles: tuple[float, float, float] | None = None
    raw_angles: tuple[float, float, float] | None = None
    points: int = 0
    note: str = ""
    timings: dict = field(default_factory=dict)
    light: LiveLight | None = None
    reused: bool = False  # the last relight served this frame (the head turned < reuse_deg)


@dataclass
class Front:
    """What :meth:`FramePath.front` found in a frame - all :meth:`FramePath.back` reads of it.

    ``frame``: the frame as given ((H, W, 3) uint8 sRGB or a YuvFrame); ``t``: its time (s);
    ``t0``: perf_counter at the start of its path; ``info``: the FrameInfo both halves fill.
    The rest is None when no head pose was found (``back`` then passes the frame through):
    ``track`` the tracked points, ``keep`` the pose's inliers among them and ``ref_idx`` their
    landmark indices, ``xy`` ((M, 2) float32) where the warp puts those landmarks, ``pose`` and
    ``rotation`` (3x3, smoothed) the head's, ``size`` (w, h), ``track_gain`` the tracking copy's
    brightening gain, ``warp`` (cur, ref, box, coarse) the warp the pose gives
    (:func:`.frame_warp.face_warp`)."""

    frame: object
    t: float
    t0: float
    info: FrameInfo
    track: object = None
    keep: np.ndarray | None = None
    ref_idx: np.ndarray | None = None
    xy: np.ndarray | None = None
    pose: object = None
    rotation: np.ndarray | None = None
    size: tuple[int, int] = (0, 0)
    track_gain: float = 1.0
    warp: tuple | None = None


class FramePath:
    """Relights faces in frames with one bundle (see the module docstring).

    mode : 'transfer' or 'paste'. strength : 0-1. fixed_env : keep the environment still relative
    to the face (no head-rotation compensation). env_turn, env_spin : the environment turned about
    the vertical by degrees, and spun by degrees per second of the frames' time from the first
    frame (:data:`relight.directions.ENV_TURN_RANGE_DEG`: the convention). focal : the frames' focal
    length in pixels, or "ortho" (None: from the frame size, see :mod:`relight.engine.pose`).
    exposure : stops (EV).
    reuse_deg : head turns below which the last relight is reused (:data:`REUSE_DEG`; 0: never).
    region : 'person' - mode transfer also relights the rest of the person (hair, ears, neck,
    shoulders) from the face's ratio (:mod:`.head_light`, the person's matte from :mod:`.person`) -
    or 'face' (the bundle's face alone). Default :data:`relight.engine.composite.DEFAULT_REGION`.
    rigid_warp : the warp's control points are a grid over the face moved rigidly by the head pose
    (the bundle's depth) plus the tracked landmarks (the default), instead of the landmarks and an
    affine ring around them (False: the path before issue 32). Measured against the live frame's
    truth: the warp's displacement halved on both synthetic heads (the still prediction warped
    with it +2-4 dB), the smear the ring's extrapolation left beside the cheek gone, real faces
    +0.3/+0.5 dB (yaleB04, yaleB07).
    live_source : the slow maps - the person's matte and ratio (region person) and the live
    light's fit (mode transfer) - made on a worker thread while frames go on with the newest made
    (a frame or two older: a live source's next frame should not wait for them); False (files,
    the service's single requests) makes them in the frame that needs them: runs are repeatable.
    """

    def __init__(self, bundle, env: np.ndarray, *, mode: str = composite.DEFAULT_MODE, strength: float = 1.0,
                 fixed_env: bool = False, focal: float | None = None, exposure: float = 0.0,
                 tolerance: float = DEFAULT_TOLERANCE, relighter=None, reuse_deg: float = REUSE_DEG,
                 region: str = composite.DEFAULT_REGION,
                 rigid_warp: bool = True, live_source: bool = False, env_turn: float = 0.0, env_spin: float = 0.0):
        from relight.kernels.relighter import Relighter

        limit_threads()
        self.bundle = bundle
        self.relighter = relighter if relighter is not None else Relighter(bundle, tolerance=tolerance)
        # The relit reference frame, filled in place by the relight of each frame (its out=).
        self.relit_frame = np.zeros_like(self.relighter.frame)
        self.set_mode(mode)
        self.set_strength(strength)
        self.set_exposure(exposure)
        self.set_env_turn(env_turn)
        self.set_env_spin(env_spin)
        self.fixed_env = bool(fixed_env)
        if not (np.isfinite(reuse_deg) and 0 <= reuse_deg <= 5):
            raise InputError(f"reuse_deg {reuse_deg}: use 0 (always relight) to 5 degrees")
        self.reuse_deg = float(reuse_deg)
        self.relighter.lights(env)  # a bad environment refused before the rig's seconds of work
        self.env = None
        self.draft = False  # relit as a draft while a light is moved (set_environment(moved=True))
        self.live_light = self.person = None  # (made below, once the rig is)
        self._relit_key = None  # (env, exposure, rotation) of the relight in relit_frame
        self._track_gain = 1.0  # the last tracking copy's brightening (.tracking_image.track_exposure)
        self.rig = rig = FaceRig.build(bundle, self.relighter, focal)
        self.focal = rig.focal
        room = bundle.room_light
        from .acquire import FaceFinder

        finder = FaceFinder.from_relighter(self.relighter, rig.solid_full, scale=rig.ref_track_scale,
                                           room=bundle.ambient_frame() if room is not None else None)
        self.tracker = FaceTracker(rig.track_reference, rig.track_landmarks, rig.track_mask, finder=finder)
        # (after the finder's basis: the environment's rows, made ahead on the device's queue,
        # would hold its two dozen renders back - 1.5 s of a 720p bundle's start)
        self.set_environment(env)
        from relight.kernels.compositor import Compositor

        self.compositor = Compositor(rig.alpha_crop, rig.fill, rig.inv_ambient, rig.normal_crop, rig.origin,
                                     self.relighter)
        self.rigid_warp = bool(rigid_warp)
        if region not in composite.REGIONS:
            raise InputError(f"region {region!r}: use one of {', '.join(composite.REGIONS)}")
        self.region = region
        # live_source: the slow maps - the person's (region person) and the live light's fits -
        # made on one worker thread beside the frames
        self.live_source = bool(live_source)
        worker = Worker()
        self.person = PersonStage(bundle, rig, self.compositor, worker, live_source=self.live_source)
        self.live_light = LiveLightStage(bundle, rig, self.relighter, self.tracker, worker,
                                         live_source=self.live_source)
        self._estimators: dict[tuple[int, int], PoseEstimator] = {}
        self.angle_filter = OneEuroFilter(ANGLE_MIN_CUTOFF, ANGLE_BETA)
        self.gain_filter = OneEuroFilter(GAIN_MIN_CUTOFF, 0.0)

    # ------------------------------------------------------------------ settings
    def set_environment(self, env: np.ndarray, moved: bool = False) -> None:
        """Relight under ``env`` from the next frame: a frozen copy is kept (the Relighter then
        recognises it without hashing it every frame, and the caller's array stays theirs).
        ``moved``: the same light moved (a key dragged on a page) - mode transfer's locked
        exposure is kept (the face darkens as the key goes to its side, as it would) instead of
        matched anew, the person's maps are remade as when they are due (beside a live source's
        frames; the last ones serve a frame or two) instead of in the next frame, and the face
        is relit as a draft (the low-rank part alone: no texel row made while the light moves)
        until :meth:`settle`."""
        from relight.kernels.relighter import frozen

        env = frozen(env)
        self.relighter.lights(env)  # validates and converts once
        self.env = env
        self.draft = bool(moved)
        if not moved:
            self.relighter.prefetch_rows(env)  # the exact texels' rows, ahead of the head's turns
        if self.live_light is not None:  # (the first environment comes before the stages)
            if moved:
                self.person.light_moved()  # its ratio remade when due, soon
            else:
                self.live_light.new_environment()  # mode transfer's exposure, locked anew
                self.person.new_environment()  # the person's ratio was the last environment's

    def settle(self) -> None:
        """The moved light came to rest: relit in full from the next frame (its exact texels'
        rows made - ahead of the head's turns, on their own thread)."""
        if self.draft:
            self.draft = False
            self._relit_key = None
            self.relighter.prefetch_rows(self.env)

    @property
    def whole_head(self) -> bool:
        """Whether the rest of the person is relit with the face (region 'person', mode transfer)."""
        return self.region == "person" and self.mode == "transfer"

    def set_mode(self, mode: str) -> None:
        if mode not in composite.MODES:
            raise InputError(f"mode {mode!r}: use one of {', '.join(composite.MODES)}")
        self.mode = mode

    def set_strength(self, strength: float) -> None:
        if not (np.isfinite(strength) and 0.0 <= strength <= 1.0):
            raise InputError(f"strength {strength}: use a number from 0 to 1")
        self.strength = float(strength)

    def set_exposure(self, ev: float) -> None:
        lo, hi = EXPOSURE_RANGE_EV
        if not (np.isfinite(ev) and lo <= ev <= hi):
            raise InputError(f"exposure {ev}: use stops (EV) between {lo:g} and {hi:g}")
        self.exposure = float(2.0 ** ev)

    def set_env_turn(self, deg: float) -> None:
        """Turn the environment about the vertical by ``deg`` (:data:`relight.directions.ENV_TURN_RANGE_DEG`)."""
        lo, hi = ENV_TURN_RANGE_DEG
        if not (np.isfinite(deg) and lo <= deg <= hi):
            raise InputError(f"environment turn {deg}: use degrees between {lo:g} and {hi:g}")
        self.env_turn = float(deg)

    def set_env_spin(self, deg_per_s: float) -> None:
        """Spin the environment about the vertical by ``deg_per_s`` degrees per second of the
        frames' time, from the next frame on (where the turn has it)."""
        lo, hi = ENV_SPIN_RANGE_DEG_S
        if not (np.isfinite(deg_per_s) and lo <= deg_per_s <= hi):
            raise InputError(f"environment spin {deg_per_s}: use degrees per second between {lo:g} and {hi:g}")
        self.env_spin = float(deg_per_s)
        self._spin_t0 = None  # the spin counts from the next frame's time

    def env_rotation(self, t: float) -> np.ndarray | None:
        """The environment's rotation (3x3, lights moved by it) at frame time ``t``, or None when
        it is not turned (then nothing is composed: the path's numbers are as without it)."""
        if self.env_spin != 0.0:
            if self._spin_t0 is None:
                self._spin_t0 = t
            deg = self.env_turn + self.env_spin * (t - self._spin_t0)
        else:
            deg = self.env_turn
        deg = float(np.remainder(deg + 180.0, 360.0) - 180.0)
        return rotation_matrix(deg, 0.0, 0.0) if deg != 0.0 else None

    def _estimator(self, size: tuple[int, int]) -> PoseEstimator:
        est = self._estimators.get(size)
        if est is None:
            est = PoseEstimator(self.rig.model, size, self.focal)
            self._estimators = {size: est}
        return est

    def reset(self) -> None:
        """Forget the track and the filters (a new, unrelated video follows)."""
        self.tracker.drop(back_off=False)
        self.tracker.prev = None
        self.angle_filter.reset()
        self.gain_filter.reset()
        self.live_light.reset()
        self.person.reset()
        for est in self._estimators.values():
            est.last = None

    # ------------------------------------------------------------------ per frame
    def process(self, rgb, t: float):
        """The relit frame and what happened (see the module docstring): :meth:`front` then
        :meth:`back`. ``rgb``: (H, W, 3) uint8 sRGB, or a :class:`relight.video_yuv.YuvFrame` (a
        decoded frame kept in its planes: only the face's box is converted, and a YuvFrame comes
        back)."""
        return self.back(self.front(rgb, t))

    def front(self, rgb, t: float) -> Front:
        """The first half of :meth:`process` - track and head pose - for a frame: what
        :meth:`back` needs. Touches only the tracker, the pose estimator and the angle filter, so
        a caller may run it for the next frame while :meth:`back` runs for this one (on another
        thread: ``defer_reference=True`` there keeps the tracker's live-lit reference for
        :meth:`commit_reference`)."""
        info = FrameInfo()
        tm = info.timings
        t0 = time.perf_counter()
        from relight.video_yuv import YuvFrame

        yuv = isinstance(rgb, YuvFrame)
        if not yuv:
            rgb = np.asarray(rgb)
            if rgb.dtype != np.uint8 or rgb.ndim != 3 or rgb.shape[2] != 3:
                raise InputError(f"frame of shape {rgb.shape} and type {rgb.dtype}: expected (H, W, 3) uint8 RGB")
        h, w = rgb.shape[:2]
        size = (w, h)
        est = self._estimator(size)
        grey, ts, track_gain = tracking_image(rgb)
        if track_gain != self._track_gain and self.tracker.prev is not None:
            # The tracking copy's brightening changed (a bright hand or a lamp entered the frame,
            # the camera's exposure stepped): the last frame brought to this one's codes, or LK's
            # brightness constancy fails for every point at once.
            self.tracker.prev = cv2.convertScaleAbs(self.tracker.prev, alpha=track_gain / self._track_gain)
        self._track_gain = track_gain
        last = est.last
        predict = (lambda idx: est.project(last, idx) * ts) if last is not None else None
        refind = (lambda idx, g: self._refind(est, last, ts, g, idx)) if last is not None else None
        track = self.tracker.update(grey, predict, refind)
        if track is not None and ts < 1:
            track = type(track)(ref_index=track.ref_index, xy=track.xy / np.float32(ts))
        tm["track"] = (time.perf_counter() - t0) * 1e3
        t1 = time.perf_counter()
        pose = est.solve(track.ref_index, track.xy) if track is not None else None
        if pose is None:
            if track is not None:
                self.tracker.drop()
            self.angle_filter.reset()
            tm["pose"] = (time.perf_counter() - t1) * 1e3
            info.note = "no face found" if track is None else "no consistent head pose"
            tm["total"] = (time.perf_counter() - t0) * 1e3
            return Front(rgb, t, t0, info)
        keep = pose.inliers
        ref_idx = track.ref_index[keep]
        # The pose again (Levenberg-Marquardt from the first): one more pass converges further
        # (measured on the synthetic live clip: rotation error 2.1 -> 1.3 deg median).
        refined = est.refine(ref_idx, track.xy[keep])
        if refined is not None and refined.inliers.size >= keep.size // 2:
            pose = refined
        else:
            est.last = pose
        # The warp's control points: the pose's projection of the landmarks plus what it leaves
        # of each tracked point beyond the tracking noise (a rigid face is warped rigidly instead
        # of bent by every point's error).
        xy = regularised_points(est.project(pose, ref_idx).astype(np.float32), track.xy[keep], size)
        angles = self.angle_filter(pose.angles, t)
        rotation = rotation_matrix(*angles)
        info.face, info.angles, info.raw_angles = True, tuple(float(a) for a in angles), pose.angles
        info.points = int(keep.size)
        tm["pose"] = (time.perf_counter() - t1) * 1e3
        t2 = time.perf_counter()
        warp = face_warp(self.rig, est, pose, size, ref_idx, xy, self.rigid_warp)  # the pose alone decides it
        tm["warp"] = (time.perf_counter() - t2) * 1e3
        return Front(rgb, t, t0, info, track=track, keep=keep, ref_idx=ref_idx, xy=xy, pose=pose, rotation=rotation,
                     size=size, track_gain=track_gain, warp=warp)

    def back(self, front: Front, defer_reference: bool = False):
        """The second half of :meth:`process` (relight, warp, live light, composite) for the
        result of :meth:`front`."""
        self.person.next_frame()
        if front.pose is None:
            return front.frame, front.info
        rgb, t, t0, info = front.frame, front.t, front.t0, front.info
        track, keep, ref_idx, rotation = front.track, front.keep, front.ref_idx, front.rotation
        tm = info.timings
        t2 = time.perf_counter()
        # Leave out a relight the head's small turn does not need (REUSE_DEG): this path's own
        # last relight, kept in its own frame. Else queued, not waited for: the warp and the live
        # light's fit run on the host meanwhile; synced before the host reads the relit frame (the
        # compositor's kernels queue after it).
        from relight.kernels.relighter import rotation_angle_deg

        # The relighter's rotation: the head's (a head turned by R sees the light from d at R^T d),
        # with the environment's own turn E composed (its lights at E d: seen at R^T E d).
        env_rot = self.env_rotation(t)
        turn = with_env_turn(None if self.fixed_env else rotation, env_rot)
        last = self._relit_key
        info.reused = bool(last is not None and last[0] is self.env and last[1] == self.exposure and turn is not None
                           and last[2] is not None and self.reuse_deg > 0
                           and rotation_angle_deg(last[2], turn) < self.reuse_deg)
        if not info.reused:
            self.relighter.relight(self.env, turn, exposure=self.exposure, out=self.relit_frame, wait=False,
                                   direct=0 if self.draft else None)
            self._relit_key = (self.env, self.exposure, turn)
        img = self.relit_frame
        tm["relight"] = (time.perf_counter() - t2) * 1e3
        t3 = time.perf_counter()
        cur, ref, box, coarse = front.warp
        anchor = tuple(float(v) for v in cur.mean(axis=0))  # the head's place (frame px): the person's maps follow it
        if coarse is None:
            info.face = False
            info.note = "face outside the frame"
            tm["total"] = (time.perf_counter() - t0) * 1e3
            return rgb, info
        # A YuvFrame: its box alone in RGB (offset: the box's corner in the frame) - with the
        # person's box (the last one, grown) when the person is relit too.
        frame = rgb
        offset = np.zeros(2, np.float32)
        frame_box = box
        if not isinstance(rgb, np.ndarray):
            want = box
            if self.whole_head and self.strength > 0:
                last = self.person.last_maps()
                fh, fw = rgb.shape[:2]
                pb = last[1].moved(anchor).box if last is not None else None
                if pb is not None:
                    g = int(np.ceil(YUV_PERSON_MARGIN * max(fw, fh)))
                    want = union_box(box, (pb[0] - g, pb[1] - g, pb[2] + g, pb[3] + g))
                else:  # no person's box yet: the whole frame
                    want = (0, 0, fw, fh)
            ebox = rgb.even_box(want)  # (clipped to the frame)
            offset = np.array(ebox[:2], np.float32)
            rgb = rgb.rgb_box(ebox)
            box = (box[0] - ebox[0], box[1] - ebox[1], box[2] - ebox[0], box[3] - ebox[1])
            cur = cur - offset
        flat = img.reshape(-1, 3)
        layer_mode, live_median, tau, eps = composite.LAYER_MODE[self.mode], 0.0, 0.0, float(self.rig.ratio_eps)
        if self.mode == "transfer":  # the live light, fitted to this frame's face
            layer_mode, gain, live_median, tau, eps, waited = self.live_light.transfer(
                rgb, cur, ref, rotation, t, flat, tm, front.track_gain, defer_reference, self.rigid_warp)
            info.light = self.live_light.last
        elif self.mode == "ambient":
            # The lighting ratio's median is 1: the face keeps its brightness.
            waited = sync_relight(self.relighter, tm)
            gain = ambient_gain(self.rig, flat)
        else:
            # paste: the relit face's median matched to the live face's at the tracked points.
            waited = sync_relight(self.relighter, tm)
            gain = paste_gain(self.rig, rgb, flat, track.xy[keep] - offset, ref_idx)
        gain = float(np.exp(self.gain_filter([np.log(max(gain, EPS_VALUE))], t)[0]))
        tm["warp"] = tm.get("warp", 0.0) + (time.perf_counter() - t3) * 1e3 - tm.get("light", 0.0) - waited
        t4 = time.perf_counter()
        live_buf = self.relighter.slot("live")[1] if layer_mode == "live" else None
        self.compositor.layer(relit=self.relighter.buffer(self.relit_frame), live=live_buf, mode=layer_mode,
                              gain=gain * self.exposure, strength=self.strength, eps=eps,
                              ratio_max=composite.RATIO_MAX, rotation=rotation, live_median=live_median)
        if self.whole_head and layer_mode == "live" and self.strength > 0:
            # The light's change carried from the face over the rest of the person (.head_light):
            # hair, ears, neck, shoulders; nothing off the person changes - the face's composite
            # and the person's in one kernel pass over the face's box and the person's.
            t6 = time.perf_counter()
            from .head_light import MATTE_FLOOR

            maps, union = self.person.maps(frame, frame_box, coarse, rotation, tau, anchor, info.reused, PERSON_EVERY,
                                           env=self.env, strength=self.strength, fixed_env=self.fixed_env,
                                           texel_light=self.live_light.texel_light, env_rotation=env_rot)
            ox, oy = int(offset[0]), int(offset[1])
            if frame is not rgb and not (union[0] >= ox and union[1] >= oy and union[2] <= ox + rgb.shape[1]
                                         and union[3] <= oy + rgb.shape[0]):
                # the person reached beyond the frame's converted box: all of it in RGB
                rgb, ox, oy, box = frame.to_rgb(), 0, 0, frame_box
                ebox = (0, 0, rgb.shape[1], rgb.shape[0])
            out = self.compositor.composite_person(rgb, (union[0] - ox, union[1] - oy, union[2] - ox, union[3] - oy),
                                                   box, coarse, GRID_STEP, mode="live", tau=tau, person=maps.grid,
                                                   person_origin=maps.origin, person_scale=maps.scale,
                                                   floor=MATTE_FLOOR, offset=(ox, oy), gate=maps.gate)
            tm["person"] = (time.perf_counter() - t6) * 1e3
        else:
            out = self.compositor.composite(rgb, box, coarse, GRID_STEP, mode=layer_mode, tau=tau)
        if frame is not rgb:
            out = frame.with_rgb_box(ebox, rgb, out)
        tm["composite"] = (time.perf_counter() - t4) * 1e3 - tm.get("person", 0.0)
        tm["total"] = (time.perf_counter() - t0) * 1e3
        return out, info

    def _refind(self, est, pose, ts, grey, idx):
        """The landmarks ``idx`` found again in ``grey`` (:func:`.refind.refind_landmarks`, against
        the tracker's live-lit reference when there is one): a Track, or None."""
        ref = self.tracker.lit_reference if self.tracker.lit_reference is not None else self.tracker.reference
        return refind_landmarks(self.rig, ref, est, pose, ts, grey, idx)

    def commit_reference(self) -> None:
        """Hand the tracker the live-lit reference a deferred :meth:`back` made (between frames,
        when no :meth:`front` runs)."""
        self.live_light.commit_reference()
