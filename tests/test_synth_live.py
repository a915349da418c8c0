"""The synthetic live video (``relight synth OUT --live``): streams, truth, and geometry checked
against predictions made here from the documented convention (not from the renderer)."""

import json

import av
import cv2
import numpy as np
import pytest

from relight.cli import main
from relight.colour import decode_srgb8
from relight.directions import rotation_matrix
from relight.envmap import load_environment
from relight.errors import InputError
from relight.imageio import read_image
from relight.pipeline.synth.head import height_units, inside
from relight.pipeline.synth.live_clip import LiveConfig, LiveScene
from relight.pipeline.synth.motion import head_pose_track, make_audio
from relight.spherical_harmonics import environment_sh9, sh9_irradiance
from relight.video_read import read_frames
from relight.video_write import AUDIO_RATE, VideoWriter

from .tolerances import (
    AUDIO_DURATION_S,
    CHIN_ROW_RANGE,
    COVERAGE_MEAN_ABS,
    F32_CLOSE,
    F32_LOOSE,
    F32_ZERO,
    FRAME_OTHER_POSE_RATIO,
    FRAME_RENDER_CODES,
    LANDMARK_PX,
    NOISE_RMS_RANGE,
    POSE_RANGE_SHARE,
    POSE_STEP_SHARE,
    RADIANCE_MEAN_REL,
    RADIANCE_P95_REL,
    REFERENCE_HEAD_REL,
    REFERENCE_WALL_ABS,
    SH_COSINE_ABS,
    SHADING_BOTTOM_RATIO,
    SHADING_SIDE_RATIO,
    SHADING_TOP_RATIO,
    SILHOUETTE_IOU,
    SILHOUETTE_MIRRORED_IOU,
    SILHOUETTE_RIGHT_IOU,
    TONE_HZ_ABS,
    TONE_PEAK_MAX,
    TONE_RMS_RANGE,
    TURNED_LIGHT_RATIO,
)

SIZE, SEED, SECONDS = (320, 180), 5, 2.0


@pytest.fixture(scope="module")
def live(tmp_path_factory):
    """A 2-second 320x180 live video made through the command line, and its truth."""
    out = tmp_path_factory.mktemp("live")
    assert main(["synth", str(out), "--live", "--size", f"{SIZE[0]}x{SIZE[1]}", "--duration", str(SECONDS),
                 "--seed", str(SEED), "--quiet"]) == 0
    meta = json.loads((out / "truth" / "meta.json").read_text())
    return out, meta


@pytest.fixture(scope="module")
def scene():
    """The same scene, prepared (head shaded under the room light, mesh built)."""
    sc = LiveScene(LiveConfig(width=SIZE[0], height=SIZE[1], duration=SECONDS, seed=SEED))
    sc.prepare()
    return sc


def _iou(a, b):
    return (a & b).sum() / (a | b).sum()


def _full(box, tile, shape):
    x0, y0, x1, y1 = box
    out = np.zeros(shape + tile.shape[2:], dtype=np.float64)
    out[y0:y1, x0:x1] = tile
    return out


def _pivot(head):
    """The documented pivot: the head centre, half a head unit behind the frontmost point."""
    cx, cy = head.center
    return np.array([cx, -cy, head.height[head.mask].max() - 0.5 * head.scale])


def _moved(points, rotation, pivot, t):
    """R (P - C) + C + (tx, -ty, 0), written out from the convention in docs/studio.md (live video)."""
    return (np.asarray(points) - pivot) @ rotation.T + pivot + np.array([t[0], -t[1], 0.0])


