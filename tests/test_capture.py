"""`relight capture` end to end: a synthetic video against its truth, the real RTI set against
its held-out photos, and broken inputs."""

import json

import cv2
import numpy as np
import pytest

from relight import load_bundle
from relight.cli import main
from relight.colour import linear_to_srgb
from relight.errors import InputError
from relight.pipeline.capture import capture
from relight.pipeline.capture_types import CaptureOptions
from relight.pipeline.evaluate import evaluate_capture
from relight.pipeline.image_set import read_lp
from relight.video_write import VideoWriter

from .once import synthesized
from .tolerances import (
    AMBIENT_16BIT_ABS,
    CAPTURE_MASK_IOU,
    DOME_FULL_PSNR,
    DOME_MARGIN_OVER_PTM,
    DOWNSCALED_FACE_PIXELS,
    FACE_MARGIN_DB,
    FACE_PIXELS_REL,
    FLASH_PRECISION,
    FLASH_RECALL,
    HALF_STORE_REL,
    LIGHT_DIR_MEAN_DEG,
    LIGHT_DIR_P95_DEG,
    MESH_NORMAL_DEG,
    NORMAL_MEDIAN_DEG,
    PHONE_CAPTURE_EXTRA_DEG,
    POWER_BIAS_CODES,
    REGISTRATION_RMS_PX,
    SAMPLE_16BIT_ABS,
    SMALL_CAPTURE_LIGHT_DIR_MEAN_DEG,
    SRGB_BIAS_CODES,
    VFR_DROP_SHARE,
    VFR_JITTER_S,
)


@pytest.fixture(scope="module")
def synth_capture(tmp_path_factory):
    from relight.pipeline.synth.config import SynthConfig

    return synthesized(tmp_path_factory, "capture-480x270",
                       SynthConfig(width=480, height=270, duration=8.0, seed=4, truth_envs=("builtin:studio",)))


@pytest.mark.slow  # the capture and its truth comparison (~25 s): `make test-slow`, CI
def test_video_capture_meets_the_accuracy_goals(synth_capture, tmp_path):
    report_dir = tmp_path / "report"
    assert main(["capture", str(synth_capture.video), "-o", str(tmp_path / "f.bundle"), "--report",
                 str(report_dir), "--quiet"]) == 0
    report = json.loads((report_dir / "report.json").read_text())
    for key in ("flash_frames", "light_dirs", "transforms", "reference_frame", "rejected", "timings"):
        assert key in report
    for png in ("brightness", "registration", "directions", "normals", "maps", "visibility"):
        assert (report_dir / f"{png}.png").stat().st_size > 1000
    bundle = load_bundle(tmp_path / "f.bundle")
    m = evaluate_capture(report, bundle, synth_capture.truth)
    assert m["flash_precision"] >= FLASH_PRECISION and m["flash_recall"] >= FLASH_RECALL, m
    assert m["registration_rms_px"] <= REGISTRATION_RMS_PX, m
    assert m["light_dir_mean_deg"] <= LIGHT_DIR_MEAN_DEG and m["light_dir_p95_deg"] <= LIGHT_DIR_P95_DEG, m
    assert m["normal_median_deg"] <= NORMAL_MEDIAN_DEG, m
    assert m["mask_iou"] > CAPTURE_MASK_IOU, m
    maps = bundle.pixel_maps()
    assert np.isfinite(maps.astype(np.float32)).all()
    # The default bundle holds the maps' recipe (maps only with --keep-maps); its two makers -
    # every texel on the device, a few texels in NumPy - agree.
    assert not {"maps", "maps_rows", "samples"} & set(bundle.arrays) and bundle.recipe is not None
    assert maps.shape[0] == bundle.pixels.size == bundle.normal.shape[0]
    from relight.numerics import HALF_TINY  # rows are flushed below it, as the kernels read them

    np.testing.assert_allclose(bundle.texel_rows([5])[0].astype(np.float32), maps[:, :, 5].T.astype(np.float32),
                               rtol=HALF_STORE_REL, atol=HALF_TINY)
    assert bundle.landmarks.shape[0] > 20


def _phone_capture_metrics(video, truth, tmp_path):
    report_dir = tmp_path / "report"
    capture(video, tmp_path / "f.bundle", progress=False, report_dir=report_dir)
    report = json.loads((report_dir / "report.json").read_text())
    return evaluate_capture(report, load_bundle(tmp_path / "f.bundle"), truth), report


