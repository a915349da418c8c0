"""The per-frame path's tracking, head pose, re-anchoring and warps."""

import cv2
import numpy as np
import pytest

from relight.directions import rotation_angles, rotation_matrix

from .tolerances import (
    F32_EXACT,
    F32_LOOSE,
    F64_EXACT,
    MODEL_NORMAL_MEDIAN_DEG,
    NCC_SELF_PEAK,
    ONE_EURO_LAG_DEG,
    ONE_EURO_REST_STD,
    POSE_NOISY_DEG,
    POSE_NOISY_GAIN,
    POSE_OUTLIER_DEG,
    POSE_SYNTHETIC_DEG,
    REFIND_FOUND_SHARE,
    REFIND_MEDIAN_PX,
    REFIND_START_PX,
    WARP_AFFINE_PX,
    WARP_HULL_SHARE,
)


def test_one_euro_filter_is_still_at_rest_and_follows_motion():
    from relight.engine.pose import OneEuroFilter

    f = OneEuroFilter(min_cutoff=1.0, beta=0.05)
    rng = np.random.default_rng(0)
    noisy = [f(5.0 + rng.normal(0, 0.5), i / 30) for i in range(120)]
    assert np.std(noisy[60:]) < ONE_EURO_REST_STD  # jitter of 0.5 smoothed
    f.reset()
    ramp = [f(30.0 * i / 30, i / 30)[()] for i in range(60)]  # 30 deg/s
    assert abs(ramp[-1] - 30.0 * 59 / 30) < ONE_EURO_LAG_DEG  # follows a fast turn with little lag
    slow = OneEuroFilter(min_cutoff=1.0, beta=0.0)
    lagged = [slow(30.0 * i / 30, i / 30)[()] for i in range(60)]
    assert abs(lagged[-1] - 30.0 * 59 / 30) > abs(ramp[-1] - 30.0 * 59 / 30)


def _bump_head(seed: int, n: int):
    """A landmark model on a Gaussian bump 60 px high (640x360 frame, default focal): its pose
    estimator and ``seen(angles) -> (n, 2)``, the landmarks' image positions with the head turned
    by (yaw, pitch, roll) degrees about their centroid."""
    from relight.engine.pose import PoseEstimator, camera_matrix, lift_landmarks

    rng = np.random.default_rng(seed)
    k_ref = camera_matrix((640, 360))
    pts = rng.uniform([220, 80], [420, 300], size=(n, 2))
    depth = 60 * np.exp(-((pts[:, 0] - 320) ** 2 + (pts[:, 1] - 190) ** 2) / 8000.0)
    model = lift_landmarks(pts, depth, k_ref)
    flip = np.diag([1.0, -1.0, -1.0])
    centre = model.mean(axis=0)

    def seen(angles):
        moved = (model - centre) @ (flip @ rotation_matrix(*angles) @ flip).T + centre
        proj = moved @ k_ref.T
        return proj[:, :2] / proj[:, 2:]

    return PoseEstimator(model, (640, 360)), seen


def test_pose_recovers_a_known_rotation():
    est, seen = _bump_head(1, 60)
    assert np.allclose(est.solve(np.arange(60), seen((0.0, 0.0, 0.0))).rotation, np.eye(3), atol=F32_LOOSE)
    for angles in [(20, 0, 0), (-15, 10, 5), (0, -12, -8)]:
        xy = seen(angles)
        xy[:5] += 40.0  # outliers
        est.last = None
        pose = est.solve(np.arange(60), xy)
        assert pose is not None and pose.inliers.size >= 50
        assert np.allclose(pose.angles, angles, atol=POSE_SYNTHETIC_DEG)
        assert np.allclose(rotation_angles(pose.rotation), angles, atol=POSE_SYNTHETIC_DEG)


def test_pose_is_not_held_back_by_a_lagging_warm_start():
    """A warm start from a pose 10 deg behind, with a fifth of the points left where that pose
    put them (drifted tracks): the pose must follow the rest (the warm start alone settled at
    13.6 deg, choosing its points by the lagging pose)."""
    est, seen = _bump_head(4, 80)
    est.last = est.solve(np.arange(80), seen((10.0, 0.0, 0.0)))
    xy = seen((20.0, 0.0, 0.0))
    xy[:16] = seen((10.0, 0.0, 0.0))[:16]
    pose = est.solve(np.arange(80), xy)
    assert pose is not None and abs(pose.angles[0] - 20.0) < POSE_OUTLIER_DEG


