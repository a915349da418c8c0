"""Reading and writing images safely (OpenImageIO underneath).

Every read is bounded: the file size and the header's dimensions are checked before any
pixel is decoded, and decoding errors (truncated or corrupt files) become
:class:`~relight.errors.InputError` with a message that says what to change. Every write
is atomic: a temporary file in the destination folder is renamed over the target, so an
interrupted write never leaves a half-written file where a good one was.

Colour: float formats (EXR, HDR, float TIFF) are linear; integer formats (PNG, JPEG, 8/16-bit
TIFF) are sRGB-encoded and decoded to linear here, unless ``linearize=False``.
"""

from __future__ import annotations

import contextlib
import errno
import os
import re
import struct
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .colour import linear_to_srgb, srgb_to_linear
from .errors import InputError, OutputError, RelightError, os_reason
from .numerics import FLOAT, require_finite

#: Default limits for images read from users (a 16K x 8K environment map still fits).
MAX_IMAGE_DIM = 16384
MAX_IMAGE_PIXELS = 16384 * 8192
MAX_FILE_BYTES = 2 << 30

LINEAR_EXTENSIONS = {".exr", ".hdr", ".pfm"}
LDR_EXTENSIONS = {".png", ".jpg", ".jpeg"}
#: A fixed timestamp keeps written files byte-identical for identical data.
_FIXED_DATETIME = "2000:01:01 00:00:00"


@dataclass(frozen=True)
class ImageInfo:
    """What the header of an image file says."""

    width: int
    height: int
    channels: int
    format: str  # OIIO base type name, e.g. "uint8", "half", "float"
    linear: bool  # True when the pixel values are linear light (float formats)


def _oiio():
    import OpenImageIO as oiio  # deferred: keeps `import relight` light

    return oiio


def _error_text(source) -> str:
    """OpenImageIO's last error of ``source`` (the module, an ImageInput or ImageOutput) as text;
    a damaged file's bytes can reach the message, which the binding then fails to decode."""
    try:
        return source.geterror()
    except UnicodeDecodeError:
        return "its error message is not readable text"


def probe_image(path: str | os.PathLike, *, max_dim: int = MAX_IMAGE_DIM,
                max_pixels: int = MAX_IMAGE_PIXELS, max_bytes: int = MAX_FILE_BYTES) -> ImageInfo:
    """Read and validate an image header without decoding pixels."""
    oiio = _oiio()
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such file; check the path")
    size = path.stat().st_size
    if size == 0:
        raise InputError(f"{path}: the file is empty; re-export it")
    if size > max_bytes:
        raise InputError(f"{path}: {size} bytes is more than the {max_bytes}-byte limit; use a smaller image")
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise InputError(f"{path}: not a readable image ({_error_text(oiio) or 'unknown format'}); "
                         "use EXR, HDR, PNG or JPEG")
    try:
        spec = inp.spec()
        w, h, c, d = spec.width, spec.height, spec.nchannels, spec.depth
        fmt = str(spec.format)
    finally:
        inp.close()
    if w <= 0 or h <= 0 or c <= 0 or d != 1:
        raise InputError(f"{path}: header says {w}x{h}x{d} with {c} channel(s); the file is corrupt")
    if w > max_dim or h > max_dim or w * h > max_pixels:
        raise InputError(f"{path}: header says {w}x{h} pixels, more than the limit of {max_dim} per side and "
                         f"{max_pixels} in all; downscale the image")
    if c > 4:
        raise InputError(f"{path}: {c} channels; expected 1 (grey), 3 (RGB) or 4 (RGBA)")
    linear = fmt in ("half", "float", "double")
    return ImageInfo(width=w, height=h, channels=c, format=fmt, linear=linear)


