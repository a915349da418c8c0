"""The synthetic capture studio: determinism, truth consistency, the sphere's mirror law, a
detectable face, real cast shadows."""

import hashlib
import json

import cv2
import numpy as np
import pytest
import trimesh

from relight.colour import decode_srgb8, luminance
from relight.directions import rotation_matrix, sphere_point_for_light
from relight.errors import InputError
from relight.imageio import read_image
from relight.pipeline.synth import acquisition
from relight.pipeline.synth.config import SynthConfig
from relight.pipeline.synth.studio import OLAT_DIRECTIONS, TRUTH_GRID, Studio, synthesize
from relight.video_read import read_frames

from .tolerances import (
    DRIFT_GAIN_RANGE,
    DRIFT_WALL_CORR,
    DRIFT_WB_STD,
    F32_CLOSE,
    F32_EXACT,
    FRAME_REPRO_BIAS_CODES,
    FRAME_REPRO_MEAN_CODES,
    FRAME_WRONG_LIGHT_MEAN_CODES,
    HAAR_MIN_HIT_RATE,
    HIGHLIGHT_MAX_PX,
    HIGHLIGHT_MEDIAN_PX,
    LIT_CHEEK_SHADOW_SHARE,
    NOSE_SHADOW_SHARE,
    POINT_VS_OLAT_REL,
)


@pytest.fixture(scope="module")
def capture(small_capture):
    res, cfg = small_capture
    meta = json.loads((res.truth / "meta.json").read_text())
    frames = list(read_frames(res.video))
    return res, cfg, meta, frames


def _digest(folder):
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(folder.iterdir())}


@pytest.mark.slow  # two renders of a clip (~9 s): `make test-slow`, CI
def test_same_seed_same_truth(tmp_path):
    cfg = SynthConfig(width=192, height=108, duration=2.0, seed=11, truth_envs=("builtin:studio",))
    a = synthesize(tmp_path / "a", cfg, progress=False)
    b = synthesize(tmp_path / "b", cfg, progress=False)
    assert _digest(a.truth) == _digest(b.truth)
    assert [f.tobytes() for f in read_frames(a.video)] == [f.tobytes() for f in read_frames(b.video)]
    c = synthesize(tmp_path / "c", SynthConfig(**{**cfg.__dict__, "seed": 12}), progress=False)
    assert json.loads((c.truth / "meta.json").read_text())["light_dirs"] != \
        json.loads((a.truth / "meta.json").read_text())["light_dirs"]


def test_meta_contract(capture):
    res, cfg, meta, frames = capture
    for key in ("fps", "size", "frame_count", "flash_frames", "light_dirs", "sphere", "head_motion",
                "reference_frame"):
        assert key in meta
    assert meta["size"] == [cfg.width, cfg.height] and meta["fps"] == cfg.fps
    assert meta["frame_count"] == len(frames) == len(meta["head_motion"])
    assert frames[0].shape == (cfg.height, cfg.width, 3)
    assert sorted(int(k) for k in meta["light_dirs"]) == meta["flash_frames"]
    dirs = np.array(list(meta["light_dirs"].values()))
    np.testing.assert_allclose(np.linalg.norm(dirs, axis=1), 1.0, atol=F32_EXACT)
    assert (dirs[:, 2] > -0.2).all()  # the hand stays over the front hemisphere
    # 5 Hz for 6 s: ~30 pulses, about two to three frames lit by each for most of their exposure.
    assert 20 <= len(meta["pulses"]) <= 34
    assert 40 <= len(meta["flash_frames"]) <= 100
    ref = meta["reference_frame"]
    assert meta["flash_fraction"][ref] == 0 and meta["head_motion"][ref] == [0, 0, 0]
    motion = np.array(meta["head_motion"])
    assert np.hypot(motion[:, 0], motion[:, 1]).max() <= acquisition.MAX_SHIFT_PX_AT_540 * cfg.height / 540 + 1e-6
    assert np.abs(motion[:, 2]).max() <= acquisition.MAX_ROT_DEG + 1e-9
    assert np.abs(motion).max() > 0  # the head does move


def test_flash_timing_is_unsynchronised(capture):
    _, _, meta, _ = capture
    frac = np.array(meta["flash_fraction"])
    assert ((frac > 0.05) & (frac < 0.95)).sum() >= 10  # frames straddling a flash edge
    starts = np.array([p["start"] for p in meta["pulses"]])
    periods = np.diff(starts)
    assert periods.std() > 0.005  # jittered, not a metronome