def test_a_minority_consensus_is_refitted_over_every_point():
    """Every landmark 2.5 px off (Gaussian) at a 20-degree turn: RANSAC's largest consensus at
    its threshold is a fifth of them and its pose 1-4.6 deg off; the pose solve hands out is fitted
    over every point (Cauchy) and must be closer on every head; told the points are not each the
    face's own measurement (``robust=False``), it keeps the consensus."""
    from relight.engine.pose import TRACK_INLIERS
    from relight.kernels.relight_inputs import rotation_angle_deg

    truth = rotation_matrix(20.0, 5.0, 0.0)
    consensus, fitted = [], []
    for seed in range(8):
        est, seen = _bump_head(seed, 100)
        xy = seen((20.0, 5.0, 0.0)) + np.random.default_rng(100 + seed).normal(0.0, 2.5, (100, 2))
        first = est.from_scratch(np.arange(100), xy)
        kept = est.solve(np.arange(100), xy, robust=False)  # (points a rough first pose placed)
        assert np.allclose(kept.rvec, first.rvec) and np.array_equal(kept.inliers, first.inliers)
        est.last = None
        pose = est.solve(np.arange(100), xy)
        assert first.inliers.size < TRACK_INLIERS * 100 and pose.inliers.size > first.inliers.size
        consensus.append(rotation_angle_deg(truth, first.rotation))
        fitted.append(rotation_angle_deg(truth, pose.rotation))
    assert max(fitted) < POSE_NOISY_DEG
    assert np.mean(fitted) < POSE_NOISY_GAIN * np.mean(consensus)


def test_the_robust_fit_converges_and_ignores_gross_outliers():
    """From a start 6 deg and 20 px off, exact points give back the pose; a third of them 40 px
    off barely move it; a start or points not finite, or too few points, come back unchanged."""
    from relight.engine.pose import robust_fit

    est, seen = _bump_head(2, 90)
    xy = seen((-15.0, 8.0, 4.0))
    exact = est.solve(np.arange(90), xy)
    start_r = exact.rvec + np.array([[0.1], [0.0], [0.0]])
    start_t = exact.tvec + np.array([[20.0], [0.0], [0.0]])
    rvec, tvec = robust_fit(est.model, xy, start_r, start_t, est.k, 1.67)
    assert np.allclose(rvec, exact.rvec, atol=1e-6) and np.allclose(tvec, exact.tvec, atol=1e-3)
    bad = xy.copy()
    bad[::3] += 40.0
    rvec, _ = robust_fit(est.model, bad, start_r, start_t, est.k, 1.67)
    assert np.degrees(np.linalg.norm(rvec - exact.rvec)) < POSE_OUTLIER_DEG
    for args in [(est.model, xy, start_r * np.nan, start_t), (est.model[:3], xy[:3], start_r, start_t),
                 (est.model, np.where(np.arange(90)[:, None] == 5, np.inf, xy), start_r, start_t)]:
        rvec, tvec = robust_fit(*args, est.k, 1.67)
        assert np.array_equal(rvec, args[2], equal_nan=True) and np.array_equal(tvec, args[3])


