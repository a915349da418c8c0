"""Head pose from tracked landmarks: PnP with RANSAC against the bundle's depth, One Euro smoothing.

The model: each reference landmark lifted to 3D with the bundle's depth (pixels toward the
camera), placed so that a pinhole camera of focal length ``f_ref`` at the reference frame's
centre sees it exactly where the reference shows it (the reference pose is the identity). A
frame's pose is ``cv2.solvePnPRansac`` against that model with the frame's own camera (focal
length given, or ``DEFAULT_FOCAL`` x the frame's larger side: a phone or webcam of ~60-degree
field of view); a very long focal length models the orthographic synthetic camera. A tracked
frame's pose starts from the last one, fitted with a robust (Cauchy) loss, each point weighted by
how squarely its surface faces the camera (:func:`robust_fit`, :func:`facing`); where RANSAC's
consensus is a minority of the points, the pose is fitted so again over all of them.

Rotations handed out are in relight's camera space (+X right, +Y up, +Z toward the camera; see
:mod:`relight.directions`): ``R`` turns the reference head into this frame's head, and
``relight.directions.rotation_angles(R)`` gives (yaw, pitch, roll) in degrees. OpenCV's camera
space (+Y down, +Z away) is converted at this boundary only.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from relight.directions import rotation_angles
from relight.errors import InputError
from relight.numerics import px_at

#: Default focal length as a multiple of the frame's larger side.
DEFAULT_FOCAL = 0.85
#: ``focal="ortho"``: an orthographic camera (``relight synth``'s) modelled as a pinhole this many
#: frame sides away (measured on synthetic live video: 5-10 give the same pose error; PnP gets
#: unstable far beyond).
ORTHOGRAPHIC_FOCAL = 8.0
#: RANSAC reprojection threshold (px at 540 rows) and iterations.
RANSAC_PX_AT_540 = 2.5
RANSAC_ITERATIONS = 60
#: RANSAC's minimal solver: EPnP (5 points a hypothesis). AP3P (4 points) was measured 2.4x
#: faster (0.87 against 2.13 ms a call on the synthetic live clip's 104 points) but its noisier
#: hypotheses cost pose accuracy on the four bench clips: median 1.22 -> 1.28 deg, p95 2.37 ->
#: 2.49, max 2.5-3.6 -> 3.8-4.8 deg; kept EPnP.
RANSAC_SOLVER = cv2.SOLVEPNP_EPNP
#: Fewest RANSAC inliers for a pose to be believed.
MIN_INLIERS = 8
#: While tracking, the share of points the previous pose must explain to skip RANSAC.
TRACK_INLIERS = 0.6
#: While tracking, RANSAC checks the warm start's pose (:meth:`PoseEstimator.solve`) every this
#: many frames, and at once when the share of points it explains drops below CHECK_DROP x the
#: last frame's: a lagging pose (a fast turn) is caught within a sixth of a second at 30 fps,
#: the frames between skip RANSAC (1.5-2 ms at 720p). The share is itself no test: the bundle's
#: depth is not the head's, so a right pose explains only 55-90 % of the points within the
#: threshold (measured on the synthetic 640x360 and 1280x720 clips, 5th-95th percentile).
CHECK_EVERY = 2
CHECK_DROP = 0.85
#: A pose whose consensus is a minority of the tracked points (fewer than TRACK_INLIERS of them:
#: RANSAC chose it) is fitted again over every point with a Cauchy loss at the RANSAC threshold's
#: scale (:func:`robust_fit`): at a strong, fast turn the largest consensus at the threshold is a
#: third of the points and a biased third - on the synthetic 80-degree webcam clip 37-42 of 108,
#: whose own exact positions give a pose 4-5.6 deg off where all the points' give 1.8-2.3. The
#: points outside it still pull, weighted down by their error. Only there: every frame's pose
#: refitted so (SciPy's least_squares, its loss per coordinate) worsened the orthographic clip's
#: p95 (2.82 -> 3.50 deg), where the consensus is the right pose's. Gauss-Newton steps on the
#: reweighted points, Levenberg-damped so the loss never rises, at most this many.
ROBUST_ITERATIONS = 12
#: ... and it stops when a step lowers the loss by less than this share of it.
ROBUST_TOLERANCE = 1e-6
#: relight camera space <-> OpenCV camera space (flip Y and Z).
_FLIP = np.diag([1.0, -1.0, -1.0])


def camera_matrix(size: tuple[int, int], focal: float | str | None = None) -> np.ndarray:
    """3x3 pinhole intrinsics for a (width, height) frame: principal point at the centre.

    focal : pixels, None (``DEFAULT_FOCAL`` x the larger side) or "ortho" (an orthographic camera)."""
    w, h = size
    if focal == "ortho":
        f = ORTHOGRAPHIC_FOCAL * max(w, h)
    else:
        f = float(focal) if focal else DEFAULT_FOCAL * max(w, h)
    if not (np.isfinite(f) and f > 0):
        raise InputError(f"focal length {focal}: use a positive number of pixels")
    return np.array([[f, 0.0, w / 2.0], [0.0, f, h / 2.0], [0.0, 0.0, 1.0]])


def lift_landmarks(landmarks: np.ndarray, depth_at: np.ndarray, k_ref: np.ndarray) -> np.ndarray:
    """(N, 3) float64 model points (OpenCV camera space of the reference) of reference pixels
    ``landmarks`` (N, 2) with depths ``depth_at`` (N,) pixels toward the camera.

    The head's reference distance is one focal length (a model unit is one reference pixel at
    that distance), nearer by each point's depth."""
    f, cx, cy = k_ref[0, 0], k_ref[0, 2], k_ref[1, 2]
    z = f - np.asarray(depth_at, dtype=np.float64)
    z = np.maximum(z, 0.05 * f)  # a depth beyond the camera would be a broken bundle: keep it in front
    x = (landmarks[:, 0] - cx) * z / f
    y = (landmarks[:, 1] - cy) * z / f
    return np.stack([x, y, z], axis=1)


