"""The per-frame path shared by ``relight filter``, ``relight live`` and the service: track ->
pose -> (relight, live light, person, light field: each at its own rate) -> the field applied.

One flow: a :class:`.rig.FaceRig` (everything the path needs of a bundle, prepared once, frozen),
then, per frame, :meth:`FramePath.front` (track, head pose, warp: a :class:`Front`) and
:meth:`FramePath.back`: the scheduler (:mod:`.schedule`) says which slow stages run on this frame
and why - the relight of the bundle, the live light's fit, the person's maps, the light field
(:mod:`.field`: the face's and the person's change of light as a coarse grid of affine changes of
linear light, made on a copy of the frame scaled to about :data:`.field.FIELD_ROWS` rows) - and the
field, made now or carried with the head, is applied to the frame at its full resolution in one
pass (:class:`relight.kernels.field_apply.FieldApplier`), in the decoder's planes for a
:class:`relight.video_yuv.YuvFrame`. :class:`FramePath` is the one stateful object: the rig, the
relighter, the tracker, the pose estimators and filters, the scheduler, the environment and the
stage objects it owns (:class:`.frame_light.LiveLightStage`, :class:`.frame_person.PersonStage`).
``process(frame, t)`` takes an (H, W, 3) uint8 sRGB frame - or a YuvFrame - and its time in
seconds, and returns the relit frame (the same kind, same size; the input unchanged where no
face is found) and a :class:`FrameInfo`.

Frames of any size work: tracking finds the face wherever it is; the warp maps the bundle's
reference into the frame.
"""
from __future__ import annotations

import time

import cv2
import numpy as np

from relight.directions import ENV_SPIN_RANGE_DEG_S, ENV_TURN_RANGE_DEG, rotation_matrix, with_env_turn
from relight.errors import InputError
from relight.kernels.relighter import DEFAULT_TOLERANCE
from relight.numerics import EPS_VALUE

from . import composite
from .field import FIELD_ROWS
from .focal import FocalSearch
from .frame_data import FrameInfo, Front, LayerLight
from .frame_field import FieldStage
from .frame_light import LiveLightStage, sync_relight
from .frame_person import PersonStage
from .frame_warp import face_warp, regularised_points
from .gains import ambient_gain, paste_gain
from .pose import OneEuroFilter, PoseEstimator, camera_matrix
from .refind import posed_track, refind_landmarks
from .rig import FaceRig
from .schedule import RELIGHT_DEG, Head, Plan, Scheduler, face_brightness, thumbnail
from .threads import Worker, limit_threads
from .tracking import FaceTracker
from .tracking_image import tracking_image

#: Head turns (degrees) below which the last relight serves (:data:`.schedule.RELIGHT_DEG`).
REUSE_DEG = RELIGHT_DEG
#: Exposure a caller may add to the relit light, in stops (EV): the light scaled by 2^EV.
EXPOSURE_RANGE_EV = (-20.0, 20.0)

#: One Euro filter settings for the head angles (degrees) and the exposure gain (log).
ANGLE_MIN_CUTOFF = 1.5
ANGLE_BETA = 0.2
GAIN_MIN_CUTOFF = 0.5


#: A face's pose is provisional for at most this many re-anchorings after it is found, until one
#: moves it less than SETTLED_DEG (the relight's own threshold): the pose filter starts again at
#: each (:meth:`FramePath._settle_pose`).
SETTLE_ANCHORINGS = 3
SETTLED_DEG = RELIGHT_DEG


