"""The reflectance bundle's file format - the one module that knows its fields - and its reader:
reading and validating (:func:`read_bundle_file`; :func:`relight.kernels.bundle.load_bundle`
wraps it into a :class:`relight.kernels.bundle.Bundle`). The capture writes it with
:func:`relight.pipeline.bundle_write.write_bundle`, from the names defined here.

Format (version 4), little-endian::

    offset 0   8 bytes   magic b"RLBUNDLE"
    offset 8   u32       format version (4; 3 loads too - its basis all 8-bit - and 1 and 2, which hold the maps)
    offset 12  u32       CRC-32 of the header bytes
    offset 16  u64       header length H
    offset 24  H bytes   header: UTF-8 JSON {"format", "version", "meta", "arrays"}
    then       arrays, each starting on a 64-byte boundary

``arrays`` maps a field name to ``{"dtype", "shape", "offset", "nbytes", "crc32"}`` (dtype in
NumPy's string form, offset absolute). Arrays are raw C-order data, so loading memory-maps
them (read-only); every array's CRC-32 is checked on load (about 3 GB/s). No pickle anywhere.
Writes (:mod:`relight.pipeline.bundle_write`) go to a temporary file in the same folder that is
renamed over the target, so a killed writer leaves any previous bundle intact.

Fields (P = head pixels, K = light samples, T = active map texels; crop = the stored region
of the reference frame, ``crop_origin`` its top-left pixel in the frame):

======================  ===========================  ========================================
field                   shape, dtype                 meaning
======================  ===========================  ========================================
pixels                  (P,) int32                   flat row-major indices of the head pixels in the crop
mask_crop               (h, w) bool                  head pixels in the crop
ambient                 (h, w, 3) float16            registered no-flash average (image sets: their
                                                     ambient frame, or 0), linear (float32 before version 3)
background_jpeg         (N,) uint8                   a full no-flash frame, sRGB, as a JPEG (format 3 and later)
background              (H, W, 3) uint8              the same frame as pixels (formats 1 and 2)
normal                  (P, 3) float32               camera-space unit normals
albedo                  (P, 3) float16               Lambertian albedo, linear, flash units (float32 before 3)
depth                   (h, w) float32               height toward the camera, pixels
landmarks               (N, 2) float32               trackable points of the reference (frame px)
light_dirs              (K, 3) float32               sample light directions (camera space)
samples_code (r)        (K, P, 3) uint8              the light samples, 8-bit codes (:mod:`relight.kernels.recipe`)
samples_scale (r)       (P, 3) float16               their per-pixel, per-channel scale (linear, flash units)
horizon_code (r)        (R, n_az) uint8              horizon elevations (visibility; absent without it)
horizon_index (r)       (P,) int32                   each pixel's row of horizon_code (large heads share a row
                                                     per 2x2 pixels; absent: a row per pixel)
model_albedo (r)        (P, 3) float16               the shading model's albedo, linear, flash units
model_spec (r)          (P, 3) float16               its specular lobe's weight
model_trust (r)         (P,) float16                 its trust, 0-1
spline_blend (r)        (P,) float16                 the model path's weight against the spline, 0-1
tri_texel_vertices      (h_map * w_map, 3) int32     each map texel's triangle (vertex ids)
tri_texel_weights       (h_map * w_map, 3) float32   its spherical barycentric weights
samples (*)             (K, P, 3) float16            flash-only colour of each pixel per sample
maps (*)                (P, 3, Tp) float16           reflectance maps, pixel-major: per pixel and channel
                                                     the T active texels, zero padded to Tp (multiple of 16)
maps_rows (*)           (T, 3, P) float16            the maps texel-major
map_texels              (T,) int32                   map texel (row-major in the lat-long map) of each column
transport_u             (T, K) float32               compact transport: orthogonal texel basis (orthonormal
                                                     times a power of two that keeps transport_v's peaks
                                                     in float16's range, transport.V_HALF_PEAK)
transport_v             (P / 16, 3, K8, 16) int8     maps projected on it: the first K8 (<= 16) ranks in
                                                     8 bits, blocks of 16 pixels (every rank before
                                                     version 4; float16 before version 3)
transport_v_scale       (P, 3) float16               per pixel and channel: transport_v's peak (step x 127)
transport_v4 (4)        (P / 16, 3, K - K8, 8) uint8 the other ranks in 4 bits (two's complement, -7..7):
                                                     byte s of a block holds pixel s (low bits), s + 8 (high)
transport_v4_scale (4)  (P, 3) float16               per pixel and channel: transport_v4's peak (step x 7)
transport_errors        (K,) float32                 largest validation error (relative L2) at each rank
transport_sigma         (K,) float32                 singular values
tri_vertices            (V, 3) float64               triangulation vertices (samples, then black lights)
tri_faces               (F, 3) int32                 triangulation faces
======================  ===========================  ========================================

(r) the maps' recipe: a bundle stores what its maps are made of, not the maps (12 KB per face
pixel); any texel of any map is made again from it exactly as the capture made it
(:meth:`Bundle.texel_rows`, :meth:`Bundle.pixel_maps`). (*) only in bundles captured with
``--keep-maps`` (the maps themselves) or by a method without a recipe (the classical fits,
``--paper-adaptation``): those hold ``maps_rows`` instead of the recipe. (4) only when the
bundle stores more than 16 ranks (format 4).
``meta["stored"]`` lists the fields a bundle holds.

Units: linear Rec.709; "flash units" means a pixel's value under a light as strong as the
capture flash (a white Lambertian surface facing it reads 1). Relighting under an environment
of radiance L is ``sum_t maps[p, :, t] * L(t) * solid_angle(t) / pi`` (the solid angle is the
exact form of the paper's sin-latitude normalisation); see :mod:`relight.kernels.transport`.
"""