def lift_straight(landmarks: np.ndarray, depth_at: np.ndarray, k_ref: np.ndarray) -> np.ndarray:
    """(N, 3) float64 model points of reference pixels ``landmarks`` (N, 2) with depths
    ``depth_at`` (N,) seen by an orthographic camera: the head's own shape (a model unit is one
    reference pixel across and in depth), placed one focal length of ``k_ref`` away as
    :func:`lift_landmarks` places it. That lift sees the reference through a pinhole (a long one
    for an orthographic capture), so its near points come out smaller than its far ones by their
    depth over that focal length - 2 % for a face through :data:`ORTHOGRAPHIC_FOCAL`: a
    perspective of its own, which the focal search (:mod:`.focal`) would take for the frames'."""
    f, cx, cy = k_ref[0, 0], k_ref[0, 2], k_ref[1, 2]
    z = np.maximum(f - np.asarray(depth_at, dtype=np.float64), 0.05 * f)
    return np.stack([landmarks[:, 0] - cx, landmarks[:, 1] - cy, z], axis=1).astype(np.float64)


@dataclass
class Pose:
    """A frame's head pose: R (3x3, relight camera space, reference -> frame), the OpenCV
    rvec/tvec that project the model, and the RANSAC inliers (indices into the track)."""

    rotation: np.ndarray
    rvec: np.ndarray
    tvec: np.ndarray
    inliers: np.ndarray

    @property
    def angles(self) -> tuple[float, float, float]:
        return rotation_angles(self.rotation)