def test_truth_files(capture):
    res, cfg, meta, _ = capture
    mask = cv2.imread(str(res.truth / "mask.png"), cv2.IMREAD_GRAYSCALE) > 0
    normals = read_image(res.truth / "normals.exr")
    depth = read_image(res.truth / "depth.exr")[..., 0]
    np.testing.assert_allclose(np.linalg.norm(normals[mask], axis=1), 1.0, atol=F32_CLOSE)
    # depth only inside the head, reaching a visible share of its size (definitional bound, not a tolerance)
    assert (depth[~mask] == 0).all() and depth[mask].max() > 0.3 * meta["head_scale"]
    for rel in list(meta["files"]["relit"].values()) + list(meta["files"]["olat"].values()):
        img = read_image(res.out / rel)
        assert np.isfinite(img).all() and (img >= 0).all() and (img[~mask] == 0).all() and img[mask].max() > 0
    mesh = trimesh.load(res.truth / "head.ply", process=False)
    assert len(mesh.vertices) == mask.sum()
    # Finer than the pipeline's 64x32 reflectance maps.
    assert TRUTH_GRID[0] >= 128 and TRUTH_GRID[1] >= 64


def _single_pulse(meta, i):
    t0 = i / meta["fps"]
    t1 = t0 + meta["exposure_time"]
    hits = [p for p in meta["pulses"] if p["end"] > t0 and p["start"] < t1]
    return hits[0] if len(hits) == 1 else None


def _rerender(studio, meta, i, direction):
    """Frame i re-made from the truth alone: its light direction, head roll and flash level."""
    roll = meta["head_motion"][i][2]
    d = rotation_matrix(roll=-roll) @ np.asarray(direction, dtype=np.float64)
    power = np.full((1, 1, 3), np.pi * meta["flash_strength"] * meta["flash_level"][i])
    flash = studio.shader.shade(d[None], power)[0]
    return studio.camera_frame(i, noisy=False, flash=flash)


def _tilted(d, degrees):
    """``d`` turned by ``degrees`` toward or away from the camera axis (a clearly wrong light)."""
    axis = np.cross(d, [0.0, 0.0, 1.0])
    axis = axis / np.linalg.norm(axis) if np.linalg.norm(axis) > 1e-6 else np.array([1.0, 0.0, 0.0])
    a = np.radians(degrees)
    return d * np.cos(a) + np.cross(axis, d) * np.sin(a) + axis * (axis @ d) * (1 - np.cos(a))