def test_facing_is_the_cosine_toward_the_camera_and_zero_behind():
    """A point on the optical axis facing the camera: 1; the pose turned 60 deg about Y: 0.5; a
    normal facing away: 0; a weight of zero in the robust fit is the point left out."""

    from relight.engine.pose import facing, robust_fit

    obj = np.array([[0.0, 0.0, 0.0]] * 3)
    normals = np.array([[0.0, 0.0, -1.0], [0.0, 0.0, -1.0], [0.0, 0.0, 1.0]])
    tvec = np.array([[0.0], [0.0], [500.0]])
    assert np.allclose(facing(normals, obj, np.zeros((3, 1)), tvec), [1.0, 1.0, 0.0])
    turned = np.array([[0.0], [np.radians(60.0)], [0.0]])
    assert np.allclose(facing(normals, obj, turned, tvec), [0.5, 0.5, 0.0])
    assert np.allclose(facing(normals, obj, np.array([[0.0], [np.pi], [0.0]]), tvec), [0.0, 0.0, 1.0])

    est, seen = _bump_head(5, 60)
    xy = seen((12.0, -6.0, 3.0))
    exact = est.solve(np.arange(60), xy)
    bad = xy.copy()
    bad[:10] += np.array([6.0, -4.0])
    w = np.ones(60)
    w[:10] = 0.0
    start_r, start_t = exact.rvec + 0.05, exact.tvec + 5.0
    with_weights = robust_fit(est.model, bad, start_r, start_t, est.k, 1.67, weights=w)
    left_out = robust_fit(est.model[10:], bad[10:], start_r, start_t, est.k, 1.67)
    assert np.allclose(with_weights[0], left_out[0], atol=1e-9) and np.allclose(with_weights[1], left_out[1], atol=1e-6)
    assert np.allclose(with_weights[0], exact.rvec, atol=1e-6)
    for w_bad in (np.full(60, np.nan), -w, np.zeros(60), np.ones(59)):
        assert np.array_equal(robust_fit(est.model, bad, start_r, start_t, est.k, 1.67, weights=w_bad)[0], start_r)


def test_the_warm_start_weights_points_by_how_squarely_they_face_the_camera():
    """Tracking from the last pose, a third of the points on surfaces turned almost edge-on
    (normals 85 deg from the camera) and 2.5 px off where the head puts them (within the warm
    start's reach): told the normals, the pose follows the points that face the camera; without
    them, Levenberg-Marquardt splits the difference."""
    from relight.engine.pose import PoseEstimator
    from relight.kernels.relight_inputs import rotation_angle_deg

    est, seen = _bump_head(6, 90)
    normals = np.tile([0.0, 0.0, -1.0], (90, 1))
    edge = np.arange(90) % 3 == 0
    normals[edge] = [np.sin(np.radians(85.0)), 0.0, -np.cos(np.radians(85.0))]
    xy = seen((8.0, 4.0, 0.0))
    xy[edge] += [2.5, 0.0]
    truth = rotation_matrix(8.0, 4.0, 0.0)
    errors = []
    for told in (normals, None):
        e = PoseEstimator(est.model, (640, 360), normals=told)
        e.last = e.solve(np.arange(90), seen((6.0, 3.0, 0.0)))
        e._since_check, e._share = -10, 0.0  # (the warm start alone: no RANSAC check on this frame)
        pose = e.solve(np.arange(90), xy)
        errors.append(rotation_angle_deg(truth, pose.rotation))
    assert errors[0] < 0.5 * errors[1], errors


def test_the_rigs_model_normals_are_the_bundles_normals(frame_path, small_bundle):
    """The landmarks' normals the pose weights by (from the lifted depth) agree with the bundle's
    own (photometric) normals there, turned into OpenCV's space, and are unit and face the camera."""
    rig = frame_path.rig
    x0, y0 = small_bundle.crop_origin
    cw = np.asarray(small_bundle.mask_crop).shape[1]
    where = {int(p): i for i, p in enumerate(np.asarray(small_bundle.pixels, np.int64))}
    pts = np.rint(rig.control_ref[:rig.n_landmarks] - [x0, y0]).astype(np.int64)
    idx = [where.get(int(y) * cw + int(x)) for x, y in pts]
    ok = np.array([i is not None for i in idx])
    assert ok.mean() > 0.9
    theirs = np.asarray(small_bundle.normal, np.float64)[[i for i in idx if i is not None]] * [1.0, -1.0, -1.0]
    theirs /= np.linalg.norm(theirs, axis=1, keepdims=True)
    ours = rig.model_normals[:rig.n_landmarks][ok]
    assert np.allclose(np.linalg.norm(rig.model_normals, axis=1), 1.0) and (rig.model_normals[:, 2] <= 0).all()
    assert np.median(np.degrees(np.arccos(np.clip((theirs * ours).sum(1), -1.0, 1.0)))) < MODEL_NORMAL_MEDIAN_DEG


