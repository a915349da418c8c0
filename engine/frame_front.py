"""The frame path's first half (:meth:`relight.engine.frame_path.FramePath.front`): a frame's
face tracked, its head pose solved and filtered, the warp the pose gives - a :class:`.frame_data.Front`.
:class:`FrontStage` holds what that takes from frame to frame: the tracker, a pose estimator for
the frames' size, the focal search (:mod:`.focal`), the pose filter and the settling of a face
just found."""
from __future__ import annotations

import time

import cv2
import numpy as np

from relight.directions import rotation_matrix
from relight.errors import InputError

from .focal import FocalSearch
from .frame_data import FrameInfo, Front
from .frame_settings import FrameSettings
from .frame_warp import face_warp, regularised_points
from .pose import OneEuroFilter, PoseEstimator, camera_matrix
from .refind import posed_track, refind_landmarks
from .rig import FaceRig
from .schedule import RELIGHT_DEG, face_brightness, thumbnail
from .threads import Worker
from .tracking import FaceTracker
from .tracking_image import tracking_image

#: One Euro filter settings for the head angles (degrees).
ANGLE_MIN_CUTOFF = 1.5
ANGLE_BETA = 0.2

#: A face's pose is provisional for at most this many re-anchorings after it is found, until one
#: moves it less than SETTLED_DEG (the relight's own threshold): the pose filter starts again at
#: each (:meth:`FrontStage._settle_pose`).
SETTLE_ANCHORINGS = 3
SETTLED_DEG = RELIGHT_DEG


def _in_frame(track, ts: float):
    """A tracking copy's track (its points at the copy's scale ``ts`` of the frame) in the
    frame's pixels (None stays None)."""
    if track is None or ts >= 1:
        return track
    return type(track)(ref_index=track.ref_index, xy=track.xy / np.float32(ts))


