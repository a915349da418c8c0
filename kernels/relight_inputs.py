"""What a relight is given, checked and prepared on the host: the head rotation
(:func:`check_rotation`; :func:`rotation_angle_deg` measures the turn between two, for leaving
out a relight a small turn does not need), the environment frozen for the per-frame path
(:func:`frozen`) and the texel light bounded (:func:`check_light`). InputError for anything
:class:`relight.kernels.relighter.Relighter` cannot relight.
"""

from __future__ import annotations

import numpy as np

from relight.envmap import freeze
from relight.errors import InputError

#: Largest accepted deviation of a rotation matrix from orthonormal.
ROTATION_TOL = 1e-3
#: Largest total texel light accepted (radiance x exposure): keeps every result finite in float32
#: (reflectance halves are at most 65504).
MAX_LIGHT = 1e30


def frozen(env) -> np.ndarray:
    """A read-only float32 copy of an environment that owns its data:
    :meth:`relight.kernels.relighter.Relighter.lights` recognises it by identity, so a per-frame
    caller passing it again pays no hashing (a copy even of a frozen array: the caller's array
    stays the caller's; see :func:`relight.envmap.freeze`, which :func:`relight.load_environment`
    applies)."""
    return freeze(np.array(env, dtype=np.float32, order="C"))


def check_rotation(rotation) -> np.ndarray | None:
    """A valid 3x3 rotation as float64, or None; InputError for anything else."""
    if rotation is None:
        return None
    r = np.asarray(rotation, dtype=np.float64)
    if r.shape != (3, 3) or not np.isfinite(r).all():
        raise InputError(f"rotation must be a finite 3x3 matrix, got shape {r.shape}")
    # (on the nine numbers in Python: np.linalg.det and the array temporaries took 0.15 ms a call)
    (a, b, c), (d, e, f), (g, h, i) = r.tolist()
    det = a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g)
    rows = ((a, b, c), (d, e, f), (g, h, i))
    off = max(abs(sum(x * y for x, y in zip(rows[m], rows[n], strict=True)) - (m == n))
              for m in range(3) for n in range(m, 3))
    if not off <= ROTATION_TOL or det < 0:
        raise InputError("rotation must be a proper rotation matrix (orthonormal, determinant +1); "
                         "build one with relight.directions.rotation_matrix(yaw, pitch, roll)")
    return r


def rotation_angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    """The angle (degrees) of the rotation taking ``a`` to ``b`` (both 3x3 rotations)."""
    tr = float(np.einsum("ij,ij->", a, b))  # trace(a^T b)
    return float(np.degrees(np.arccos(min(max((tr - 1.0) / 2.0, -1.0), 1.0))))


def check_light(lp: np.ndarray) -> np.ndarray:
    """``lp`` (the texel light, radiance x exposure) if its total is at most MAX_LIGHT; InputError
    otherwise."""
    total = float(np.abs(lp).sum())
    if not total <= MAX_LIGHT:
        raise InputError(f"environment radiance x exposure is too large (total {total:.3g}, at most {MAX_LIGHT:g}): "
                         "lower the exposure or rescale the environment map")
    return lp