def test_reanchoring_finds_landmarks_where_the_pose_misplaces_them(frame_path, small_bundle):
    """The reference moved by a known similarity; the pose given to the search is 2 px off: the
    landmarks are found where they are, not where the pose puts them."""
    from relight.engine.tracking_image import TRACK_ROWS, track_exposure

    fp = frame_path
    fp.reset()
    ref = np.ascontiguousarray(np.asarray(small_bundle.background))
    h, w = ref.shape[:2]
    centre = fp.rig.control_ref[:fp.rig.n_landmarks].mean(axis=0)
    sim = cv2.getRotationMatrix2D((float(centre[0]), float(centre[1])), 3.0, 1.0)
    sim[:, 2] += (2.4, -1.3)
    frame = cv2.warpAffine(ref, sim, (w, h), flags=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
    idx = np.arange(fp.rig.n_landmarks)
    truth = fp.rig.control_ref[idx] @ sim[:, :2].T + sim[:, 2]
    est = fp.front_stage.estimator((w, h))
    est.last = None
    pose = est.solve(idx, truth + np.array([2.0, 0.0]))
    assert pose is not None
    ts = min(1.0, TRACK_ROWS / h)
    grey = cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY)
    if ts < 1:
        grey = cv2.resize(grey, (round(w * ts), round(h * ts)), interpolation=cv2.INTER_AREA)
    grey, _ = track_exposure(grey)
    found = fp.front_stage._refind(est, pose, ts, grey, idx)
    assert found is not None and len(found) >= REFIND_FOUND_SHARE * len(idx)
    err = np.linalg.norm(found.xy / ts - truth[found.ref_index], axis=1)
    before = np.linalg.norm(est.project(pose, found.ref_index) - truth[found.ref_index], axis=1)
    assert np.median(before) > REFIND_START_PX and np.median(err) < REFIND_MEDIAN_PX


def test_batched_correlation_matches_opencv_match_template():
    """Re-anchoring's all-at-once normalised cross-correlation against cv2.matchTemplate
    (TM_CCOEFF_NORMED) per window, and the parabola peak against its closed form."""
    from relight.engine.refind import normalised_correlation, parabola_peaks

    rng = np.random.default_rng(3)
    win = rng.integers(0, 256, (40, 21, 21)).astype(np.uint8)
    tpl = rng.integers(0, 256, (40, 13, 13)).astype(np.uint8)
    tpl[5] = win[5, 2:15, 6:19]  # an exact match at offset (y 2, x 6)
    win[7] = 40  # a flat window: no correlation
    r, contrast = normalised_correlation(win, tpl)
    ref = np.stack([cv2.matchTemplate(w, t, cv2.TM_CCOEFF_NORMED) for w, t in zip(win, tpl, strict=True)])
    assert r.shape == ref.shape == (40, 9, 9)
    assert np.abs(r - ref).max() < 1e-5
    assert np.unravel_index(r[5].argmax(), r[5].shape) == (2, 6) and r[5].max() > NCC_SELF_PEAK
    assert np.all(r[7] == 0.0)
    np.testing.assert_allclose(contrast, tpl.reshape(40, -1).astype(np.float64).std(axis=1), rtol=F32_EXACT)
    # a parabola y = -(x - 0.3)^2 sampled at -1, 0, 1 peaks at 0.3; a flat or rising one at 0
    np.testing.assert_allclose(parabola_peaks(np.array([-1.69, 1.0]), np.array([-0.09, 1.0]),
                                              np.array([-0.49, 1.0])), [0.3, 0.0], atol=F64_EXACT)