def _meets_capture_goals(m):
    assert m["flash_precision"] >= FLASH_PRECISION and m["flash_recall"] >= FLASH_RECALL, m
    assert m["light_dir_mean_deg"] <= LIGHT_DIR_MEAN_DEG + PHONE_CAPTURE_EXTRA_DEG, m
    assert m["light_dir_p95_deg"] <= LIGHT_DIR_P95_DEG + PHONE_CAPTURE_EXTRA_DEG, m
    assert m["normal_median_deg"] <= NORMAL_MEDIAN_DEG, m
    assert m["registration_rms_px"] <= REGISTRATION_RMS_PX, m


@pytest.mark.slow
def test_iphone_hdr_portrait_video_captures_as_well(synth_capture, tmp_path):
    """The capture as an iPhone stores it - HEVC, 10-bit, BT.2020 primaries and matrix, the HLG
    curve, portrait frames turned in the file plus a display rotation - meets the plain capture's
    goals against the same truth (light directions within a stated margin for the second lossy
    encode)."""
    from relight.video_colour import VideoColour
    from relight.video_read import probe_video

    from .phone_video import encode_like_phone

    hdr = VideoColour(matrix="bt2020", primaries="bt2020", transfer="hlg", bits=10)
    video = encode_like_phone(synth_capture.video, tmp_path / "iphone.mov", hdr, codec="libx265", rotation=90)
    info = probe_video(synth_capture.video)
    assert (probe_video(video).width, probe_video(video).height) == (info.width, info.height)
    m, report = _phone_capture_metrics(video, synth_capture.truth, tmp_path)
    assert any("hlg transfer" in n for n in report["notes"]), report["notes"]
    _meets_capture_goals(m)


@pytest.fixture(scope="module")
def synth_capture_60fps(tmp_path_factory):
    from relight.pipeline.synth.config import SynthConfig
    from relight.pipeline.synth.studio import synthesize

    out = tmp_path_factory.mktemp("cap60")
    return synthesize(out / "synth", SynthConfig(width=480, height=270, duration=6.0, fps=60.0, seed=4,
                                                 truth_envs=("builtin:studio",)), progress=False)


@pytest.mark.slow
def test_variable_frame_rate_video_captures_as_well(synth_capture_60fps, tmp_path):
    """A 60 fps phone video with a variable frame rate - a fifth of the frames dropped at random
    and the rest stamped with +-3 ms of jitter - meets the capture's goals: flash timing,
    exposure and motion are reasoned in the frames' timestamps, not their numbers."""
    from relight.video_colour import VideoColour

    from .phone_video import encode_like_phone, renumbered_truth

    src = synth_capture_60fps
    rng = np.random.default_rng(7)
    keep = np.flatnonzero(rng.random(src.frame_count) > VFR_DROP_SHARE)
    times = keep / 60.0 + rng.uniform(-VFR_JITTER_S, VFR_JITTER_S, keep.size)
    times -= times[0]
    video = encode_like_phone(src.video, tmp_path / "vfr.mp4", VideoColour(transfer="bt709"), codec="libx264",
                              keep=keep, times=times, fps=60.0)
    truth = renumbered_truth(src.truth, keep, tmp_path / "truth")
    m, report = _phone_capture_metrics(video, truth, tmp_path)
    _meets_capture_goals(m)


