"""The live frame's benchmark (relight.bench.live_frame): its figures on outputs whose answer is
known - the input unchanged, the truth pasted on the person, a ghost off the person, a relit
core with an unrelit ring (a seam) - on a real truth clip of the synthetic studio."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from relight.bench import live_frame
from relight.imageio import write_image
from relight.video_read import read_frames

SIZE, FPS = (160, 90), 5
#: The reference silhouette moved with the true pose covers each frame's silhouette (the two
#: rasterisations differ only on edge pixels).
MOVED_MASK_IOU = 0.9
#: An output that is the truth plus uniform noise of this many codes on the person.
INNER_CODES = 5


@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    from relight.pipeline.synth.live_clip import LiveConfig, synthesize_live

    out = tmp_path_factory.mktemp("lf")
    synthesize_live(out, LiveConfig(width=SIZE[0], height=SIZE[1], duration=1.0, fps=FPS, seed=4,
                                    truth_envs=("builtin:sunset",)), progress=False)
    meta = json.loads((out / "truth" / "meta.json").read_text())
    inputs = list(read_frames(out / "live.mp4"))
    truths = [cv2.imread(str(out / (meta["files"]["live_truth"]["sunset"] % i)))[..., ::-1] for i in range(FPS)]
    sils = [cv2.imread(str(out / (meta["files"]["silhouette"] % i)), cv2.IMREAD_GRAYSCALE) > 0 for i in range(FPS)]
    return out, inputs, truths, sils


def _write(folder, frames):
    folder.mkdir()
    for i, f in enumerate(frames):
        write_image(folder / f"{i:06d}.png", np.ascontiguousarray(f, dtype=np.uint8))
    return folder


def test_the_input_unchanged_scores_as_the_input(clip, tmp_path):
    live, inputs, _, _ = clip
    doc = live_frame.evaluate(None, live, "sunset", _write(tmp_path / "same", inputs))
    assert doc["silhouette_psnr"] == pytest.approx(doc["input_psnr"])
    assert doc["outside_mean_codes"] == 0.0 and doc["outside_p999_codes"] == 0.0
    assert doc["seam_ratio"] is None and doc["flicker_codes"] is None  # nothing composited
    assert doc["noise_floor_psnr"] > doc["input_psnr"]  # the sensor's noise is smaller than the relight
    assert not doc["goals_met"]["over_input"]


def test_the_truth_on_the_person_meets_the_goals_and_a_ghost_is_caught(clip, tmp_path):
    live, inputs, truths, sils = clip
    rng = np.random.default_rng(0)
    pasted = []
    for inp, truth, sil in zip(inputs, truths, sils, strict=True):
        out = inp.copy()
        noisy = np.clip(truth.astype(int) + rng.integers(-INNER_CODES, INNER_CODES + 1, truth.shape), 0, 255)
        out[sil] = noisy[sil]
        pasted.append(out)
    doc = live_frame.evaluate(None, live, "sunset", _write(tmp_path / "pasted", pasted))
    assert doc["silhouette_psnr"] > doc["input_psnr"] + live_frame.GOALS["over_input_db"]
    assert doc["outside_mean_codes"] == 0.0
    assert doc["seam_ratio"] is not None and doc["seam_ratio"] <= live_frame.GOALS["seam_ratio"]
    # a ghost: a patch off the person brightened by 20 codes in every frame
    ghosted = [p.copy() for p in pasted]
    for g in ghosted:
        g[2:22, 2:22] = np.clip(g[2:22, 2:22].astype(int) + 20, 0, 255)
    doc = live_frame.evaluate(None, live, "sunset", _write(tmp_path / "ghost", ghosted))
    assert doc["outside_p999_codes"] >= 19 and not doc["goals_met"]["outside_p999"]


def test_a_relit_core_with_an_unrelit_ring_is_a_seam(clip, tmp_path):
    live, inputs, truths, sils = clip
    cored = []
    for inp, truth, sil in zip(inputs, truths, sils, strict=True):
        core = cv2.erode(sil.astype(np.uint8), np.ones((17, 17), np.uint8)) > 0
        out = inp.copy()
        out[core] = truth[core]
        cored.append(out)
    doc = live_frame.evaluate(None, live, "sunset", _write(tmp_path / "core", cored))
    assert doc["seam_ratio"] > live_frame.GOALS["seam_ratio"]


def test_the_bundle_mask_moves_with_the_true_pose(clip):
    live, _, _, sils = clip
    scene = live_frame.live_scene(live)
    ref = cv2.imread(str(live / "truth" / "mask_reference.png"), cv2.IMREAD_GRAYSCALE) > 0
    for region, sil in zip(live_frame.face_regions(scene, ref), sils, strict=True):
        assert (region & sil).sum() / (region | sil).sum() > MOVED_MASK_IOU
