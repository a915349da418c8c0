import cv2
import numpy as np
import pytest

from relight.directions import (
    angle_between_deg,
    direction_to_equirect_uv,
    equirect_directions,
    equirect_solid_angles,
    equirect_uv_to_direction,
    light_for_sphere_point,
    rigid_matrix,
    rotation_angles,
    rotation_matrix,
    sphere_point_for_light,
)

from .tolerances import F32_EXACT, F64_CLOSE, F64_EXACT


@pytest.mark.parametrize(("u", "v", "d"), [
    (0.5, 0.5, (0, 0, 1)),     # centre column: +Z, toward the camera
    (0.25, 0.5, (1, 0, 0)),    # a quarter of the width: +X
    (0.75, 0.5, (-1, 0, 0)),
    (0.0, 0.5, (0, 0, -1)),    # the edges: -Z
    (0.5, 0.0, (0, 1, 0)),     # top row: +Y (up)
    (0.5, 1.0, (0, -1, 0)),
])
def test_openexr_latlong_convention(u, v, d):
    np.testing.assert_allclose(equirect_uv_to_direction(u, v), d, atol=F64_EXACT)


def test_uv_round_trip():
    rng = np.random.default_rng(1)
    u = rng.uniform(0, 1, 1000)
    v = rng.uniform(0.001, 0.999, 1000)
    u2, v2 = direction_to_equirect_uv(equirect_uv_to_direction(u, v))
    np.testing.assert_allclose(v2, v, atol=F64_EXACT)
    np.testing.assert_allclose(np.mod(u2 - u + 0.5, 1) - 0.5, 0, atol=F64_EXACT)


def test_solid_angles_sum_to_sphere():
    for w in (8, 64, 512):
        dw = equirect_solid_angles(w, w // 2)
        assert dw.sum() * w == pytest.approx(4 * np.pi, rel=F64_EXACT)
    d = equirect_directions(64, 32)
    np.testing.assert_allclose(np.linalg.norm(d, axis=-1), 1.0, atol=F64_EXACT)


def test_rotation_convention_and_round_trip():
    # Yaw about +Y turns +Z toward +X; pitch about +X turns +Y toward +Z; roll about +Z turns +X toward +Y.
    np.testing.assert_allclose(rotation_matrix(yaw=90) @ [0, 0, 1], [1, 0, 0], atol=F64_EXACT)
    np.testing.assert_allclose(rotation_matrix(pitch=90) @ [0, 1, 0], [0, 0, 1], atol=F64_EXACT)
    np.testing.assert_allclose(rotation_matrix(roll=90) @ [1, 0, 0], [0, 1, 0], atol=F64_EXACT)
    rng = np.random.default_rng(2)
    for _ in range(50):
        a = (rng.uniform(-170, 170), rng.uniform(-85, 85), rng.uniform(-170, 170))
        r = rotation_matrix(*a)
        np.testing.assert_allclose(r @ r.T, np.eye(3), atol=F64_EXACT)
        np.testing.assert_allclose(rotation_angles(r), a, atol=F64_CLOSE)


def test_rigid_matrix_matches_opencv_sign():
    m = rigid_matrix(2.0, -1.0, 7.5, (100.0, 50.0))
    ref = cv2.getRotationMatrix2D((100.0, 50.0), 7.5, 1.0)
    ref[:, 2] += (2.0, -1.0)
    np.testing.assert_allclose(m, ref, atol=F64_EXACT)


def test_mirror_law_round_trip():
    sphere = (300.0, 200.0, 50.0)
    rng = np.random.default_rng(3)
    d = rng.normal(size=(200, 3))
    d[:, 2] = np.abs(d[:, 2]) + 0.05
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    xy = sphere_point_for_light(d, sphere)
    assert (np.hypot(xy[:, 0] - 300, xy[:, 1] - 200) <= 50 * np.sqrt(0.5) + 1e-9).all()
    assert angle_between_deg(light_for_sphere_point(xy, sphere), d).max() < 1e-6
    # A light straight at the camera is reflected at the sphere's centre; one from the right
    # (+X) on the sphere's right, one from above (+Y) on its upper half (smaller row).
    np.testing.assert_allclose(sphere_point_for_light(np.array([0, 0, 1.0]), sphere), (300, 200))
    assert sphere_point_for_light(np.array([1.0, 0, 1.0]), sphere)[0] > 300
    assert sphere_point_for_light(np.array([0, 1.0, 1.0]), sphere)[1] < 200


def test_angle_between_is_accurate_at_small_angles():
    a = np.array([1.0, 0, 0])
    b = np.array([np.cos(1e-7), np.sin(1e-7), 0])
    assert angle_between_deg(a, b) == pytest.approx(np.degrees(1e-7), rel=F32_EXACT)