# ---------------------------------------------------------------------- files
def test_video_has_the_frames_and_an_audio_track(live):
    out, meta = live
    n = int(round(SECONDS * 30))
    assert meta["frame_count"] == n and meta["size"] == list(SIZE) and meta["fps"] == 30.0
    with av.open(str(out / "live.mp4")) as c:
        assert len(c.streams.video) == 1 and len(c.streams.audio) == 1
        frames = [f for f in c.decode(video=0)]
    assert len(frames) == n and (frames[0].width, frames[0].height) == SIZE
    with av.open(str(out / "live.mp4")) as c:
        a = c.streams.audio[0]
        assert a.codec_context.name == "aac" and a.codec_context.sample_rate == AUDIO_RATE
        assert a.codec_context.layout.nb_channels == 1
        assert abs(float(a.duration * a.time_base) - SECONDS) < AUDIO_DURATION_S
        samples = np.concatenate([f.to_ndarray()[0] for f in c.decode(audio=0)])
    assert abs(samples.size - SECONDS * AUDIO_RATE) <= 2048  # AAC frames are 1024 samples
    # A 440 Hz tone at a modest level.
    body = samples[AUDIO_RATE // 10:int(1.9 * AUDIO_RATE)]
    spectrum = np.abs(np.fft.rfft(body * np.hanning(body.size)))
    peak_hz = np.argmax(spectrum) * AUDIO_RATE / body.size
    assert abs(peak_hz - 440.0) < TONE_HZ_ABS
    assert TONE_RMS_RANGE[0] < np.sqrt(np.mean(body**2)) < TONE_RMS_RANGE[1] and np.abs(body).max() < TONE_PEAK_MAX
    assert meta["audio"]["kind"] == "tone" and meta["audio"]["sample_rate"] == AUDIO_RATE


def test_truth_has_one_smooth_pose_per_frame_within_the_amplitudes(live):
    _, meta = live
    cfg = LiveConfig()
    for key in ("kind", "fps", "size", "frame_count", "seed", "head_rotation", "head_translation", "pivot",
                "conventions", "audio", "files"):
        assert key in meta
    assert meta["kind"] == "live" and meta["seed"] == SEED
    rot, trans = np.array(meta["head_rotation"]), np.array(meta["head_translation"])
    assert rot.shape == (meta["frame_count"], 3) and trans.shape == (meta["frame_count"], 2)
    amp = np.array([cfg.yaw, cfg.pitch, cfg.roll])
    shift = cfg.shift * 0.04 * SIZE[1]
    assert np.all(np.abs(rot) <= amp) and np.all(np.abs(trans) <= shift + 1e-9)
    # Most of each range is covered, even in a 2-second clip, and the motion is smooth.
    assert np.all(rot.max(axis=0) - rot.min(axis=0) > POSE_RANGE_SHARE * amp)
    assert np.all(trans.max(axis=0) - trans.min(axis=0) > POSE_RANGE_SHARE * shift)
    assert np.all(np.abs(np.diff(rot, axis=0)).max(axis=0) < POSE_STEP_SHARE * amp)
    assert np.abs(rot[0]).max() > 0  # frame 0 need not be the reference pose
    assert "Ry(yaw) Rx(pitch) Rz(roll)" in meta["conventions"]
    for rel in ("video", "reference", "mask_reference"):
        assert (live[0] / meta["files"][rel]).is_file()


def test_same_seed_same_motion_other_seed_other_motion():
    a = head_pose_track(np.random.default_rng(1), 90, 30.0, (30, 15, 8), 7.0)
    b = head_pose_track(np.random.default_rng(1), 90, 30.0, (30, 15, 8), 7.0)
    c = head_pose_track(np.random.default_rng(2), 90, 30.0, (30, 15, 8), 7.0)
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
    assert not np.allclose(a[0], c[0])


def test_reference_files_show_the_static_studios_head(live, scene):
    out, _ = live
    studio = scene.studio
    mask = read_image(out / "truth" / "mask_reference.png", linearize=False)[..., 0] > 0.5
    # alpha 0.5: the silhouette's edge (definitional bound, not a tolerance)
    assert _iou(mask, studio.head.alpha > 0.5) > SILHOUETTE_IOU
    # The reference frame against the static capture's reference frame (no flash, no noise).
    ref = read_image(out / "truth" / "reference.png")
    static = decode_srgb8(studio.sensor.expose(studio.render_frame(studio.reference_frame,
                                                                    flash=np.zeros_like(studio.ambient_head())),
                                               1.0, np.ones(3), None))
    inner = cv2.erode(studio.head.mask.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    rel = np.abs(ref[inner] - static[inner]).sum(axis=1) / np.maximum(static[inner].sum(axis=1), 1e-3)
    assert np.median(rel) < REFERENCE_HEAD_REL
    wall = np.zeros_like(inner)
    wall[:, :SIZE[0] // 8] = True  # far from the head and the studio's mirror sphere
    assert np.abs(ref[wall] - static[wall]).mean() < REFERENCE_WALL_ABS


# ---------------------------------------------------------------------- geometry
def test_reference_pose_matches_the_static_head(scene):
    head, mesh = scene.head, scene.mesh
    box, img, cov = mesh.render(np.eye(3), (0.0, 0.0))
    cov = _full(box, cov, head.mask.shape)
    # coverage/alpha 0.5: the silhouette's edge (definitional bound, not a tolerance)
    assert _iou(cov > 0.5, head.alpha > 0.5) > SILHOUETTE_IOU
    assert np.abs(cov - head.alpha).mean() < COVERAGE_MEAN_ABS
    rad = _full(box, img, head.mask.shape)
    ref = scene.studio.head_image(scene.studio.ambient_head())
    inner = cv2.erode(head.mask.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    rel = np.abs(rad[inner] - ref[inner]).sum(axis=1) / np.maximum(ref[inner].sum(axis=1), 1e-6)
    assert rel.mean() < RADIANCE_MEAN_REL and np.percentile(rel, 95) < RADIANCE_P95_REL
    # Same seed and size: the live head is the static capture's head.
    assert np.allclose(scene.pivot, _pivot(head))


@pytest.mark.parametrize("pose, shift", [((20.0, 0.0, 0.0), (0.0, 0.0)), ((0.0, -12.0, 0.0), (0.0, 0.0)),
                                         ((0.0, 0.0, 8.0), (0.0, 0.0)), ((-25.0, 10.0, 6.0), (3.0, -2.0)),
                                         ((30.0, 15.0, 8.0), (-4.5, 5.0))])
def test_nose_tip_lands_where_the_rotation_puts_it(scene, pose, shift):
    head, mesh = scene.head, scene.mesh
    yn, xn = np.unravel_index(np.argmax(np.where(head.mask, head.height, -np.inf)), head.mask.shape)
    marker = np.zeros(head.mask.shape)
    marker[yn, xn] = 1.0
    r = rotation_matrix(*pose)
    box, img, _ = mesh.render(r, shift, values=mesh.vertex_values(marker))
    v = _full(box, img, head.mask.shape)[..., 0]
    ys, xs = np.mgrid[:v.shape[0], :v.shape[1]]
    measured = np.array([(v * xs).sum(), (v * ys).sum()]) / v.sum()
    q = _moved([xn, -yn, head.height[yn, xn]], r, _pivot(head), shift)
    predicted = np.array([q[0], -q[1]])
    assert np.hypot(*(measured - predicted)) < LANDMARK_PX
    if pose[0] > 0:  # +yaw: right-handed about +Y, the nose (toward +Z) swings toward +X (right)
        assert measured[0] - shift[0] > xn + 3.0
    if pose[1] < 0 and pose[0] == 0:  # -pitch: the nose rises (toward +Y, up the image)
        assert measured[1] < yn - 3.0
    if pose[2] > 0 and pose[:2] == (0.0, 0.0):  # +roll: counter-clockwise on screen; the tip is below
        assert measured[0] > xn + 0.5  # the pivot row, so it swings to the right


def _splat_silhouette(head, rotation, pivot):
    """The silhouette predicted without the renderer: 4x4 analytic surface points per pixel,
    moved by the documented formula, splatted, gaps closed."""
    h, w = head.mask.shape
    off = (np.arange(4) + 0.5) / 4 - 0.5
    ys, xs = np.nonzero(cv2.dilate(head.mask.astype(np.uint8), np.ones((3, 3), np.uint8)))
    x = (xs[:, None, None] + off[None, None, :] + 0 * off[None, :, None]).ravel()
    y = (ys[:, None, None] + off[None, :, None] + 0 * off[None, None, :]).ravel()
    cx, cy = head.center
    u, v = (x - cx) / head.scale, (cy - y) / head.scale
    keep = inside(u, v)
    pts = np.stack([x[keep], -y[keep], height_units(u[keep], v[keep]) * head.scale], axis=1)
    q = _moved(pts, rotation, pivot, (0.0, 0.0))
    qx, qy = np.round(q[:, 0]).astype(int), np.round(-q[:, 1]).astype(int)
    ok = (qx >= 0) & (qx < w) & (qy >= 0) & (qy < h)
    mask = np.zeros((h, w), np.uint8)
    mask[qy[ok], qx[ok]] = 1
    return cv2.morphologyEx(mask, cv2.MORPH_CLOSE, np.ones((3, 3), np.uint8)).astype(bool)


@pytest.mark.parametrize("pose", [(25.0, 0.0, 0.0), (-25.0, 10.0, 6.0), (30.0, -15.0, -8.0)])
def test_silhouette_matches_an_independent_projection(scene, pose):
    head, mesh = scene.head, scene.mesh
    r = rotation_matrix(*pose)
    box, _, cov = mesh.render(r, (0.0, 0.0))
    rendered = _full(box, cov, head.mask.shape) > 0.5
    rows = slice(0, int(0.85 * head.mask.shape[0]))  # the splat has no neck below the frame
    right = _iou(rendered[rows], _splat_silhouette(head, r, _pivot(head))[rows])
    mirrored = _iou(rendered[rows], _splat_silhouette(head, rotation_matrix(-pose[0], pose[1], pose[2]),
                                                      _pivot(head))[rows])
    assert right > SILHOUETTE_RIGHT_IOU and mirrored < SILHOUETTE_MIRRORED_IOU
    # With this pivot (behind the face), +yaw swings the face right and the silhouette's rim left.
    cols = np.nonzero(rendered[rows].any(axis=0))[0]
    ref_cols = np.nonzero((head.alpha > 0.5)[rows].any(axis=0))[0]
    if pose[0] > 0:
        assert cols.min() < ref_cols.min() - 2
    else:
        assert cols.max() > ref_cols.max() + 2


# ---------------------------------------------------------------------- shading
def test_spherical_harmonics_irradiance():
    dirs = np.array([[0, 0, 1.0], [1.0, 0, 0], [0, -1.0, 0], [0.6, 0.0, -0.8]])
    uniform = environment_sh9(load_environment("builtin:uniform"))
    assert np.allclose(sh9_irradiance(uniform, dirs), np.pi, rtol=F32_LOOSE)
    # A small light of power pi straight ahead: irradiance ~ pi max(cos, 0) (order-2 SH: within 0.1 pi).
    sh = environment_sh9(load_environment("builtin:point:0,0,1"))
    e = sh9_irradiance(sh, dirs)[:, 0]
    assert np.allclose(e, np.pi * np.maximum(dirs[:, 2], 0.0), atol=SH_COSINE_ABS * np.pi)


def test_turning_toward_the_ceiling_light_and_the_window_brightens(scene):
    mesh = scene.mesh
    assert np.allclose(mesh.colours(np.eye(3)), mesh.radiance, rtol=F32_CLOSE, atol=F32_ZERO)

    def level(*pose):
        return float(mesh.colours(rotation_matrix(*pose)).mean())

    # the panel is above
    assert level(0, -15, 0) > SHADING_TOP_RATIO * level(0, 0, 0) > SHADING_BOTTOM_RATIO * level(0, 15, 0)
    assert level(-25, 0, 0) > SHADING_SIDE_RATIO * level(25, 0, 0)  # the window is on the left (-X)
    # The SH quadratic form gives what rotating the normals and evaluating SH gives.
    r = rotation_matrix(17, -9, 5)
    direct = mesh.radiance * np.minimum(np.maximum(sh9_irradiance(mesh.sh, mesh.normal @ r.T), 0.0)
                                        / mesh._e_ref, 8.0)
    assert np.allclose(mesh.colours(r), direct, rtol=F32_LOOSE, atol=F32_ZERO)


# ---------------------------------------------------------------------- audio and settings
# ---------------------------------------------------------------------- the live frame's truth
def test_turned_head_at_the_reference_pose_is_the_static_truth(scene):
    """The live truth's shading at the reference pose is the static studio's (same lights, same
    shadows): the room light's radiance equals the head's room-lit radiance the clip starts from."""
    room = scene.studio.room
    (turned,) = scene.studio.turned_head_radiance([room], np.eye(3))
    np.testing.assert_allclose(turned, scene.studio.ambient_head(), rtol=F32_LOOSE, atol=F32_ZERO)


def test_a_head_turned_toward_a_light_is_lit_more(scene):
    """Convention: yaw turns the face toward +X (R z = (sin yaw, 0, cos yaw)); under one light at
    +X the face turned toward it reflects more and its cast shadows turn with it."""
    env = load_environment("builtin:point:1,0,0.4")
    toward, away = (scene.studio.turned_head_radiance([env], rotation_matrix(y, 0, 0))[0].mean()
                    for y in (25.0, -25.0))
    assert toward > TURNED_LIGHT_RATIO * away
    # the same light seen from the turned head's own frame: a pure roll keeps the camera's view
    roll = rotation_matrix(0, 0, 30)
    (rolled,) = scene.studio.turned_head_radiance([env], roll)
    d = roll.T @ (np.array([1.0, 0.0, 0.4]) / np.linalg.norm([1.0, 0.0, 0.4]))
    (again,) = scene.studio.turned_head_radiance([load_environment(f"builtin:point:{d[0]},{d[1]},{d[2]}")], np.eye(3))
    assert np.abs(rolled - again).mean() < RADIANCE_MEAN_REL * np.abs(again).mean()


@pytest.mark.slow  # a live clip and its truth rendered by the command (~8 s): `make test-slow`, CI
def test_live_truth_frames_through_the_command_line(tmp_path):
    """--live --truth-env writes every frame with the person under each environment (the camera's
    exposure, no noise) and the person's pixels; the background is the clip's own, untouched."""
    out, size, fps = tmp_path / "lt", (160, 90), 5
    assert main(["synth", str(out), "--live", "--size", f"{size[0]}x{size[1]}", "--duration", "1", "--fps",
                 str(fps), "--seed", str(SEED), "--truth-env", "builtin:sunset", "--truth-env", "builtin:window",
                 "--quiet"]) == 0
    meta = json.loads((out / "truth" / "meta.json").read_text())
    assert meta["files"]["live_truth"] == {"sunset": "truth/live_sunset/%04d.png",
                                           "window": "truth/live_window/%04d.png"}
    assert meta["files"]["silhouette"] == "truth/silhouette/%04d.png"
    assert meta["envs"] == {"sunset": "builtin:sunset", "window": "builtin:window"}
    sc = LiveScene(LiveConfig(width=size[0], height=size[1], duration=1.0, fps=fps, seed=SEED))
    changed = []
    for i in range(fps):
        sil = cv2.imread(str(out / "truth" / "silhouette" / f"{i:04d}.png"), cv2.IMREAD_UNCHANGED)
        assert sil.shape == size[::-1] and set(np.unique(sil)) <= {0, 255}
        _, cov = sc.render(*sc.pose(i))
        np.testing.assert_array_equal(sil > 0, cov > 0.5)
        plain = sc.camera_frame(i, noisy=False)
        outside = cv2.dilate((cov > 0).astype(np.uint8), np.ones((3, 3), np.uint8)) == 0
        for stem in ("sunset", "window"):
            img = cv2.imread(str(out / (meta["files"]["live_truth"][stem] % i)))[..., ::-1]
            assert img.shape == (*size[::-1], 3)
            np.testing.assert_array_equal(img[outside], plain[outside])
            changed.append(np.abs(img[sil > 0].astype(int) - plain[sil > 0]).mean())
    assert min(changed) > FRAME_RENDER_CODES  # the person is relit, every frame


def test_noise_audio_and_no_audio(tmp_path):
    rng = np.random.default_rng(0)
    a = make_audio("noise", AUDIO_RATE, rng)
    assert a.dtype == np.float32 and a.size == AUDIO_RATE
    assert NOISE_RMS_RANGE[0] < a[1000:-1000].std() < NOISE_RMS_RANGE[1]
    assert make_audio("none", AUDIO_RATE, rng) is None
    out = tmp_path / "quiet"
    assert main(["synth", str(out), "--live", "--size", "128x72", "--duration", "1", "--audio", "none",
                 "--noise", "0", "--quiet"]) == 0
    with av.open(str(out / "live.mp4")) as c:
        assert len(c.streams.audio) == 0 and len(c.streams.video) == 1
    assert json.loads((out / "truth" / "meta.json").read_text())["audio"] is None


def test_audio_writer_is_atomic_and_checks_its_input(tmp_path):
    target = tmp_path / "v.mp4"
    tone = np.zeros(AUDIO_RATE, dtype=np.float32)
    with pytest.raises(RuntimeError):
        with VideoWriter(target, 30, (64, 48), audio=tone) as w:
            w.write(np.zeros((48, 64, 3), np.uint8))
            raise RuntimeError("killed")
    assert not target.exists() and list(tmp_path.iterdir()) == []
    for bad in (np.full(10, 2.0), np.zeros((2, 10)), np.array([np.nan, 0.0]), np.zeros(10, dtype=np.int16)):
        with pytest.raises(InputError):
            VideoWriter(target, 30, (64, 48), audio=bad)


@pytest.mark.parametrize("change, word", [({"width": 321}, "--size"), ({"fps": 1.0}, "--fps"),
                                          ({"duration": 0.2}, "--duration"), ({"yaw": 90.0}, "yaw"),
                                          ({"pitch": -1.0}, "pitch"), ({"shift": 50.0}, "shift"),
                                          ({"ambient": 0.0}, "--ambient"), ({"noise": float("nan")}, "--noise"),
                                          ({"crf": 60}, "--crf"), ({"audio": "beep"}, "--audio"),
                                          ({"seed": -1}, "--seed"), ({"start_yaw": 50.0}, "--start-yaw"),
                                          ({"start_pitch": float("nan")}, "--start-pitch"),
                                          ({"start_yaw": -80.0, "head_mesh": "head.obj"}, "--start-yaw")])
def test_bad_settings_say_what_to_change(change, word):
    with pytest.raises(InputError, match=word):
        LiveConfig(**change).validate()


def test_command_line_refuses_capture_flags_with_live(tmp_path, capsys):
    assert main(["synth", str(tmp_path / "o"), "--live", "--flash-hz", "3", "--quiet"]) == 2
    assert "--flash-hz" in capsys.readouterr().err
    assert main(["synth", str(tmp_path / "o"), "--live", "--truth-env", "builtin:sunset", "--truth-env",
                 "other/sunset.exr", "--quiet"]) == 2
    assert "distinct names" in capsys.readouterr().err
    assert main(["synth", str(tmp_path / "o"), "--audio", "noise", "--quiet"]) == 2
    assert "--live" in capsys.readouterr().err
    assert main(["synth", str(tmp_path / "o"), "--live", "--size", "200x101", "--quiet"]) == 2
    assert main(["synth", str(tmp_path / "o"), "--start-yaw", "20", "--quiet"]) == 2
    assert "--live" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_a_clip_starts_from_the_pose_it_is_told_and_eases_into_its_motion(tmp_path):
    """--start-yaw/--start-pitch: frame 0 is at that pose (the truth's meta says so), the head
    eases into the same motion the clip has without them (equal from the ease's end), staying
    between the start and that motion, never jumping more than the ease's own steepest step
    beyond the motion's."""
    from relight.pipeline.synth.motion import START_EASE_S

    plain = LiveScene(LiveConfig(width=160, height=90, duration=4.0, fps=15, seed=SEED)).rotations
    told = LiveScene(LiveConfig(width=160, height=90, duration=4.0, fps=15, seed=SEED, start_yaw=40.0,
                                start_pitch=-25.0)).rotations
    assert told[0, 0] == 40.0 and told[0, 1] == -25.0 and told[0, 2] == plain[0, 2]  # (the roll is its own)
    after = int(np.ceil(START_EASE_S * 15))
    np.testing.assert_array_equal(told[after:], plain[after:])
    start = np.array([40.0, -25.0])
    lo, hi = np.minimum(start, plain[:after, :2]), np.maximum(start, plain[:after, :2])
    assert ((told[:after, :2] >= lo - 1e-6) & (told[:after, :2] <= hi + 1e-6)).all()
    steepest = np.pi / 2 * np.abs(start - plain[:after, :2]).max(axis=0) / (START_EASE_S * 15)
    assert (np.abs(np.diff(told[:, :2], axis=0)).max(axis=0) <= np.abs(np.diff(plain[:, :2], axis=0)).max(axis=0)
            + steepest + 1e-6).all()
    out = tmp_path / "turned"
    assert main(["synth", str(out), "--live", "--size", "160x90", "--duration", "1", "--fps", "5", "--seed",
                 str(SEED), "--start-yaw", "-30", "--start-pitch", "10", "--audio", "none", "--quiet"]) == 0
    meta = json.loads((out / "truth" / "meta.json").read_text())
    assert meta["start_pose"]["yaw"] == -30.0 and meta["start_pose"]["pitch"] == 10.0
    assert meta["head_rotation"][0][:2] == [-30.0, 10.0] and meta["config"]["start_yaw"] == -30.0


@pytest.mark.parametrize("pose", [(0.0, 15.0, 8.0), (0.0, -15.0, -8.0), (30.0, 15.0, -8.0)])
def test_neck_stays_on_the_bottom_edge(scene, pose):
    """At the largest pitch and roll, shifted up as far as the motion goes, the neck still leaves
    the frame at the bottom (it is extended below the frame, not cut at the reference's edge)."""
    head, mesh = scene.head, scene.mesh
    lift = scene.config.shift_px
    box, _, cov = mesh.render(rotation_matrix(*pose), (0.0, -lift))
    bottom = _full(box, cov, head.mask.shape)[-1]
    ref_bottom = (head.alpha[-1] > 0.5).sum()
    # 0.5: the silhouette's edge (definitional bound, not a tolerance)
    assert CHIN_ROW_RANGE[0] * ref_bottom < (bottom > 0.5).sum() < CHIN_ROW_RANGE[1] * ref_bottom


def test_each_video_frame_shows_its_recorded_pose(live, scene):
    out, meta = live
    frames = list(read_frames(out / "live.mp4"))
    assert len(frames) == meta["frame_count"]
    for k in (0, 23, len(frames) - 1):
        renders = [scene.render(rotation_matrix(*meta["head_rotation"][j]), meta["head_translation"][j])
                   for j in (k, (k + 6) % len(frames))]
        head = (renders[0][1] > 0) | (renders[1][1] > 0)
        got = frames[k].astype(float)[head]
        right, other = (np.abs(got - scene.expose(lin, None).astype(float)[head]).mean() for lin, _ in renders)
        assert right < FRAME_RENDER_CODES and other > FRAME_OTHER_POSE_RATIO * right