from __future__ import annotations

import json
import os
import struct
import zlib
from enum import StrEnum
from pathlib import Path

import numpy as np

from relight.errors import InputError
from relight.imageio import image_size

from .layout import padded_texels

MAGIC = b"RLBUNDLE"
#: Format versions this relight reads (versions 1 and 2 store the maps, not their recipe).
READABLE_VERSIONS = (1, 2, 3, 4)
#: The file's first bytes: magic, format version, the header's CRC-32 and length (read here, written
#: by :func:`relight.pipeline.bundle_write.write_bundle`).
PREFIX = struct.Struct("<8sIIQ")
#: Largest header accepted (a corrupt length must not make us allocate gigabytes).
MAX_HEADER = 64 << 20


class Field(StrEnum):
    """The bundle's array fields, by the name the file stores (the table above says each one's
    shape, type and meaning). The one place their names are written: everything that reads or
    writes a bundle's arrays keys them with these (``arrays[Field.PIXELS]``). A member is a
    ``str``, so a file's plain-string keys find it; its repr is the name's, as messages quote it."""

    PIXELS = "pixels"
    MASK_CROP = "mask_crop"
    AMBIENT = "ambient"
    BACKGROUND = "background"
    BACKGROUND_JPEG = "background_jpeg"
    NORMAL = "normal"
    ALBEDO = "albedo"
    DEPTH = "depth"
    LANDMARKS = "landmarks"
    LIGHT_DIRS = "light_dirs"
    SAMPLES_CODE = "samples_code"
    SAMPLES_SCALE = "samples_scale"
    HORIZON_CODE = "horizon_code"
    HORIZON_INDEX = "horizon_index"
    MODEL_ALBEDO = "model_albedo"
    MODEL_SPEC = "model_spec"
    MODEL_TRUST = "model_trust"
    SPLINE_BLEND = "spline_blend"
    TRI_TEXEL_VERTICES = "tri_texel_vertices"
    TRI_TEXEL_WEIGHTS = "tri_texel_weights"
    SAMPLES = "samples"
    MAPS = "maps"
    MAPS_ROWS = "maps_rows"
    MAP_TEXELS = "map_texels"
    TRANSPORT_U = "transport_u"
    TRANSPORT_V = "transport_v"
    TRANSPORT_V_SCALE = "transport_v_scale"
    TRANSPORT_V4 = "transport_v4"
    TRANSPORT_V4_SCALE = "transport_v4_scale"
    TRANSPORT_ERRORS = "transport_errors"
    TRANSPORT_SIGMA = "transport_sigma"
    TRI_VERTICES = "tri_vertices"
    TRI_FACES = "tri_faces"

    def __repr__(self) -> str:
        return repr(self.value)


#: Fields every bundle holds.
REQUIRED = (Field.PIXELS, Field.MASK_CROP, Field.AMBIENT, Field.NORMAL, Field.ALBEDO, Field.DEPTH, Field.LIGHT_DIRS,
            Field.MAP_TEXELS)
