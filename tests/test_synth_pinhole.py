"""The live studio through a webcam's pinhole (``relight synth --live --fov DEG --distance CM``):
the projection against the documented formula written out here, what the truth records, the
body below a scan's cut, and the flags' refusals."""

import json
import math

import numpy as np
import pytest

from relight.cli import main
from relight.directions import rotation_matrix
from relight.errors import InputError
from relight.pipeline.synth.live_clip import LiveConfig, LiveScene
from relight.pipeline.synth.mesh_render import extend_below
from relight.pipeline.synth.pinhole import HEAD_UNIT_CM, Pinhole, image_points

from .tolerances import F32_CLOSE, LANDMARK_PX

SIZE, SEED = (320, 180), 5


@pytest.fixture(scope="module")
def scenes():
    """The head through a 50-degree pinhole at 60 cm, and a renderer of the same mesh through the
    orthographic camera (the scene's mesh with its camera taken away: one studio built, not two)."""
    import copy

    pin = LiveScene(LiveConfig(width=SIZE[0], height=SIZE[1], duration=1.0, seed=SEED, fov=50.0, distance=60.0))
    ortho = copy.copy(pin.mesh)
    ortho.camera = None
    return ortho, pin


def test_the_pinhole_is_the_documented_one():
    """f = (W / 2) / tan(fov / 2), the eye the distance in head units in front of the pivot, a
    point at the pivot's depth magnified by f / D about the frame's centre, a nearer one more."""
    cam = Pinhole.from_fov((640, 360), 65.0, 60.0, head_scale=100.0, pivot_z=-20.0)
    assert cam.focal == pytest.approx(320.0 / math.tan(math.radians(32.5)))
    assert cam.distance_px == pytest.approx(60.0 / HEAD_UNIT_CM * 100.0)
    assert cam.eye_z == pytest.approx(-20.0 + cam.distance_px) and cam.center == (320.0, 180.0)
    x, y = cam.image_points(np.array([[420.0, -230.0, -20.0], [420.0, -230.0, 80.0], [320.0, -180.0, 50.0]]))
    m = cam.focal / cam.distance_px
    np.testing.assert_allclose([x[0], y[0]], [320.0 + 100.0 * m, 180.0 + 50.0 * m])
    near = cam.focal / (cam.distance_px - 100.0)
    np.testing.assert_allclose([x[1], y[1]], [320.0 + 100.0 * near, 180.0 + 50.0 * near])
    np.testing.assert_allclose([x[2], y[2]], [320.0, 180.0])  # the axis
    ox, oy = image_points(None, np.array([[12.0, -34.0, 5.0]]))
    assert (ox[0], oy[0]) == (12.0, 34.0)
    with pytest.raises(InputError, match="--distance"):
        cam.image_points(np.array([[0.0, 0.0, cam.eye_z - 1.0]]))


def test_a_pinhole_clip_shows_the_head_where_the_formula_puts_it(scenes):
    """The nose tip of a turned, moved head lands at the pinhole's projection of the documented
    motion (not the orthographic one); the reference head is magnified by f / D."""
    ortho, pin = scenes
    head, mesh = pin.head, pin.mesh
    yn, xn = np.unravel_index(np.argmax(np.where(head.mask, head.height, -np.inf)), head.mask.shape)
    marker = np.zeros(head.mask.shape)
    marker[yn, xn] = 1.0
    r, shift = rotation_matrix(-20.0, 10.0, 5.0), (4.0, -3.0)
    box, img, _ = mesh.render(r, shift, values=mesh.vertex_values(marker))
    x0, y0, x1, y1 = box
    v = img[..., 0]
    ys, xs = np.mgrid[y0:y1, x0:x1]
    measured = np.array([(v * xs).sum(), (v * ys).sum()]) / v.sum()
    c = pin.pivot
    q = (np.array([xn, -yn, head.height[yn, xn]]) - c) @ r.T + c + np.array([shift[0], -shift[1], 0.0])
    cam = pin.camera
    depth = cam.eye_z - q[2]
    predicted = np.array([cam.center[0] + cam.focal * (q[0] - cam.center[0]) / depth,
                          cam.center[1] + cam.focal * (-q[1] - cam.center[1]) / depth])
    assert np.hypot(*(measured - predicted)) < LANDMARK_PX
    assert np.hypot(q[0] - predicted[0], -q[1] - predicted[1]) > 3 * LANDMARK_PX  # not the orthographic place
    # the reference head's width (its middle rows: the neck reaches the frame's bottom) magnified
    # between what a head unit behind the pivot and one in front of it are
    rows = slice(int(0.2 * SIZE[1]), int(0.6 * SIZE[1]))
    covers = [np.zeros(SIZE[::-1]) for _ in range(2)]
    for cover, mesh in zip(covers, (ortho, pin.mesh), strict=True):
        (x0, y0, x1, y1), _, cov = mesh.render(np.eye(3))
        cover[y0:y1, x0:x1] = cov
    widths = [np.ptp(np.nonzero(c[rows].max(axis=0) > 0.5)[0]) for c in covers]
    unit = head.scale
    assert cam.focal / (cam.distance_px + unit) < widths[1] / widths[0] < cam.focal / (cam.distance_px - unit)
    assert widths[1] > widths[0] + 4  # a 50-degree lens at 60 cm: larger than the orthographic reference