class PoseEstimator:
    """PnP + RANSAC of tracked landmarks against the model, warm-started from the last pose."""

    def __init__(self, model: np.ndarray, frame_size: tuple[int, int], focal: float | None = None,
                 normals: np.ndarray | None = None):
        self.model = np.asarray(model, dtype=np.float64)
        #: (N, 3) the model points' unit surface normals (toward the reference camera), or None:
        #: the warm start and the robust fit weight each point by how squarely it faces the
        #: camera (:func:`facing`); without them the warm start is Levenberg-Marquardt.
        self.normals = None if normals is None else np.asarray(normals, dtype=np.float64)
        self.k = camera_matrix(frame_size, focal)
        self.frame_size = frame_size
        self.last: Pose | None = None
        self._since_check = 0
        self._share = 0.0  # the share of points the last pose explained

    def solve(self, ref_index: np.ndarray, xy: np.ndarray, robust: bool = True) -> Pose | None:
        """The pose of this frame's tracked points (None when no consistent pose exists).

        Tracking (a previous pose): a fit from it (:meth:`_track`: weighted by :func:`facing`
        with the model's normals, else Levenberg-Marquardt), then again on the points whose
        reprojection error is under twice the RANSAC threshold (when most points agree,
        ``TRACK_INLIERS``); RANSAC then LM on its inliers checks it every ``CHECK_EVERY`` frames
        and when the share it explains drops (``CHECK_DROP``) - the one that explains more points
        is kept. At acquisition, and when the warm start fails: RANSAC, then LM. ``robust``: a
        pose whose consensus is a minority is then fitted over every point (:func:`robust_fit`) -
        for points that are each the face's own measurement; not for points a detector's rough
        first pose placed, whose errors share that pose's (the caller knows which it holds)."""
        if len(ref_index) < MIN_INLIERS:
            self.last = None
            return None
        obj = self.model[ref_index]
        img = np.asarray(xy, dtype=np.float64).reshape(-1, 1, 2)
        thr = px_at(RANSAC_PX_AT_540, self.frame_size[1])
        normals = None if self.normals is None else self.normals[ref_index]
        pose = self._track(obj, img, thr, normals) if self.last is not None else None
        if pose is None:
            pose = self._ransac(obj, img, thr)
            self._since_check = 0
            if pose is not None:
                self._share = self._explained(obj, img, pose, thr) / len(obj)
        else:
            # The warm start picks its inliers by the last pose, so a head that turned fast can
            # keep a lagging pose by its own choice of points (measured: 8 deg off for 45 frames
            # while its points were within 0.4 px). RANSAC from scratch too; the pose that
            # explains more points wins - every CHECK_EVERY frames, or at once when the warm
            # start explains a smaller share than the last pose did. A warm start that explains
            # every point cannot be beaten.
            explained = self._explained(obj, img, pose, thr)
            self._since_check += 1
            share = explained / len(obj)
            if explained < len(obj) and (self._since_check >= CHECK_EVERY or share < CHECK_DROP * self._share):
                self._since_check = 0
                other = self._ransac(obj, img, thr)
                if other is not None:
                    n_other = self._explained(obj, img, other, thr)
                    if n_other > explained:
                        pose, share = other, n_other / len(obj)
            self._share = share
        if robust and pose is not None and pose.inliers.size < TRACK_INLIERS * len(obj):
            pose = self._robust(obj, img, pose, thr, normals)
        self.last = pose
        return pose

    def from_scratch(self, ref_index: np.ndarray, xy: np.ndarray) -> Pose | None:
        """The pose of these points by RANSAC then LM alone - no warm start, :attr:`last` left
        as it is (a candidate's pose, compared before one is taken)."""
        if len(ref_index) < MIN_INLIERS:
            return None
        img = np.asarray(xy, dtype=np.float64).reshape(-1, 1, 2)
        return self._ransac(self.model[ref_index], img, px_at(RANSAC_PX_AT_540, self.frame_size[1]))

    def few_points_pose(self, points: np.ndarray, xy: np.ndarray) -> Pose | None:
        """A rough pose from a few model-space points (K, 3) (K >= 4, :func:`lift_landmarks`) seen
        at ``xy`` (K, 2) frame px - the detector's keypoints: SQPnP (the global minimum of the
        algebraic error, no start needed) then LM on all of them (too few to vote out an
        outlier). :attr:`last` is left as it is. None when it fails or puts the points behind the
        camera."""
        obj = np.asarray(points, np.float64).reshape(-1, 3)
        img = np.asarray(xy, np.float64).reshape(-1, 1, 2)
        if len(obj) < 4 or len(obj) != len(img) or not (np.isfinite(obj).all() and np.isfinite(img).all()):
            return None
        try:
            ok, rvec, tvec = cv2.solvePnP(obj.reshape(-1, 1, 3), img, self.k, None, flags=cv2.SOLVEPNP_SQPNP)
            if not ok:
                return None
            rvec, tvec = cv2.solvePnPRefineLM(obj.reshape(-1, 1, 3), img, self.k, None, rvec, tvec)
        except cv2.error:
            return None
        return self._finish(obj, img, rvec, tvec, np.arange(len(obj)))

    def refine(self, ref_index: np.ndarray, xy: np.ndarray) -> Pose | None:
        """The last pose refined by Levenberg-Marquardt on these points (a pose's inliers: no
        RANSAC); None (the last pose kept) when it does not converge on most of them."""
        if self.last is None or len(ref_index) < MIN_INLIERS:
            return None
        obj = self.model[ref_index]
        img = np.asarray(xy, dtype=np.float64).reshape(-1, 1, 2)
        pose = self._track(obj, img, px_at(RANSAC_PX_AT_540, self.frame_size[1]))
        if pose is not None:
            self.last = pose
        return pose

    def _finish(self, obj, img, rvec, tvec, inl) -> Pose | None:
        r_cv, _ = cv2.Rodrigues(rvec)
        # The model sits in the reference camera's space: a plausible pose keeps it in front.
        if not (np.isfinite(rvec).all() and np.isfinite(tvec).all()) or \
                ((obj[inl] @ r_cv.T)[:, 2] + tvec[2, 0]).min() <= 0:
            return None
        return Pose(rotation=_FLIP @ r_cv @ _FLIP, rvec=rvec, tvec=tvec, inliers=inl)

    def _errors(self, obj, img, rvec, tvec) -> np.ndarray:
        """(N,) px between where the pose (rvec, tvec) projects the points and where they were seen."""
        proj, _ = cv2.projectPoints(obj, rvec, tvec, self.k, None)
        return np.linalg.norm((proj - img).reshape(-1, 2), axis=1)

    def _explained(self, obj, img, pose: Pose, thr: float) -> int:
        """How many of the points ``pose`` projects within ``thr`` px of where they were seen."""
        return int((self._errors(obj, img, pose.rvec, pose.tvec) < thr).sum())

    def _robust(self, obj, img, pose: Pose, thr: float, normals=None) -> Pose:
        """``pose`` fitted again over every point by :func:`robust_fit` (its inliers those within
        twice ``thr`` px, as a warm start's are), each point weighted by :func:`facing` under
        ``pose`` when the points' ``normals`` are known; ``pose`` itself when that fit leaves the
        model behind the camera."""
        weights = None if normals is None else facing(normals, obj, pose.rvec, pose.tvec)
        rvec, tvec = robust_fit(obj, img, pose.rvec, pose.tvec, self.k, thr, weights=weights)
        inl = np.flatnonzero(self._errors(obj, img, rvec, tvec) < 2.0 * thr)
        fitted = self._finish(obj, img, rvec, tvec, inl) if inl.size >= MIN_INLIERS else None
        return fitted if fitted is not None else pose

    def _track(self, obj, img, thr, normals=None) -> Pose | None:
        """The warm start: from the last pose, twice a fit on the points within twice ``thr`` px
        - with the points' ``normals`` known, :func:`robust_fit` weighted by :func:`facing` (a
        point's error counts as its patch is seen); else Levenberg-Marquardt. None when the
        points within reach are fewer than TRACK_INLIERS of them."""
        rvec, tvec = self.last.rvec.copy(), self.last.tvec.copy()
        try:
            for _ in range(2):
                inl = np.flatnonzero(self._errors(obj, img, rvec, tvec) < 2.0 * thr)
                if inl.size < max(MIN_INLIERS, TRACK_INLIERS * len(obj)):
                    return None
                if normals is None:
                    rvec, tvec = cv2.solvePnPRefineLM(obj[inl], img[inl], self.k, None, rvec, tvec)
                else:
                    rvec, tvec = robust_fit(obj[inl], img[inl], rvec, tvec, self.k, thr,
                                            weights=facing(normals[inl], obj[inl], rvec, tvec))
            inl = np.flatnonzero(self._errors(obj, img, rvec, tvec) < 2.0 * thr)
        except cv2.error:
            return None
        if inl.size < max(MIN_INLIERS, TRACK_INLIERS * len(obj)):
            return None
        return self._finish(obj, img, rvec, tvec, inl)

    def _ransac(self, obj, img, thr) -> Pose | None:
        try:
            ok, rvec, tvec, inl = cv2.solvePnPRansac(obj.reshape(-1, 1, 3), img, self.k, None,
                                                     iterationsCount=RANSAC_ITERATIONS, reprojectionError=thr,
                                                     confidence=0.99, flags=RANSAC_SOLVER)
            if not ok or inl is None or len(inl) < MIN_INLIERS:
                return None
            inl = inl.ravel()
            rvec, tvec = cv2.solvePnPRefineLM(obj[inl].reshape(-1, 1, 3), img[inl], self.k, None, rvec, tvec)
        except cv2.error:
            return None
        return self._finish(obj, img, rvec, tvec, inl)

    def project(self, pose: Pose, ref_index: np.ndarray) -> np.ndarray:
        """(M, 2) frame positions of model points ``ref_index`` under ``pose``."""
        return self.project_points(pose, self.model[ref_index])

    def project_points(self, pose: Pose, points: np.ndarray) -> np.ndarray:
        """(M, 2) frame positions of any model-space points (M, 3) (:func:`lift_landmarks`) under ``pose``."""
        pts, _ = cv2.projectPoints(np.asarray(points, np.float64).reshape(-1, 1, 3), pose.rvec, pose.tvec, self.k,
                                   None)
        return pts.reshape(-1, 2)


