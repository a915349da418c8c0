"""Face tracking: the bundle's reference landmarks followed through a video.

Every tracked point keeps the index of the reference landmark it came from, so it carries that
landmark's 3D position (for the head pose) and its reference position (for the warp).

* Acquire: OpenCV's Haar cascade finds the face in the frame (on a downscaled copy) and in the
  reference; the box pair gives a similarity guess for every landmark; pyramidal Lucas-Kanade
  from the reference (brightness matched inside the face box) refines it; forward-backward
  checked. No face, or too few points survive: no track (the caller passes the frame through).
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
from relight.faces import detect_face_grey
from relight.numerics import px_at

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
#: While no face is in view, the subspace search (~0.7 s a 320x240 frame here, the Haar box 30
#: ms) runs again after 1, 2, 4, then every SEARCH_BACKOFF_MAX frames: an empty room costs an
#: eighth of that per frame instead of all of it, a face that comes back is found within
#: SEARCH_BACKOFF_MAX frames (or at once when the Haar box sees it).
SEARCH_BACKOFF_MAX = 8
#: Haar detection runs on a copy at most this many rows high.
DETECT_ROWS = 360
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


def detect_face_box(grey: np.ndarray) -> tuple[int, int, int, int] | None:
    """The largest frontal face (x, y, w, h) in a grey frame, or None (detected on a copy of
    ``DETECT_ROWS`` rows: :func:`relight.faces.detect_face_grey`)."""
    return detect_face_grey(grey, DETECT_ROWS)


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

    def __init__(self, reference: np.ndarray, landmarks: np.ndarray, mask: np.ndarray, finder=None):
        self.reference = np.ascontiguousarray(reference)
        self.finder = finder
        self.landmarks = thin_points(np.asarray(landmarks, dtype=np.float32).reshape(-1, 2), MAX_TRACKED)
        if len(self.landmarks) < MIN_POINTS:
            raise InputError(f"the bundle has {len(self.landmarks)} landmarks; tracking needs {MIN_POINTS}")
        self.mask = mask
        box = detect_face_box(self.reference)
        if box is None:  # the reference face as the mask's bounding box
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
        # Back-off of the subspace search while no face is found: frames to skip, and the gap.
        self.search_wait = 0
        self.search_gap = 0

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
        frame) puts it (:meth:`relight.engine.acquire.FaceFinder.relit`); the plain reference
        without a finder or when the fit explains little of the face."""
        if self.finder is None:
            return self.reference
        from relight.colour import decode_srgb8, encode_srgb8

        relit, share = self.finder.relit(decode_srgb8(grey), sim)
        if not share > RELIT_MIN_SHARE:
            return self.reference
        out = self.reference.copy()
        x0, y0 = (int(round(v)) for v in self.finder.origin)
        h, w = relit.shape
        region = out[y0:y0 + h, x0:x0 + w]
        m = self.finder.mask[:region.shape[0], :region.shape[1]]
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

    def acquire(self, grey: np.ndarray) -> Track | None:
        """Find the face from scratch: Haar box -> similarity guess -> LK from the reference; where
        that finds nothing (a face lit from one side, a tight crop), the bundle's own face in its
        illumination subspace (:mod:`relight.engine.acquire`) -> LK from the reference relit as
        the frame is lit."""
        box = detect_face_box(grey)
        if box is not None:
            rx, ry, rw, _ = self.ref_box
            x, y, w, _ = box
            s = w / max(rw, 1)
            guess = (self.landmarks - np.array([rx, ry], np.float32)) * s + np.array([x, y], np.float32)
            track = self.from_reference(grey, guess, box=box)
            if track is not None:
                return track
        if self.finder is None:
            return None
        if self.search_wait > 0:  # a recent search found nothing: the Haar box alone this frame
            self.search_wait -= 1
            return None
        track = self._search(grey)
        if track is None:
            self._back_off()
        else:
            self.search_gap = 0
        return track

    def _search(self, grey: np.ndarray) -> Track | None:
        from relight.colour import decode_srgb8

        found = self.finder.find(decode_srgb8(grey))
        if found is None:
            return None
        guess = (self.landmarks @ found.sim[:, :2].T + found.sim[:, 2]).astype(np.float32)
        h, w = grey.shape
        inside = (guess[:, 0] >= 0) & (guess[:, 0] < w) & (guess[:, 1] >= 0) & (guess[:, 1] < h)
        if inside.sum() < MIN_POINTS:
            return None
        idx = np.flatnonzero(inside)
        return self.from_reference(grey, guess[idx], idx, reference=self.relit_reference(grey, found.sim))

    def update(self, grey: np.ndarray, predict=None, refind=None) -> Track | None:
        """This frame's track (None: no face). ``predict(ref_index) -> (M, 2)`` gives where the
        current pose puts landmarks (used to re-anchor); without it tracks are only followed.
        ``refind(ref_index, grey) -> Track or None``: the landmarks searched again with templates
        warped by the current pose (:func:`relight.engine.refind.refind_landmarks`); when
        given, re-anchoring uses it instead of LK from the reference."""
        grey = np.ascontiguousarray(grey)
        track = None
        if self.track is not None and self.prev is not None and self.prev.shape == grey.shape:
            pts, ok = self._flow(self.prev, grey, self.track.xy)
            if ok.sum() >= MIN_POINTS:
                track = Track(ref_index=self.track.ref_index[ok], xy=pts[ok].astype(np.float32))
        self.age += 1
        if track is not None and predict is not None and (
                self.age >= REANCHOR_EVERY or len(track) < REANCHOR_BELOW * self.anchored):
            idx = np.arange(len(self.landmarks))
            guess = np.asarray(predict(idx), dtype=np.float32)
            h, w = grey.shape
            inside = (guess[:, 0] >= 0) & (guess[:, 0] < w) & (guess[:, 1] >= 0) & (guess[:, 1] < h)
            fresh = None
            if inside.sum() >= MIN_POINTS and refind is not None:
                fresh = refind(idx[inside], grey)
            elif inside.sum() >= MIN_POINTS:  # no pose to warp templates with: LK from the reference
                ref = self.lit_reference
                if ref is None and self.finder is not None:
                    sim, _ = cv2.estimateAffinePartial2D(self.landmarks[track.ref_index], track.xy, method=cv2.LMEDS)
                    if sim is not None and np.isfinite(sim).all():
                        ref = self.relit_reference(grey, sim)
                fresh = self.from_reference(grey, guess[inside], idx[inside], reference=ref)
            if fresh is not None:
                # Keep the followed points and add (or correct) the ones found again - those that
                # agree with them, or for new ones with where the pose puts them, within
                # REANCHOR_AGREE px: matching the flat reference to a turned head can lock a point
                # onto the wrong corner, and a handful of those would swing the pose.
                tol = px_at(REANCHOR_AGREE_AT_540, grey.shape[0])
                merged = dict(zip(track.ref_index.tolist(), track.xy, strict=True))
                for k, p in zip(fresh.ref_index.tolist(), fresh.xy, strict=True):
                    near = merged.get(k, guess[k])
                    if float(np.hypot(*(p - near))) <= tol:
                        merged[k] = p
                keys = np.fromiter(merged.keys(), dtype=np.int64)
                track = Track(ref_index=keys, xy=np.array([merged[k] for k in keys], dtype=np.float32))
                self.age = 0
        if track is None:
            track = self.acquire(grey)
            self.age = 0
        if self.age == 0 and track is not None:
            self.anchored = len(track)
        self.track = track
        self.prev = grey
        return track

    def drop(self, *, back_off: bool = True) -> None:
        """Forget the current track: the next frames acquire the face again. ``back_off``: the
        track was found to be no face (no consistent pose), so the subspace search backs off as
        after a search that found none; else (a new, unrelated video) it starts afresh."""
        self.track = None
        self.lit_reference = None
        if back_off:
            self._back_off()
        else:
            self.search_wait = self.search_gap = 0

    def _back_off(self) -> None:
        self.search_gap = min(max(1, 2 * self.search_gap), SEARCH_BACKOFF_MAX)
        self.search_wait = self.search_gap
