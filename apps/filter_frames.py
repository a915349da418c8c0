"""``relight filter`` with frames as files: an image sequence (a folder of images) relit into a
video or a folder of PNG frames (:func:`filter_sequence`), and a video relit into PNG frames
(:func:`filter_video_frames`); the PNG folder appears only complete (:func:`png_folder`)."""

from __future__ import annotations

import os
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from relight.errors import InputError, OutputError, os_reason
from relight.imageio import clean_stale_temps, dir_mode, temp_prefix
from relight.video_write import DEFAULT_PRESET

from .filter_video import VIDEO_CODECS

#: Image files read as a sequence when IN is a folder.
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".exr", ".tif", ".tiff", ".bmp")
MAX_SEQUENCE = 100_000


def _sequence(folder: Path) -> list[Path]:
    files = sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file())
    if not files:
        raise InputError(f"{folder}: no images ({', '.join(IMAGE_SUFFIXES)}) in the folder")
    if len(files) > MAX_SEQUENCE:
        raise InputError(f"{folder}: more than {MAX_SEQUENCE} images; split the sequence")
    return files


def _read_rgb8(path: Path) -> np.ndarray:
    from relight.colour import encode_srgb8
    from relight.imageio import read_image

    img = read_image(path, linearize=path.suffix.lower() not in (".exr",))
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=2)
    return encode_srgb8(np.clip(img[..., :3], 0.0, 1.0))


def filter_sequence(folder, out, handle, fps, crf, res, progress, tqdm, preset: str = DEFAULT_PRESET):
    """Relight the images of ``folder`` (one size, in name order, at ``fps``) through ``handle``
    into the video ``out`` (its suffix one of VIDEO_CODECS) or, else, a folder of PNG frames."""
    from relight.imageio import write_image
    from relight.video_write import VideoWriter

    files = _sequence(folder)
    first = _read_rgb8(files[0])
    size = (first.shape[1], first.shape[0])
    if out.suffix.lower() in VIDEO_CODECS:
        if size[0] % 2 or size[1] % 2:
            raise InputError(f"{folder}: images are {size[0]}x{size[1]}; H.264 needs even sizes (crop them)")
        with VideoWriter(out, fps, size, crf=crf, preset=preset) as wr:
            for i, f in enumerate(tqdm(files, desc="filter", unit="frame", disable=not progress)):
                rgb = first if i == 0 else _read_rgb8(f)
                if rgb.shape != first.shape:
                    raise InputError(f"{f}: {rgb.shape[1]}x{rgb.shape[0]}, the sequence started at "
                                     f"{size[0]}x{size[1]}; all images must have one size")
                wr.write(handle(rgb, i / fps, i))
        return
    with png_folder(out) as tmp:
        for i, f in enumerate(tqdm(files, desc="filter", unit="frame", disable=not progress)):
            rgb = first if i == 0 else _read_rgb8(f)
            write_image(tmp / f"{i:06d}.png", handle(rgb, i / fps, i))


def is_folder_output(out: Path) -> bool:
    """A folder of PNG frames is written where OUT is a folder or a name without a suffix."""
    return out.is_dir() or out.suffix == ""


@contextmanager
def png_folder(out: Path):
    """A folder of PNG frames (``000000.png``, ...): written into a temporary folder beside it,
    renamed to ``out`` when complete (an existing ``out`` must be an empty folder)."""
    import shutil
    import tempfile

    _refuse_occupied(out)  # before any work
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        clean_stale_temps(out.parent, out.name)  # a killed run's folder
        tmp = Path(tempfile.mkdtemp(prefix=temp_prefix(out.name), suffix=".tmp", dir=out.parent))
    except OSError as exc:
        raise OutputError(f"cannot write {out}: {os_reason(exc)}") from exc
    try:
        yield tmp
        _refuse_occupied(out)  # and again: something may have been put there meanwhile
        if out.exists():
            out.rmdir()
        os.chmod(tmp, dir_mode())  # (mkdtemp's 0700 would survive the rename)
        os.replace(tmp, out)
    except BaseException as exc:
        shutil.rmtree(tmp, ignore_errors=True)
        if isinstance(exc, OSError):  # a frame's OutputError names the temporary folder: name the output
            raise OutputError(f"cannot write {out}: {os_reason(exc.__cause__ or exc)}") from exc
        raise


def _refuse_occupied(out: Path) -> None:
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise InputError(f"{out}: exists and is not an empty folder; choose another output")


def filter_video_frames(inp, out, pipeline, res, progress, tqdm):
    """A video into a folder of PNG frames (no second encode: what a measurement wants; the
    audio is left out)."""
    import av

    from relight.imageio import write_image
    from relight.video_read import METADATA_ERRORS, probe_video, read_frames

    info = probe_video(inp)
    fps = info.fps if info.fps and info.fps > 0 else 30.0
    with av.open(str(inp), metadata_errors=METADATA_ERRORS) as c:
        if c.streams.audio:
            res.audio = "left out (PNG frames)"
    bar = tqdm(total=info.frame_count or None, desc="filter", unit="frame", disable=not progress)
    index = 0
    try:
        with png_folder(out) as tmp, pipeline:
            pipeline.done = lambda frame_out, i: write_image(tmp / f"{i:06d}.png", frame_out)
            for rgb in read_frames(inp):
                pipeline.put(rgb, index / fps, index, index)
                index += 1
                bar.update(1)
            pipeline.drain()
            if index == 0:
                raise InputError(f"{inp}: the video has no frames")
    finally:
        bar.close()