#: The reference frame: a JPEG (format 3 and later) or raw pixels (before).
BACKGROUND = (Field.BACKGROUND_JPEG, Field.BACKGROUND)
#: A bundle holds its maps (``maps_rows``) or all of these (their recipe).
RECIPE = (Field.SAMPLES_CODE, Field.SAMPLES_SCALE, Field.MODEL_ALBEDO, Field.MODEL_SPEC, Field.MODEL_TRUST,
          Field.SPLINE_BLEND, Field.TRI_VERTICES, Field.TRI_FACES, Field.TRI_TEXEL_VERTICES, Field.TRI_TEXEL_WEIGHTS)
#: Fields only ``--keep-maps`` bundles hold (the maps themselves, the float16 samples).
MAPS_ONLY = (Field.MAPS, Field.MAPS_ROWS, Field.SAMPLES)


def missing_fields(names) -> list[Field]:
    """The fields a bundle must hold that ``names`` (a collection of field names) lacks, in the
    order the reader checks them: :data:`REQUIRED`, the recipe (:data:`RECIPE`, unless the maps
    are stored as ``maps_rows``), then the reference frame (``background_jpeg``, unless either
    :data:`BACKGROUND` field is there). The writer and the reader both ask it."""
    missing = [k for k in REQUIRED if k not in names]
    if Field.MAPS_ROWS not in names:
        missing += [k for k in RECIPE if k not in names]
    if not any(k in names for k in BACKGROUND):
        missing.append(Field.BACKGROUND_JPEG)
    return missing


_ALLOWED_DTYPES = {"|b1", "|u1", "|i1", "<i4", "<i8", "<f2", "<f4", "<f8"}
#: The meta keys every bundle must hold, each a pair of whole numbers within the bound: the
#: reference frame's (W, H), the stored crop's top-left pixel in it, the lat-long map's (W, H).
META_PAIRS = {"frame_size": (1, 1 << 16), "crop_origin": (0, 1 << 16), "map_size": (2, 4096)}


def check_meta(meta, where: str = "bundle") -> dict:
    """``meta`` checked against the schema the readers rely on (:data:`META_PAIRS`; a
    ``sample_scale``, when present, a positive finite number): InputError naming the key."""
    if not isinstance(meta, dict):
        raise InputError(f"{where}: its meta is not a JSON object; the file is corrupt")
    for key, (lo, hi) in META_PAIRS.items():
        v = meta.get(key)
        if not (isinstance(v, list | tuple) and len(v) == 2
                and all(isinstance(x, int) and not isinstance(x, bool) and lo <= x < hi for x in v)):
            raise InputError(f"{where}: meta {key!r} is {v!r}, not two whole numbers in [{lo}, {hi}); "
                             "the bundle is incomplete or corrupt: capture it again")
    scale = meta.get("sample_scale", 1.0)
    if not (isinstance(scale, int | float) and not isinstance(scale, bool) and np.isfinite(scale) and scale > 0):
        raise InputError(f"{where}: meta 'sample_scale' is {scale!r}, not a positive number; capture it again")
    direct = meta.get("transport_direct", 0)
    if not (isinstance(direct, int) and not isinstance(direct, bool) and 0 <= direct <= MAX_DIRECT_TEXELS):
        raise InputError(f"{where}: meta 'transport_direct' is {direct!r}, not a whole number in [0, "
                         f"{MAX_DIRECT_TEXELS}]; the bundle is corrupt: capture it again")
    return meta


#: Most exact texels a bundle may ask the compact path for (its kernel's direct rows; captures use 8).
MAX_DIRECT_TEXELS = 64


def decode_background(data: np.ndarray, frame_size: tuple[int, int]) -> np.ndarray:
    """The (H, W, 3) uint8 sRGB frame of :func:`relight.pipeline.bundle_write.encode_background`
    data; its header must say ``frame_size`` (width, height) before anything is decoded (a hostile
    file cannot make us allocate more)."""
    import cv2

    from relight.imageio import image_size

    size = image_size(memoryview(np.ascontiguousarray(data, dtype=np.uint8)).tobytes())
    if size is None or tuple(size) != tuple(frame_size):
        raise InputError(f"the bundle's reference frame is not a {frame_size[0]}x{frame_size[1]} JPEG "
                         f"(header: {size}); the bundle is damaged - capture it again")
    img = cv2.imdecode(np.ascontiguousarray(data, dtype=np.uint8), cv2.IMREAD_COLOR)
    if img is None or img.shape[:2] != (frame_size[1], frame_size[0]):
        raise InputError("the bundle's reference frame does not decode; the bundle is damaged - capture it again")
    return np.ascontiguousarray(img[..., ::-1])


