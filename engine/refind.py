"""Re-anchoring: the bundle's landmarks found again in a frame by template matching, where the
head pose puts them (:func:`refind_landmarks`, the tracker's ``refind``: see
:meth:`relight.engine.tracking.FaceTracker.update`), and the matching's parts - the batched
normalised cross-correlation (:func:`normalised_correlation`) and its sub-pixel peak
(:func:`parabola_peaks`) - and a face's start from the head pose its detected keypoints give
(:func:`posed_track`: the tracker's ``posed``).

Images are (H, W) uint8 grey codes at the tracking scale (:mod:`.tracking_image`); points are
(N, 2) float32 pixels (x right, y down).
"""
from __future__ import annotations

import cv2
import numpy as np

from relight.numerics import EPS_VALUE

from .face_detect import POSE_KEYPOINTS
from .pose import MIN_INLIERS
from .tracking import MIN_POINTS, Track

#: Re-anchoring (:func:`refind_landmarks`): template side and search radius (px at the tracking
#: scale), the least contrast a template needs (std of its 8-bit codes) and the least normalised
#: cross-correlation a match needs. Measured on three synthetic heads at 640x360 (each its own
#: 24 s 4 Hz capture; `relight bench video`): head rotation error median 2.02 / 2.48 / 2.07 ->
#: 1.15 / 1.23 / 1.29 deg, p95 3.95 / 5.97 / 5.49 -> 2.83 / 1.99 / 2.36, with the pose's RANSAC
#: check (:meth:`relight.engine.pose.PoseEstimator.solve`); that check alone: 1.68 / 2.67 / 1.38.
REFIND_TEMPLATE = 13
REFIND_RADIUS = 4
REFIND_MIN_STD = 4.0
REFIND_MIN_NCC = 0.6
#: A face found anew from its keypoints' head pose (:func:`posed_track`): the landmarks searched
#: within this share of the detected face's box diagonal (at most ACQUIRE_RADIUS_MAX px at the
#: tracking scale, at least REFIND_RADIUS) of where that pose puts them. Measured on the scanned
#: head at yaw -45..45 and pitch -30..30 (35 poses, 640x360): the keypoints' pose puts the
#: landmarks a median 3.4 % of the diagonal from where the pose found with them puts them, 10 %
#: at the 90th percentile; the RANSAC pose that follows needs only a share of them found.
ACQUIRE_RADIUS_SHARE = (0.1, 0.05)
ACQUIRE_RADIUS_MAX = 16
#: ... and the pose found with them is kept when it explains at least this many (twice the fewest
#: a pose is solved from, :data:`.pose.MIN_INLIERS`): measured on the same head over yaw -60..60
#: and pitch -30..30, the starts that explained 8-14 landmarks were 5-67 deg off, those with 17 or
#: more 1.4-7 deg (the goal's poses, |yaw| <= 45 and |pitch| <= 15, 21-100).
POSED_MIN_POINTS = 2 * MIN_INLIERS
#: Finite-difference step (reference px) of the pose's local affine at a landmark (the rig's
#: ``refind_model``: :class:`relight.engine.rig.FaceRig`), and the least area that affine may keep
#: (a landmark the turned head shows at a fifth of its area is grazing: its template would be a
#: smear).
REFIND_STEP = 2.0
REFIND_MIN_AREA = 0.2


def parabola_peaks(a0: np.ndarray, a1: np.ndarray, a2: np.ndarray) -> np.ndarray:
    """Sub-sample offsets (-0.5..0.5) of the peaks of the parabolas through three samples around
    maxima ``a1`` (arrays of the same shape); 0 where they do not curve down."""
    a0, a1, a2 = (np.asarray(a, np.float64) for a in (a0, a1, a2))
    den = a0 - 2.0 * a1 + a2
    curved = den < 0
    off = 0.5 * (a0 - a2) / np.where(curved, den, -1.0)
    return np.where(curved, np.clip(off, -0.5, 0.5), 0.0)


