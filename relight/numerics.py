"""The dtype policy, written down once.

* ``FLOAT`` (float32) on the hot path: images, maps, kernel buffers.
* ``ACCUM`` (float64) where a sum or a fit needs it: solid-angle integrals, least squares,
  statistics over many frames.

Every function that could let a NaN or Inf escape calls :func:`require_finite` on what it
returns, so a non-finite value never leaves silently.
"""

from __future__ import annotations

import numpy as np

from .errors import InputError, NumericalError

FLOAT = np.float32
ACCUM = np.float64

#: Denominators smaller than this are treated as zero (guarded divisions).
EPS = 1e-12


def require_finite(name: str, array: np.ndarray, *, user_input: bool = False) -> np.ndarray:
    """Return ``array`` unchanged, or raise if it holds NaN or Inf.

    ``user_input`` selects the exception: :class:`InputError` for data a user gave us (the
    message says to fix the file), :class:`NumericalError` for our own results.
    """
    array = np.asarray(array)
    if array.dtype.kind in "fc" and not np.isfinite(array).all():
        bad = int(np.size(array) - np.count_nonzero(np.isfinite(array)))
        if user_input:
            raise InputError(
                f"{name} holds {bad} non-finite value(s) (NaN or Inf); "
                "fix or re-export the data with finite values only"
            )
        raise NumericalError(f"{name}: {bad} non-finite value(s) produced; this is a bug, please report it")
    return array


def safe_divide(num: np.ndarray, den: np.ndarray, fill: float = 0.0) -> np.ndarray:
    """``num / den`` where ``|den| > EPS``, ``fill`` elsewhere (no warnings, no Inf)."""
    num = np.asarray(num)
    den = np.asarray(den)
    out = np.full(np.broadcast_shapes(num.shape, den.shape), fill, dtype=np.result_type(num, den, FLOAT))
    ok = np.abs(den) > EPS
    np.divide(num, den, out=out, where=ok)
    return out
