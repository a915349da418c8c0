"""Stage 2: register the head's small motions (paper section 3.1, "Face registration").

Viola-Jones (:mod:`relight.faces`) finds the face in the reference (first no-flash) frame; Shi-Tomasi corners inside
it are tracked by pyramidal Lucas-Kanade into every later no-flash frame (from the reference
directly, seeded with the previous frame's motion, checked forward-backward); RANSAC rejects
outliers and the rigid motion (rotation + translation, no scale) is the least-squares (SVD)
fit to the inliers. Flash frames take the motion linearly interpolated between the no-flash
frames around them and are warped back onto the reference.

Motions use the convention of :func:`relight.directions.rigid_matrix`: ``[tx, ty, rot_deg]``
about a centre ``c`` maps reference pixel ``p`` to ``R(rot)(p - c) + c + t``.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from relight.directions import rigid_matrix
from relight.errors import InputError
from relight.numerics import EPS_VALUE

#: Lucas-Kanade settings: window, pyramid levels, forward-backward tolerance (pixels).
LK_WINDOW = 21
LK_LEVELS = 3
FB_TOLERANCE = 0.5
#: RANSAC inlier distance (pixels) and iterations.
RANSAC_PX = 1.0
RANSAC_ITERS = 300
#: Pre-smoothing of the (dark, noisy) frames before tracking, pixels.
TRACK_BLUR = 1.0
MAX_FEATURES = 400


def fit_rigid(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Least-squares rigid motion (rotation + translation) taking src (N, 2) to dst (N, 2): 2x3 matrix."""
    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    ms, md = src.mean(axis=0), dst.mean(axis=0)
    cov = (dst - md).T @ (src - ms)
    u, _, vt = np.linalg.svd(cov)
    d = np.sign(np.linalg.det(u @ vt)) or 1.0
    rot = u @ np.diag([1.0, d]) @ vt
    return np.hstack([rot, (md - rot @ ms)[:, None]])


