"""The accuracy benchmark's parts: metrics, variants from one preparation, the scene evaluation
(environments, single lights, heat maps) and the report; the synth's sparse-sides sampling."""

import numpy as np
import pytest

from relight.bench import accuracy, accuracy_metrics, accuracy_report

from .tolerances import (
    EXTRAPOLATION_GAIN,
    F64_CLOSE,
    F64_EXACT,
    OLAT_REL_RMSE_MAX,
    SPARSE_SIDES_REACH,
    SPARSE_SIDES_SHARE,
)


def test_env_metrics_psnr_of_a_known_error():
    """A hand-computed case: inside the mask the prediction is 1.0 everywhere, the truth 0.625 and
    0.375 in equal numbers. The least-squares gain is 0.5 (truth . pred / pred . pred = 0.5 n / n),
    the residual +-0.125 (MSE 1/64) and the peak 0.625 (25/64): PSNR = 10 log10(25) = 13.9794 dB.
    Outside the mask a brighter truth (100) and a wild prediction that must count for nothing."""
    truth = np.full((16, 16, 3), 100.0, np.float32)  # (SSIM's window needs 11 x 11)
    pred = np.full((16, 16, 3), -7.0, np.float32)
    mask = np.zeros((16, 16), bool)
    mask[4:12, 3:13] = True
    checker = (np.add.outer(np.arange(16), np.arange(16)) % 2 == 0)[..., None]
    truth[mask] = np.where(checker, 0.625, 0.375)[mask]
    pred[mask] = 1.0
    m = accuracy_metrics.env_metrics(pred, truth, mask)
    assert m["gain"] == pytest.approx(0.5, rel=F64_EXACT)
    assert m["psnr"] == pytest.approx(13.979400086720377, rel=F64_EXACT)  # 10 * log10(25)


def test_env_metrics_fit_one_gain_and_follow_the_error():
    from skimage.metrics import peak_signal_noise_ratio

    rng = np.random.default_rng(0)
    truth = rng.uniform(0.1, 2.0, (40, 50, 3)).astype(np.float32)
    mask = np.zeros((40, 50), bool)
    mask[5:35, 5:45] = True
    same = accuracy_metrics.env_metrics(2.0 * truth, truth, mask)  # twice as bright: the gain takes it out
    assert same["gain"] == pytest.approx(0.5) and same["psnr"] > 100 and same["ssim"] == pytest.approx(1.0)
    noisy = truth + rng.normal(0, 0.02, truth.shape).astype(np.float32)
    m = accuracy_metrics.env_metrics(noisy, truth, mask)
    # references: the gain by NumPy's least squares, the PSNR by scikit-image (peak: the truth's
    # largest value in the mask, as the benchmark defines it)
    a, b = noisy[mask].astype(np.float64).ravel(), truth[mask].astype(np.float64).ravel()
    g = np.linalg.lstsq(a[:, None], b, rcond=None)[0][0]
    want = peak_signal_noise_ratio(b, g * a, data_range=b.max())
    assert m["gain"] == pytest.approx(g, rel=F64_CLOSE)
    assert m["psnr"] == pytest.approx(want, rel=F64_CLOSE) and 0.5 < m["ssim"] < 1.0
    worse = accuracy_metrics.env_metrics(truth + rng.normal(0, 0.1, truth.shape).astype(np.float32), truth, mask)
    assert worse["psnr"] < m["psnr"] - 10 and worse["ssim"] < m["ssim"]


def test_masked_ssim_is_scikit_images_inside_the_mask():
    from skimage.metrics import structural_similarity

    rng = np.random.default_rng(1)
    a = rng.uniform(0, 1, (32, 32, 3))
    b = np.clip(a + rng.normal(0, 0.05, a.shape), 0, 1)
    inner = np.zeros((32, 32), bool)
    inner[5:-5, 5:-5] = True  # scikit-image's mean leaves out the 11x11 window's half width
    want = structural_similarity(a, b, channel_axis=2, data_range=1.0, gaussian_weights=True, sigma=1.5,
                                 use_sample_covariance=False)
    assert accuracy_metrics.masked_ssim(b, a, inner) == pytest.approx(want, rel=F64_CLOSE)


def test_sparse_sides_thin_the_samples_at_wide_azimuths():
    from relight.pipeline.synth.acquisition import AZIMUTH_MAX, hand_direction

    t = np.linspace(0, 60, 20000)
    phase = np.zeros(4)
    share = {}
    for sparse in (False, True):
        d = hand_direction(t, 60.0, phase, sparse_sides=sparse)
        az = np.degrees(np.arctan2(d[:, 0], d[:, 2]))
        share[sparse] = np.mean(np.abs(az) > 0.7 * AZIMUTH_MAX)
        assert np.abs(az).max() > SPARSE_SIDES_REACH * AZIMUTH_MAX  # the sides are still reached
    assert share[True] < SPARSE_SIDES_SHARE * share[False], share


@pytest.mark.slow
def test_variants_and_scene_evaluation(small_capture, tmp_path):
    """Three variants from one preparation of a real (synthetic) capture, evaluated like the
    benchmark does: the model lights beyond the hull must beat black lights on single lights
    over the whole sphere, every figure finite, the heat map written, the report rendered."""
    res, cfg = small_capture
    variants = {k: accuracy.VARIANTS[k] for k in ("full", "full -extrapolation", "ptm")}
    bundles = accuracy.build_variants(res.video, tmp_path / "bundles", variants=variants)
    assert set(bundles) == set(variants)
    for info in bundles.values():
        # timings positive and ordered; a bundle is never empty (definitional bound, not a tolerance)
        assert info["capture_s"] >= info["prepare_s"] > 0 and info["bundle_mb"] > 0.1
    envs = {"studio": ("builtin:studio", "whole sphere"), "point": ("builtin:point:0.8,0.1,0.6", "in hull")}
    scene = accuracy.evaluate_scene(cfg, res.out, bundles, envs, tmp_path, "small", False)
    rows = scene["variants"]
    for v, row in rows.items():
        for e in row["envs"].values():
            assert np.isfinite(e["psnr"]) and 15 < e["psnr"] < 60 and 0 < e["ssim"] <= 1, (v, e)
        assert 0 < row["olat"]["rel_rmse_hull"] < row["olat"]["rel_rmse_whole"] < OLAT_REL_RMSE_MAX, (v, row["olat"])
        assert row["relight_ms"] > 0
    without = rows["full -extrapolation"]["olat"]["rel_rmse_whole"]
    assert rows["full"]["olat"]["rel_rmse_whole"] < EXTRAPOLATION_GAIN * without
    assert (tmp_path / scene["heat_map"]).stat().st_size > 1000
    assert not any((tmp_path / "bundles").glob("*.bundle"))  # evaluated bundles are removed

    doc = {"quick": True, "envs": {k: {"source": s, "kind": kind} for k, (s, kind) in envs.items()},
           "scenes": [scene], "dome": None, "dome_skipped": "not in this test", "seconds": 1.0,
           "stability": [{"case": "c", "variant": "full", "max_rel_error": 1e-4, "finite": True, "error": None}]}
    for name in accuracy.VARIANTS:  # the report lists every variant; fill the ones not run here
        for sc in doc["scenes"]:
            sc["variants"].setdefault(name, rows["ptm"])
    doc["summary"] = accuracy.summarise(doc)
    md = accuracy.report_markdown(doc)
    assert "| full |" in md and "heat_small.png" in md and "not measured" in md
    assert "stability: 1 case x variant runs, non-finite: 0" in accuracy_report.table(doc)
