"""Face tracking: the bundle's reference landmarks followed through a video.

Every tracked point keeps the index of the reference landmark it came from, so it carries that
landmark's 3D position (for the head pose) and its reference position (for the warp).

* Acquire: the face detector (:mod:`.face_detect`: BlazeFace, turned, tilted and side-lit faces
  included) finds the faces in the frame with six keypoints each; the similarity that takes the
  reference's face to a face's guesses every landmark; pyramidal Lucas-Kanade from the
  reference brightness matched there, and from the reference relit as the frame is lit where the
  bundle's illumination subspace puts the face (:mod:`.face_subspace`), refines it -
  forward-backward checked, the start that holds more points kept. With the caller's
  ``posed`` start (the path's: a head pose from the face's keypoints, the landmarks searched by
  templates the pose turns - a head turned 45 deg, which a similarity of the frontal reference
  does not follow) a third start, kept when it holds more points. Of several faces the one
  followed the most landmarks of is taken (the bundle's person). No face, or too few points
  survive: no track (the caller passes the frame through).
* Track: pyramidal LK from the previous frame, forward-backward checked.
* Re-anchor: every ``REANCHOR_EVERY`` frames, or when the points thin out, the landmarks are
  searched again from the reference, starting where the current pose puts them (drift and lost
  points come back) - with a pose, by templates warped as the pose shows each landmark (the
  caller's ``refind``); a track that cannot be re-anchored for long is dropped and re-detected.

Images are (H, W) uint8 grey; points are (N, 2) float32 frame pixels (x right, y down).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from relight.errors import InputError
from relight.numerics import px_at

from .face_detect import Face, FaceDetector, face_similarity

#: Lucas-Kanade window (px, at 540 rows; scaled with the frame), pyramid levels, iterations.
LK_WINDOW_AT_540 = 15
LK_LEVELS = 3
LK_ITERATIONS = 20
#: Most landmarks followed (the bundle's, thinned evenly over the face).
MAX_TRACKED = 120
#: Largest forward-backward disagreement kept (px, at 540 rows).
FB_MAX_AT_540 = 0.8
#: Fewest points a track needs; below this the face counts as lost.
MIN_POINTS = 8
#: Re-anchor from the reference this often (frames), or when fewer than this share of the points
#: found at the last anchoring is left.
REANCHOR_EVERY = 2
REANCHOR_BELOW = 0.6
#: The reference is resampled into the frame's geometry before LK when the frame's size differs
#: or the face's scale differs by more than this share.
REWARP_SCALE = 0.08
#: While no face is in view, the search for a small face (the detector's squares: ~15 runs of its
#: model, ~70 ms at 720p) runs again after 1, 2, 4, then every SEARCH_BACKOFF_MAX frames; the
#: whole frame (one run, ~5 ms) is searched on every frame.
SEARCH_BACKOFF_MAX = 8
#: A face's first start from the plain reference that holds at least this share of the landmarks
#: is kept without trying the relit start (the subspace's search, ~20 ms of a
#: request): measured on the first frames, the two starts hold complementary faces - the studio's
#: clips in their room's light 39-52 of 120 plain, none relit; the ten side-lit Yale clips none
#: plain, 63-92 relit.
PLAIN_START_SHARE = 0.25
#: The posed start (the caller's ``posed``: a head pose from the face's keypoints, 11-17 ms a face
#: on this machine - two RANSACs and two wide template searches) is tried only when the
#: similarity's start holds less than this share of the landmarks: a face turned little, which
#: that start follows, does not pay for it (a single request is a first frame). Measured on the
#: scanned head's first frames at 640x360: the similarity's start held 63-114 of its 120 landmarks
#: at the five poses within 15 deg of the front where it held 60 or more, and posed them 0.1-3.3
#: deg off (the posed start 0.1-2.8); at 30-45 deg of yaw it held 8-46 or none.
POSED_BELOW_SHARE = 0.5
#: Faces (best first) tried when the detector finds several (the one LK follows the most landmarks of is taken).
CANDIDATE_FACES = 3
#: A point found again by re-anchoring replaces the followed one (or joins, when it was lost) only
#: within this distance (px at 540 rows) of it (or of where the pose puts it).
REANCHOR_AGREE_AT_540 = 3.0
#: The reference relit as a frame shows it is used when it explains at least this share of the
#: face's variance there (else the plain reference, brightness matched).
RELIT_MIN_SHARE = 0.5


@dataclass
class Track:
    """Points of one frame: ``ref_index`` (M,) landmark indices, ``xy`` (M, 2) float32 positions."""

    ref_index: np.ndarray
    xy: np.ndarray

    def __len__(self) -> int:
        return int(self.ref_index.size)


def face_xywh(face: Face) -> tuple[int, int, int, int]:
    """A detected face's box as (x, y, w, h) whole pixels."""
    x0, y0, x1, y1 = (float(v) for v in face.box)
    return int(round(x0)), int(round(y0)), max(int(round(x1 - x0)), 1), max(int(round(y1 - y0)), 1)