def normalised_correlation(windows: np.ndarray, templates: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Normalised cross-correlation (``cv2.TM_CCOEFF_NORMED``: gain and offset free) of each
    template over its window, all at once.

    windows : (n, S, S) uint8; templates : (n, T, T) uint8, T <= S. Returns ((n, S-T+1, S-T+1)
    float64 correlations in -1..1, 0 where a window patch or the template is flat; (n,) the
    templates' standard deviations in codes)."""
    win = np.ascontiguousarray(windows, dtype=np.uint8)
    tpl = np.asarray(templates, np.float32)
    n, s = win.shape[:2]
    t = tpl.shape[1]
    o = s - t + 1
    area = float(t * t)
    tz = tpl - tpl.mean(axis=(1, 2), keepdims=True, dtype=np.float64).astype(np.float32)
    t_norm2 = np.einsum("nij,nij->n", tz, tz, dtype=np.float64)
    # numerator: sum of tz x window patch (tz sums to 0, so the patch's mean drops out), in two
    # separable steps: every template row against every window row at every column offset
    # (one batched product), then summed along the diagonals. float32 is exact to ~1e-6 here
    # (codes <= 255, T^2 terms); the four-dimensional patch array would be 5x the bytes.
    rows = np.lib.stride_tricks.sliding_window_view(win.astype(np.float32), t, axis=2).reshape(n, s * o, t)
    c = (rows @ tz.transpose(0, 2, 1)).reshape(n, s, o, t)  # c[k, y, x, i] = sum_j win[k, y, x + j] tz[k, i, j]
    num = c[:, 0:o, :, 0].astype(np.float64)
    for i in range(1, t):
        num += c[:, i:i + o, :, i]
    # each patch's sum and sum of squares: one integral image of the windows stacked in a column
    ii, ii2 = cv2.integral2(win.reshape(n * s, s), sdepth=cv2.CV_64F, sqdepth=cv2.CV_64F)
    top = (np.arange(n) * s)[:, None] + np.arange(o)[None, :]  # (n, o) first row of each patch

    def box(a):
        b, u = a[top + t], a[top]
        return b[:, :, t:] - b[:, :, :o] - u[:, :, t:] + u[:, :, :o]

    s1, s2 = box(ii), box(ii2)
    var = np.maximum(s2 - s1 * s1 / area, 0.0)
    den = np.sqrt(var * t_norm2[:, None, None])
    tiny = EPS_VALUE * area  # a patch or template flatter than a thousandth of a code
    r = np.where(den > tiny, num / np.maximum(den, tiny), 0.0)
    return np.clip(r, -1.0, 1.0), np.sqrt(t_norm2 / area)


def refind_landmarks(rig, reference, est, pose, ts, grey, idx, radius: int = REFIND_RADIUS):
    """A Track of the landmarks ``idx`` found again in ``grey`` (the tracking image, ``ts`` its
    scale of the frame), or None. ``rig``: the path's :class:`relight.engine.rig.FaceRig`;
    ``reference``: the tracker's reference (the live-lit one when there is one); ``est``: the
    frame's :class:`relight.engine.pose.PoseEstimator`.

    Each landmark's template is cut from ``reference`` through the local affine map the head
    ``pose`` gives there (finite differences of the lifted model), so a turned head's landmark
    looks as the frame shows it; it is searched
    within ``radius`` px (at the tracking scale; :data:`REFIND_RADIUS` by default) of where the
    pose puts it by normalised cross-correlation
    (gain and offset free), the peak refined to sub-pixel by a parabola per axis. Templates
    without contrast, matches below ``REFIND_MIN_NCC`` and peaks on the search border
    (the landmark is farther) are left out."""
    rs = rig.ref_track_scale
    idx = np.asarray(idx)
    n, m_all = len(idx), len(rig.control_ref)
    d = REFIND_STEP
    P = est.project_points(pose, rig.refind_model[np.concatenate([idx, idx + m_all, idx + 2 * m_all])]) * ts
    c, jx, jy = P[:n], (P[n:2 * n] - P[:n]) / (d * rs), (P[2 * n:] - P[:n]) / (d * rs)
    T, R = REFIND_TEMPLATE, int(radius)
    h = (T - 1) / 2.0
    H, W = grey.shape
    # All landmarks at once (NumPy and one cv2.remap): per landmark, OpenCV's warpAffine,
    # matchTemplate and minMaxLoc cost ~50 us each with their Python overhead (6 ms a call).
    det = jx[:, 0] * jy[:, 1] - jy[:, 0] * jx[:, 1]
    gx = np.round(c[:, 0] - h).astype(np.int64) - R
    gy = np.round(c[:, 1] - h).astype(np.int64) - R
    ok = np.isfinite(det) & (det > REFIND_MIN_AREA) & (gx >= 0) & (gy >= 0) & \
        (gx + T + 2 * R <= W) & (gy + T + 2 * R <= H)
    sel = np.flatnonzero(ok)
    if sel.size < MIN_POINTS:
        return None
    dt = det[sel]
    i00, i01 = (jy[sel, 1] / dt)[:, None, None], (-jy[sel, 0] / dt)[:, None, None]  # the inverse affine
    i10, i11 = (-jx[sel, 1] / dt)[:, None, None], (jx[sel, 0] / dt)[:, None, None]
    u = (np.arange(T, dtype=np.float64) - h)[None, None, :]  # template column - h
    v = u.transpose(0, 2, 1)  # template row - h
    # template pixel (row v, column u) of landmark k reads the reference at L_k + inv_k (u, v)
    lx = (rig.control_ref[idx[sel], 0] * rs)[:, None, None]
    ly = (rig.control_ref[idx[sel], 1] * rs)[:, None, None]
    mx, my = lx + i00 * u + i01 * v, ly + i10 * u + i11 * v
    tmpl = cv2.remap(reference, mx.reshape(-1, T).astype(np.float32), my.reshape(-1, T).astype(np.float32),
                     cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).reshape(-1, T, T)
    side = np.arange(T + 2 * R)
    win = grey[gy[sel, None, None] + side[None, :, None], gx[sel, None, None] + side[None, None, :]]
    r, contrast = normalised_correlation(win, tmpl)
    flat = r.reshape(len(sel), -1)
    best = flat.argmax(axis=1)  # the first maximum in row order
    py, px = np.divmod(best, r.shape[2])
    peak = flat[np.arange(len(sel)), best]
    good = (contrast >= REFIND_MIN_STD) & (peak >= REFIND_MIN_NCC) & \
        (px > 0) & (px < r.shape[2] - 1) & (py > 0) & (py < r.shape[1] - 1)
    if int(good.sum()) < MIN_POINTS:
        return None
    k = np.flatnonzero(good)
    px, py, rk = px[k], py[k], r[k]
    ar = np.arange(k.size)
    dx = parabola_peaks(rk[ar, py, px - 1], rk[ar, py, px], rk[ar, py, px + 1])
    dy = parabola_peaks(rk[ar, py - 1, px], rk[ar, py, px], rk[ar, py + 1, px])
    xy = np.stack([gx[sel[k]] + px + dx + h, gy[sel[k]] + py + dy + h], axis=1).astype(np.float32)
    return Track(ref_index=idx[sel[k]], xy=xy)


def posed_track(rig, reference, est, keypoint_model, face, ts, grey):
    """A Track of the landmarks of a detected ``face`` (:class:`.face_detect.Face` in ``grey``,
    the tracking image at ``ts`` of the frame) found from a head pose - the start a head turned
    beyond what a similarity of the frontal reference follows needs - or None.

    The pose of the face's :data:`.face_detect.POSE_KEYPOINTS` against the reference's
    (``keypoint_model``: (6, 3), the reference face's keypoints lifted, :meth:`.rig.FaceRig.lift`;
    :meth:`.pose.PoseEstimator.few_points_pose`) is a rough one; every landmark is searched by
    :func:`refind_landmarks` (templates the pose turns) within :data:`ACQUIRE_RADIUS_SHARE` of the
    face's size of where it puts them, and the pose of those (RANSAC,
    :meth:`.pose.PoseEstimator.from_scratch`) keeps its inliers - at least
    :data:`POSED_MIN_POINTS`, else None. ``est.last`` is not touched."""
    k = list(POSE_KEYPOINTS)
    first = est.few_points_pose(keypoint_model[k], np.asarray(face.keypoints, np.float64)[k] / ts)
    if first is None:
        return None
    pose = first
    for share in ACQUIRE_RADIUS_SHARE:
        radius = int(np.clip(round(share * face.size), REFIND_RADIUS, ACQUIRE_RADIUS_MAX))
        found = refind_landmarks(rig, reference, est, pose, ts, grey, np.arange(rig.n_landmarks), radius)
        if found is None:
            return None
        pose = est.from_scratch(found.ref_index, found.xy / np.float32(ts))
        if pose is None:
            return None
    if pose.inliers.size < POSED_MIN_POINTS:
        return None
    return Track(ref_index=found.ref_index[pose.inliers], xy=found.xy[pose.inliers])
