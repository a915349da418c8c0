"""The frames' focal length found from the head itself: no focal length to guess (issue 49).

A webcam's field of view is not told (60-80 degrees across, and a flat photo moved about is an
orthographic view), yet the pose depends on it: a head off the frame's centre is seen from the
side by ``atan(offset / f)``, and its near parts are magnified more than its far ones by the
head's depth over the distance. With the wrong focal length a rigid model explains the tracked
points worse. So while the first second is tracked (with the default guess,
:data:`.pose.DEFAULT_FOCAL`, at first), every :data:`SAMPLE_EVERY`-th posed frame's inlier points
are kept; when :data:`STAGES`' counts of them are in (5, 10, 20 and 40 frames) the search runs
over all kept so far: each candidate focal length (:data:`CANDIDATES` x the frame's larger side,
the last the long one that models an orthographic camera) is scored by how well the best rigid
pose at that focal length explains each kept frame's points - the mean over the frames of the RMS
reprojection error, each point's error capped at :data:`ERROR_CAP_PX` (a point LK lost must not
decide) - in the frame for a file, on a worker beside a live source's frames (no frame waits for
it). The lowest score wins, refined by a parabola through it and its neighbours in log focal
length; the estimator switches to it when it explains the kept frames' points better than the
focal length in use does beyond their frame-to-frame scatter: a one-sided paired t-test of the
frames' RMS errors at the two focal lengths, at :data:`SIGNIFICANCE`. A fixed share of the mean
(2 % before) refused the right focal length on heads whose score is shallow - through the
studio's 80-degree webcam, on two heads of four the minimum lay within 8 % of the truth, 1.7-1.8 %
below the guess's score but lower in 14-15 of 20 frames (paired t 2.8-3.0) - while a 50-degree
clip, whose right answer is near the guess, scores t -1.3 to 1.9.

Why in stages: until the first switch every frame is posed at the guess, and through a short lens
that costs more than the search's remaining error - an off-centre head's view ray is off by
``atan(offset / f)`` at the wrong ``f``. With one run after 40 frames (20 taken every other
frame before), the studio's 80-degree heads (guess 1.43x the truth) were posed 2.7-5.2 deg off
(mean) over their first second against 1.4-2.4 told. Even one frame's points put the minimum
within 0.8-1.25x of the truth there, and five frames are enough for the test to refute a guess
that far off on two heads of four; the later runs refine over more frames, each against the
focal length then in use (its evidence, not the guess's, is what a new one must beat).

The model scored is the head's own shape (:attr:`.rig.FaceRig.shape_model`): an orthographic
capture's reference lifted straight, not through the long pinhole the pose's model is lifted
with - that lift makes near points smaller than far ones by their depth over its focal length, a
perspective of its own the search took for the frames' (with exact points of the studio's
80-degree clip: 0.91 of the true focal length, 1.00 straight).

Measured on the perspective studio (an orthographic capture's bundle, 640x360 clips of 50, 65
and 80 degrees at 60 cm: docs/performance.md): the score's minimum lies 14-17 % short of the
true focal length (21-28 % before the straight lift): the tracked points themselves lean that
way - at the true focal length, the points the path tracks put the minimum at 0.75-0.77 of it
where the exact points put it at 0.95 (the bundle's depth is not the head's), and tracked at a
shorter one they lean further. On an orthographic clip the minimum lies at 3-5x the frame's
side, where a long one is right.
"""

from __future__ import annotations

import cv2
import numpy as np

from .pose import ORTHOGRAPHIC_FOCAL, camera_matrix

#: Candidate focal lengths, times the frame's larger side (fields of view of 107 to 14 degrees
#: across it, then the orthographic model's long focal length; the widest below the studio's
#: 80-degree webcam's minimum, so the parabola refines it).
CANDIDATES = (0.37, 0.45, 0.55, 0.65, 0.8, 1.0, 1.25, 1.6, 2.0, 2.5, 3.2, 4.0, ORTHOGRAPHIC_FOCAL)
#: The search runs when this many posed frames' points are kept, over all kept so far (1.3 s at
#: 30 fps by the last), each run switching from the focal length in use only on its own evidence:
#: the first runs end the guess early where the frames refute it clearly, the later ones refine.
STAGES = (5, 10, 20, 40)
#: A posed frame's points are kept every this many posed frames, at most this many points each
#: (spread over the face's).
SAMPLE_EVERY = 1
MAX_POINTS = 40
#: Fewest inlier points a kept frame has.
MIN_POINTS = 12
#: A point's reprojection error is capped at this many pixels at 540 rows in the score.
ERROR_CAP_PX = 3.0
#: The estimate replaces the guess when the kept frames' RMS errors are lower at it than at the
#: guess with this one-sided significance (a paired t-test over the frames; else the guess is as good).
SIGNIFICANCE = 0.05


def frame_errors(model: np.ndarray, samples: list, size: tuple[int, int], focal: float) -> np.ndarray:
    """(len(samples),) float64: each of ``samples``' ((ref_index, xy) pairs) RMS error (px, each
    point capped) of the rigid pose (EPnP then Levenberg-Marquardt) of the ``model``'s points at
    ``focal``; NaN where no pose was found."""
    k = camera_matrix(size, focal)
    cap = ERROR_CAP_PX * size[1] / 540.0
    rms = np.full(len(samples), np.nan)
    for i, (idx, xy) in enumerate(samples):
        obj = model[idx].reshape(-1, 1, 3)
        img = np.asarray(xy, np.float64).reshape(-1, 1, 2)
        try:
            ok, rvec, tvec = cv2.solvePnP(obj, img, k, None, flags=cv2.SOLVEPNP_EPNP)
            if not ok:
                continue
            rvec, tvec = cv2.solvePnPRefineLM(obj, img, k, None, rvec, tvec)
            proj, _ = cv2.projectPoints(obj, rvec, tvec, k, None)
        except cv2.error:
            continue
        err = np.minimum(np.linalg.norm((proj - img).reshape(-1, 2), axis=1), cap)
        if np.isfinite(err).all():
            rms[i] = float(np.sqrt(np.mean(err * err)))
    return rms