@pytest.mark.parametrize("full", [(720, 1280), (540, 960), (360, 640), (1080, 1920), (271, 481)])
def test_the_lit_reference_box_downscales_to_the_same_pixels(full):
    """The face box the live-lit tracking reference is remade in: the tracker's downscale of the
    full box equals the same pixels of the whole frame downscaled (the template matching must not
    shift)."""
    from relight.engine.tracking_image import aligned_box
    from relight.video_yuv import downscale_area

    img = np.random.default_rng(0).random(full).astype(np.float32)
    small = downscale_area(img, (480, 270))
    mask = np.zeros((270, 480), bool)
    mask[90:181, 170:311] = True
    (a, b, c, d), (e, f, g, h) = aligned_box(mask, full)
    assert mask[a:b, c:d].sum() == mask.sum()
    crop = downscale_area(img[e:f, g:h], (d - c, b - a))
    assert np.abs(crop - small[a:b, c:d]).max() < 1e-6


def test_piecewise_affine_warp_reproduces_an_affine_map():
    from relight.engine.warp import GRID_STEP, OUTSIDE, inverse_map

    rng = np.random.default_rng(2)
    ref = rng.uniform(50, 250, size=(40, 2))
    a = np.array([[1.1, 0.2], [-0.15, 0.9]])
    cur = ref @ a.T + np.array([30.0, -10.0])
    box = (0, 0, 320, 260)
    m = inverse_map(cur, ref, box)
    ys, xs = np.mgrid[0:260, 0:320]
    want = (np.stack([xs, ys], -1) - np.array([30.0, -10.0])) @ np.linalg.inv(a).T
    from scipy.spatial import Delaunay

    inside = Delaunay(cur).find_simplex(np.stack([xs, ys], -1).reshape(-1, 2)).reshape(260, 320) >= 0
    valid = m[..., 0] > OUTSIDE / 2
    near = cv2.dilate(inside.astype(np.uint8), np.ones((2 * GRID_STEP + 1,) * 2, np.uint8)) > 0
    # covers the hull, and at most a grid cell beyond it
    assert valid.sum() > WARP_HULL_SHARE * inside.sum() and not (valid & ~near).any()
    assert np.abs(m[valid] - want[valid]).max() < WARP_AFFINE_PX


def test_the_mesh_warp_is_the_piecewise_affine_warp_drawn_with_depth():
    """The fixed-topology mesh (the rigid warp's) maps a grid as the per-frame triangulation does
    where both are defined (an affine motion: the same map whatever the triangles); a triangle
    turned away is left out, and of two overlapping ones the nearer wins."""
    from relight.engine.warp import OUTSIDE, coarse_map, mesh_coarse_map, reference_triangles

    rng = np.random.default_rng(5)
    ref = rng.uniform(50, 250, size=(60, 2))
    a = np.array([[1.1, 0.2], [-0.15, 0.9]])
    cur = ref @ a.T + np.array([30.0, -10.0])
    box = (0, 0, 320, 260)
    tri = reference_triangles(ref)
    got = mesh_coarse_map(cur, ref, tri, box, depth=rng.uniform(1, 2, len(ref)))
    want = coarse_map(cur, ref, box)
    both = (got[..., 0] > OUTSIDE / 2) & (want[..., 0] > OUTSIDE / 2)
    assert np.array_equal(got[..., 0] > OUTSIDE / 2, want[..., 0] > OUTSIDE / 2)
    assert np.abs(got[both] - want[both]).max() < WARP_AFFINE_PX
    # two triangles over the same frame region, mapped to different reference places: depth decides
    quad = np.array([[10, 10], [110, 10], [10, 110]], np.float64)
    cur2 = np.concatenate([quad, quad])
    ref2 = np.concatenate([quad, quad + 500.0])
    tris = np.array([[0, 1, 2], [3, 4, 5]], np.int32)  # turning from +x toward +y, as reference_triangles
    box2 = (0, 0, 120, 120)
    for near, shift in ((np.array([1.0, 1, 1, 2, 2, 2]), 0.0), (np.array([2.0, 2, 2, 1, 1, 1]), 500.0)):
        m = mesh_coarse_map(cur2, ref2, tris, box2, depth=near)
        inside = m[..., 0] > OUTSIDE / 2
        assert inside.sum() > 10 and (m[inside][:, 0] >= shift).all() and (m[inside][:, 0] < shift + 120).all()
    # the same triangle with its corners reversed in this frame (turned away): nothing covered
    assert mesh_coarse_map(cur2[:3], ref2[:3], np.array([[0, 2, 1]], np.int32), box2) is None