@pytest.mark.slow  # a whole capture more (~10-15 s): `make test-slow`, CI
def test_downscaled_capture_meets_the_goals_and_relights_full_size_frames(synth_capture, tmp_path):
    """--face-pixels below the head's size: the capture is worked on downscaled (face and sphere
    found on scaled-down first seconds, the first seconds decoded again instead of held), meets
    the goals against the full-size truth, records its scale, and the per-frame path relights
    the video's full-size frames with it."""
    from relight.engine.frame_path import FramePath
    from relight.pipeline import ingest as ingest_mod
    from relight.video_read import read_frames

    report_dir = tmp_path / "report"
    opts = CaptureOptions(face_pixels=DOWNSCALED_FACE_PIXELS)
    # As a 4K capture would: detection on a smaller copy, nothing of the first seconds held.
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(ingest_mod, "DETECT_MAX_SIDE", 320)
        mp.setattr(ingest_mod, "HOLD_HEAD_BYTES", 0)
        capture(synth_capture.video, tmp_path / "s.bundle", opts, progress=False, report_dir=report_dir)
    report = json.loads((report_dir / "report.json").read_text())
    b = load_bundle(tmp_path / "s.bundle")
    s = b.meta["capture_scale"]
    # the 480x270 source's scale to the capture frame lies inside the head's range (definitional bound, not a tolerance)
    assert 0.3 < s < 0.8 and b.meta["source_size"] == [480, 270]
    assert b.frame_size == (round(480 * s), round(270 * s)) and b.background.shape[:2] == b.frame_size[::-1]
    assert abs(b.pixels.size - DOWNSCALED_FACE_PIXELS) < FACE_PIXELS_REL * DOWNSCALED_FACE_PIXELS
    assert any("downscaled" in n for n in report["notes"])
    m = evaluate_capture(report, b, synth_capture.truth)
    _meets_capture_goals(m)
    # The live side: full-size frames of the same video, the downscaled bundle.
    from relight import load_environment

    fp = FramePath(b, load_environment("builtin:sunset"))
    dark = set(report["dark_frames"][:12])
    frames = [f for i, f in enumerate(read_frames(synth_capture.video)) if i in dark]
    found = 0
    for k, rgb in enumerate(frames):
        out, info = fp.process(rgb, k / 30.0)
        assert out.shape == rgb.shape and out.dtype == np.uint8
        found += info.face
    assert found >= len(frames) - 1
    assert np.abs(out.astype(int) - rgb.astype(int)).max() > 20  # relit, not passed through


def test_stages_can_be_switched_off(small_capture, tmp_path):
    from relight.pipeline.samples import SampleOptions

    synth, _ = small_capture  # (the suite's shared capture: this one's own clip cost 18 s to render)
    opts = CaptureOptions(method="barycentric", map_size=(32, 16),
                          samples=SampleOptions(register=False, subtract_ambient=False, flash_hz=5.0))
    res = capture(synth.video, tmp_path / "b.bundle", opts, progress=False)
    b = load_bundle(res.bundle)
    assert b.meta["method"] == "barycentric" and not b.meta["visibility"] and b.map_size == (32, 16)
    assert all(v == [0, 0, 0] for v in res.report["transforms"].values())


@pytest.mark.slow  # a capture more (~8 s): `make test-slow`; the cone's own accuracy is test_sphere's
def test_a_capture_told_a_focal_length_reads_the_sphere_through_it(small_capture, tmp_path):
    """``relight capture --focal``: the sphere's light directions are read through that pinhole
    (the ball's cone fitted to its outline, pipeline.sphere.refine_cone). Told a pinhole so far
    that it is the studio's orthographic camera (a focal length of 1000 frame widths), the
    directions are as near the studio's truth as the orthographic capture's (measured: 1.02 /
    2.27 deg mean / p95 against 1.05 / 2.29 - the small capture's ball is 18 px), and the bundle
    records the camera."""
    from relight.pipeline.samples import SampleOptions

    synth, cfg = small_capture
    focal = 1000.0 * cfg.width
    res = capture(synth.video, tmp_path / "f.bundle", CaptureOptions(samples=SampleOptions(focal=focal)),
                  progress=False)
    bundle = load_bundle(res.bundle)
    assert bundle.meta["camera_focal"] == pytest.approx(focal)
    m = evaluate_capture(res.report, bundle, synth.truth)
    assert m["light_dir_mean_deg"] <= SMALL_CAPTURE_LIGHT_DIR_MEAN_DEG, m
    assert m["light_dir_p95_deg"] <= LIGHT_DIR_P95_DEG, m


def _psnr_on_test(bundle, test_dir):
    """Mean PSNR of `render --light` (the default bundle's path: texels made from its recipe)
    against the held-out photos, inside the head."""
    from relight import Relighter

    rl = Relighter(bundle)
    mask = np.asarray(bundle.mask)
    out = []
    for name, d in read_lp(test_dir / "dirs.lp"):
        truth = cv2.imread(str(test_dir / name))[..., ::-1][mask] / 255.0
        pred = linear_to_srgb(np.clip(np.array(rl.relight_light(d))[mask], 0.0, None))
        out.append(10 * np.log10(1.0 / np.mean((truth - pred) ** 2)))
    return float(np.mean(out))