def score(model: np.ndarray, samples: list, size: tuple[int, int], focal: float) -> float:
    """The mean over ``samples`` of :func:`frame_errors` (px; inf when no frame was posed)."""
    rms = frame_errors(model, samples, size, focal)
    return float(np.nanmean(rms)) if np.isfinite(rms).any() else float("inf")


def significantly_lower(errors: np.ndarray, reference: np.ndarray, significance: float = SIGNIFICANCE) -> bool:
    """Whether the frames' ``errors`` are lower than their ``reference`` errors (same frames, NaN
    where a frame was not posed) by more than their scatter: a one-sided paired t-test at
    ``significance`` over the frames posed in both (at least 3; ``scipy.stats.ttest_rel``). Equal
    errors are not lower."""
    from scipy.stats import ttest_rel

    errors, reference = np.asarray(errors, np.float64), np.asarray(reference, np.float64)
    both = np.isfinite(errors) & np.isfinite(reference)
    d = reference[both] - errors[both]
    if d.size < 3 or not d.mean() > 0:
        return False
    if not d.std(ddof=1) > 0:
        return True  # lower in every frame by the same amount (the t statistic's spread is 0)
    return bool(ttest_rel(errors[both], reference[both], alternative="less").pvalue < significance)


def best_focal(scores: np.ndarray, focals: np.ndarray) -> float:
    """The focal length at the lowest of ``scores`` (one per ``focals``, increasing), refined by
    a parabola through it and its neighbours in log focal length (kept inside them)."""
    i = int(np.argmin(scores))
    if i == 0 or i == len(scores) - 1 or not np.isfinite(scores[i - 1:i + 2]).all():
        return float(focals[i])
    x = np.log(focals[i - 1:i + 2])
    y = scores[i - 1:i + 2]
    # the vertex of the parabola through three points
    d = (x[0] - x[1]) * (x[0] - x[2]) * (x[1] - x[2])
    a = (x[2] * (y[1] - y[0]) + x[1] * (y[0] - y[2]) + x[0] * (y[2] - y[1])) / d
    b = (x[2] ** 2 * (y[0] - y[1]) + x[1] ** 2 * (y[2] - y[0]) + x[0] ** 2 * (y[1] - y[2])) / d
    if not (a > 0):
        return float(focals[i])
    return float(np.exp(np.clip(-b / (2 * a), x[0], x[2])))


class FocalSearch:
    """The search over one frame size's tracked frames (see the module docstring): :meth:`observe`
    each posed frame; whenever :attr:`ready`, :meth:`run` - in the frame for a file, on a worker
    beside a live source's frames (one run at a time; :meth:`observe` may go on meanwhile). Each
    run scores the points kept so far (the next of :data:`STAGES`' counts, :data:`MAX_POINTS` a
    frame; ~3.5 ms of CPU a frame scored, ~0.27 s over the four runs) and :attr:`done` after the last."""

    def __init__(self, model: np.ndarray, size: tuple[int, int], guess: float):
        self.model = np.asarray(model, np.float64)
        self.size = tuple(size)
        self.guess = float(guess)
        self.focals = np.asarray(CANDIDATES, np.float64) * max(self.size)
        self.samples: list = []
        self._posed = 0
        self.stage = 0  # the runs made
        #: The focal length in use (px): the guess until a run finds one better.
        self.current = self.guess

    @property
    def found(self) -> float | None:
        """The last focal length found (px; None: none found, or not yet) - :attr:`current` once a
        run switched from the guess (a switch needs errors lower than the focal length in use's,
        so never to the same one)."""
        return None if self.current == self.guess else self.current

    @property
    def done(self) -> bool:
        """Every run made."""
        return self.stage >= len(STAGES)

    @property
    def ready(self) -> bool:
        """The next run's samples are in."""
        return not self.done and len(self.samples) >= STAGES[self.stage]

    def observe(self, ref_index: np.ndarray, xy: np.ndarray) -> None:
        """A posed frame's inlier points (model indices, (N, 2) frame px): every SAMPLE_EVERY-th
        kept (with at least MIN_POINTS), at most MAX_POINTS of them spread over the list, until
        the last run's count."""
        if self.done or len(self.samples) >= STAGES[-1] or len(ref_index) < MIN_POINTS:
            return
        if self._posed % SAMPLE_EVERY == 0:
            pick = np.unique(np.linspace(0, len(ref_index) - 1, min(len(ref_index), MAX_POINTS)).round().astype(int))
            self.samples.append((np.array(ref_index)[pick], np.array(xy, np.float64)[pick]))
        self._posed += 1

    def run(self) -> float | None:
        """The next run: score every candidate over the samples kept so far; the focal length to
        switch to when it explains their points significantly better than the one in use
        (:func:`significantly_lower`; it becomes :attr:`current`), else None."""
        samples = self.samples[:STAGES[self.stage]]
        self.stage += 1
        if self.done:
            self.samples = []  # (nothing more is kept)
        scores = np.array([score(self.model, samples, self.size, float(f)) for f in self.focals])
        focal = best_focal(scores, self.focals)
        if not significantly_lower(frame_errors(self.model, samples, self.size, focal),
                                   frame_errors(self.model, samples, self.size, self.current)):
            return None
        self.current = focal
        return focal