def _in_frame(track, ts: float):
    """A tracking copy's track (its points at the copy's scale ``ts`` of the frame) in the
    frame's pixels (None stays None)."""
    if track is None or ts >= 1:
        return track
    return type(track)(ref_index=track.ref_index, xy=track.xy / np.float32(ts))


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
    affine ring around them (False: the path before issue 32).
    live_source : the slow stages - the light field with the relight and the layer it is made of
    (once a field is in use), the person's matte and ratio (region person) and the live light's
    fit (mode transfer) - made on worker threads while frames go on with the newest made, carried
    with the head (a frame or two older: a live source's next frame should not wait for them; a
    change the user asks for is still made in the frame); False (files, the service's single
    requests) makes them in the frame that needs them: runs are repeatable.
    field_rows : the light field's rows (:data:`.field.FIELD_ROWS`): a frame is scaled down by the
    even factor that leaves about this many (:func:`.field.field_factor`).
    workers : (field worker, maps worker) - :class:`.threads.Worker` s the slow stages run on,
    shared by several paths (a service's stream clients: one slow stage of each kind runs at a
    time, whoever's it is, and the frames keep the cores); None: the path's own.
    """

    def __init__(self, bundle, env: np.ndarray, *, mode: str = composite.DEFAULT_MODE, strength: float = 1.0,
                 fixed_env: bool = False, focal: float | None = None, exposure: float = 0.0,
                 tolerance: float = DEFAULT_TOLERANCE, relighter=None, reuse_deg: float = REUSE_DEG,
                 region: str = composite.DEFAULT_REGION, rigid_warp: bool = True, live_source: bool = False,
                 env_turn: float = 0.0, env_spin: float = 0.0, field_rows: int = FIELD_ROWS, workers=None):
        from relight.kernels.relighter import Relighter

        limit_threads()
        self.bundle = bundle
        self.relighter = relighter if relighter is not None else Relighter(bundle, tolerance=tolerance)
        # The relit reference frame, filled in place by the relight of each frame (its out=).
        self.relit_frame = np.zeros_like(self.relighter.frame)
        self._field_job = None  # (the Future of _field_work in flight: the setters below join it)
        self._focal_job = None  # (a live source's focal search on the maps' worker: .focal)
        self.set_mode(mode)
        self.set_strength(strength)
        self.set_exposure(exposure)
        self.set_env_turn(env_turn)
        self.set_env_spin(env_spin)
        self.fixed_env = bool(fixed_env)
        if not (np.isfinite(reuse_deg) and 0 <= reuse_deg <= 5):
            raise InputError(f"reuse_deg {reuse_deg}: use 0 (always relight) to 5 degrees")
        self.reuse_deg = float(reuse_deg)
        if not (isinstance(field_rows, (int, np.integer)) and 16 <= field_rows <= 4320):
            raise InputError(f"field_rows {field_rows}: use a number of rows from 16 to 4320")
        self.field_rows = int(field_rows)
        self.relighter.lights(env)  # a bad environment refused before the rig's seconds of work
        self.env = None
        self.draft = False  # relit as a draft while a light is moved (set_environment(moved=True))
        self.live_light = self.person = None  # (made below, once the rig is)
        self._relit_key = None  # (env, exposure, turn) of the relight in relit_frame
        self._track_gain = 1.0  # the last tracking copy's brightening (.tracking_image.track_exposure)
        self.rig = rig = FaceRig.build(bundle, self.relighter, focal)
        self.focal = rig.focal
        # No focal length told: the frames' own is searched for over the first seconds (.focal).
        self.auto_focal = focal is None
        self._focal_search: FocalSearch | None = None
        room = bundle.room_light
        from .face_subspace import FaceSubspace

        subspace = FaceSubspace.from_relighter(self.relighter, rig.solid_full, scale=rig.ref_track_scale,
                                               room=bundle.ambient_frame() if room is not None else None)
        self.tracker = FaceTracker(rig.track_reference, rig.track_landmarks, rig.track_mask, subspace=subspace)
        # The reference face's keypoints lifted: a turned face's first pose (:func:`.refind.posed_track`).
        ref_face = self.tracker.ref_face
        self._keypoint_model = rig.lift(ref_face.keypoints / np.float32(rig.ref_track_scale)) \
            if ref_face is not None else None
        field_worker, maps_worker = workers if workers is not None else \
            (Worker("relight-field", background=live_source), Worker(background=live_source))
        self._own_workers = workers is None  # made here: stopped by close()
        self._field_worker = field_worker  # a live source's slow stages, beside its frames
        self._maps_worker = maps_worker
        # (after the subspace's basis: the environment's rows, made ahead on the device's queue,
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
        self.person = PersonStage(bundle, rig, self.compositor, maps_worker, live_source=self.live_source)
        self.live_light = LiveLightStage(bundle, rig, self.relighter, self.tracker, maps_worker,
                                         live_source=self.live_source)
        self.schedule = Scheduler()
        self.field = FieldStage(self.compositor, self.field_rows)
        self._field_key = None  # the settings the field was made with (:meth:`_plan`)
        self._new_target = True  # a new environment since the person's maps were made
        self._estimators: dict[tuple[int, int], PoseEstimator] = {}
        self.angle_filter = OneEuroFilter(ANGLE_MIN_CUTOFF, ANGLE_BETA)
        self._settling = 0  # re-anchorings left while a face's pose is provisional (:meth:`_settle_pose`)
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
        from relight.kernels.relight_inputs import frozen

        self.join()
        env = frozen(env)
        self.relighter.lights(env)  # validates and converts once
        self.env = env
        self.draft = bool(moved)
        if not moved:
            self.relighter.prefetch_rows(env)  # the exact texels' rows, ahead of the head's turns
        if self.live_light is not None:  # (the first environment comes before the stages)
            self._new_target = True  # the person's maps remade for it (on the worker for a live source)
            if moved:
                self.person.light_moved()  # its ratio remade when due, soon
            else:
                self.live_light.new_environment()  # mode transfer's exposure, locked anew
                self.person.new_environment()  # the person's ratio was the last environment's

    def settle(self) -> None:
        """The moved light came to rest: relit in full from the next frame (its exact texels'
        rows made - ahead of the head's turns, on their own thread)."""
        self.join()
        if self.draft:
            self.draft = False
            self._relit_key = None
            self.relighter.prefetch_rows(self.env)

    @property
    def whole_head(self) -> bool:
        """Whether the rest of the person is relit with the face (region 'person', mode transfer)."""
        return self.region == "person" and self.mode == "transfer"

    # The setters wait for the slow stages beside a live source's frames (:meth:`join`: they read
    # the settings) only when a value changes: a caller that sets every frame's settings (the
    # service does) does not make each frame wait for them.
    def _setting(self, name: str, value) -> None:
        if getattr(self, name, None) != value:
            self.join()
            setattr(self, name, value)

    def set_mode(self, mode: str) -> None:
        if mode not in composite.MODES:
            raise InputError(f"mode {mode!r}: use one of {', '.join(composite.MODES)}")
        self._setting("mode", mode)

    def set_strength(self, strength: float) -> None:
        if not (np.isfinite(strength) and 0.0 <= strength <= 1.0):
            raise InputError(f"strength {strength}: use a number from 0 to 1")
        self._setting("strength", float(strength))

    def set_exposure(self, ev: float) -> None:
        lo, hi = EXPOSURE_RANGE_EV
        if not (np.isfinite(ev) and lo <= ev <= hi):
            raise InputError(f"exposure {ev}: use stops (EV) between {lo:g} and {hi:g}")
        self._setting("exposure", float(2.0 ** ev))

    def set_env_turn(self, deg: float) -> None:
        """Turn the environment about the vertical by ``deg`` (:data:`relight.directions.ENV_TURN_RANGE_DEG`)."""
        lo, hi = ENV_TURN_RANGE_DEG
        if not (np.isfinite(deg) and lo <= deg <= hi):
            raise InputError(f"environment turn {deg}: use degrees between {lo:g} and {hi:g}")
        self._setting("env_turn", float(deg))

    def set_env_spin(self, deg_per_s: float) -> None:
        """Spin the environment about the vertical by ``deg_per_s`` degrees per second of the
        frames' time, from the next frame on (where the turn has it)."""
        self.join()
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
            self._focal_search = FocalSearch(self.rig.shape_model, size, est.k[0, 0]) if self.auto_focal else None
            self._focal_job = None  # (another size's search: its result is not this one's)
        return est

    @property
    def frames_focal(self) -> float | None:
        """The focal length (px) the frames' poses are solved with now (None before a frame): the
        one told, the default guess, or the one found (:mod:`.focal`)."""
        return next((float(e.k[0, 0]) for e in self._estimators.values()), None)

    @property
    def focal_found(self) -> bool:
        """Whether the frames' focal length was found (:mod:`.focal`) rather than told or guessed."""
        return self._focal_search is not None and self._focal_search.found is not None

    def _search_focal(self, est: PoseEstimator, ref_idx: np.ndarray, xy: np.ndarray) -> None:
        """A posed frame's points to the focal search; the search run once its samples are in - in
        the frame for a file, on the maps' worker for a live source - and the estimator switched to
        the focal length it found (its pose solved afresh on the next frame)."""
        search = self._focal_search
        if search is None or (search.done and self._focal_job is None):
            return
        if self._focal_job is not None:
            if not self._focal_job.done():
                return
            found, self._focal_job = self._focal_job.result(), None
        else:
            search.observe(ref_idx, xy)
            if not search.ready:
                return
            if self.live_source:
                self._focal_job = self._maps_worker.submit(search.run)
                return
            found = search.run()
        if found is not None:
            est.k = camera_matrix(est.frame_size, found)
            est.last = None

    def close(self) -> None:
        """Wait for the slow stages in flight and stop the worker threads this path made (workers
        given to it are their giver's to stop). The path may not be used after. A slow stage's
        error is not raised here (it was the frames' to report; close runs on the way out of one)."""
        try:
            self.join()
        except Exception:  # (see above)
            pass
        finally:
            if self._own_workers:
                self._field_worker.close()
                self._maps_worker.close()

    def __enter__(self) -> FramePath:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def reset(self) -> None:
        """Forget the track and the filters (a new, unrelated video follows)."""
        self.join()
        self.tracker.drop(back_off=False)
        self.tracker.prev = None
        self.angle_filter.reset()
        self.gain_filter.reset()
        self.live_light.reset()
        self.person.reset()
        self.schedule.reset()
        self.field.reset()
        for est in self._estimators.values():
            est.last = None
        if self.auto_focal:  # another video: another camera, searched for afresh (join waited for its job)
            self._estimators, self._focal_search, self._focal_job = {}, None, None

    def warm_up(self, size: tuple[int, int] | None = None, planes: bool = True) -> float:
        """Run every kernel and model the frames will (and make PoCL compile each for its work-group
        shape) before the first real frame: the bundle's own reference frame, scaled to ``size``
        (w, h; None: as it is), through the path - RGB and, with ``planes``, in Y'CbCr planes -
        then :meth:`reset`. A live source's first frames then wait for no compile (measured on a
        fresh machine: one frame waited 1.9 s). Returns the seconds it took."""
        from relight.video_yuv import YuvFrame, rgb_to_planes

        t0 = time.perf_counter()
        ref = np.ascontiguousarray(self.bundle.background)
        if size is not None and tuple(size) != (ref.shape[1], ref.shape[0]):
            ref = cv2.resize(ref, tuple(size), interpolation=cv2.INTER_AREA)
        frames = [ref]
        if planes and ref.shape[0] % 2 == 0 and ref.shape[1] % 2 == 0:
            frames.append(YuvFrame(*rgb_to_planes(ref)))
        live, self.live_source = self.live_source, False  # (the slow maps in the frame: all of them run)
        self.person.live_source = self.live_light.live_source = False
        try:
            for i, f in enumerate(frames):
                self.reset()
                for k in range(2):
                    self.process(f, (2 * i + k) / 30.0)
        finally:
            self.live_source = self.person.live_source = self.live_light.live_source = live
            self.reset()
        return time.perf_counter() - t0

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
        posed = (lambda face, g: posed_track(self.rig, self._tracking_reference(), est, self._keypoint_model, face,
                                             ts, g)) if self._keypoint_model is not None else None
        track = _in_frame(self.tracker.update(grey, predict, refind, posed), ts)
        tm["track"] = (time.perf_counter() - t0) * 1e3
        t1 = time.perf_counter()
        pose = est.solve(track.ref_index, track.xy) if track is not None else None
        if pose is not None and self.tracker.acquired:
            track, pose = self._anchor_acquired(est, pose, grey, ts, track)
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
        self._settle_pose(last, pose)
        self._search_focal(est, ref_idx, track.xy[keep])
        angles = self.angle_filter(pose.angles, t)
        rotation = rotation_matrix(*angles)
        info.face, info.angles, info.raw_angles = True, tuple(float(a) for a in angles), pose.angles
        info.points = int(keep.size)
        tm["pose"] = (time.perf_counter() - t1) * 1e3
        t2 = time.perf_counter()
        warp = face_warp(self.rig, est, pose, size, ref_idx, xy, self.rigid_warp)  # the pose alone decides it
        tm["warp"] = (time.perf_counter() - t2) * 1e3
        thumb = thumbnail(grey)
        return Front(rgb, t, t0, info, track=track, keep=keep, ref_idx=ref_idx, xy=xy, pose=pose, rotation=rotation,
                     size=size, track_gain=track_gain, warp=warp, brightness=face_brightness(grey, track.xy * ts),
                     thumb=thumb, thumb_scale=thumb.shape[0] / h)

    def back(self, front: Front, defer_reference: bool = False):
        """The second half of :meth:`process` for the result of :meth:`front`: the scheduler's
        plan (:mod:`.schedule`), the slow stages it names - in this frame, or for a live source
        with a field in use beside the frames (:meth:`_field_work` on a worker: this frame and the
        next go on with the field in use, carried with the head, until it is made; a change the
        user asked for - a setting, the light - is made in the frame: it shows at once) - and the
        light field applied.
        ``defer_reference``: the tracker's live-lit reference kept for :meth:`commit_reference`
        (a caller running :meth:`front` of the next frame meanwhile)."""
        self.person.next_frame()
        self.schedule.next_frame()
        self._take_field(front.info.timings)
        if not defer_reference:
            self.commit_reference()
        if front.pose is None:
            return front.frame, front.info
        info, tm = front.info, front.info.timings
        box = front.warp.box
        if box is None:
            return front.outside()
        anchor = tuple(float(v) for v in front.warp.cur.mean(axis=0))  # the head's place: the field follows it
        head = Head(anchor, front.rotation, float(np.hypot(box[2] - box[0], box[3] - box[1])), front.brightness,
                    front.thumb, front.thumb_scale)
        env_rot = self.env_rotation(front.t)
        # The relighter's rotation: the head's (a head turned by R sees the light from d at R^T d),
        # with the environment's own turn E composed (its lights at E d: seen at R^T E d).
        turn = with_env_turn(None if self.fixed_env else front.rotation, env_rot)
        self.field.check_space(front.frame)
        # (while a field is made beside the frames the stages are the worker's: nothing is planned)
        plan, asked = self._plan(head, turn) if self._field_job is None else (Plan(), False)
        info.ran = plan.ran()
        info.reused = plan.relight is None
        if self.whole_head and self.strength > 0:
            self.person.touch()
        if plan.field is not None and self.live_source and self.field.last is not None and not asked:
            self._field_job = self._field_worker.submit(self._field_work, front, head, plan, env_rot, turn,
                                                        self.schedule.frame, True, {})
        elif plan.field is not None:
            made = self._field_work(front, head, plan, env_rot, turn, self.schedule.frame, defer_reference, tm)
            if made is None:
                return front.outside()
            self._took_field(made)
        if plan.field is None or self._field_job is not None:
            self.field.carry(anchor, front.size)
        if self.mode == "transfer":
            info.light = self.live_light.last
        t4 = time.perf_counter()
        out = self.field.apply(front.frame)
        tm["composite"] = (time.perf_counter() - t4) * 1e3
        tm["total"] = (time.perf_counter() - front.t0) * 1e3
        return out, info

    def _field_work(self, front: Front, head: Head, plan: Plan, env_rot, turn, frame: int, defer: bool, tm: dict):
        """The slow stages ``plan`` names for the frame ``front`` (number ``frame``): the relight,
        the live light, the person's maps and the light field (:meth:`_make_field`). Returns
        (the field made - a :class:`.field.LightField` or None -, the stages that ran, the head,
        ``frame``, ``tm``: the ms they took), or None when the warp's coarse map leaves the frame.
        Touches the relighter, the compositor and the stages, never the tracker (the live-lit
        reference is kept for :meth:`commit_reference` with ``defer``): a live source runs it on a
        worker while frames go on (:meth:`_take_field` takes what it made)."""
        t3 = time.perf_counter()
        coarse = front.warp.coarse()  # the warp's coarse map: made only for a field
        tm["warp"] = tm.get("warp", 0.0) + (time.perf_counter() - t3) * 1e3
        if coarse is None:
            return None
        ran = ["field"]
        t2 = time.perf_counter()
        if plan.relight is not None:  # queued, not waited for: synced before the host reads it
            self.relighter.relight(self.env, turn, exposure=self.exposure, out=self.relit_frame, wait=False,
                                   direct=0 if self.draft else None)
            self._relit_key = (self.env, self.exposure, turn)
            ran.append("relight")
        tm["relight"] = (time.perf_counter() - t2) * 1e3
        made = self._make_field(front, coarse, head, plan, env_rot, defer, tm, ran, frame)
        return made, ran, head, frame, tm

    def _took_field(self, made, tm: dict | None = None) -> None:
        """What :meth:`_field_work` made taken into use: the field, the scheduler's marks of the
        stages that ran (at the frame they ran for), their ms added to ``tm``."""
        fld, ran, head, frame, job_tm = made
        self.field.last = fld
        for stage in ran:
            self.schedule.ran(stage, head, frame)
        if "person" in ran:
            self._new_target = False
        if tm is not None:
            for k, v in job_tm.items():
                tm[k] = tm.get(k, 0.0) + v

    def _take_field(self, tm: dict | None, wait: bool = False) -> None:
        """A field made beside the frames taken into use once made (``wait``: waited for)."""
        job = self._field_job
        if job is None or not (wait or job.done()):
            return
        self._field_job = None
        made = job.result()
        if made is not None:
            self._took_field(made, tm)

    def join(self) -> None:
        """Wait for the slow stages a live source runs beside its frames (the field, then the
        person's maps and the live light's fit) and take what they made: after it the path's
        state is its own thread's (a setting changed, a reset, a test comparing frames); and for
        the focal search on the maps' worker (its result is taken on the next frame)."""
        if self._field_job is not None:
            self._take_field(None, wait=True)
        if self._focal_job is not None:
            self._focal_job.result()

    def _plan(self, head: Head, turn) -> tuple[Plan, bool]:
        """The scheduler's plan for this frame (:meth:`.schedule.Scheduler.plan`) from what the path
        holds: the last relight's key, the live light and the person's maps in use (and those made
        beside the frames, waiting), the settings the field was made with; and whether it answers
        a change the user asked for (a setting, the light, the exposure: shown on this frame, its
        field made in it, never beside the frames)."""
        from relight.kernels.relight_inputs import rotation_angle_deg

        last = self._relit_key
        key_changed = last is None or last[0] is not self.env or last[1] != self.exposure or \
            (turn is None) != (last[2] is None)
        if not key_changed and turn is not None and self.reuse_deg == 0:
            key_changed = rotation_angle_deg(last[2], turn) > 0  # (reuse_deg 0: every turn relights)
        delivered = self.live_light.ready() or self.person.ready()
        settings = (self.mode, self.strength, self.draft, self.exposure, self.region, self.fixed_env, id(self.env))
        asked = key_changed or settings != self._field_key
        plan = self.schedule.plan(head, relight_key_changed=key_changed, light_wanted=self.mode == "transfer",
                                  has_light=self.live_light.now is not None,
                                  person_wanted=self.whole_head and self.strength > 0,
                                  has_person=self.person.last_maps() is not None,
                                  new_environment=self._new_target,
                                  settings_changed=settings != self._field_key or delivered,
                                  relight_deg=self.reuse_deg, has_field=self.field.last is not None,
                                  light_fits=self.live_light.fits, person_box=self._person_box(),
                                  field_box=self.field.last.box if self.field.last is not None else None)
        self._field_key = settings
        self._field_env = self.env  # (kept alive: the id above stays its)
        return plan, asked

    def _person_box(self):
        """The frame's box the person's maps in use reach (None: none in use)."""
        last = self.person.last_maps()
        return last.maps.box if last is not None else None

    def _make_field(self, front: Front, coarse: np.ndarray, head: Head, plan: Plan, env_rot, defer: bool, tm: dict,
                    ran: list, frame: int):
        """The light field of this frame (:mod:`.frame_field`): the face's layer built for it (the
        live light fitted when the plan says), the person's maps (region person: made when the
        plan says, else the last ones carried), then the field over the box they reach (returned:
        a :class:`.field.LightField` or None). ``coarse``: the warp's coarse map (made by the
        caller). The stages that ran are appended to ``ran``, their ms to ``tm``."""
        rgb, t = front.frame, front.t
        box = front.warp.box
        t3 = time.perf_counter()
        if self.whole_head and self.strength > 0 and not self.live_source and \
                (self.live_light.now is not None or plan.light is not None) and \
                self.person.makes_now(rgb, plan.person is not None):
            # its model beside the live light's fit (a file's frames and single requests: a live
            # source makes its slow stages beside its frames already; before a live light the
            # person's maps are not made at all)
            self.person.start_matte(rgb)
        light = self._light(front, plan, defer, tm, ran)
        gain = float(np.exp(self.gain_filter([np.log(max(light.gain, EPS_VALUE))], t)[0]))
        tm["warp"] = tm.get("warp", 0.0) + (time.perf_counter() - t3) * 1e3 - tm.get("light", 0.0) - light.waited_ms
        live_buf = self.relighter.slot("live")[1] if light.mode == "live" else None
        self.compositor.layer(relit=self.relighter.buffer(self.relit_frame), live=live_buf, mode=light.mode,
                              gain=gain * self.exposure, strength=self.strength, eps=light.eps,
                              ratio_max=composite.RATIO_MAX, rotation=front.rotation, live_median=light.live_median)
        maps = None
        if self.whole_head and light.mode == "live" and self.strength > 0:
            t6 = time.perf_counter()
            maps = self.person.maps(rgb, box, coarse, front.rotation, light.tau, head.anchor, plan.person is not None,
                                    env=self.env, strength=self.strength, fixed_env=self.fixed_env,
                                    texel_light=self.live_light.texel_light, env_rotation=env_rot)
            if plan.person is not None:
                ran.append("person")
            tm["person"] = (time.perf_counter() - t6) * 1e3
        t7 = time.perf_counter()
        made = self.field.made(rgb, box, coarse, light.mode, light.tau, maps, head.anchor, frame)
        tm["field"] = (time.perf_counter() - t7) * 1e3
        return made

    def _light(self, front: Front, plan: Plan, defer: bool, tm: dict, ran: list) -> LayerLight:
        """The layer's light for this frame, by mode (a :class:`.frame_data.LayerLight`): mode
        transfer's live light fitted when the plan says (:meth:`.frame_light.LiveLightStage.transfer`;
        "light" appended to ``ran``)."""
        rgb = front.frame
        cur, ref = front.warp.cur, front.warp.ref
        flat = self.relit_frame.reshape(-1, 3)
        if self.mode == "transfer":
            out = self.live_light.transfer(rgb, cur, ref, front.rotation, front.t, flat, tm, front.track_gain, defer,
                                           self.rigid_warp, plan.light is not None)
            if plan.light is not None:
                ran.append("light")
            return out
        waited = sync_relight(self.relighter, tm)
        if self.mode == "ambient":  # the lighting ratio's median is 1: the face keeps its brightness
            gain = ambient_gain(self.rig, flat)
        else:  # paste: the relit face's median matched to the live face's at the tracked points
            gain = paste_gain(self.rig, rgb, flat, front.track.xy[front.keep], front.ref_idx)
        return LayerLight(composite.LAYER_MODE[self.mode], gain, 0.0, 0.0, float(self.rig.ratio_eps), waited)

    def _anchor_acquired(self, est, pose, grey, ts, track):
        """(track, pose) of a face found on this frame: its landmarks found again at once with the
        pose they gave (:meth:`.tracking.FaceTracker.anchor_acquired`) and the pose solved again
        (the first kept where that fails). The pose is provisional for the next few re-anchorings
        (:meth:`_settle_pose`)."""
        self._settling = SETTLE_ANCHORINGS
        followed = self.tracker.track
        anchored = self.tracker.anchor_acquired(grey, lambda idx: est.project(pose, idx) * ts,
                                                lambda idx, g: self._refind(est, pose, ts, g, idx))
        anchored = _in_frame(anchored, ts)
        again = est.solve(anchored.ref_index, anchored.xy)
        if again is None:  # the pass undone: the acquisition's points and pose
            est.last, self.tracker.track = pose, followed
            return track, pose
        return anchored, again

    def _settle_pose(self, last, pose) -> None:
        """A face's first re-anchorings after it was found move its points (and the pose) by up to
        ~1 deg while they converge - the live-lit reference they match arrives a frame or two
        after the face is found; the pose filter would follow each step for a second or more as
        if the head turned (measured on the tests' still head: 0.76 deg over 20 frames, relit again
        at frame 21). While the pose is provisional (:data:`SETTLE_ANCHORINGS` re-anchorings after
        it was found, until one moves it less than :data:`SETTLED_DEG`) the filter starts again at
        each re-anchoring's pose."""
        if not (self._settling and self.tracker.reanchored):
            return
        from relight.kernels.relight_inputs import rotation_angle_deg

        if last is not None and rotation_angle_deg(last.rotation, pose.rotation) < SETTLED_DEG:
            self._settling = 0
            return
        self._settling -= 1
        self.angle_filter.reset()

    def _tracking_reference(self) -> np.ndarray:
        """What the landmarks are matched against: the tracker's live-lit reference when there is
        one, else its reference."""
        return self.tracker.lit_reference if self.tracker.lit_reference is not None else self.tracker.reference

    def _refind(self, est, pose, ts, grey, idx):
        """The landmarks ``idx`` found again in ``grey`` (:func:`.refind.refind_landmarks`, against
        :meth:`_tracking_reference`): a Track, or None."""
        return refind_landmarks(self.rig, self._tracking_reference(), est, pose, ts, grey, idx)

    def commit_reference(self) -> None:
        """Hand the tracker the live-lit reference a deferred :meth:`back` made (between frames,
        when no :meth:`front` runs)."""
        self.live_light.commit_reference()
