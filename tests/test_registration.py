"""Stage 2: rigid registration."""

import cv2
import numpy as np
import pytest

from relight.directions import rigid_matrix
from relight.pipeline.registration import (
    Tracker,
    fit_rigid,
    interpolate_motions,
    matrix_to_motion,
    ransac_rigid,
    warp_to_reference,
)

from .tolerances import F32_EXACT, F64_CLOSE, RIGID_FIT_PX, WARP_ROUND_TRIP


def test_fit_rigid_is_exact_and_ransac_ignores_outliers():
    rng = np.random.default_rng(0)
    src = rng.uniform(0, 300, (80, 2))
    m = rigid_matrix(2.5, -1.25, 0.3, (150.0, 150.0))
    dst = src @ m[:, :2].T + m[:, 2]
    np.testing.assert_allclose(fit_rigid(src, dst), m, atol=F64_CLOSE)
    bad = dst.copy()
    bad[:25] += rng.uniform(-30, 30, (25, 2))
    est, inl = ransac_rigid(src, bad)
    np.testing.assert_allclose(est, m, atol=F32_EXACT)
    assert not inl[:25].any() and inl[25:].all()


def test_motion_round_trip_and_interpolation():
    c = (120.0, 80.0)
    mot = (1.5, -0.75, 0.2)
    assert matrix_to_motion(rigid_matrix(*mot, c), c) == pytest.approx(mot, abs=F64_CLOSE)
    out = interpolate_motions({0: (0, 0, 0), 10: (1.0, 2.0, 0.5)}, [0, 5, 10, 12])
    assert out[5] == pytest.approx((0.5, 1.0, 0.25)) and out[12] == pytest.approx((1.0, 2.0, 0.5))


def _texture(h=240, w=320, seed=3):
    rng = np.random.default_rng(seed)
    img = cv2.GaussianBlur(rng.uniform(0, 255, (h, w)).astype(np.float32), (0, 0), 2.0)
    img = (img - img.min()) / np.ptp(img) * 180 + 40
    return img.astype(np.uint8)


def test_tracker_recovers_small_motions_to_a_tenth_of_a_pixel():
    ref = _texture()
    tracker = Tracker(ref)
    c = (160.0, 120.0)
    for mot in [(0.4, -0.3, 0.1), (2.7, 1.9, -0.3), (-1.2, 0.6, 0.05)]:
        m = rigid_matrix(*mot, c)
        moved = cv2.warpAffine(ref, m, (320, 240), flags=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
        res = tracker.track(moved)
        est = matrix_to_motion(res.matrix, c)
        ys, xs = np.mgrid[40:200:20, 40:280:20]
        pts = np.stack([xs.ravel(), ys.ravel(), np.ones(xs.size)], axis=1)
        err = np.linalg.norm(pts @ m.T - pts @ rigid_matrix(*est, c).T, axis=1)
        assert err.max() < RIGID_FIT_PX, (mot, est)


def test_warp_to_reference_undoes_the_motion():
    ref = _texture().astype(np.float32)
    mot = (1.3, -0.8, 0.25)
    c = (160.0, 120.0)
    moved = cv2.warpAffine(ref, rigid_matrix(*mot, c), (320, 240), flags=cv2.INTER_CUBIC)
    back = warp_to_reference(moved, mot, c)
    assert np.abs(back - ref)[20:-20, 20:-20].mean() < WARP_ROUND_TRIP
