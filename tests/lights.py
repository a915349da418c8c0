"""Light-direction sets the reflectance and spline tests share."""

import numpy as np

from relight.directions import fibonacci_sphere


def front_directions(k: int, seed: int = 0, min_z: float = 0.2) -> np.ndarray:
    """(k, 3) unit directions drawn at random (seeded) from a Fibonacci sphere of 4k points,
    those with z > ``min_z`` (toward the camera)."""
    d = fibonacci_sphere(4 * k)
    d = d[d[:, 2] > min_z]
    rng = np.random.default_rng(seed)
    return d[rng.choice(len(d), k, replace=False)]