def orient_exif(pixels: np.ndarray, orientation: int) -> np.ndarray:
    """``pixels`` (H, W, ...) as stored, turned upright by the EXIF ``orientation`` tag (1-8: the
    way a camera says how it was held; 1 or an unknown value: as stored)."""
    ops = {2: lambda a: a[:, ::-1], 3: lambda a: a[::-1, ::-1], 4: lambda a: a[::-1],
           5: lambda a: a.swapaxes(0, 1), 6: lambda a: np.rot90(a, -1), 7: lambda a: np.rot90(a, -1)[::-1],
           8: lambda a: np.rot90(a, 1)}
    op = ops.get(int(orientation))
    return np.ascontiguousarray(op(pixels)) if op is not None else pixels


def read_image(path: str | os.PathLike, *, linearize: bool = True, orient: bool = False, **limits) -> np.ndarray:
    """Read an image as float32 RGB (H, W, 3).

    Grey images are replicated to three channels, alpha is dropped. With ``linearize``
    (default) integer-format images are decoded from sRGB to linear; float formats are
    returned as stored (linear). With ``orient`` a photo's EXIF orientation is honoured
    (:func:`orient_exif`; environment maps and frames are read as stored). Raises
    :class:`InputError` for missing, oversized, truncated, corrupt or non-finite files.
    """
    oiio = _oiio()
    info = probe_image(path, **limits)
    inp = oiio.ImageInput.open(str(path))
    if inp is None:  # pragma: no cover - probe_image opened it a moment ago
        raise InputError(f"{path}: could not be reopened ({_error_text(oiio)})")
    try:
        orientation = inp.spec().get_int_attribute("Orientation", 1) if orient else 1
        pixels = inp.read_image(0, 0, 0, info.channels, "float")
        err = _error_text(inp)
    finally:
        inp.close()
    if pixels is None or err:
        raise InputError(f"{path}: the pixel data could not be decoded ({err or 'unknown error'}); "
                         "the file is truncated or corrupt, re-export it")
    pixels = np.asarray(pixels, dtype=FLOAT).reshape(info.height, info.width, info.channels)
    if info.channels in (1, 2):
        pixels = np.repeat(pixels[..., :1], 3, axis=2)
    else:
        pixels = pixels[..., :3]
    require_finite(str(path), pixels, user_input=True)
    if linearize and not info.linear:
        pixels = srgb_to_linear(pixels)
    return np.ascontiguousarray(orient_exif(pixels, orientation), dtype=FLOAT)


def temp_prefix(name: str) -> str:
    """Prefix of a writer's temporary file or folder for the target ``name``: temporaries are
    named ``.{name}.{pid}.{random}.tmp{ext}``, so one a killed writer left behind is known by
    its target and its (gone) process - see :func:`clean_stale_temps`."""
    return f".{name}.{os.getpid()}."


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError):
        return True  # another user's process (or not a pid we can ask about): left alone
    return True


def clean_stale_temps(folder: str | os.PathLike, name: str, *, prefix: str | None = None) -> list[Path]:
    """Remove the temporaries of target ``name`` in ``folder`` whose writer process is gone
    (killed before its rename); the ones of live writers are left. ``prefix`` replaces the
    ``.{name}.`` start of the names (the service's upload folders). Returns what was removed."""
    import shutil

    start = re.escape(prefix if prefix is not None else f".{name}.")
    pattern = re.compile(rf"^{start}(\d+)[.-][^.]+(\.tmp|$)")
    removed = []
    try:
        entries = list(Path(folder).iterdir())
    except OSError:
        return removed
    for e in entries:
        m = pattern.match(e.name)
        if not m or int(m.group(1)) == os.getpid() or _alive(int(m.group(1))):
            continue
        with contextlib.suppress(OSError):
            if e.is_dir() and not e.is_symlink():
                shutil.rmtree(e)
            else:
                e.unlink()
            removed.append(e)
    return removed


