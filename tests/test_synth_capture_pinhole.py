"""The capture studio through a pinhole (``relight synth --fov DEG`` without ``--live``): the
head moved in space and seen through the camera, by the same convention as the image-plane
warp; its truth on the reference frame's pixels; what the truth records; the evaluator's motion
through the camera."""

import json

import numpy as np
import pytest

from relight.cli import main
from relight.pipeline.synth import acquisition
from relight.pipeline.synth.config import SynthConfig
from relight.pipeline.synth.pinhole_view import capture_mesh, posed_layer
from relight.pipeline.synth.studio import Studio

from .tolerances import F32_CLOSE

SMALL = dict(width=320, height=180, duration=1.0, seed=3, truth_envs=("builtin:uniform",))
#: The mesh's render against the image-plane warp of the same motion: their mean difference over
#: the head's inside at most this share of the difference with the roll turned the other way.
SAME_MOTION_SHARE = 0.25


def _inside(box, values, coverage, shape):
    """A render's (values over coverage, fully covered pixels) on the whole frame."""
    x0, y0, x1, y1 = box
    cov = np.zeros(shape[:2])
    cov[y0:y1, x0:x1] = coverage
    val = np.zeros(shape)
    val[y0:y1, x0:x1] = values
    inner = cov > 0.999
    return val[inner] / cov[inner, None], inner


def test_the_mesh_moves_the_head_as_the_image_plane_warp_does():
    """With no camera the capture's mesh at a frame's [tx, ty, rot] shows what the orthographic
    studio's warp shows (the pinhole path's convention: roll counter-clockwise on screen, ty down);
    the roll or the shift the other way does not."""
    studio = Studio(SynthConfig(**SMALL, head_motion=3.0))
    mesh = capture_mesh(studio.head, studio.ambient_head(), studio.room, studio.pivot,
                        reach_px=studio._reach, camera=None)
    image = studio.head_image(studio.ambient_head())
    motion = np.array([5.0, -4.0, 4.0])
    studio.motion[1] = motion
    studio.matrices[1] = acquisition.motion_matrices(motion[None], studio.head.center)[0]
    warped = studio.render_frame(1, flash=np.zeros_like(studio.ambient_head()))
    errors = []
    for row in (motion, motion * [1, 1, -1], motion * [1, -1, 1]):
        vals, inner = _inside(*posed_layer(mesh, image, row), warped.shape)
        errors.append(float(np.abs(vals - warped[inner]).mean()))
    assert errors[0] < SAME_MOTION_SHARE * min(errors[1:]), errors


@pytest.fixture(scope="module")
def pinhole_studio():
    return Studio(SynthConfig(**SMALL, fov=65.0))


def test_a_pinhole_captures_truth_lies_on_its_reference_frame(pinhole_studio):
    """A light's share of the reference frame (the frame with it minus without it) is the truth's
    image of that light through the pinhole, pixel for pixel over the head; the orthographic
    reference's image is elsewhere (a 65-degree lens at 60 cm shows the head smaller)."""
    st = pinhole_studio
    rad = st.shader.shade(np.array([[0.0, 0.0, 1.0]]), np.full((1, 1, 3), np.pi))[0].astype(np.float32)
    ref = st.reference_frame
    share = st.render_frame(ref, flash=rad) - st.render_frame(ref, flash=np.zeros_like(rad))
    (truth,), mask = st.pinhole_truth([st.head_image(rad)])
    inner = mask & (st.render_frame(ref, flash=np.full_like(rad, 1e3)).min(axis=2) > 999.0)  # fully covered
    assert inner.sum() > 0.8 * mask.sum() > 0
    np.testing.assert_allclose(share[inner], truth[inner], atol=F32_CLOSE * 10, rtol=F32_CLOSE * 10)
    assert mask.sum() < 0.9 * st.head.mask.sum()  # through the lens, not the orthographic reference
    assert (mask & ~st.head.mask).any()