class FrontStage:
    """Tracking and the head pose in a frame path. ``rig``: the path's :class:`.rig.FaceRig`;
    ``tracker``: its :class:`.tracking.FaceTracker`; ``auto_focal``: no focal length was told (the
    frames' own is searched for over the first seconds, :mod:`.focal`); ``worker``: the
    :class:`.threads.Worker` a live source's focal search runs on."""

    def __init__(self, rig: FaceRig, tracker: FaceTracker, auto_focal: bool, worker: Worker):
        self.rig = rig
        self.tracker = tracker
        self.auto_focal = bool(auto_focal)
        self.worker = worker
        # The reference face's keypoints lifted: a turned face's first pose (:func:`.refind.posed_track`).
        ref_face = tracker.ref_face
        self.keypoint_model = rig.lift(ref_face.keypoints / np.float32(rig.ref_track_scale)) \
            if ref_face is not None else None
        self.estimators: dict[tuple[int, int], PoseEstimator] = {}
        self.focal_search: FocalSearch | None = None
        self.focal_job = None  # (a live source's focal search on the worker)
        self.focal_next: float | None = None  # a focal length found, taken at the next frame's start
        self.angle_filter = OneEuroFilter(ANGLE_MIN_CUTOFF, ANGLE_BETA)
        self.settling = 0  # re-anchorings left while a face's pose is provisional (:meth:`_settle_pose`)
        self.track_gain = 1.0  # the last tracking copy's brightening (.tracking_image.track_exposure)

    def estimator(self, size: tuple[int, int]) -> PoseEstimator:
        """The pose estimator of frames of ``size`` (w, h): made on the first such frame (and the
        focal search with it when the focal length was not told)."""
        est = self.estimators.get(size)
        if est is None:
            est = PoseEstimator(self.rig.model, size, self.rig.focal, self.rig.model_normals)
            self.estimators = {size: est}
            self.focal_search = FocalSearch(self.rig.shape_model, size, est.k[0, 0]) if self.auto_focal else None
            self.focal_job = self.focal_next = None  # (another size's search: its result is not this one's)
        return est

    @property
    def frames_focal(self) -> float | None:
        """The focal length (px) the frames' poses are solved with now (None before a frame)."""
        return next((float(e.k[0, 0]) for e in self.estimators.values()), None)

    @property
    def focal_found(self) -> bool:
        """Whether the frames' focal length was found (:mod:`.focal`) rather than told or guessed."""
        return self.focal_search is not None and self.focal_search.found is not None

    def join(self) -> None:
        """Wait for a focal search in flight (its result is taken on the next frame)."""
        if self.focal_job is not None:
            self.focal_job.result()

    def reset(self) -> None:
        """Forget the track, the pose filter and the last poses (a new, unrelated video follows);
        after :meth:`join`."""
        self.tracker.drop(back_off=False)
        self.tracker.prev = None
        self.angle_filter.reset()
        for est in self.estimators.values():
            est.last = None
        if self.auto_focal:  # another video: another camera, searched for afresh
            self.estimators, self.focal_search, self.focal_job, self.focal_next = {}, None, None, None

    def front(self, rgb, t: float, settings: FrameSettings) -> Front:
        """A frame's :class:`.frame_data.Front` (see :meth:`relight.engine.frame_path.FramePath.front`)."""
        info = FrameInfo()
        tm = info.timings
        t0 = time.perf_counter()
        from relight.video_yuv import YuvFrame

        if not isinstance(rgb, YuvFrame):
            rgb = np.asarray(rgb)
            if rgb.dtype != np.uint8 or rgb.ndim != 3 or rgb.shape[2] != 3:
                raise InputError(f"frame of shape {rgb.shape} and type {rgb.dtype}: expected (H, W, 3) uint8 RGB")
        h, w = rgb.shape[:2]
        size = (w, h)
        est = self.estimator(size)
        if self.focal_next is not None:  # the focal length the search found: the pose solved afresh with it
            est.k, est.last, self.focal_next = camera_matrix(est.frame_size, self.focal_next), None, None
        grey, ts, track_gain = tracking_image(rgb)
        if track_gain != self.track_gain and self.tracker.prev is not None:
            # The tracking copy's brightening changed (a bright hand or a lamp entered the frame,
            # the camera's exposure stepped): the last frame brought to this one's codes, or LK's
            # brightness constancy fails for every point at once.
            self.tracker.prev = cv2.convertScaleAbs(self.tracker.prev, alpha=track_gain / self.track_gain)
        self.track_gain = track_gain
        last = est.last
        predict = (lambda idx: est.project(last, idx) * ts) if last is not None else None
        refind = (lambda idx, g: self._refind(est, last, ts, g, idx)) if last is not None else None
        posed = (lambda face, g: posed_track(self.rig, self._tracking_reference(), est, self.keypoint_model, face,
                                             ts, g)) if self.keypoint_model is not None else None
        track = _in_frame(self.tracker.update(grey, predict, refind, posed), ts)
        tm["track"] = (time.perf_counter() - t0) * 1e3
        t1 = time.perf_counter()
        # A face just found, or whose pose is still provisional, holds points its first rough pose
        # placed: their errors are that pose's, not independent - the robust fit over all of them
        # followed it (measured: a head found turned 21 deg, RANSAC's pose 1.1 deg off, the fit
        # over every point 7.3, kept by the track for two seconds).
        robust = not (self.tracker.acquired or self.settling)
        pose = est.solve(track.ref_index, track.xy, robust) if track is not None else None
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
        self._search_focal(est, ref_idx, track.xy[keep], settings.live_source)
        angles = self.angle_filter(pose.angles, t)
        rotation = rotation_matrix(*angles)
        info.face, info.angles, info.raw_angles = True, tuple(float(a) for a in angles), pose.angles
        info.points = int(keep.size)
        tm["pose"] = (time.perf_counter() - t1) * 1e3
        t2 = time.perf_counter()
        warp = face_warp(self.rig, est, pose, size, ref_idx, xy, settings.rigid_warp)  # the pose alone decides it
        tm["warp"] = (time.perf_counter() - t2) * 1e3
        thumb = thumbnail(grey)
        return Front(rgb, t, t0, info, track=track, keep=keep, ref_idx=ref_idx, xy=xy, pose=pose, rotation=rotation,
                     size=size, track_gain=track_gain, warp=warp, brightness=face_brightness(grey, track.xy * ts),
                     thumb=thumb, thumb_scale=thumb.shape[0] / h)

    def _search_focal(self, est: PoseEstimator, ref_idx: np.ndarray, xy: np.ndarray, live_source: bool) -> None:
        """A posed frame's points to the focal search; each of its runs made once its samples are
        in - in the frame for a file, on the worker for a live source (one at a time, the frames'
        points still kept meanwhile) - and the estimator switched to the focal length a run found at
        the next frame's start (its pose solved afresh there)."""
        search = self.focal_search
        if search is None or (search.done and self.focal_job is None):
            return
        search.observe(ref_idx, xy)
        if self.focal_job is not None:
            if not self.focal_job.done():
                return
            found, self.focal_job = self.focal_job.result(), None
        elif not search.ready:
            return
        elif live_source:
            self.focal_job = self.worker.submit(search.run)
            return
        else:
            found = search.run()
        # Taken at the next frame's start: this frame's warp and light go on with the camera its pose
        # was solved with (the new camera with the old pose put the face 10x off where an
        # orthographic clip's first run switched).
        self.focal_next = found

    def _anchor_acquired(self, est, pose, grey, ts, track):
        """(track, pose) of a face found on this frame: its landmarks found again at once with the
        pose they gave (:meth:`.tracking.FaceTracker.anchor_acquired`) and the pose solved again
        (the first kept where that fails). The pose is provisional for the next few re-anchorings
        (:meth:`_settle_pose`)."""
        self.settling = SETTLE_ANCHORINGS
        followed = self.tracker.track
        anchored = self.tracker.anchor_acquired(grey, lambda idx: est.project(pose, idx) * ts,
                                                lambda idx, g: self._refind(est, pose, ts, g, idx))
        anchored = _in_frame(anchored, ts)
        again = est.solve(anchored.ref_index, anchored.xy, robust=False)
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
        if not (self.settling and self.tracker.reanchored):
            return
        from relight.kernels.relight_inputs import rotation_angle_deg

        if last is not None and rotation_angle_deg(last.rotation, pose.rotation) < SETTLED_DEG:
            self.settling = 0
            return
        self.settling -= 1
        self.angle_filter.reset()

    def _tracking_reference(self) -> np.ndarray:
        """What the landmarks are matched against: the tracker's live-lit reference when there is
        one, else its reference."""
        return self.tracker.lit_reference if self.tracker.lit_reference is not None else self.tracker.reference

    def _refind(self, est, pose, ts, grey, idx):
        """The landmarks ``idx`` found again in ``grey`` (:func:`.refind.refind_landmarks`, against
        :meth:`_tracking_reference`): a Track, or None."""
        return refind_landmarks(self.rig, self._tracking_reference(), est, pose, ts, grey, idx)
