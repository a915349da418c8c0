"""sRGB <-> linear conversions (IEC 61966-2-1 transfer function, sRGB/Rec.709 primaries).

All images inside relight are *linear* RGB, float32. sRGB encoding happens only at the
boundary: reading LDR images and video, writing PNG/JPEG and video.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from .numerics import FLOAT

#: Rec.709 luminance weights for linear RGB.
LUMINANCE = np.array([0.2126, 0.7152, 0.0722], dtype=FLOAT)


def srgb_to_linear(encoded: np.ndarray) -> np.ndarray:
    """Decode sRGB values in [0, 1] to linear light.

    encoded : (...) float, sRGB-encoded, 0-1. Returns float32 linear, 0-1.
    """
    c = np.asarray(encoded, dtype=FLOAT)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4).astype(FLOAT)


def linear_to_srgb(linear: np.ndarray) -> np.ndarray:
    """Encode linear light to sRGB; input is clipped to [0, 1] first.

    linear : (...) float, linear, 0-1 (values outside are clipped). Returns float32, 0-1.
    """
    c = np.clip(np.asarray(linear, dtype=FLOAT), 0.0, 1.0)
    return np.where(c <= 0.0031308, c * 12.92, 1.055 * c ** (1.0 / 2.4) - 0.055).astype(FLOAT)


@lru_cache(maxsize=1)
def decode_lut8() -> np.ndarray:
    """(256,) float32: linear value of each 8-bit sRGB code (what decode_srgb8 looks up)."""
    return srgb_to_linear(np.arange(256, dtype=FLOAT) / 255.0)


@lru_cache(maxsize=1)
def encode_lut() -> tuple[np.ndarray, int]:
    """(table, n): the 8-bit sRGB code of each linear value i / n, i = 0..n (what encode_srgb8
    and the kernels' encoders look up, rounding v * n + 0.5 down)."""
    # 16384 linear steps: finer than one 8-bit sRGB code everywhere (the darkest code
    # spans 1/(255*12.92) ~ 3e-4 in linear, the LUT step is 6e-5).
    n = 16384
    lut = np.round(linear_to_srgb(np.arange(n + 1, dtype=np.float64) / n) * 255.0).astype(np.uint8)
    return lut, n


def decode_srgb8(image: np.ndarray) -> np.ndarray:
    """uint8 sRGB image -> float32 linear (0-1), exact per code value."""
    image = np.asarray(image, dtype=np.uint8)
    if image.ndim in (2, 3) and image.size and (image.ndim == 2 or image.shape[2] <= 4):
        import cv2

        # OpenCV's table lookup is several times faster than NumPy's fancy indexing.
        return cv2.LUT(image, decode_lut8().reshape(1, 256))
    return decode_lut8()[image]


def encode_srgb8(linear: np.ndarray) -> np.ndarray:
    """float linear (clipped to 0-1) -> uint8 sRGB, rounded to the nearest code.

    Uses a 16k-entry lookup table: as exact as the 8-bit output and ~10x faster than the
    power function, which matters on the per-frame path.
    """
    lut, n = encode_lut()
    idx = np.clip(np.asarray(linear, dtype=FLOAT) * n + 0.5, 0, n).astype(np.int32)
    return lut[idx]


def luminance(linear_rgb: np.ndarray) -> np.ndarray:
    """(..., 3) linear RGB -> (...) linear luminance (Rec.709 weights)."""
    return np.asarray(linear_rgb, dtype=FLOAT) @ LUMINANCE