def _cauchy_cost(err: np.ndarray, scale: float, weights: np.ndarray) -> float:
    """sum over points of weights * ln(1 + (err / scale)^2) (err: (N,) px)."""
    return float((weights * np.log1p((err / scale) ** 2)).sum())


def facing(normals: np.ndarray, obj: np.ndarray, rvec: np.ndarray, tvec: np.ndarray) -> np.ndarray:
    """(N,) float64 in [0, 1]: how squarely each model point's surface faces the camera under the
    pose (rvec, tvec) - the cosine between its turned normal (``normals`` (N, 3), unit, the model's
    space) and its direction to the camera, 0 where it faces away. A point's tracked position is
    as good as its patch: a surface turned by an angle shows its texture compressed by that
    angle's cosine, and one near the silhouette is about to be hidden."""
    r, _ = cv2.Rodrigues(np.asarray(rvec, np.float64).reshape(3, 1))
    cam = np.asarray(obj, np.float64).reshape(-1, 3) @ r.T + np.asarray(tvec, np.float64).ravel()
    dist = np.linalg.norm(cam, axis=1)
    cos = -np.einsum("ij,ij->i", np.asarray(normals, np.float64).reshape(-1, 3) @ r.T, cam) / np.maximum(dist, 1e-9)
    return np.clip(np.nan_to_num(cos, nan=0.0), 0.0, 1.0)