def bounding_xywh(xs: np.ndarray, ys: np.ndarray) -> tuple[int, int, int, int]:
    """The box (x, y, w, h) of points' coordinates ``xs``, ``ys`` (whole pixels, both ends in)."""
    return int(xs.min()), int(ys.min()), int(np.ptp(xs)) + 1, int(np.ptp(ys)) + 1


def thin_points(points: np.ndarray, n: int) -> np.ndarray:
    """At most ``n`` of ``points`` (N, 2), spread evenly (farthest-point order from the first)."""
    if len(points) <= n:
        return points
    chosen = [0]
    d = np.linalg.norm(points - points[0], axis=1)
    for _ in range(n - 1):
        k = int(np.argmax(d))
        chosen.append(k)
        d = np.minimum(d, np.linalg.norm(points - points[k], axis=1))
    return points[np.sort(chosen)]


class FaceTracker:
    """Follows the reference landmarks (N, 2) of ``reference`` (grey uint8) through frames."""

    def __init__(self, reference: np.ndarray, landmarks: np.ndarray, mask: np.ndarray, subspace=None):
        self.reference = np.ascontiguousarray(reference)
        self.subspace = subspace
        self.landmarks = thin_points(np.asarray(landmarks, dtype=np.float32).reshape(-1, 2), MAX_TRACKED)
        if len(self.landmarks) < MIN_POINTS:
            raise InputError(f"the bundle has {len(self.landmarks)} landmarks; tracking needs {MIN_POINTS}")
        self.mask = mask
        self.detector = FaceDetector()
        # The reference's face: its keypoints map a face found in a frame to the landmarks; its box
        # is where brightness is matched (the mask's bounding box when the detector sees none).
        self.ref_face = self._reference_face()
        if self.ref_face is not None:  # (within the reference: a tight crop's face box passes its edges)
            h, w = self.reference.shape
            x0, y0, bw, bh = face_xywh(self.ref_face)
            x1, y1 = min(x0 + bw, w), min(y0 + bh, h)
            x0, y0 = max(x0, 0), max(y0, 0)
            box = (x0, y0, max(x1 - x0, 1), max(y1 - y0, 1))
        else:
            ys, xs = np.nonzero(mask)
            box = bounding_xywh(xs, ys)
        self.ref_box = box
        self.prev: np.ndarray | None = None
        self.track: Track | None = None
        # The reference as the live light shows it (set by the frame path from its light
        # estimate): what re-anchoring matches while it is set.
        self.lit_reference: np.ndarray | None = None
        self.anchored = len(self.landmarks)  # points the track had when last found or re-anchored
        self.age = 0
        # what this frame's update did: found the face anew, or re-anchored its track
        self.acquired = self.reanchored = False
        # Back-off of the search for a small face while no face is found: frames to skip, and the gap.
        self.search_wait = 0
        self.search_gap = 0

    def _reference_face(self) -> Face | None:
        """The detector's face in the reference: the surer of the face found in it and on a copy
        with a plain border around it. A photo set's reference is a tight crop of the face, which
        the detector, made for faces in a scene, sees poorly there (a real Yale face: score 0.57,
        its box three quarters of the face; every frame of its clip then went unrelit); a video's
        reference frame shows the face in the room, smaller once bordered."""
        found = self.detector.detect(self.reference)
        h, w = self.reference.shape
        pad = max(h, w) // 2
        boxed = cv2.copyMakeBorder(self.reference, pad, pad, pad, pad, cv2.BORDER_CONSTANT,
                                   value=int(np.median(self.reference)))
        bordered = [Face(score=f.score, box=f.box - np.float32(pad), keypoints=f.keypoints - np.float32(pad))
                    for f in self.detector.detect(boxed)[:1]]
        return max(found[:1] + bordered, key=lambda f: f.score, default=None)

    def _lk_params(self, rows: int) -> tuple[dict, float]:
        s = px_at(1.0, rows)
        win = int(max(9, round(LK_WINDOW_AT_540 * s)) | 1)
        return (dict(winSize=(win, win), maxLevel=LK_LEVELS,
                     criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, LK_ITERATIONS, 0.02)),
                max(FB_MAX_AT_540 * s, 0.5))

    def _flow(self, a: np.ndarray, b: np.ndarray, pts: np.ndarray, guess: np.ndarray | None = None):
        """LK a -> b with a forward-backward check: (new points, ok mask). (OpenCV's Python
        binding cannot take prebuilt pyramids, so each call builds its own.)"""
        params, fb_max = self._lk_params(b.shape[0])
        p0 = pts.reshape(-1, 1, 2).astype(np.float32)
        if guess is not None:
            p1, st, _ = cv2.calcOpticalFlowPyrLK(a, b, p0, guess.reshape(-1, 1, 2).astype(np.float32).copy(),
                                                 flags=cv2.OPTFLOW_USE_INITIAL_FLOW, **params)
        else:
            p1, st, _ = cv2.calcOpticalFlowPyrLK(a, b, p0, None, **params)
        back, st2, _ = cv2.calcOpticalFlowPyrLK(b, a, p1, p0.copy(), flags=cv2.OPTFLOW_USE_INITIAL_FLOW, **params)
        err = np.linalg.norm((back - p0).reshape(-1, 2), axis=1)
        ok = (st.ravel() == 1) & (st2.ravel() == 1) & (err < fb_max)
        h, w = b.shape
        p1 = p1.reshape(-1, 2)
        ok &= (p1[:, 0] >= 0) & (p1[:, 0] < w) & (p1[:, 1] >= 0) & (p1[:, 1] < h)
        return p1, ok

    def _matched_reference(self, grey: np.ndarray, box, sim=None, reference=None) -> np.ndarray:
        """The reference (or ``reference``) with its face box's brightness and contrast matched to
        ``box`` of ``grey`` (``sim``: the reference -> frame similarity; the frame's box is taken
        there)."""
        reference = self.reference if reference is None else reference
        rx, ry, rw, rh = self.ref_box
        if sim is not None:
            corners = np.array([[rx, ry], [rx + rw, ry + rh]], np.float64) @ sim[:, :2].T + sim[:, 2]
            x, y = (int(v) for v in corners.min(axis=0))
            w, h = (int(v) + 1 for v in np.abs(corners[1] - corners[0]))
        else:
            x, y, w, h = box
        a = reference[ry:ry + rh, rx:rx + rw].astype(np.float32)
        b = grey[max(y, 0):max(y + h, 0), max(x, 0):max(x + w, 0)].astype(np.float32)
        if a.size < 16 or b.size < 16:
            return reference
        gain = float(b.std()) / max(float(a.std()), 1.0)
        gain = float(np.clip(gain, 0.25, 4.0))
        off = float(b.mean()) - gain * float(a.mean())
        return cv2.convertScaleAbs(reference, alpha=gain, beta=off)

    def relit_reference(self, grey: np.ndarray, sim: np.ndarray) -> np.ndarray:
        """The reference with its face relit as ``grey`` shows it where ``sim`` (reference ->
        frame) puts it (:meth:`relight.engine.face_subspace.FaceSubspace.relit`); the plain reference
        without a subspace or when the fit explains little of the face."""
        relit = self._relit(grey, sim)
        return self.reference if relit is None else relit

    def _relit(self, grey: np.ndarray, sim: np.ndarray) -> np.ndarray | None:
        """:meth:`relit_reference`, or None where it would be the plain reference."""
        if self.subspace is None:
            return None
        from relight.colour import decode_srgb8, encode_srgb8

        relit, share = self.subspace.relit(decode_srgb8(grey), sim)
        if not share > RELIT_MIN_SHARE:
            return None
        out = self.reference.copy()
        x0, y0 = (int(round(v)) for v in self.subspace.origin)
        h, w = relit.shape
        region = out[y0:y0 + h, x0:x0 + w]
        m = self.subspace.mask[:region.shape[0], :region.shape[1]]
        region[m] = encode_srgb8(np.clip(relit[:region.shape[0], :region.shape[1]][m], 0.0, 1.0))
        return out

    def from_reference(self, grey: np.ndarray, guess: np.ndarray, index: np.ndarray | None = None,
                       box=None, reference: np.ndarray | None = None) -> Track | None:
        """Landmarks (all, or ``index``) searched in ``grey`` from the reference (or the given
        ``reference``, e.g. :meth:`relit_reference`), starting at ``guess``.

        The reference is first brought into the frame's geometry by the similarity that best
        takes the landmarks to ``guess`` (frames of another size or scale than the reference
        work), its face box's brightness matched; then LK from it, forward-backward checked."""
        idx = np.arange(len(self.landmarks)) if index is None else np.asarray(index)
        if box is None:
            box = bounding_xywh(guess[:, 0], guess[:, 1])
        src = self.landmarks[idx].astype(np.float32)
        sim, _ = cv2.estimateAffinePartial2D(src, guess.astype(np.float32), method=cv2.LMEDS)
        if sim is None or not np.isfinite(sim).all():
            return None
        scale = float(np.sqrt(abs(np.linalg.det(sim[:, :2]))))
        # A reference relit as the frame is lit is already matched in brightness; the plain one
        # gets its face box's brightness and contrast matched.
        if grey.shape == self.reference.shape and (self.track is not None or abs(scale - 1.0) < REWARP_SCALE):
            # Same geometry (or re-anchoring a followed face, whose apparent scale change is a
            # turn, not a zoom): LK straight from the reference, which resampling would blur.
            ref = reference if reference is not None else self._matched_reference(grey, box)
            start = src
        else:
            src_img = reference if reference is not None else self._matched_reference(grey, box, sim)
            size = (grey.shape[1], grey.shape[0])
            ref = cv2.warpAffine(src_img, sim, size, flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
            # Beyond the reference's frame the frame itself: LK's coarse pyramid levels then see
            # the same surroundings in both (a smeared border would pull them off a small face).
            cover = cv2.warpAffine(np.full(src_img.shape, 255, np.uint8), sim, size, flags=cv2.INTER_NEAREST,
                                   borderMode=cv2.BORDER_CONSTANT)
            ref = np.where(cover > 0, ref, grey)
            start = (src @ sim[:, :2].T + sim[:, 2]).astype(np.float32)
        pts, ok = self._flow(ref, grey, start, guess)
        if ok.sum() < MIN_POINTS:
            return None
        return Track(ref_index=idx[ok], xy=pts[ok].astype(np.float32))

    def acquire(self, grey: np.ndarray, posed=None) -> Track | None:
        """Find the face from scratch (see the module docstring): the detector's faces -> the
        similarity of their keypoints -> LK from the reference relit as the frame is lit, and
        ``posed(face, grey) -> Track or None`` when given (see :meth:`update`). The
        squares for a small face are searched only when the whole frame shows none and no
        search backs off (:data:`SEARCH_BACKOFF_MAX`)."""
        small = self.search_wait == 0
        if not small:
            self.search_wait -= 1
        faces = self.detector.detect(grey, small=small)
        track = self._from_faces(grey, faces[:CANDIDATE_FACES], posed) if faces else None
        if track is None:
            if small:
                self._back_off()
        else:
            self.search_wait = self.search_gap = 0
        return track

    def face_similarity(self, face: Face) -> np.ndarray | None:
        """The (2, 3) reference -> frame similarity a detected face gives: against the reference's
        face (:func:`.face_detect.face_similarity`), or (the detector saw no face in the
        reference) the boxes' scale and shift."""
        if self.ref_face is not None:
            return face_similarity(self.ref_face, face)
        rx, ry, rw, _ = self.ref_box
        x, y, w, _ = face_xywh(face)
        s = w / max(rw, 1)
        return np.array([[s, 0.0, x - s * rx], [0.0, s, y - s * ry]])

    def _from_faces(self, grey: np.ndarray, faces: list[Face], posed=None) -> Track | None:
        """The track of the face among ``faces`` that the most landmarks are followed of from the
        reference: the bundle's person (another face does not look like its reference, and the
        subspace of a few smooth basis images explains any face about as well). Per face, the
        similarity's start (:meth:`_track_at`) and - when that holds less than
        :data:`POSED_BELOW_SHARE` of the landmarks - ``posed``'s, the one holding more points."""
        best = None
        for face in faces:
            sim = self.face_similarity(face)
            track = self._track_at(grey, sim, face_xywh(face)) if sim is not None else None
            tried = posed is not None and (track is None or len(track) < POSED_BELOW_SHARE * len(self.landmarks))
            other = posed(face, grey) if tried else None
            if other is not None and (track is None or len(other) > len(track)):
                track = other
            if track is not None and (best is None or len(track) > len(best)):
                best = track
        return best

    def _track_at(self, grey: np.ndarray, sim: np.ndarray, box) -> Track | None:
        """LK from the reference of the landmarks ``sim`` places in ``grey``. Two starts, the one LK
        holds more points from kept: the reference brightness matched at the detector's guess (a
        face in the room's light; the relit reference, a fit of a few basis images, is too smooth
        for LK there: 8 points or none where the plain one held 31-43 on the tests' small synthetic
        head), and the reference relit as the frame is lit where the subspace puts the face
        (:meth:`.face_subspace.FaceSubspace.refine` from the guess, a few % of the face off: a face
        lit from one side, which the plain reference does not look like - on the real side-lit
        Yale clip the plain start alone relit the face 4.6 dB below the still prediction). The
        relit start is tried only when the plain one holds less than :data:`PLAIN_START_SHARE`
        of the landmarks."""
        track = self._lk_at(grey, sim, box, None)
        if track is not None and len(track) >= PLAIN_START_SHARE * len(self.landmarks):
            return track
        if self.subspace is not None:
            from relight.colour import decode_srgb8

            refined = self.subspace.refine(decode_srgb8(grey), sim)
            if refined is not None:
                reference = self._relit(grey, refined[0])
                if reference is not None:
                    other = self._lk_at(grey, refined[0], box, reference)
                    if other is not None and (track is None or len(other) > len(track)):
                        track = other
        return track

    def _lk_at(self, grey: np.ndarray, sim: np.ndarray, box, reference: np.ndarray | None) -> Track | None:
        """LK from ``reference`` (None: the reference brightness matched) of the landmarks ``sim``
        places inside ``grey``."""
        guess = (self.landmarks @ sim[:, :2].T + sim[:, 2]).astype(np.float32)
        h, w = grey.shape
        inside = (guess[:, 0] >= 0) & (guess[:, 0] < w) & (guess[:, 1] >= 0) & (guess[:, 1] < h)
        if inside.sum() < MIN_POINTS:
            return None
        idx = np.flatnonzero(inside)
        return self.from_reference(grey, guess[idx], idx, box=box, reference=reference)

    def _reanchor(self, grey: np.ndarray, track: Track, predict, refind) -> Track:
        """``track`` with the landmarks found again (see :meth:`update`) merged in; ``age`` back to
        0 when any were."""
        idx = np.arange(len(self.landmarks))
        guess = np.asarray(predict(idx), dtype=np.float32)
        h, w = grey.shape
        inside = (guess[:, 0] >= 0) & (guess[:, 0] < w) & (guess[:, 1] >= 0) & (guess[:, 1] < h)
        fresh = None
        if inside.sum() >= MIN_POINTS and refind is not None:
            fresh = refind(idx[inside], grey)
        elif inside.sum() >= MIN_POINTS:  # no pose to warp templates with: LK from the reference
            ref = self.lit_reference
            if ref is None and self.subspace is not None:
                sim, _ = cv2.estimateAffinePartial2D(self.landmarks[track.ref_index], track.xy, method=cv2.LMEDS)
                if sim is not None and np.isfinite(sim).all():
                    ref = self.relit_reference(grey, sim)
            fresh = self.from_reference(grey, guess[inside], idx[inside], reference=ref)
        if fresh is None:
            return track
        # Keep the followed points and add (or correct) the ones found again - those that agree
        # with them, or for new ones with where the pose puts them, within REANCHOR_AGREE px:
        # matching the flat reference to a turned head can lock a point onto the wrong corner, and
        # a handful of those would swing the pose.
        tol = px_at(REANCHOR_AGREE_AT_540, grey.shape[0])
        merged = dict(zip(track.ref_index.tolist(), track.xy, strict=True))
        for k, p in zip(fresh.ref_index.tolist(), fresh.xy, strict=True):
            near = merged.get(k, guess[k])
            if float(np.hypot(*(p - near))) <= tol:
                merged[k] = p
        keys = np.fromiter(merged.keys(), dtype=np.int64)
        self.age = 0
        return Track(ref_index=keys, xy=np.array([merged[k] for k in keys], dtype=np.float32))

    def anchor_acquired(self, grey: np.ndarray, predict, refind) -> Track:
        """The track acquired on this frame (:attr:`acquired`) re-anchored at once with the head
        pose it gave (``predict``, ``refind`` as for :meth:`update`; ``grey``: this frame's
        tracking copy): the first re-anchoring made on the frame the face is found, not two
        frames later (on the tests' shadowed cheek the track then held 42-49 points, against 18-32
        when LK from the reference alone started it)."""
        self.track = self._reanchor(grey, self.track, predict, refind)
        self.anchored = len(self.track)
        return self.track

    def update(self, grey: np.ndarray, predict=None, refind=None, posed=None) -> Track | None:
        """This frame's track (None: no face). ``predict(ref_index) -> (M, 2)`` gives where the
        current pose puts landmarks (used to re-anchor); without it tracks are only followed.
        ``refind(ref_index, grey) -> Track or None``: the landmarks searched again with templates
        warped by the current pose (:func:`relight.engine.refind.refind_landmarks`); when
        given, re-anchoring uses it instead of LK from the reference. ``posed(face, grey) -> Track
        or None``: a face's start from a head pose (see the module docstring), tried at
        acquisition beside the similarity's."""
        grey = np.ascontiguousarray(grey)
        track = None
        if self.track is not None and self.prev is not None and self.prev.shape == grey.shape:
            pts, ok = self._flow(self.prev, grey, self.track.xy)
            if ok.sum() >= MIN_POINTS:
                track = Track(ref_index=self.track.ref_index[ok], xy=pts[ok].astype(np.float32))
        self.age += 1
        self.acquired = self.reanchored = False
        if track is not None and predict is not None and (
                self.age >= REANCHOR_EVERY or len(track) < REANCHOR_BELOW * self.anchored):
            track = self._reanchor(grey, track, predict, refind)
            self.reanchored = self.age == 0
        if track is None:
            track = self.acquire(grey, posed)
            self.age = 0
            self.acquired = track is not None
        if self.age == 0 and track is not None:
            self.anchored = len(track)
        self.track = track
        self.prev = grey
        return track

    def drop(self, *, back_off: bool = True) -> None:
        """Forget the current track: the next frames acquire the face again. ``back_off``: the
        track was found to be no face (no consistent pose), so the search for a small face backs
        off as after a search that found none; else (a new, unrelated video) it starts afresh."""
        self.track = None
        self.lit_reference = None
        if back_off:
            self._back_off()
        else:
            self.search_wait = self.search_gap = 0

    def _back_off(self) -> None:
        self.search_gap = min(max(1, 2 * self.search_gap), SEARCH_BACKOFF_MAX)
        self.search_wait = self.search_gap