def ransac_rigid(src: np.ndarray, dst: np.ndarray, *, threshold: float = RANSAC_PX, iters: int = RANSAC_ITERS,
                 rng: np.random.Generator | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Rigid motion robust to outliers: (2x3 matrix refitted on the inliers, inlier mask).

    All hypotheses (from random point pairs) are built and scored at once.
    """
    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    n = len(src)
    if n < 2:
        raise ValueError("need at least two point pairs")
    rng = rng or np.random.default_rng(0)
    i = rng.integers(0, n, iters)
    j = rng.integers(0, n, iters)
    ds, dd = src[j] - src[i], dst[j] - dst[i]
    ok = (i != j) & (np.linalg.norm(ds, axis=1) >= 4.0)
    if ok.any():
        # Rotation of the pair's vector; translation from the first point.
        ang = np.arctan2(dd[ok, 1], dd[ok, 0]) - np.arctan2(ds[ok, 1], ds[ok, 0])
        c, s = np.cos(ang), np.sin(ang)
        si, di = src[i[ok]], dst[i[ok]]
        tx = di[:, 0] - (c * si[:, 0] - s * si[:, 1])
        ty = di[:, 1] - (s * si[:, 0] + c * si[:, 1])
        px = c[:, None] * src[None, :, 0] - s[:, None] * src[None, :, 1] + tx[:, None]
        py = s[:, None] * src[None, :, 0] + c[:, None] * src[None, :, 1] + ty[:, None]
        inl = np.hypot(px - dst[None, :, 0], py - dst[None, :, 1]) < threshold
        best = inl[np.argmax(inl.sum(axis=1))]
    else:
        best = np.zeros(n, dtype=bool)
    if best.sum() < 2:
        best = np.ones(n, dtype=bool)
    m = fit_rigid(src[best], dst[best])
    # One refinement: re-select with the least-squares fit, refit.
    inl = np.linalg.norm(src @ m[:, :2].T + m[:, 2] - dst, axis=1) < threshold
    if inl.sum() >= 2:
        m = fit_rigid(src[inl], dst[inl])
        best = inl
    return m, best


def matrix_to_motion(m: np.ndarray, center: tuple[float, float]) -> tuple[float, float, float]:
    """A rigid 2x3 matrix as ``[tx, ty, rot_deg]`` about ``center`` (inverse of rigid_matrix)."""
    a = m[:, :2]
    rot = np.degrees(np.arctan2(a[0, 1], a[0, 0]))
    c = np.asarray(center, dtype=np.float64)
    t = a @ c + m[:, 2] - c
    return float(t[0]), float(t[1]), float(rot)


def prepare(grey: np.ndarray) -> np.ndarray:
    """The tracker's view of a frame: grey uint8, lightly smoothed against sensor noise."""
    return cv2.GaussianBlur(grey, (0, 0), TRACK_BLUR)


@dataclass
class TrackResult:
    """Motion of one frame: 2x3 matrix (reference -> frame), inliers used, RMS residual (px)."""

    matrix: np.ndarray
    inliers: int
    residual: float


class Tracker:
    """Tracks Shi-Tomasi corners of the reference into later frames; one rigid motion per frame."""

    def __init__(self, reference_grey: np.ndarray, region: np.ndarray | None = None, *,
                 max_features: int = MAX_FEATURES):
        self.ref = prepare(reference_grey)
        pts = cv2.goodFeaturesToTrack(self.ref, maxCorners=max_features, qualityLevel=0.005, minDistance=4,
                                      mask=None if region is None else region.astype(np.uint8) * 255,
                                      blockSize=7)
        if pts is None or len(pts) < 6:
            raise InputError("too few trackable features in the reference frame: the face needs texture and "
                             "light in the no-flash frames")
        self.points = pts.reshape(-1, 2).astype(np.float32)
        self.last = np.hstack([np.eye(2), np.zeros((2, 1))])
        self._ref_stats = self._stats(self.ref)
        self.rng = np.random.default_rng(0)

    def _stats(self, img):
        return float(img.mean()), float(img.std()) + EPS_VALUE

    def _match_brightness(self, img: np.ndarray) -> np.ndarray:
        # The camera's exposure and the dark frames' residual light change brightness between
        # frames; Lucas-Kanade assumes it constant, so match mean and contrast to the reference.
        m, s = self._stats(img)
        rm, rs = self._ref_stats
        out = (img.astype(np.float32) - m) * (rs / s) + rm
        return np.clip(out + 0.5, 0, 255).astype(np.uint8)

    def track(self, grey: np.ndarray) -> TrackResult:
        """Motion from the reference to ``grey`` (same size, uint8)."""
        img = self._match_brightness(prepare(grey))
        guess = (self.points @ self.last[:, :2].T + self.last[:, 2]).astype(np.float32)
        crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 40, 0.003)
        win = (LK_WINDOW, LK_WINDOW)
        fwd, st, _ = cv2.calcOpticalFlowPyrLK(self.ref, img, self.points, guess.copy(), winSize=win,
                                              maxLevel=LK_LEVELS, criteria=crit, flags=cv2.OPTFLOW_USE_INITIAL_FLOW)
        back, st2, _ = cv2.calcOpticalFlowPyrLK(img, self.ref, fwd, self.points.copy(), winSize=win,
                                                maxLevel=LK_LEVELS, criteria=crit, flags=cv2.OPTFLOW_USE_INITIAL_FLOW)
        ok = (st.ravel() == 1) & (st2.ravel() == 1) & (np.linalg.norm(back - self.points, axis=1) < FB_TOLERANCE)
        if ok.sum() < 6:
            return TrackResult(self.last.copy(), int(ok.sum()), float("inf"))
        m, inl = ransac_rigid(self.points[ok].astype(np.float64), fwd[ok].astype(np.float64), rng=self.rng)
        res = np.linalg.norm(self.points[ok][inl] @ m[:, :2].T + m[:, 2] - fwd[ok][inl], axis=1)
        self.last = m
        return TrackResult(m, int(inl.sum()), float(np.sqrt(np.mean(res**2))))


def interpolate_motions(known: dict[int, tuple[float, float, float]], frames,
                        times: np.ndarray | None = None) -> dict[int, tuple[float, float, float]]:
    """Motions at ``frames`` linearly interpolated between the known frames (held at the ends),
    in time when ``times`` (seconds per frame number) is given, else in frame numbers."""
    idx = np.array(sorted(known), dtype=np.int64)
    vals = np.array([known[int(i)] for i in idx], dtype=np.float64)
    frames = np.asarray(list(frames), dtype=np.int64)
    at = (lambda f: np.asarray(times, dtype=np.float64)[f]) if times is not None else (lambda f: f.astype(np.float64))
    x, xp = at(frames), at(idx)
    cols = [np.interp(x, xp, vals[:, k]) for k in range(3)]
    return {int(f): (float(cols[0][i]), float(cols[1][i]), float(cols[2][i])) for i, f in enumerate(frames)}


def warp_to_reference(image: np.ndarray, motion: tuple[float, float, float], center: tuple[float, float],
                      origin: tuple[int, int] = (0, 0), *, interpolation: int = cv2.INTER_CUBIC) -> np.ndarray:
    """Resample ``image`` (a crop at ``origin`` of a frame with ``motion``) onto the reference grid."""
    m = rigid_matrix(*motion, center)
    o = np.asarray(origin, dtype=np.float64)
    mc = m.copy()
    mc[:, 2] = m[:, :2] @ o + m[:, 2] - o
    h, w = image.shape[:2]
    return cv2.warpAffine(image, mc, (w, h), flags=interpolation | cv2.WARP_INVERSE_MAP,
                          borderMode=cv2.BORDER_REPLICATE)
