"""The capture's image-set path: an RTI image set (images + ``dirs.lp``, optional ``mask.png``
and room-light frame) read into the :class:`~relight.pipeline.capture_types.Prepared` samples the
back half starts from, skipping the video's stages 1-3; and the ``.lp`` parser and the set's
image decoding the benchmarks use too."""

from __future__ import annotations

import time
from pathlib import Path

import cv2
import numpy as np

from relight.colour import encode_srgb8, srgb_to_linear
from relight.errors import InputError
from relight.imageio import read_image

from .capture_progress import Progress
from .capture_types import CaptureOptions, Prepared

#: Largest image set accepted (files).
MAX_IMAGES = 2000
#: An image set's room-light frame (no light of the set on): subtracted from every image and kept
#: as the bundle's ambient, as a video capture's no-flash frames are.
AMBIENT_NAMES = ("ambient.png", "ambient.exr", "ambient.tif", "ambient.tiff", "ambient.jpg")


def read_lp(path: Path) -> list[tuple[str, np.ndarray]]:
    """Parse an RTI ``.lp`` file: first line N, then ``filename x y z`` per line."""
    try:
        text = path.read_text(encoding="utf-8", errors="strict")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read the light-position file ({exc})") from None
    if len(text) > 1 << 20:
        raise InputError(f"{path}: {len(text)} bytes is far too long for a light-position file")
    lines = [ln.strip() for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    if not lines:
        raise InputError(f"{path}: empty light-position file")
    try:
        n = int(lines[0].split()[0])
    except ValueError:
        raise InputError(f"{path}: the first line must be the number of images") from None
    if not (1 <= n <= MAX_IMAGES) or len(lines) - 1 < n:
        raise InputError(f"{path}: says {n} images but lists {len(lines) - 1}; fix the count (at most {MAX_IMAGES})")
    out = []
    for i, ln in enumerate(lines[1:n + 1], start=2):
        parts = ln.split()
        if len(parts) < 4:
            raise InputError(f"{path}:{i}: expected 'filename x y z', got {ln!r}")
        name = parts[0]
        if "/" in name or "\\" in name or name.startswith(".."):
            raise InputError(f"{path}:{i}: image names must be plain file names in the same folder, got {name!r}")
        try:
            d = np.array([float(v) for v in parts[1:4]])
        except ValueError:
            raise InputError(f"{path}:{i}: x y z must be numbers, got {parts[1:4]}") from None
        peak = float(np.max(np.abs(d))) if np.isfinite(d).all() else 0.0
        if peak == 0.0:
            raise InputError(f"{path}:{i}: light direction {parts[1:4]} is not a finite non-zero vector")
        d = d / peak  # first to about 1: the norm of 1e308-sized or subnormal entries stays finite
        out.append((name, d / np.linalg.norm(d)))
    return out


def read_set_image(f: Path, transfer: str) -> tuple[np.ndarray, np.ndarray]:
    """(linear (h, w, 3) float32, clipped (h, w) bool) of one image of an RTI set, its 8/16-bit
    code values decoded with ``transfer`` (:data:`~relight.pipeline.capture_types.TRANSFERS`; EXR/HDR
    are linear as stored)."""
    if f.suffix.lower() in (".exr", ".hdr"):
        img = read_image(f)
        return img, np.zeros(img.shape[:2], dtype=bool)
    raw = read_image(f, linearize=False)  # 0-1 code values, 8 or 16 bits
    clip = raw.max(axis=2) >= 250 / 255.0
    if transfer == "linear":
        return raw, clip
    return srgb_to_linear(raw), clip


def prepare_images(folder, opts: CaptureOptions, progress: Progress, timings: dict) -> Prepared:
    """An RTI image set: images + ``dirs.lp`` (+ optional ``mask.png``, ``ambient.png``) skip
    stages 1-3. Files are decoded with ``opts.transfer`` (EXR/HDR: linear); an ambient frame is
    subtracted from every image and becomes the bundle's ambient."""
    t0 = time.perf_counter()
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(f"{folder}: not a folder; --images takes a folder with images and dirs.lp")
    lps = sorted(folder.glob("*.lp"))
    if not lps:
        raise InputError(f"{folder}: no .lp light-position file (e.g. dirs.lp) found")
    entries = read_lp(lps[0])
    images, clipped, size = [], [], None
    for i, (name, _) in enumerate(entries):
        f = folder / name
        img, clip = read_set_image(f, opts.transfer)
        if size is None:
            size = img.shape[:2]
        elif img.shape[:2] != size:
            raise InputError(f"{f}: {img.shape[1]}x{img.shape[0]}, the others are {size[1]}x{size[0]}; "
                             "all images of a set must have one size")
        images.append(img.astype(np.float32))
        clipped.append(clip)
        progress("images", i + 1, len(entries))
    h, w = size
    mask = None
    mpath = folder / "mask.png"
    if mpath.exists():
        m = cv2.imread(str(mpath), cv2.IMREAD_UNCHANGED)
        if m is None or m.shape[:2] != (h, w):
            raise InputError(f"{mpath}: must be a {w}x{h} image (white = object)")
        if m.ndim == 3:
            m = m[..., 3] if m.shape[2] == 4 and m[..., 3].min() < 255 else m[..., :3].max(axis=2)
        mask = m > 127
    else:
        mask = np.ones((h, w), dtype=bool)
    notes = []
    ambient = np.zeros((h, w, 3), dtype=np.float32)
    listed = {name for name, _ in entries}
    amb_path = next((folder / n for n in AMBIENT_NAMES if (folder / n).exists() and n not in listed), None)
    if amb_path is not None:
        ambient, _ = read_set_image(amb_path, opts.transfer)
        if ambient.shape[:2] != (h, w):
            raise InputError(f"{amb_path}: {ambient.shape[1]}x{ambient.shape[0]}, the images are {w}x{h}; "
                             "the room-light frame must have their size (or remove it)")
        notes.append(f"{amb_path.name}: the room light, subtracted from every image")
    timings["read_images"] = time.perf_counter() - t0
    dirs = np.array([d for _, d in entries])
    stack = np.stack(images)
    if amb_path is not None:
        np.maximum(stack - ambient[None], 0.0, out=stack)
    background = encode_srgb8(np.clip(np.median(stack, axis=0) + ambient, 0.0, 1.0))
    report = {"light_dirs": {name: [round(float(x), 6) for x in d] for name, d in entries},
              "rejected": {}, "notes": notes, "images": len(entries), "transfer": opts.transfer}
    return Prepared(images=stack, dirs=dirs, clipped=np.stack(clipped), ambient=ambient.astype(np.float32),
                    background=background, origin=(0, 0), frame_size=(w, h), face_local=None, mask=mask,
                    meta={"source": str(folder), "kind": "images", "lp": lps[0].name, "transfer": opts.transfer},
                    report=report)