def _fsync_dir(folder: Path) -> None:
    """Make a rename in ``folder`` durable (a power cut after it keeps the new file)."""
    with contextlib.suppress(OSError):
        fd = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, *, mode: int | None = None):
    """Yield a temporary path beside ``path``; rename it over ``path`` on success, with the
    permission bits ``mode`` (None: :func:`file_mode`'s, as ``open()`` would give).

    An OSError of the writing (no space, a read-only file system, no permission) becomes an
    :class:`OutputError` naming ``path``.

    The temporary name keeps the extension (image writers pick the format from it). On any
    exception the temporary file is removed and ``path`` is left as it was; a writer killed
    outright (``kill -9``, power loss) leaves its temporary, which the next write of ``path``
    removes (:func:`clean_stale_temps`). ``path`` is never a partly written file.
    """
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        clean_stale_temps(path.parent, path.stem)
        fd, tmp = tempfile.mkstemp(prefix=temp_prefix(path.stem), suffix=f".tmp{path.suffix}", dir=path.parent)
        os.close(fd)
    except OSError as exc:
        raise OutputError(f"cannot write {path}: {os_reason(exc)}") from exc
    try:
        yield Path(tmp)
        os.chmod(tmp, file_mode() if mode is None else mode)
        os.replace(tmp, path)
        _fsync_dir(path.parent)
    except BaseException as exc:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        if isinstance(exc, OSError) and not isinstance(exc, RelightError) and _is_write_error(exc, tmp, path):
            raise OutputError(f"cannot write {path}: {os_reason(exc)}") from exc
        raise


#: errno values that only writing raises (a full disk or quota, a read-only file system, a file
#: too large for it): whoever raised them, the output could not be written.
_WRITE_ERRNOS = {errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EFBIG}


def _is_write_error(exc: OSError, tmp, path: Path) -> bool:
    """Whether an OSError raised while writing ``tmp`` (the temporary of ``path``) is the
    output's: a write-only errno, or one naming the temporary or the target (an input's error
    raised inside the same ``with`` keeps its own message)."""
    named = {str(tmp), str(path)}
    return exc.errno in _WRITE_ERRNOS or str(exc.filename) in named or str(exc.filename2) in named


def file_mode() -> int:
    """The permission bits of a file relight writes, as ``open()`` would give them: 0666 less
    the process's umask (0644 under the usual 022), like other tools' outputs. (A temporary
    file is made 0600, and its mode would survive the rename.) Bundles are owner-only instead:
    :data:`relight.pipeline.bundle_write.BUNDLE_MODE`."""
    return 0o666 & ~_umask()


def check_free_space(path: str | os.PathLike, need: int, what: str = "it") -> None:
    """Raise :class:`OutputError` when the folder ``path`` will be written in (its nearest
    existing parent) has less than ``need`` bytes free: said before a long job, not after it."""
    import shutil

    folder = _existing_folder(path)
    check_writable(path)
    try:
        free = shutil.disk_usage(folder).free
    except OSError:
        return  # (not knowable here: the write itself will say)
    if free < need:
        raise OutputError(f"cannot write {path}: no space left on device ({free / 1e6:.1f} MB free in {folder}, "
                          f"{what} needs about {need / 1e6:.1f} MB); free some space or write elsewhere")


def _existing_folder(path) -> Path:
    folder = Path(path).absolute().parent
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    return folder


def check_writable(path: str | os.PathLike) -> None:
    """Raise :class:`OutputError` when ``path`` cannot be written: its folder (or the nearest
    existing parent) is on a read-only file system or not writable by this user."""
    folder = _existing_folder(path)
    read_only = False
    with contextlib.suppress(OSError, AttributeError):
        read_only = bool(os.statvfs(folder).f_flag & os.ST_RDONLY)
    if read_only:
        raise OutputError(f"cannot write {path}: read-only file system; write elsewhere")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise OutputError(f"cannot write {path}: permission denied on {folder}; write elsewhere")


def dir_mode() -> int:
    """The permission bits of a folder relight writes (a folder of frames), as ``mkdir`` gives:
    0777 less the umask (a temporary folder is made 0700)."""
    return 0o777 & ~_umask()


