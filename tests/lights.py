"""What the light tests share: light-direction sets (the reflectance and spline tests) and what a
white surface reads under an environment (the key light, photo and preset tests)."""

import numpy as np

from relight.colour import LUMINANCE
from relight.directions import equirect_directions, equirect_solid_angles, fibonacci_sphere


def front_directions(k: int, seed: int = 0, min_z: float = 0.2) -> np.ndarray:
    """(k, 3) unit directions drawn at random (seeded) from a Fibonacci sphere of 4k points,
    those with z > ``min_z`` (toward the camera)."""
    d = fibonacci_sphere(4 * k)
    d = d[d[:, 2] > min_z]
    rng = np.random.default_rng(seed)
    return d[rng.choice(len(d), k, replace=False)]


def white_reading(env: np.ndarray, normal) -> float:
    """What a white Lambertian surface facing ``normal`` reads under ``env`` ((H, 2H, 3) linear
    radiance): its irradiance / pi, as luminance, in flashes - summed over the map's texels in
    float64, independently of relight's own light sampling."""
    h, w = env.shape[:2]
    n = np.asarray(normal, float) / np.linalg.norm(normal)
    cos = np.clip(equirect_directions(w, h) @ n, 0, None) * equirect_solid_angles(w, h)[:, None]
    return float(np.einsum("hw,hwc->c", cos, env.astype(np.float64)) @ LUMINANCE) / np.pi