def test_relight_synth_fov_writes_a_capture_through_the_pinhole(tmp_path):
    """`relight synth OUT --fov 65`: the truth's meta holds the camera and the pivot, its mask is
    the pinhole's (smaller than the orthographic capture's), depth and normals lie on it."""
    out = tmp_path / "pin"
    args = ["synth", str(out), "--size", "320x180", "--duration", "1", "--fps", "10", "--flash-hz", "2",
            "--seed", "3", "--truth-env", "builtin:uniform", "--quiet"]
    assert main([*args, "--fov", "65", "--distance", "70"]) == 0
    meta = json.loads((out / "truth" / "meta.json").read_text())
    cam = meta["camera"]
    assert cam["model"] == "pinhole" and cam["fov_deg"] == 65.0 and cam["distance_cm"] == 70.0
    assert meta["config"]["fov"] == 65.0 and len(meta["pivot"]) == 3
    assert "pinhole" in meta["conventions"]["head_motion"] and "truth_images" in meta["conventions"]
    from relight.imageio import read_image

    mask = read_image(out / "truth" / "mask.png") > 0
    mask = mask[..., 0] if mask.ndim == 3 else mask
    depth, normals = read_image(out / "truth" / "depth.exr"), read_image(out / "truth" / "normals.exr")
    depth = depth[..., 0] if depth.ndim == 3 else depth
    assert (depth[mask] > 0).all() and (depth[~mask] == 0).all()
    np.testing.assert_allclose(np.linalg.norm(normals[mask], axis=1), 1.0, atol=1e-3)
    assert main(["synth", str(tmp_path / "ortho"), *args[2:]]) == 0
    ortho = json.loads((tmp_path / "ortho" / "truth" / "meta.json").read_text())
    assert ortho["camera"] == {"model": "orthographic"} and "pivot" not in ortho
    ortho_mask = read_image(tmp_path / "ortho" / "truth" / "mask.png") > 0
    assert mask.sum() < 0.9 * ortho_mask.sum()


@pytest.mark.slow  # a 6 s 640x360 capture through a pinhole and two captures of it (~40 s): `make test-slow`
def test_relight_capture_finds_the_focal_length_from_the_ball(tmp_path):
    """`relight capture` on a capture through a 65-degree lens, not told its camera (--focal
    auto, the default): the focal length found from the ball's outline (within 5 %), the flashes'
    directions and the registration (the evaluator's truth through the camera) as near the truth
    as an orthographic capture's; `--focal ortho` reads the ball as if seen along the axis and is
    off by about the ball's view angle (measured on a 24 s capture: 16 deg mean, against 0.3)."""
    from relight import load_bundle
    from relight.pipeline.evaluate import evaluate_capture
    from relight.pipeline.synth.studio import synthesize

    from .tolerances import LIGHT_DIR_MEAN_DEG, LIGHT_DIR_P95_DEG, REGISTRATION_RMS_PX, SPHERE_FOCAL_REL

    synth = synthesize(tmp_path / "pin", SynthConfig(width=640, height=360, duration=6.0, seed=3, fov=65.0,
                                                     truth_envs=("builtin:window",)), progress=False)
    meta = json.loads((synth.truth / "meta.json").read_text())
    figures = {}
    for label, flag in (("auto", []), ("ortho", ["--focal", "ortho"])):
        out, report = tmp_path / f"{label}.bundle", tmp_path / f"report-{label}"
        assert main(["capture", str(synth.video), "-o", str(out), "--report", str(report), "--quiet", *flag]) == 0
        rep = json.loads((report / "report.json").read_text())
        bundle = load_bundle(out)
        figures[label] = (rep["camera"], bundle.meta["camera_focal"], evaluate_capture(rep, bundle, synth.truth))
    camera, recorded, m = figures["auto"]
    assert camera["source"] == "sphere"
    assert camera["focal_px"] == pytest.approx(meta["camera"]["focal_px"], rel=SPHERE_FOCAL_REL)
    assert recorded == pytest.approx(camera["focal_px"])  # the frames not downscaled: the same pixels
    assert m["light_dir_mean_deg"] <= LIGHT_DIR_MEAN_DEG and m["light_dir_p95_deg"] <= LIGHT_DIR_P95_DEG, m
    assert m["registration_rms_px"] <= REGISTRATION_RMS_PX, m
    camera, recorded, m_ortho = figures["ortho"]
    assert camera == {"focal_px": None, "source": "orthographic"} and recorded is None
    assert m_ortho["light_dir_mean_deg"] > 5 * LIGHT_DIR_MEAN_DEG, m_ortho