def _umask() -> int:
    """The process's umask, read without changing it (Linux: /proc/self/status; else set and
    restored at once)."""
    with contextlib.suppress(OSError, ValueError):
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def write_image(path: str | os.PathLike, image: np.ndarray, *, encode_srgb: bool | None = None) -> Path:
    """Write an image atomically; the format follows the extension.

    image : (H, W) or (H, W, C) array. For ``.exr``/``.hdr`` it is written as float32 linear
    values (EXR: zip-compressed). For ``.png``/``.jpg``: uint8 arrays are written as they
    are (already encoded); float arrays are linear values, clipped to 0-1, sRGB-encoded
    (``encode_srgb=False`` writes them as already-encoded 0-1 values) and quantised to 8 bits.
    """
    oiio = _oiio()
    path = Path(path)
    ext = path.suffix.lower()
    arr = np.asarray(image)
    if arr.ndim == 2:
        arr = arr[..., None]
    if arr.ndim != 3 or arr.shape[2] not in (1, 2, 3, 4):
        raise InputError(f"write_image({path}): expected (H, W) or (H, W, 1-4) array, got {arr.shape}")
    h, w, c = arr.shape
    if ext in LINEAR_EXTENSIONS:
        data = require_finite(f"image for {path}", arr.astype(np.float32))
        fmt = "float"
    elif ext in LDR_EXTENSIONS:
        if arr.dtype == np.uint8:
            data = arr
        else:
            f = arr.astype(FLOAT)
            require_finite(f"image for {path}", f)
            if encode_srgb is None or encode_srgb:
                f = linear_to_srgb(f)
            data = np.round(np.clip(f, 0.0, 1.0) * 255.0).astype(np.uint8)
        fmt = "uint8"
    else:
        raise InputError(f"{path}: unsupported extension {ext!r}; use .exr, .hdr, .png or .jpg")
    spec = oiio.ImageSpec(w, h, c, fmt)
    if c == 1:
        spec.channelnames = ("Y",)
    spec.attribute("DateTime", _FIXED_DATETIME)
    if ext == ".exr":
        spec.attribute("compression", "zip")
    if ext in (".jpg", ".jpeg"):
        spec.attribute("Compression", "jpeg:95")
    with atomic_path(path) as tmp:
        out = oiio.ImageOutput.create(str(tmp))
        if out is None:  # pragma: no cover - format plugins ship with the wheel
            raise InputError(f"{path}: no writer for {ext} ({_error_text(oiio)})")
        ok = out.open(str(tmp), spec) and out.write_image(np.ascontiguousarray(data))
        err = _error_text(out)
        out.close()
        if not ok:
            # OpenImageIO says why in words that name the temporary and no errno: a full disk is
            # told by the space left
            import shutil

            free = None
            with contextlib.suppress(OSError):
                free = shutil.disk_usage(path.parent).free
            if free is not None and free < 2 * data.nbytes + (1 << 20):
                raise OutputError(f"cannot write {path}: no space left on device")
            raise OutputError(f"cannot write {path}: {err.replace(str(tmp), str(path))}")
    return path


def image_size(data: bytes) -> tuple[int, int] | None:
    """(width, height) from a PNG or JPEG header without decoding, or None if there is none."""
    if data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) >= 24 and data[12:16] == b"IHDR":
        return struct.unpack(">II", data[16:24])
    if data[:2] == b"\xff\xd8":
        i = 2
        while i + 9 < len(data):
            if data[i] != 0xFF:
                return None
            marker = data[i + 1]
            if marker in (0xD8, 0x01) or 0xD0 <= marker <= 0xD7:
                i += 2
                continue
            seg = struct.unpack(">H", data[i + 2:i + 4])[0]
            if 0xC0 <= marker <= 0xCF and marker not in (0xC4, 0xC8, 0xCC):
                h, w = struct.unpack(">HH", data[i + 5:i + 9])
                return w, h
            i += 2 + seg
    return None