def read_bundle_file(path: str | os.PathLike, *, verify: bool = True) -> tuple[dict, dict]:
    """A bundle file's (meta, arrays): header validated, every array checked (CRC-32) and
    memory-mapped read-only.

    Raises :class:`InputError` naming the problem and the field for a missing, truncated,
    corrupted, foreign or wrong-version file.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such bundle file; check the path")
    size = path.stat().st_size
    with open(path, "rb") as f:
        prefix = f.read(PREFIX.size)
        if len(prefix) < PREFIX.size:
            raise InputError(f"{path}: too short to be a bundle ({size} bytes); it is truncated")
        magic, version, crc, hlen = PREFIX.unpack(prefix)
        if magic != MAGIC:
            raise InputError(f"{path}: not a relight bundle (bad magic); make one with `relight capture`")
        if version not in READABLE_VERSIONS:
            raise InputError(f"{path}: bundle format version {version}, this relight reads versions "
                             f"{', '.join(map(str, READABLE_VERSIONS))}; re-run `relight capture` with this version "
                             "(or use the relight that wrote it)")
        if hlen > MAX_HEADER or PREFIX.size + hlen > size:
            raise InputError(f"{path}: header length {hlen} does not fit the {size}-byte file; it is truncated "
                             "or corrupt")
        header = f.read(hlen)
    if zlib.crc32(header) != crc:
        raise InputError(f"{path}: header checksum mismatch; the file is corrupt")
    try:
        doc = json.loads(header.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"{path}: header is not valid JSON ({exc}); the file is corrupt") from None
    if not isinstance(doc, dict) or doc.get("format") != "relight-bundle" or not isinstance(doc.get("arrays"), dict):
        raise InputError(f"{path}: header does not describe a relight bundle")
    check_meta(doc.get("meta"), str(path))
    arrays = {}
    missing = missing_fields(doc["arrays"])
    if missing:
        raise InputError(f"{path}: field {missing[0]!r} is missing; the bundle is incomplete")
    for name, spec in doc["arrays"].items():
        if not isinstance(spec, dict) or not isinstance(spec.get("dtype"), str) or spec["dtype"] not in _ALLOWED_DTYPES:
            raise InputError(f"{path}: field {name!r} has a malformed description or an unsupported type")
        try:
            dtype = np.dtype(spec["dtype"])
            shape = tuple(int(s) for s in spec["shape"])
            offset, nbytes = int(spec["offset"]), int(spec["nbytes"])
        except (KeyError, TypeError, ValueError):
            raise InputError(f"{path}: field {name!r} has a malformed description") from None
        if any(s < 0 for s in shape):
            raise InputError(f"{path}: field {name!r} has a negative size in its shape {shape}")
        if int(np.prod(shape, dtype=np.int64)) * dtype.itemsize != nbytes:
            raise InputError(f"{path}: field {name!r}: shape {shape} does not match its {nbytes} bytes")
        if offset < PREFIX.size + hlen or offset + nbytes > size:
            raise InputError(f"{path}: field {name!r} runs past the end of the file; the bundle is truncated")
        if nbytes == 0:
            arrays[name] = np.zeros(shape, dtype=dtype)
            continue
        mm = np.memmap(path, dtype=dtype, mode="r", offset=offset, shape=shape)
        if verify and zlib.crc32(memoryview(mm.reshape(-1).view(np.uint8))) != int(spec.get("crc32", -1)):
            raise InputError(f"{path}: field {name!r} fails its checksum; the bundle is corrupt, re-run capture")
        arrays[name] = mm
    meta = doc.get("meta") if isinstance(doc.get("meta"), dict) else {}
    check_fields(meta, arrays, str(path))
    return meta, arrays


#: Fields whose values are checked finite on load (the small ones; the maps, samples and
#: transport bases are checked by the products made from them).
FINITE_CHECKED_BYTES = 16 << 20


def check_fields(meta: dict, arrays: dict, where: str = "bundle") -> None:
    """The fields' shapes checked against each other and the meta (a crafted header with right
    checksums must not reach the relighter: its kernels index frames, crops and maps with these
    numbers), the head pixels inside the crop and the crop inside the frame; InputError naming
    the field otherwise."""
    def bad(name: str, why: str):
        raise InputError(f"{where}: field {name!r} {why}; the bundle is damaged or not made by relight - "
                         "capture it again")

    def need(name: str, shape: tuple, kinds: str = "fiub"):
        a = arrays.get(name)
        if a is None:
            return None
        if a.ndim != len(shape) or any(w is not None and g != w for g, w in zip(a.shape, shape, strict=True)):
            bad(name, f"has shape {a.shape}, expected {tuple('*' if d is None else d for d in shape)}")
        if a.dtype.kind not in kinds:
            bad(name, f"has type {a.dtype}, expected {'an integer' if kinds == 'iu' else 'a number'} type")
        return a

    fw, fh = meta["frame_size"]
    x0, y0 = meta["crop_origin"]
    mw, mh = meta["map_size"]
    crop = need(Field.MASK_CROP, (None, None), "b")
    ch, cw = crop.shape
    if x0 + cw > fw or y0 + ch > fh:
        bad(Field.MASK_CROP, f"of {cw}x{ch} at ({x0}, {y0}) does not fit the {fw}x{fh} frame")
    pixels = need(Field.PIXELS, (None,), "iu")
    p = pixels.shape[0]
    if p and (int(pixels.min()) < 0 or int(pixels.max()) >= ch * cw or np.any(np.diff(pixels) <= 0)):
        bad(Field.PIXELS, f"holds indices outside the {cw}x{ch} crop or out of order")
    if p != int(np.count_nonzero(crop)):
        bad(Field.PIXELS, f"lists {p} head pixels but mask_crop marks {int(np.count_nonzero(crop))}")
    need(Field.AMBIENT, (ch, cw, 3)), need(Field.DEPTH, (ch, cw))
    need(Field.NORMAL, (p, 3)), need(Field.ALBEDO, (p, 3))
    need(Field.BACKGROUND, (fh, fw, 3), "u"), need(Field.LANDMARKS, (None, 2))
    jpeg = need(Field.BACKGROUND_JPEG, (None,), "u")
    if jpeg is not None and image_size(bytes(jpeg[:1 << 16])) != (fw, fh):
        bad(Field.BACKGROUND_JPEG, f"is not a {fw}x{fh} JPEG (the frame size the meta gives)")
    need(Field.LIGHT_DIRS, (None, 3))
    tex = need(Field.MAP_TEXELS, (None,), "iu")
    t = tex.shape[0]
    if t and (int(tex.min()) < 0 or int(tex.max()) >= mw * mh):
        bad(Field.MAP_TEXELS, f"holds texels outside the {mw}x{mh} map")
    need(Field.MAPS_ROWS, (t, 3, p)), need(Field.MAPS, (p, 3, padded_texels(t))), need(Field.SAMPLES, (None, p, 3))
    need(Field.SAMPLES_CODE, (None, p, 3), "u"), need(Field.SAMPLES_SCALE, (p, 3))
    need(Field.HORIZON_INDEX, (p,), "iu"), need(Field.HORIZON_CODE, (None, None), "u")
    for name in (Field.MODEL_ALBEDO, Field.MODEL_SPEC):
        need(name, (p, 3))
    for name in (Field.MODEL_TRUST, Field.SPLINE_BLEND):
        need(name, (p,))
    need(Field.TRI_TEXEL_VERTICES, (mw * mh, 3), "iu"), need(Field.TRI_TEXEL_WEIGHTS, (mw * mh, 3))
    need(Field.TRI_VERTICES, (None, 3)), need(Field.TRI_FACES, (None, 3), "iu")
    u = need(Field.TRANSPORT_U, (t, None))
    if u is not None:
        r = u.shape[1]
        need(Field.TRANSPORT_ERRORS, (r,)), need(Field.TRANSPORT_SIGMA, (r,))
        nb = -(-p // 16)
        v = need(Field.TRANSPORT_V, (nb, 3, None, 16))
        need(Field.TRANSPORT_V_SCALE, (nb * 16, 3)), need(Field.TRANSPORT_V4, (nb, 3, None, 8), "u")
        need(Field.TRANSPORT_V4_SCALE, (nb * 16, 3))
        if v is not None and v.dtype == np.int8:
            k8 = v.shape[2] + (arrays[Field.TRANSPORT_V4].shape[2] if Field.TRANSPORT_V4 in arrays else 0)
            if k8 != r:
                bad(Field.TRANSPORT_V, f"holds {k8} ranks, transport_u {r}")
    for name, a in arrays.items():
        if a.dtype.kind == "f" and a.nbytes <= FINITE_CHECKED_BYTES and not np.isfinite(a).all():
            bad(name, "holds NaN or infinite values")
