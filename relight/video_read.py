"""Video in through PyAV (FFmpeg): a file opened and validated (:func:`probe_video`), its first
video stream decoded - bounded and checked - as sRGB frames (:func:`read_frames`), as PyAV frames
(:func:`read_frames_raw`, for :func:`relight.video_frame.crop_frame`) or as luma only
(:func:`read_luma`); the decoded frames freed as they go (:func:`release_frames`).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import InputError
from .video_colour import PLANAR_FORMATS
from .video_frame import LIMITED_TO_FULL, frame_to_rgb, whole_frame
from .video_orient import display_orientation, orient

#: Largest frame a reader accepts (8K UHD) and the longest video, in frames.
MAX_VIDEO_DIM = 7680
MAX_VIDEO_FRAMES = 200_000
#: Container metadata (titles, tags) that is not UTF-8 is read with replacement characters
#: (PyAV's default, "strict", raised UnicodeDecodeError out of the readers).
METADATA_ERRORS = "replace"


#: Decoded bytes after which :func:`release_frames` runs the cycle collector (the dead frames it
#: frees are at most this much memory).
RELEASE_BYTES = 128 << 20
_decoded_since_collect = [0]


def release_frames(frame) -> None:
    """Free decoded frames that wait for Python's cycle collector; call once per decoded frame.

    Reading a PyAV frame's ``side_data`` (the display matrix: :func:`display_orientation`) ties
    the frame and its side-data container in a reference cycle, so the frame - 12 MB at 4K -
    outlives its last use until a full collection (a frame still in use when a younger
    generation is collected moves to the oldest): a 4K capture's ingest held ~190 dead frames,
    2.9 GB, after 100 frames. A full collection (~20 ms) once every RELEASE_BYTES of decoded
    frames bounds them: every ~10 frames at 4K, ~40 at 1080p."""
    import gc

    _decoded_since_collect[0] += int(frame.width) * int(frame.height) * 3 // 2
    if _decoded_since_collect[0] >= RELEASE_BYTES:
        _decoded_since_collect[0] = 0
        gc.collect()


@dataclass(frozen=True)
class VideoInfo:
    """What a video's container says about its first video stream."""

    width: int        # as displayed (the display rotation applied)
    height: int
    fps: float
    frame_count: int  # from the container; 0 when it does not say
    turns: int = 0    # display orientation of the first frame (:func:`display_orientation`)
    mirror: bool = False

    @property
    def coded_size(self) -> tuple[int, int]:
        """(width, height) of the frames as decoded, before the display rotation."""
        return (self.height, self.width) if self.turns % 2 else (self.width, self.height)


def probe_video(path: str | os.PathLike) -> VideoInfo:
    """Open a video and validate its first video stream; only its first frame is decoded (for the
    display orientation a phone's portrait video carries)."""
    import av

    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such video file; check the path")
    try:
        with av.open(str(path), metadata_errors=METADATA_ERRORS) as container:
            if not container.streams.video:
                raise InputError(f"{path}: the file has no video stream")
            s = container.streams.video[0]
            if s.codec_context is None:
                raise InputError(f"{path}: no decoder for its video stream's codec; "
                                 "re-encode it as H.264 or HEVC")
            w, h = s.codec_context.width, s.codec_context.height
            rate = s.average_rate or s.guessed_rate or 0
            n = s.frames or 0
            turns, mirror = 0, False
            if 0 < w <= MAX_VIDEO_DIM and 0 < h <= MAX_VIDEO_DIM:
                try:
                    first = next(iter(container.decode(s)), None)
                except av.error.FFmpegError:
                    first = None  # the readers say what is broken
                if first is not None:
                    turns, mirror = display_orientation(first)
    except av.error.FFmpegError as exc:
        raise InputError(f"{path}: not a readable video ({exc}); use MP4/MOV/MKV/WebM") from None
    if not (0 < w <= MAX_VIDEO_DIM and 0 < h <= MAX_VIDEO_DIM):
        raise InputError(f"{path}: frame size {w}x{h} is outside 1..{MAX_VIDEO_DIM}; downscale the video")
    if turns % 2:
        w, h = h, w
    return VideoInfo(width=w, height=h, fps=float(rate), frame_count=int(n), turns=turns, mirror=mirror)


