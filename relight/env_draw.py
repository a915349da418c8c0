"""Lights drawn into lat-long environment maps: soft discs whose radiance integrates to a known
power (the built-in environments, the key light and its presets are made of them).

A light ``strength`` flashes strong integrates to ``strength * pi`` over its solid angle, so a
white Lambertian surface facing it reads ``strength`` (the capture's flash at the face reads 1).
Maps are float64 while drawn (sums over 10^5 texels); the callers store float32.
"""

from __future__ import annotations

import numpy as np

from .directions import equirect_directions, equirect_solid_angles
from .numerics import ACCUM


def unit(v) -> np.ndarray:
    """``v`` as a float64 unit vector (the caller makes sure it is not zero)."""
    v = np.asarray(v, dtype=ACCUM)
    return v / np.linalg.norm(v)


def disc(dirs: np.ndarray, domega: np.ndarray, centre, radius_deg: float, soft_deg: float = 0.0) -> np.ndarray:
    """Coverage (H, W) in [0, 1] of a disc of angular radius ``radius_deg`` around ``centre``
    (``dirs``, ``domega``: the map's texel directions and solid angles, :func:`grid`).

    The edge is a linear ramp one texel wide (anti-aliasing) widened by ``soft_deg``.
    """
    cosang = np.clip(dirs @ unit(centre), -1.0, 1.0)
    ang = np.degrees(np.arccos(cosang))
    texel = np.degrees(np.sqrt(domega))[:, None]
    width = texel + soft_deg
    return np.clip((radius_deg - ang) / width + 0.5, 0.0, 1.0)


def add_light(env: np.ndarray, cover: np.ndarray, domega: np.ndarray, colour, strength: float) -> None:
    """Add to ``env`` (H, W, 3) a light of coverage ``cover`` (H, W), ``strength`` flashes strong
    (times ``colour``, linear RGB): its radiance integrates to ``strength * pi``, so a white
    Lambertian surface facing it reads ``strength``, exactly, on this grid."""
    solid = float(np.sum(cover * domega[:, None]))
    env += (strength * np.pi / solid) * cover[..., None] * np.asarray(colour, dtype=ACCUM)


def grid(width: int):
    """(texel directions (H, W, 3), solid angles (H,) per texel of a row, an empty (H, W, 3) float64
    map) of a ``width`` x ``width / 2`` lat-long map."""
    height = width // 2
    dirs = equirect_directions(width, height)
    domega = equirect_solid_angles(width, height)
    return dirs, domega, np.zeros((height, width, 3), dtype=ACCUM)