@pytest.mark.slow
def test_real_rti_set_predicts_held_out_photos(shared_data, tmp_path):
    dome, test = shared_data / "rti-dome" / "Dome", shared_data / "rti-dome" / "Test"
    psnr = {}
    for method in ("full", "ptm"):
        res = capture(dome, tmp_path / f"{method}.bundle", CaptureOptions(method=method), images=True, progress=False)
        psnr[method] = _psnr_on_test(load_bundle(res.bundle), test)
    assert psnr["full"] >= DOME_FULL_PSNR, psnr
    assert psnr["full"] >= psnr["ptm"] + DOME_MARGIN_OVER_PTM, psnr


@pytest.mark.slow  # a capture of a real face set (~19 s): `make test-slow`, CI
def test_real_face_predicts_held_out_photos(shared_data, tmp_path):
    from relight.bench import accuracy, accuracy_real

    small = accuracy_real.scaled_rti(shared_data / "faces-yale" / "yaleB02", tmp_path / "yaleB02", 2)
    res = accuracy_real.evaluate_face(small, tmp_path / "eval", False,
                                 variants={k: accuracy.VARIANTS[k] for k in ("full", "barycentric", "ptm")})
    psnr = {k: v["psnr"] for k, v in res["variants"].items()}
    assert res["held_out"][0] == "P00A+000E+00.png" and len(res["held_out"]) == 9  # lights 0, 6, ..., 48
    assert psnr["full"] >= max(psnr["barycentric"], psnr["ptm"], psnr["nearest"]) + FACE_MARGIN_DB, psnr


@pytest.mark.slow
def test_a_real_face_set_seen_as_srgb_captures_finite(shared_data, tmp_path, capsys):
    """Yale B06 taken as sRGB (the default --transfer) wrote non-finite values into its bundle: a
    specular lobe fitted at grazing normals weighed ~1e5 times the samples, its maps reached
    4e4 times them beyond the captured hull, the transport's projections overflowed float16.
    It captures now, no numerical warning on the way, and its maps stay within the bound the
    stability suite sets."""
    import warnings

    from relight.bench.stability import MAX_MAP_GAIN
    from relight.kernels.recipe import recipe_maps

    out = tmp_path / "b06.bundle"
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        assert main(["capture", "--images", str(shared_data / "faces-yale" / "yaleB06"), "-o", str(out),
                     "--quiet"]) == 0
    b = load_bundle(out)  # every field checked finite on load
    r = b.recipe
    maps = recipe_maps(r, texel_major=True)
    top = np.asarray(r.samples(), np.float64).max(axis=(0, 2))
    lit = top > 0
    assert np.isfinite(maps).all()
    assert (maps.max(axis=(0, 1))[lit] / top[lit]).max() <= MAX_MAP_GAIN


