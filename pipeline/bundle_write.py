"""The capture's writer of the reflectance bundle (stage 6 writing): :func:`write_bundle` (atomic,
owner-only by default), the reference frame's JPEG (:func:`encode_background`) and the samples'
power-of-two scale for float16 storage (:func:`storage_scale`). The format, its fields and its
reader: :mod:`relight.kernels.bundle_format`."""

from __future__ import annotations

import json
import os
import zlib
from pathlib import Path

import numpy as np

from relight.errors import InputError, NumericalError
from relight.imageio import atomic_path
from relight.kernels.bundle_format import MAGIC, PREFIX, check_meta, missing_fields

#: The format version written (the reader takes :data:`relight.kernels.bundle_format.READABLE_VERSIONS`).
VERSION = 4
#: Every array starts on a multiple of this many bytes.
ALIGN = 64
#: JPEG quality of the stored reference frame (sRGB, display and tracking only: never relit).
BACKGROUND_QUALITY = 95


#: Bundles store samples and maps as float16 (largest 65504, smallest normal 6.1e-5): samples
#: are scaled by a power of two so their peak lies at most at ``STORE_PEAK`` (light adaptation
#: may multiply a value by up to 1 / MIN_COS = 10) and at least at ``STORE_FLOOR``.
STORE_PEAK = 2.0 ** 12
STORE_FLOOR = 2.0 ** -4


def storage_scale(samples: np.ndarray) -> float:
    """Power of two to divide samples by before float16 storage: 1.0 when their peak is within
    [STORE_FLOOR, STORE_PEAK] (every ordinary capture), else the one that brings the peak to
    about 1. All-zero samples: 1.0."""
    peak = float(np.max(samples)) if samples.size else 0.0
    if not np.isfinite(peak):
        raise InputError("light samples hold NaN or infinite values; check the input images")
    if peak <= 0.0 or STORE_FLOOR <= peak <= STORE_PEAK:
        return 1.0
    return float(2.0 ** np.round(np.log2(peak)))


def encode_background(rgb: np.ndarray) -> np.ndarray:
    """(N,) uint8 JPEG of an (H, W, 3) uint8 sRGB frame (quality BACKGROUND_QUALITY, 4:4:4)."""
    import cv2

    ok, buf = cv2.imencode(".jpg", np.ascontiguousarray(rgb[..., ::-1]),
                           [cv2.IMWRITE_JPEG_QUALITY, BACKGROUND_QUALITY,
                            cv2.IMWRITE_JPEG_SAMPLING_FACTOR, cv2.IMWRITE_JPEG_SAMPLING_FACTOR_444])
    if not ok:
        raise RuntimeError("could not encode the reference frame as JPEG; this is a bug, please report it")
    return buf.reshape(-1)


def _dtype_str(a: np.ndarray) -> str:
    return np.dtype(a.dtype).newbyteorder("<").str if a.dtype.byteorder not in ("|",) else a.dtype.str


#: Permission bits of a bundle: owner only. A bundle is a person's face - biometric data; widen
#: it deliberately (``relight capture --file-mode 0640``).
BUNDLE_MODE = 0o600


def write_bundle(path: str | os.PathLike, meta: dict, arrays: dict[str, np.ndarray], *,
                 mode: int = BUNDLE_MODE) -> Path:
    """Write a bundle atomically, with permission bits ``mode`` (default owner-only). ``arrays``
    values are converted to little-endian C order."""
    if not (isinstance(mode, int) and 0 <= mode <= 0o777 and mode & 0o600 == 0o600):
        raise InputError(f"file mode {mode!r}: an octal mode from 600 to 777 that lets the owner read and write")
    missing = missing_fields(arrays)
    if missing:
        raise InputError(f"bundle is missing required field(s): {', '.join(missing)}")
    check_meta(meta, str(path))
    prepared = {}
    for name, a in arrays.items():
        a = np.asarray(a)
        if a.dtype.kind == "f" and not np.isfinite(a).all():
            raise NumericalError(f"bundle field {name!r} holds non-finite values")
        a = np.ascontiguousarray(a, dtype=a.dtype.newbyteorder("<") if a.dtype.byteorder == ">" else a.dtype)
        prepared[name] = a
    directory = {}
    # Offsets depend on the header length, which depends on the offsets' digits: iterate.
    header_len = 4096
    for _ in range(8):
        offset = _align(PREFIX.size + header_len)
        directory = {}
        for name, a in prepared.items():
            directory[name] = {"dtype": _dtype_str(a), "shape": list(a.shape), "offset": offset,
                               "nbytes": int(a.nbytes), "crc32": zlib.crc32(_raw(a))}
            offset = _align(offset + a.nbytes)
        header = json.dumps({"format": "relight-bundle", "version": VERSION, "meta": meta, "arrays": directory},
                            sort_keys=True, allow_nan=False).encode("utf-8")
        if len(header) <= header_len:
            header = header + b" " * (header_len - len(header))
            break
        header_len = _align(len(header) + 1024)
    path = Path(path)
    with atomic_path(path, mode=mode) as tmp, open(tmp, "wb") as f:
        f.write(PREFIX.pack(MAGIC, VERSION, zlib.crc32(header), len(header)))
        f.write(header)
        for name, a in prepared.items():
            pos = directory[name]["offset"]
            f.write(b"\0" * (pos - f.tell()))
            f.write(_raw(a))
        f.flush()
        os.fsync(f.fileno())
    return path


def _raw(a: np.ndarray) -> np.ndarray:
    """The bytes of a C-contiguous array as a flat uint8 view (zero-size arrays included)."""
    return a.reshape(-1).view(np.uint8)


def _align(n: int) -> int:
    return (n + ALIGN - 1) // ALIGN * ALIGN