def test_the_truth_records_the_camera(tmp_path):
    """meta.json's camera: the pinhole's focal length, principal point, eye and distance (and
    "orthographic" without --fov); the conventions say which camera."""
    out = tmp_path / "pin"
    assert main(["synth", str(out), "--live", "--size", "160x90", "--duration", "1", "--fps", "5", "--seed",
                 str(SEED), "--fov", "80", "--distance", "70", "--audio", "none", "--quiet"]) == 0
    meta = json.loads((out / "truth" / "meta.json").read_text())
    cam = meta["camera"]
    assert cam["model"] == "pinhole" and cam["fov_deg"] == 80.0 and cam["distance_cm"] == 70.0
    assert cam["focal_px"] == pytest.approx(80.0 / math.tan(math.radians(40.0)))
    assert cam["principal_point"] == [80.0, 45.0] and "pinhole" in meta["conventions"]
    assert meta["config"]["fov"] == 80.0
    scene = LiveScene(LiveConfig(width=160, height=90, duration=1.0, fps=5, seed=SEED))
    assert scene.meta()["camera"] == {"model": "orthographic"} and "orthographic" in scene.meta()["conventions"]


@pytest.mark.parametrize("args, word", [(["--live", "--fov", "5"], "--fov"), (["--live", "--fov", "nan"], "--fov"),
                                        (["--live", "--fov", "65", "--distance", "10"], "--distance"),
                                        (["--live", "--distance", "80"], "--fov"), (["--distance", "80"], "--fov")])
def test_bad_camera_flags_say_what_to_change(tmp_path, capsys, args, word):
    assert main(["synth", str(tmp_path / "o"), "--size", "160x90", "--quiet", *args]) == 2
    assert word in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_a_bust_goes_on_below_its_cut():
    """extend_below: an open bottom edge gets a wall straight down, of its own vertices (the
    mesh's untouched), one colour and level normals; edges above the row are left open."""
    # a square of two triangles, rows 10 (top) to 20 (bottom): camera-space y = -row
    pts = np.array([[0.0, -10.0, 5.0], [10.0, -10.0, 5.0], [0.0, -20.0, 5.0], [10.0, -20.0, 5.0]])
    faces = np.array([[0, 2, 1], [1, 2, 3]])
    uv = np.array([[0.1, 0.9], [0.9, 0.9], [0.1, 0.1], [0.9, 0.1]])
    normals = np.array([[0.0, -0.6, 0.8]] * 4)
    albedo = np.full((4, 4, 3), 0.5, np.float32)
    p, f, u, n = extend_below(pts, faces, uv, normals, 15.0, 100.0, albedo)
    np.testing.assert_array_equal(p[:4], pts)
    np.testing.assert_array_equal(f[:2], faces)
    assert len(f) == 4 and len(p) == 8  # one open edge below row 15: (2, 3)
    walls = p[f[2:]].reshape(-1, 3)
    assert set(np.round(-walls[:, 1]).astype(int)) == {20, 120}
    assert (u[4:] == u[4]).all()
    np.testing.assert_allclose(n[4:], [[0.0, 0.0, 1.0]] * 4, atol=F32_CLOSE)
    assert len(extend_below(pts, faces, uv, normals, 25.0, 100.0, albedo)[1]) == 2  # nothing below row 25


@pytest.mark.slow  # the scan's studio built twice (~11 s): `make test-slow`, CI (extend_below's test: make test)
def test_a_wide_lens_sees_the_body_go_on(tmp_path):
    """The scan through an 80-degree lens: the body reaches the frame's bottom under the head
    (no floating bust); the same scan orthographic is unchanged by the walls (none are made)."""
    cfg = dict(width=SIZE[0], height=SIZE[1], duration=1.0, seed=SEED, head_mesh="builtin:lee-perry-smith")
    wide = LiveScene(LiveConfig(**cfg, fov=80.0))
    _, cov = wide.render(rotation_matrix(20.0, 0.0, 0.0))
    cx = int(round(wide.camera.center[0] + wide.camera.magnification * (wide.head.center[0] - wide.camera.center[0])))
    assert cov[-1, cx - 5:cx + 5].min() > 0.99
    ortho = LiveScene(LiveConfig(**cfg))
    assert len(ortho.mesh.faces) == len(ortho.studio.mesh.faces)
    with pytest.raises(InputError, match="--fov"):
        LiveConfig(**cfg, fov=130.0).validate()
