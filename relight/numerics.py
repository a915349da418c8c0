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

#: The named epsilons (no literal ones in product code):
#: denominators smaller than EPS are treated as zero (guarded divisions, weight sums, determinants);
EPS = 1e-12
#: a length, area or weight below EPS_NORM is zero - not a direction, a degenerate triangle, a
#: point on a plane - and EPS_NORM x trace is the ridge that keeps a Gram matrix positive definite;
EPS_NORM = 1e-9
#: the floor of a scale, energy or peak that a ratio is taken against (far below any radiance);
TINY_SCALE = 1e-30
#: a linear value, spread, length or statistic below EPS_VALUE (a millionth of the flash's
#: light) is zero where something is normalised by it;
EPS_VALUE = 1e-6
#: singular values (or pivots) below RANK_REL times the largest are dropped from a basis.
RANK_REL = 1e-6


#: Pixel distances (tracking windows, noise, RANSAC thresholds, a synthetic head's motion) are
#: stated for a frame of this many rows - the paper's 960x540 - and scaled with a frame's height
#: (:func:`px_at`).
REFERENCE_ROWS = 540


def px_at(px_at_reference: float, rows: float) -> float:
    """``px_at_reference`` (pixels at :data:`REFERENCE_ROWS` rows) for a frame of ``rows`` rows."""
    return float(px_at_reference) * float(rows) / REFERENCE_ROWS


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


#: Smallest normal float16 magnitude (2^-14). Stored halves below it are zero: the relighting
#: kernels read halves with integer ops and run with denormals flushed (a subnormal costs a
#: ~100-cycle microcode assist per vector on x86: measured 2.2x slower on real maps, where
#: about 1 % of the values were subnormal).
HALF_TINY = np.float16(2.0 ** -14)


def flush_subnormal_halves(array: np.ndarray, chunk: int = 4096) -> np.ndarray:
    """Set float16 values with magnitude below :data:`HALF_TINY` to zero, in place (in chunks
    of ``chunk`` rows); returns ``array``. Other dtypes pass through."""
    if array.dtype != np.float16 or array.size == 0:
        return array
    rows = array.reshape(1, -1) if array.ndim < 2 else array
    for i in range(0, rows.shape[0], chunk):
        # On the bits (float16 arithmetic is slow in NumPy): a zero exponent field is exactly
        # |x| < 2^-14 = HALF_TINY (subnormals and zeros).
        bits = rows[i:i + chunk].view(np.uint16)
        np.multiply(bits, (bits & 0x7C00) != 0, out=bits, casting="unsafe")
    return array


def half_ceil(values: np.ndarray) -> np.ndarray:
    """float16 of non-negative float32 ``values``, rounded up (never below the value: a scale
    dividing by it keeps the quotient <= 1)."""
    values = np.asarray(values, dtype=np.float32)
    out = values.astype(np.float16)
    low = out.astype(np.float32) < values
    out[low] = np.nextafter(out[low], np.float16(np.inf))
    return out


def read_halves(array: np.ndarray) -> np.ndarray:
    """float16 -> float32 as the relighting kernels read it: subnormals as zero."""
    out = np.asarray(array, dtype=np.float32)
    if np.asarray(array).dtype == np.float16:
        out[np.abs(out) < np.float32(HALF_TINY)] = 0.0
    return out