def _decoded(path: str | os.PathLike, max_frames: int, convert: Callable | None, *,
             same_size: bool = True) -> Iterator:
    """The decoded frames of the first video stream (``convert(frame)`` of each when given), at
    most ``max_frames`` of them, all of the stream's size unless ``same_size`` is False; a
    decoder's error an :class:`InputError`."""
    import av

    info = probe_video(path)
    count = 0
    try:
        with av.open(str(path), metadata_errors=METADATA_ERRORS) as container:
            stream = container.streams.video[0]
            stream.thread_type = "AUTO"
            for frame in container.decode(stream):
                release_frames(frame)
                if same_size and (frame.width, frame.height) != info.coded_size:
                    raise InputError(f"{path}: frame {count} is {frame.width}x{frame.height}, the stream said "
                                     f"{info.coded_size[0]}x{info.coded_size[1]}; variable-size streams are not "
                                     "supported")
                count += 1
                if count > max_frames:
                    raise InputError(f"{path}: more than {max_frames} frames; trim the video")
                yield frame if convert is None else convert(frame)
    except av.error.FFmpegError as exc:
        raise InputError(f"{path}: decoding failed after {count} frame(s) ({exc}); the file is corrupt") from None


def read_frames(path: str | os.PathLike, *, max_frames: int = MAX_VIDEO_FRAMES) -> Iterator[np.ndarray]:
    """Decode the first video stream as (H, W, 3) uint8 sRGB frames, in order, as displayed (the
    container's display rotation and mirror applied: a phone's portrait video comes out upright).

    Raises :class:`InputError` for an unreadable file, a corrupt stream, or more than
    ``max_frames`` frames.
    """
    yield from _decoded(path, max_frames, frame_to_rgb)


def read_frames_raw(path: str | os.PathLike, *, max_frames: int = MAX_VIDEO_FRAMES) -> Iterator:
    """Decoded frames as PyAV frames (convert with :func:`relight.video_frame.crop_frame` or
    :func:`relight.video_frame.frame_to_rgb`)."""
    yield from _decoded(path, max_frames, None)


def read_luma(path: str | os.PathLike, *, max_frames: int = MAX_VIDEO_FRAMES) -> Iterator[np.ndarray]:
    """Decode only the brightness of each frame: (H, W) uint8 full-range luma (sRGB-encoded grey).

    Reads the Y plane directly for YUV streams (no colour conversion), so it is several times
    faster than :func:`read_frames`; for brightness traces and tracking.
    """
    count = 0
    for y in _decoded(path, max_frames, _luma, same_size=False):
        count += 1
        yield y
    if count == 0:
        raise InputError(f"{path}: the video holds no frames")


def _luma(frame) -> np.ndarray:
    """(H, W) uint8 full-range luma of one decoded frame, as displayed (:func:`read_luma`)."""
    name = frame.format.name
    if name in PLANAR_FORMATS and PLANAR_FORMATS[name][0] == 8:
        y = np.frombuffer(frame.planes[0], dtype=np.uint8).reshape(
            frame.height, frame.planes[0].line_size)[:, :frame.width]
        full = name.startswith("yuvj") or int(frame.color_range) == 2
        if not full:
            y = LIMITED_TO_FULL[y]
    elif name in PLANAR_FORMATS:  # 10/12-bit: through linear light (HDR tone-mapped)
        return whole_frame(frame).luma()
    else:
        y = frame.to_ndarray(format="gray")
    return np.ascontiguousarray(orient(y, *display_orientation(frame)))
