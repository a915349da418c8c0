"""The image metrics of ``relight bench accuracy``: SSIM inside a mask, PSNR / SSIM after one
least-squares exposure gain (against the synthetic truth), and PSNR of images in [0, 1] (real
photos, no gain)."""

from __future__ import annotations

import numpy as np


def masked_ssim(pred: np.ndarray, truth: np.ndarray, mask: np.ndarray) -> float:
    """Mean SSIM inside ``mask`` of two (H, W, 3) images in [0, 1] (scikit-image, Gaussian window)."""
    from skimage.metrics import structural_similarity

    _, smap = structural_similarity(truth, pred, channel_axis=2, data_range=1.0, gaussian_weights=True,
                                    sigma=1.5, use_sample_covariance=False, full=True)
    return float(smap[mask].mean())


def env_metrics(pred: np.ndarray, truth: np.ndarray, mask: np.ndarray) -> dict:
    """PSNR (peak = the truth's maximum in the mask) and SSIM after one least-squares gain."""
    a = pred[mask].astype(np.float64)
    b = truth[mask].astype(np.float64)
    g = float((a * b).sum() / max(float((a * a).sum()), 1e-30))
    peak = max(float(b.max()), 1e-30)
    mse = float(((g * a - b) ** 2).mean())
    psnr = 10.0 * np.log10(peak * peak / max(mse, 1e-30))
    ssim = masked_ssim(np.clip(g * pred / peak, 0, 1), np.clip(truth / peak, 0, 1), mask)
    return {"psnr": float(psnr), "ssim": ssim, "gain": g}


def unit_psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(((a.astype(np.float64) - b) ** 2).mean())
    return float(10.0 * np.log10(1.0 / max(mse, 1e-30)))