def robust_fit(obj: np.ndarray, img: np.ndarray, rvec: np.ndarray, tvec: np.ndarray, k: np.ndarray,
               scale: float, iterations: int = ROBUST_ITERATIONS,
               weights: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The pose (rvec, tvec: (3, 1) float64, OpenCV's) near a start that minimises
    sum_i w_i ln(1 + (e_i / scale)^2) over every point, e_i px its reprojection error and w_i its
    ``weights`` (N,) >= 0 (None: all 1): a Cauchy (Lorentzian) loss, quadratic within ``scale``
    px and growing only as a log beyond, so a point far off still pulls a little and no point
    decides alone.

    obj : (N, 3) model points; img : (N, 2) or (N, 1, 2) seen positions (px); k : the camera's
    3x3 intrinsics. Iteratively reweighted least squares: each point weighted by
    w_i / (1 + (e_i / scale)^2), a Gauss-Newton step on the weighted points with Levenberg damping
    raised until the loss falls (the Jacobian is ``cv2.projectPoints``'), at most ``iterations``.
    The start comes back unchanged when it or the weights are not finite, fewer than 4 points
    carry weight or no step lowers the loss."""
    obj = np.asarray(obj, np.float64).reshape(-1, 1, 3)
    img = np.asarray(img, np.float64).reshape(-1, 2)
    x = np.concatenate([np.asarray(rvec, np.float64).ravel(), np.asarray(tvec, np.float64).ravel()])
    start = (x[:3].reshape(3, 1).copy(), x[3:].reshape(3, 1).copy())
    pw = np.ones(len(obj)) if weights is None else np.asarray(weights, np.float64).ravel()
    if len(img) != len(obj) or len(pw) != len(obj) or not (np.isfinite(x).all() and np.isfinite(obj).all()
                                                           and np.isfinite(img).all() and np.isfinite(pw).all()
                                                           and (pw >= 0).all() and scale > 0) \
            or (pw > 0).sum() < 4:
        return start

    def residual(v):
        """(2N,) residuals, (N,) their points' errors (px), (2N, 6) Jacobian at the pose ``v``."""
        proj, jac = cv2.projectPoints(obj, v[:3], v[3:], k, None)
        r = proj.reshape(-1, 2) - img
        return r.ravel(), np.linalg.norm(r, axis=1), jac[:, :6]

    r, err, jac = residual(x)
    cost = _cauchy_cost(err, scale, pw)
    damping = 1e-3
    for _ in range(iterations):
        w = np.repeat(pw / (1.0 + (err / scale) ** 2), 2)
        a = jac.T @ (jac * w[:, None])
        g = jac.T @ (w * r)
        if not (np.isfinite(a).all() and np.isfinite(g).all()):
            break
        damped = np.diag(np.maximum(np.diag(a), 1e-12))
        while damping < 1e8:
            step = np.linalg.solve(a + damping * damped, -g)
            r_new, err_new, jac_new = residual(x + step)
            cost_new = _cauchy_cost(err_new, scale, pw)
            if np.isfinite(cost_new) and cost_new <= cost:
                break
            damping *= 10.0
        else:
            break
        x, r, err, jac = x + step, r_new, err_new, jac_new
        converged = cost - cost_new <= ROBUST_TOLERANCE * max(cost, 1.0)
        cost, damping = cost_new, max(damping / 10.0, 1e-7)
        if converged:
            break
    return x[:3].reshape(3, 1).copy(), x[3:].reshape(3, 1).copy()


class OneEuroFilter:
    """The One Euro filter (Casiez et al. 2012) on a vector: smooth when still, no lag when moving.

    ``min_cutoff`` (Hz) sets the smoothing at rest, ``beta`` how fast the cutoff rises with speed.
    Timestamps in seconds (variable frame rate is fine); a non-increasing one resets the filter.
    """

    def __init__(self, min_cutoff: float = 1.0, beta: float = 0.05, d_cutoff: float = 1.0):
        self.min_cutoff, self.beta, self.d_cutoff = float(min_cutoff), float(beta), float(d_cutoff)
        self.x = None
        self.dx = None
        self.t = None

    @staticmethod
    def _alpha(cutoff: float, dt: float) -> float:
        tau = 1.0 / (2.0 * np.pi * cutoff)
        return 1.0 / (1.0 + tau / dt)

    def reset(self) -> None:
        self.x = self.dx = self.t = None

    def __call__(self, x, t: float) -> np.ndarray:
        x = np.asarray(x, dtype=np.float64)
        if self.x is None or self.t is None or not (t > self.t):
            self.x, self.dx, self.t = x.copy(), np.zeros_like(x), float(t)
            return x.copy()
        dt = float(t) - self.t
        dx = (x - self.x) / dt
        a_d = self._alpha(self.d_cutoff, dt)
        self.dx = self.dx + a_d * (dx - self.dx)
        cutoff = self.min_cutoff + self.beta * np.abs(self.dx)
        a = 1.0 / (1.0 + 1.0 / (2.0 * np.pi * cutoff * dt))
        self.x = self.x + a * (x - self.x)
        self.t = float(t)
        return self.x.copy()
