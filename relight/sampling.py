"""Bilinear sampling of an image at many points (:func:`bilinear`): the one helper the synthetic
studio's renderer and the composite kernels' NumPy twin read images with (the OpenCL kernels
sample the same way in float32; :func:`relight.engine.rig` reads depth through ``cv2.remap``,
which quantises positions to 1/32 px, like the device)."""

from __future__ import annotations

import numpy as np


def bilinear(img: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """(N, C) bilinear samples of ``img`` (H, W, C) at pixel positions ``x``, ``y`` (N,) (pixel
    centres at whole numbers); the edges replicated (a position outside reads the nearest edge).
    Computed in the positions' and the image's dtypes as NumPy promotes them (the weights in
    float64 for integer-offset positions)."""
    h, w = img.shape[:2]
    xc, yc = np.clip(x, 0, w - 1), np.clip(y, 0, h - 1)
    x0 = np.maximum(np.minimum(xc.astype(np.int64), w - 2), 0)
    y0 = np.maximum(np.minimum(yc.astype(np.int64), h - 2), 0)
    x1, y1 = np.minimum(x0 + 1, w - 1), np.minimum(y0 + 1, h - 1)
    fx, fy = (xc - x0)[:, None], (yc - y0)[:, None]
    a = img[y0, x0] * (1 - fx) + img[y0, x1] * fx
    b = img[y1, x0] * (1 - fx) + img[y1, x1] * fx
    return a * (1 - fy) + b * fy