def test_rerendering_a_flash_frame_reproduces_it(capture):
    res, cfg, meta, frames = capture
    studio = Studio(cfg)
    head = cv2.erode(studio.head.mask.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    picked = [i for i in meta["flash_frames"] if _single_pulse(meta, i)][::4][:6]
    assert len(picked) >= 4
    for i in picked:
        d = meta["light_dirs"][str(i)]
        diff = (_rerender(studio, meta, i, d).astype(float) - frames[i])[head]
        assert np.abs(diff).mean() < FRAME_REPRO_MEAN_CODES, (i, np.abs(diff).mean())
        assert abs(diff.mean()) < FRAME_REPRO_BIAS_CODES, (i, diff.mean())
        wrong = _rerender(studio, meta, i, _tilted(np.asarray(d), 35.0))
        assert np.abs(wrong.astype(float) - frames[i])[head].mean() > FRAME_WRONG_LIGHT_MEAN_CODES


def _flash_on_sphere(frame, dark, sphere):
    """Linear luminance the flash added inside the sphere (the room's lamps are reflected there too)."""
    cx, cy, r = sphere
    h, w = frame.shape[:2]
    y, x = np.mgrid[0:h, 0:w]
    inside = (x - cx) ** 2 + (y - cy) ** 2 < (r - 1) ** 2
    return np.clip(luminance(decode_srgb8(frame)) - luminance(decode_srgb8(dark)), 0, None) * inside, x, y


def test_sphere_highlight_obeys_the_mirror_law(capture):
    """The flash's highlight (brightness-weighted centroid of what it adds, saturated core and
    glare) sits where the mirror law puts the recorded light direction. Highlights over a
    bright reflection of the room's lamps are skipped: there the sensor clips and the flash
    cannot add its full light (the pipeline has to treat them as ambiguous)."""
    _, _, meta, frames = capture
    dark = frames[meta["reference_frame"]]
    dark_lum = luminance(decode_srgb8(dark))
    errs = []
    for i in meta["flash_frames"]:
        if not _single_pulse(meta, i):
            continue
        px, py = sphere_point_for_light(np.asarray(meta["light_dirs"][str(i)]), meta["sphere"])
        near = dark_lum[int(py) - 4:int(py) + 5, int(px) - 4:int(px) + 5]
        if near.size == 0 or near.max() - near.min() > 0.1:
            continue
        add, x, y = _flash_on_sphere(frames[i], dark, meta["sphere"])
        wgt = add * (add > 0.05)
        centroid = np.array([(x * wgt).sum(), (y * wgt).sum()]) / wgt.sum()
        errs.append(np.linalg.norm(centroid - (px, py)))
    assert len(errs) >= 10
    assert np.median(errs) < HIGHLIGHT_MEDIAN_PX and max(errs) < HIGHLIGHT_MAX_PX, errs


def test_haar_cascade_finds_the_face_in_no_flash_frames(capture):
    _, _, meta, frames = capture
    cascade = cv2.CascadeClassifier(cv2.data.haarcascades + "haarcascade_frontalface_default.xml")
    cx, cy = meta["head_center"]
    s = meta["head_scale"]
    eyes = [(cx - 0.29 * s, cy), (cx + 0.29 * s, cy)]
    dark = [i for i, f in enumerate(meta["flash_fraction"]) if f == 0]
    assert len(dark) >= 30
    hits = 0
    for i in dark:
        grey = cv2.cvtColor(frames[i], cv2.COLOR_RGB2GRAY)
        found = cascade.detectMultiScale(grey, scaleFactor=1.1, minNeighbors=5)
        hits += any(all(x <= ex <= x + w and y <= ey <= y + h for ex, ey in eyes) for x, y, w, h in found)
    assert hits / len(dark) >= HAAR_MIN_HIT_RATE


def test_the_nose_shadows_the_cheek(capture):
    _, cfg, _, _ = capture
    studio = Studio(cfg)
    light = np.array(OLAT_DIRECTIONS["right"], dtype=np.float64)
    light /= np.linalg.norm(light)
    lit = studio.shader.shade(light[None], np.full((1, 3), np.pi))[0, :, 0]
    bare = studio.shader.shade(light[None], np.full((1, 3), np.pi), shadows=False)[0, :, 0]
    pix = studio.surface.pix
    cx, cy = studio.head.center
    s = studio.head.scale
    u = (pix % cfg.width - cx) / s
    v = (cy - pix // cfg.width) / s
    beside_nose = (u > -0.2) & (u < -0.06) & (v > -0.33) & (v < -0.15)
    shadowed = lit < 0.5 * bare
    assert beside_nose.sum() > 10
    assert shadowed[beside_nose].mean() > NOSE_SHADOW_SHARE  # the nose's shadow falls on the cheek
    lit_cheek = (u > 0.1) & (u < 0.3) & (v > -0.3) & (v < -0.15)
    assert shadowed[lit_cheek].mean() < LIT_CHEEK_SHADOW_SHARE  # the lit cheek is not


def test_point_environment_matches_the_one_light_image(capture):
    res, _, meta, _ = capture
    point = read_image(res.out / meta["files"]["relit"]["point_0.8_0.1_0.6"])
    olat = read_image(res.out / meta["files"]["olat"]["olat_right"])
    sel = olat > 0.05
    rel = np.abs(point[sel] - olat[sel]) / olat[sel]
    assert np.median(rel) < POINT_VS_OLAT_REL


def test_bad_settings_say_what_to_change():
    with pytest.raises(InputError, match="--size"):
        SynthConfig(width=961, height=540).validate()
    with pytest.raises(InputError, match="--flash-hz"):
        SynthConfig(flash_hz=20).validate()
    with pytest.raises(InputError, match="distinct"):
        SynthConfig(truth_envs=("builtin:studio", "builtin:studio")).validate()
    with pytest.raises(InputError, match="--ambient"):
        SynthConfig(ambient=0).validate()


def test_camera_drift_moves_exposure_and_white_balance(tmp_path):
    cfg = SynthConfig(width=192, height=108, duration=4.0, seed=5, camera_drift=True, truth_envs=("builtin:uniform",))
    res = synthesize(tmp_path / "drift", cfg, progress=False)
    meta = json.loads((res.truth / "meta.json").read_text())
    gain = np.array(meta["exposure_gain"])
    wb = np.array(meta["white_balance"])
    assert DRIFT_GAIN_RANGE[0] < gain.max() - gain.min() < DRIFT_GAIN_RANGE[1]
    assert (wb[:, 1] == 1).all() and wb[:, 0].std() > DRIFT_WB_STD
    # The recorded gains are what the frames show: no-flash frames' wall brightness follows them.
    frames = list(read_frames(res.video))
    dark = [i for i, f in enumerate(meta["flash_fraction"]) if f == 0]
    wall = np.array([decode_srgb8(frames[i][:20, :40]).mean() for i in dark])
    assert np.corrcoef(wall, gain[dark] * wb[dark].mean(axis=1))[0, 1] > DRIFT_WALL_CORR
    still = Studio(SynthConfig(width=192, height=108, duration=2.0))
    assert (still.gain == 1).all() and (still.white_balance == 1).all()