def test_image_set_transfer_and_room_light(tmp_path):
    """An image set's files decode with the transfer it names; its ambient frame is subtracted from
    every image and kept as the bundle's (dim: not a usable room-light reference)."""
    def write16(path, img):  # grey, so OpenCV's BGR order does not matter
        cv2.imwrite(str(path), np.round(img * 65535).astype(np.uint16))

    rng = np.random.default_rng(1)
    h, w = 24, 20
    albedo = rng.uniform(0.3, 0.6, (h, w, 1)).astype(np.float32)
    ambient = np.full((h, w, 3), 0.01, np.float32)
    lines, linear = [], {}
    for i in range(14):
        a = 2 * np.pi * i / 14
        d = np.array([0.5 * np.cos(a), 0.5 * np.sin(a), 0.75])
        d /= np.linalg.norm(d)
        img = np.repeat(albedo * d[2], 3, axis=2) + ambient  # a flat face toward the camera
        linear[f"i{i}.png"] = img
        write16(tmp_path / f"i{i}.png", img)  # 16-bit linear codes
        lines.append(f"i{i}.png {d[0]:.5f} {d[1]:.5f} {d[2]:.5f}\n")
    write16(tmp_path / "ambient.png", ambient)
    (tmp_path / "dirs.lp").write_text(f"{len(lines)}\n" + "".join(lines))
    res = capture(tmp_path, tmp_path / "lin.bundle", CaptureOptions(transfer="linear", keep_maps=True), images=True,
                  progress=False)
    b = load_bundle(res.bundle)
    assert {"maps", "samples"} <= set(b.meta["stored"])  # --keep-maps: the pixel-major maps and the samples
    t = b.map_texels.size
    np.testing.assert_array_equal(np.asarray(b.maps)[:, :, :t], np.asarray(b.maps_rows).transpose(2, 1, 0))
    assert b.meta["transfer"] == "linear" and "ambient.png" in res.report["notes"][0]
    np.testing.assert_allclose(np.asarray(b.ambient), ambient, atol=AMBIENT_16BIT_ABS)
    samples = np.asarray(b.samples, dtype=np.float32)
    np.testing.assert_allclose(samples[0], (linear["i0.png"] - ambient).reshape(-1, 3), atol=SAMPLE_16BIT_ABS)
    assert b.room_light is None  # 1 % of the face's light is noise, not a reference
    # The background, declared sRGB, is the median image through the sRGB curve (not a plain
    # 1/2.2 power: 0.4 linear is code 170 in sRGB, 167 with the power).
    median = np.median(np.stack([linear[k] for k in sorted(linear)]), axis=0)
    bg = np.asarray(b.background, np.float64)
    bias = float(np.mean(bg - 255 * linear_to_srgb(np.clip(median, 0, 1))))
    bias_power = float(np.mean(bg - 255 * np.clip(median, 0, 1) ** (1 / 2.2)))
    # JPEG-stored: unbiased, not exact
    assert abs(bias) < SRGB_BIAS_CODES and abs(bias_power) > POWER_BIAS_CODES, (bias, bias_power)
    srgb = load_bundle(capture(tmp_path, tmp_path / "srgb.bundle", CaptureOptions(keep_maps=True), images=True,
                               progress=False).bundle)
    assert np.asarray(srgb.samples, np.float32).mean() < 0.5 * samples.mean()  # read as sRGB: far darker
    with pytest.raises(InputError, match="--transfer"):
        CaptureOptions(transfer="gamma").validate()


def _video(path, frames, fps=30):
    with VideoWriter(path, fps, (frames[0].shape[1], frames[0].shape[0])) as w:
        for f in frames:
            w.write(f)


def test_a_video_without_flashes_says_so(tmp_path):
    rng = np.random.default_rng(0)
    frames = [np.clip(80 + rng.normal(0, 2, (144, 256, 3)), 0, 255).astype(np.uint8) for _ in range(90)]
    _video(tmp_path / "flat.mp4", frames)
    with pytest.raises(InputError, match="no usable flash|no mirror sphere|no dark"):
        capture(tmp_path / "flat.mp4", tmp_path / "x.bundle", progress=False)
    assert not (tmp_path / "x.bundle").exists()


def test_no_sphere_where_told_gives_a_clear_error(small_capture, tmp_path, capsys):
    # A "sphere" placed on the empty wall: no highlight ever appears there.
    code = main(["capture", str(small_capture[0].video), "-o", str(tmp_path / "x.bundle"), "--sphere", "40,40,20",
                 "--quiet"])
    err = capsys.readouterr().err
    assert code == 2 and "usable flash samples" in err and "Traceback" not in err


def test_cli_needs_exactly_one_source(tmp_path, capsys):
    assert main(["capture", "-o", str(tmp_path / "x.bundle"), "--quiet"]) == 2
    assert "either a capture video or --images" in capsys.readouterr().err


@pytest.mark.parametrize(("text", "msg"), [
    ("", "empty"), ("abc\n", "number of images"), ("2\na.jpg 0 0 1\n", "lists 1"),
    ("1\na.jpg 0 0\n", "filename x y z"), ("1\na.jpg 0 0 nan\n", "finite"), ("1\n../a.jpg 0 0 1\n", "plain file"),
])
def test_bad_lp_files(tmp_path, text, msg):
    (tmp_path / "dirs.lp").write_text(text)
    with pytest.raises(InputError, match=msg):
        read_lp(tmp_path / "dirs.lp")


def test_image_set_with_nan_is_refused(tmp_path):
    from relight.imageio import write_image

    for i in range(4):
        write_image(tmp_path / f"i{i}.png", np.full((16, 16, 3), 100, np.uint8))
    import OpenImageIO as oiio

    bad = np.ones((16, 16, 3), np.float32)
    bad[3, 3] = np.nan
    o = oiio.ImageOutput.create(str(tmp_path / "i4.exr"))
    o.open(str(tmp_path / "i4.exr"), oiio.ImageSpec(16, 16, 3, "float"))
    o.write_image(bad)
    o.close()
    lines = "".join(f"i{i}.png 0.{i} 0.2 1\n" for i in range(4))
    (tmp_path / "dirs.lp").write_text("5\n" + lines + "i4.exr 0 -0.3 1\n")
    with pytest.raises(InputError, match="non-finite"):
        capture(tmp_path, tmp_path / "x.bundle", images=True, progress=False)


@pytest.mark.slow  # a whole capture more (~10-15 s): `make test-slow`, CI
def test_no_face_falls_back_to_the_whole_frame(synth_capture, tmp_path, monkeypatch):
    from relight import faces

    monkeypatch.setattr(faces, "detect_face", lambda rgb: None)  # as if the cascade saw no face
    res = capture(synth_capture.video, tmp_path / "f.bundle", CaptureOptions(method="barycentric"), progress=False)
    assert any("no face detected" in n for n in res.report["notes"])
    assert res.report["face_source"] == "none"
    b = load_bundle(res.bundle)
    assert b.pixels.size > 1000 and np.isfinite(b.pixel_maps().astype(np.float32)).all()


@pytest.mark.slow  # a whole capture more (~10-15 s): `make test-slow`, CI
def test_user_mesh_and_mesh_export(synth_capture, tmp_path):
    from relight.directions import angle_between_deg
    from relight.imageio import read_image

    opts = CaptureOptions(method="barycentric", mesh=str(synth_capture.truth / "head.ply"),
                          export_mesh=str(tmp_path / "est.ply"))
    res = capture(synth_capture.video, tmp_path / "m.bundle", opts, progress=False)
    b = load_bundle(res.bundle)
    assert b.meta["geometry"] == "mesh"
    x0, y0 = b.crop_origin
    h, w = b.mask_crop.shape
    truth_n = read_image(synth_capture.truth / "normals.exr")[y0:y0 + h, x0:x0 + w].reshape(-1, 3)
    pix = np.asarray(b.pixels)
    assert np.median(angle_between_deg(np.asarray(b.normal), truth_n[pix])) < MESH_NORMAL_DEG  # the truth's own mesh
    import trimesh

    est = trimesh.load(tmp_path / "est.ply", process=False)
    assert len(est.vertices) == pix.size and len(est.faces) > pix.size
    with pytest.raises(InputError, match="mesh"):
        capture(synth_capture.video, tmp_path / "x.bundle", CaptureOptions(mesh=str(tmp_path / "est.txt")),
                progress=False)


def test_saturated_and_black_images_stay_finite(tmp_path):
    from relight.imageio import write_image

    rng = np.random.default_rng(0)
    lines = []
    for i in range(12):
        a = 2 * np.pi * i / 12
        img = np.clip(rng.normal(120, 30, (32, 32, 3)), 0, 255).astype(np.uint8)
        if i % 4 == 0:
            img[:] = 255  # a saturated frame
        if i % 4 == 1:
            img[:] = 0  # a black one
        write_image(tmp_path / f"i{i}.png", img)
        lines.append(f"i{i}.png {0.6 * np.cos(a):.4f} {0.6 * np.sin(a):.4f} 0.8\n")
    (tmp_path / "dirs.lp").write_text(f"{len(lines)}\n" + "".join(lines))
    res = capture(tmp_path, tmp_path / "s.bundle", images=True, progress=False)
    b = load_bundle(res.bundle)
    maps = b.pixel_maps().astype(np.float32)
    assert np.isfinite(maps).all() and maps.max() <= 10.0
    assert np.isfinite(np.asarray(b.normal)).all() and np.isfinite(np.asarray(b.depth)).all()


@pytest.mark.parametrize("kw, flag", [({"model_reach": 0.0}, "--model-reach"), ({"model_reach": float("nan")},
                                      "--model-reach"), ({"map_size": (64, 64)}, "--map-size")])
def test_bad_capture_options_name_the_flag(kw, flag):
    with pytest.raises(InputError, match=flag):
        CaptureOptions(**kw).validate()
