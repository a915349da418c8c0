"""Video in and out through PyAV (FFmpeg).

Frames cross this boundary as (H, W, 3) uint8 sRGB arrays; convert with
:func:`relight.colour.decode_srgb8` / :func:`relight.colour.encode_srgb8`.
Writes are atomic (temporary file + rename); reads are bounded and validated.
"""

from __future__ import annotations

import os
import queue
import threading
from collections.abc import Iterator
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path

import numpy as np

from .colour import decode_srgb8, luminance
from .errors import InputError
from .imageio import atomic_path
from .video_colour import (
    PLANAR_FORMATS,
    VideoColour,
    encode_display8,
    frame_display_rgb,
    luma_table,
    signal_to_linear,
    video_colour,
    ycbcr_matrix,
)

#: Largest frame a reader accepts (8K UHD) and the longest video, in frames.
MAX_VIDEO_DIM = 7680
MAX_VIDEO_FRAMES = 200_000
#: Container metadata (titles, tags) that is not UTF-8 is read with replacement characters
#: (PyAV's default, "strict", raised UnicodeDecodeError out of the readers).
METADATA_ERRORS = "replace"
#: Audio written beside the video: sample rate (Hz) and AAC bit rate (bits/s, mono).
AUDIO_RATE = 48_000
AUDIO_BIT_RATE = 96_000
#: Longest audio track a writer accepts, in samples (an hour at 48 kHz).
MAX_AUDIO_SAMPLES = 3600 * AUDIO_RATE
#: H.264 quality (x264's CRF: lower = better and bigger) of the videos relight makes for people to
#: watch - ``relight filter``'s output, ``relight live``'s recording - unless told otherwise
#: (``--crf``); a .webm output is VP9 at this + 12. :class:`VideoWriter`'s own default, 16, is the
#: near-lossless quality of the synthetic captures the pipeline measures.
DEFAULT_CRF = 18


def sws_flags():
    from av.video.reformatter import Interpolation as I

    # swscale's default RGB <-> YUV paths round down: a measured bias of about -0.75 of an
    # 8-bit code per round trip (-2 with ACCURATE_RND alone). This combination measured
    # unbiased (|mean| < 0.1 code) on synthetic captures; tests/test_video.py keeps it so.
    return I.BICUBIC | I.ACCURATE_RND | I.FULL_CHR_H_INT


def to_yuv(rgb: np.ndarray):
    """RGB uint8 -> a yuv420p frame, BT.709 matrix, limited range (what players assume for HD)."""
    import av

    frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(rgb), format="rgb24")
    return frame.reformat(format="yuv420p", dst_colorspace="ITU709", dst_color_range="MPEG",
                          interpolation=sws_flags())


def _to_rgb(frame) -> np.ndarray:
    """A decoded frame -> RGB uint8, honouring its colour tags (untagged: BT.709 for HD, else
    BT.601; limited range), as FFmpeg-based players do."""
    from av.video.reformatter import ColorRange, Colorspace

    try:
        cs = Colorspace(int(frame.colorspace))
    except ValueError:
        cs = Colorspace.ITU709 if frame.height >= 720 else Colorspace.ITU601
    rng = frame.color_range if int(frame.color_range) in (1, 2) else ColorRange.MPEG
    return frame.reformat(format="rgb24", src_colorspace=cs, src_color_range=rng,
                          interpolation=sws_flags()).to_ndarray()


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


def display_orientation(frame) -> tuple[int, bool]:
    """How a decoded frame is shown: (quarter turns counter-clockwise, then mirror left-right),
    from the display matrix its container carries (phones store portrait video as landscape
    frames plus this matrix); (0, False) without one.

    FFmpeg's matrix (``AV_FRAME_DATA_DISPLAYMATRIX``, 16.16 fixed point) is a rotation, possibly
    with one column negated (a mirror); its rotation angle is read as ``av_display_rotation_get``
    does, and a mirrored matrix (negative determinant) is a mirror after the rotation that angle
    implies. Angles that are not a multiple of 90 degrees go to the nearest one.

    A frame may carry side data PyAV cannot name - FFmpeg 8 (the PyAV 18 wheels) adds types 28-31
    (LCEVC, VIEW_ID, 3D_REFERENCE_DISPLAYS: multi-view HEVC as phones' spatial video; EXIF: every
    PNG OpenImageIO writes) that PyAV's ``Type`` enum lacks, and its side-data container then
    refuses the whole frame (``ValueError: 31 is not a valid Type``). Then the rotation is read as
    PyAV reads it for ``frame.rotation`` (FFmpeg's ``av_display_rotation_get`` on the raw side
    data, no container) and a mirror, which only the matrix itself shows, is not seen."""
    data = None
    try:
        entries = list(getattr(frame, "side_data", ()) or ())
    except (ValueError, KeyError, TypeError):  # an entry of a type PyAV cannot name
        return _rotation_only(frame), False
    for sd in entries:
        if str(getattr(sd, "type", "")).endswith("DISPLAYMATRIX"):
            data = bytes(sd)
            break
    if data is None or len(data) < 36:
        return 0, False
    m = np.frombuffer(data[:36], dtype="<i4").astype(np.float64) / 65536.0
    s0, s1 = np.hypot(m[0], m[3]), np.hypot(m[1], m[4])
    if not (s0 > 0 and s1 > 0):
        return 0, False
    angle = -np.degrees(np.arctan2(m[1] / s1, m[0] / s0))  # av_display_rotation_get
    mirror = bool(m[0] * m[4] - m[1] * m[3] < 0)
    if mirror:
        angle = -angle - 180.0
    return int(np.round(angle / 90.0)) % 4, mirror


def _rotation_only(frame) -> int:
    """Quarter turns counter-clockwise from PyAV's ``frame.rotation`` (degrees; 0 without a
    display matrix or on a PyAV without it)."""
    try:
        angle = float(getattr(frame, "rotation", 0) or 0)
    except (ValueError, TypeError):
        return 0
    return int(np.round(angle / 90.0)) % 4 if np.isfinite(angle) else 0


def orient(img: np.ndarray, turns: int, mirror: bool) -> np.ndarray:
    """``img`` (H, W, ...) turned ``turns`` quarter turns counter-clockwise, then mirrored
    left-right when ``mirror`` (see :func:`display_orientation`); a view when nothing changes."""
    out = np.rot90(img, turns % 4) if turns % 4 else img
    return out[:, ::-1] if mirror else out


def _check_audio(audio: np.ndarray, rate: int) -> np.ndarray:
    """Mono samples for :class:`VideoWriter`: 1-D, finite, within -1..1 -> float32."""
    a = np.asarray(audio)
    if a.ndim != 1 or a.size == 0 or not np.issubdtype(a.dtype, np.floating):
        raise InputError(f"audio must be a non-empty 1-D float array of mono samples, got {a.shape} {a.dtype}")
    if not (8000 <= int(rate) <= 192_000):
        raise InputError(f"audio rate {rate} Hz: use 8000 to 192000 Hz")
    if a.size > MAX_AUDIO_SAMPLES:
        raise InputError(f"audio of {a.size} samples is longer than {MAX_AUDIO_SAMPLES}; shorten it")
    if not np.all(np.isfinite(a)) or np.abs(a).max() > 1.0:
        raise InputError("audio samples must be finite and within -1..1; scale the signal down")
    return np.ascontiguousarray(a, dtype=np.float32)


class VideoWriter:
    """Encode RGB frames to H.264 (yuv420p) in an MP4, atomically.

    Use as a context manager; the file appears at ``path`` only when the block completes.
    ``audio``: optional mono samples (1-D float, -1 to 1) at ``audio_rate`` Hz, encoded as an
    AAC stream beside the video (interleaved with it as the frames arrive; whatever is left
    when the block ends is written then, so the audio may be longer or shorter than the video).
    """

    def __init__(self, path: str | os.PathLike, fps: float, size: tuple[int, int], *, crf: int = 16,
                 preset: str = "veryfast", codec: str = "libx264", audio: np.ndarray | None = None,
                 audio_rate: int = AUDIO_RATE):
        w, h = size
        if w % 2 or h % 2:
            raise InputError(f"video size {w}x{h}: H.264 (yuv420p) needs even width and height")
        self.path = Path(path)
        self.fps = Fraction(fps).limit_denominator(1001)
        self.size = (int(w), int(h))
        self.crf = crf
        self.preset = preset
        self.codec = codec
        self.frames = 0
        self.audio = None if audio is None else _check_audio(audio, audio_rate)
        self.audio_rate = int(audio_rate)
        self._audio_done = 0  # samples of ``audio`` handed to the encoder so far

    def __enter__(self) -> VideoWriter:
        import av

        self._atomic = atomic_path(self.path)
        tmp = self._atomic.__enter__()
        self._container = av.open(str(tmp), mode="w")
        stream = self._container.add_stream(self.codec, rate=self.fps)
        stream.width, stream.height = self.size
        stream.pix_fmt = "yuv420p"
        stream.codec_context.time_base = 1 / self.fps
        options = {"crf": str(self.crf), "preset": self.preset}
        if self.codec == "libx264":
            # x264's macroblock-tree rate control was measured to give different bytes for
            # identical input from run to run (even on one thread); same-seed captures must be
            # identical, so it is off (a few percent more bits at the same quality).
            options["x264-params"] = "mbtree=0"
        stream.options = options
        cc = stream.codec_context
        cc.colorspace, cc.color_range, cc.color_primaries = 1, 1, 1  # BT.709, limited range
        cc.color_trc = 13  # IEC 61966-2-1: the frames carry the sRGB transfer curve
        self._stream = stream
        self._audio_stream = None
        if self.audio is not None:
            # Every stream must exist before the first packet is muxed (the header is written then).
            astream = self._container.add_stream("aac", rate=self.audio_rate)
            astream.codec_context.layout = "mono"
            astream.codec_context.format = "fltp"
            astream.codec_context.bit_rate = AUDIO_BIT_RATE
            astream.codec_context.time_base = Fraction(1, self.audio_rate)
            self._audio_stream = astream

        # Colour conversion and encoding run on a worker thread (FFmpeg releases the GIL), so
        # the caller renders the next frame meanwhile; the short queue bounds memory.
        self._queue: queue.Queue = queue.Queue(maxsize=4)
        self._error: BaseException | None = None
        self._worker = threading.Thread(target=self._encode_loop, name="relight-video-writer", daemon=True)
        self._worker.start()
        return self

    def _encode_loop(self) -> None:
        while True:
            item = self._queue.get()
            if item is None:
                return
            if self._error is not None:
                continue  # drain after a failure; the caller sees the error
            try:
                index, rgb = item
                frame = to_yuv(rgb) if isinstance(rgb, np.ndarray) else rgb.to_av()
                frame.pts = index
                frame.time_base = 1 / self.fps
                for packet in self._stream.encode(frame):
                    self._container.mux(packet)
                if self._audio_stream is not None:
                    self._encode_audio(int(round((index + 1) / self.fps * self.audio_rate)))
            except BaseException as exc:  # re-raised in the caller's thread
                self._error = exc

    def _encode_audio(self, until: int | None) -> None:
        """Encode the audio samples up to index ``until`` (None: all, then flush the encoder).

        Only whole encoder frames are sent before the end (AAC takes 1024 samples a frame;
        the last one may be short)."""
        import av

        stream = self._audio_stream
        total = self.audio.size
        step = stream.codec_context.frame_size or 1024
        end = total if until is None else min(until, total)
        while self._audio_done < end and (until is None or self._audio_done + step <= end):
            a = self._audio_done
            chunk = self.audio[a:a + step]
            frame = av.AudioFrame.from_ndarray(np.ascontiguousarray(chunk[None, :]), format="fltp", layout="mono")
            frame.sample_rate = self.audio_rate
            frame.pts = a
            frame.time_base = Fraction(1, self.audio_rate)
            for packet in stream.encode(frame):
                self._container.mux(packet)
            self._audio_done = a + chunk.size
        if until is None:
            for packet in stream.encode():
                self._container.mux(packet)

    def _raise_worker_error(self) -> None:
        if self._error is not None:
            raise OSError(f"{self.path}: encoding failed ({self._error})") from self._error

    def write(self, rgb) -> None:
        """Append one (H, W, 3) uint8 sRGB frame (do not modify the array afterwards), or a
        :class:`relight.video_yuv.YuvFrame` of the writer's size (encoded as it is)."""
        if not isinstance(rgb, np.ndarray) and hasattr(rgb, "to_av"):
            if rgb.shape != (self.size[1], self.size[0], 3):
                raise InputError(f"frame must be {self.size[0]}x{self.size[1]}, got {rgb.shape[1]}x{rgb.shape[0]}")
        elif rgb.shape != (self.size[1], self.size[0], 3) or rgb.dtype != np.uint8:
            raise InputError(f"frame must be ({self.size[1]}, {self.size[0]}, 3) uint8, got {rgb.shape} {rgb.dtype}")
        self._raise_worker_error()
        self._queue.put((self.frames, rgb))
        self.frames += 1

    def __exit__(self, exc_type, exc, tb) -> None:
        try:
            self._queue.put(None)
            self._worker.join()
            if exc_type is None:
                self._raise_worker_error()
                for packet in self._stream.encode():
                    self._container.mux(packet)
                if self._audio_stream is not None:
                    self._encode_audio(None)
        except BaseException as err:
            self._container.close()
            self._atomic.__exit__(type(err), err, err.__traceback__)
            raise
        self._container.close()
        self._atomic.__exit__(exc_type, exc, tb)


def read_luma(path: str | os.PathLike, *, max_frames: int = MAX_VIDEO_FRAMES) -> Iterator[np.ndarray]:
    """Decode only the brightness of each frame: (H, W) uint8 full-range luma (sRGB-encoded grey).

    Reads the Y plane directly for YUV streams (no colour conversion), so it is several times
    faster than :func:`read_frames`; for brightness traces and tracking.
    """
    import av

    probe_video(path)
    count = 0
    try:
        with av.open(str(path), metadata_errors=METADATA_ERRORS) as container:
            stream = container.streams.video[0]
            stream.thread_type = "AUTO"
            for frame in container.decode(stream):
                release_frames(frame)
                count += 1
                if count > max_frames:
                    raise InputError(f"{path}: more than {max_frames} frames; trim the video")
                name = frame.format.name
                if name in PLANAR_FORMATS and PLANAR_FORMATS[name][0] == 8:
                    y = np.frombuffer(frame.planes[0], dtype=np.uint8).reshape(
                        frame.height, frame.planes[0].line_size)[:, :frame.width]
                    full = name.startswith("yuvj") or int(frame.color_range) == 2
                    if not full:
                        y = _LIMITED_TO_FULL[y]
                elif name in PLANAR_FORMATS:  # 10/12-bit: through linear light (HDR tone-mapped)
                    yield whole_frame(frame).luma()
                    continue
                else:
                    y = frame.to_ndarray(format="gray")
                yield np.ascontiguousarray(orient(y, *display_orientation(frame)))
    except av.error.FFmpegError as exc:
        raise InputError(f"{path}: decoding failed after {count} frame(s) ({exc}); the file is corrupt") from None
    if count == 0:
        raise InputError(f"{path}: the video holds no frames")


@dataclass
class FrameCrop:
    """A region of a decoded frame kept in its native planes (YUV 4:2:0: 1.5 samples a pixel;
    uint8 for 8-bit video, uint16 for 10/12-bit).

    Convert with :meth:`linear` (float32 linear Rec.709, the stream's colour tags honoured:
    :mod:`relight.video_colour`) or :meth:`rgb` (uint8 sRGB for display and detection; HDR
    tone-mapped) only when colour is needed; :meth:`luma` is almost free.
    """

    y: np.ndarray | None           # (h, w) luma codes (None for an RGB crop)
    u: np.ndarray | None = None    # chroma planes covering the crop
    v: np.ndarray | None = None
    offset: tuple[int, int] = (0, 0)  # where the crop starts in the 2x-upsampled chroma block
    shift: int = 0                 # 2: 4:2:0, 1: 4:2:2, 0: 4:4:4
    colour: VideoColour = VideoColour()
    # (h, w, 3) as displayed, for frames not in planar Y'CbCr: uint8 sRGB codes, uint16
    # non-linear signal (65535 = 1) in the stream's primaries, or float32 linear Rec.709.
    rgb_data: np.ndarray | None = None
    turns: int = 0                 # the display orientation (:func:`display_orientation`) applied
    mirror: bool = False           # to every output; the planes stay as coded

    @property
    def shape(self) -> tuple[int, int]:
        if self.rgb_data is not None:
            return self.rgb_data.shape[:2]
        h, w = self.y.shape
        return (w, h) if self.turns % 2 else (h, w)

    def _shown(self, img: np.ndarray) -> np.ndarray:
        return np.ascontiguousarray(orient(img, self.turns, self.mirror))

    def luma(self, *, native: bool = False) -> np.ndarray:
        """(h, w) uint8 luma: sRGB-encoded grey (full range; HDR tone-mapped), or with ``native``
        the stored codes' top 8 bits, range as stored (cheapest: for tracking, which only
        needs relative brightness)."""
        import cv2

        if self.rgb_data is not None:
            return cv2.cvtColor(self.rgb(), cv2.COLOR_RGB2GRAY)
        if native:
            y = self.y if self.y.dtype == np.uint8 else (self.y >> (self.colour.bits - 8)).astype(np.uint8)
            return self._shown(y)
        if self.colour.plain_srgb8:
            return self._shown(self.y if self.colour.full_range else _LIMITED_TO_FULL[self.y])
        return encode_display8(self.luma_linear(), self.colour.transfer)

    def luma_linear(self) -> np.ndarray:
        """(h, w) float32 linear grey of the luma codes (a brightness trace's input)."""
        if self.rgb_data is not None:
            return luminance(self.linear())
        if self.colour.plain_srgb8:
            return decode_srgb8(self.luma())
        return self._shown(luma_table(self.colour)[self.y])

    def sparse(self, step: int) -> FrameCrop:
        """Every ``step``-th pixel each way (nearest chroma), as displayed: cheap statistics."""
        if self.rgb_data is not None:
            return FrameCrop(y=None, rgb_data=self.rgb_data[::step, ::step], colour=self.colour)
        if self.turns % 4 or self.mirror:
            # The display grid, exactly (rare: turned videos): taken from the full conversion.
            return FrameCrop(y=None, rgb_data=self.linear()[::step, ::step], colour=self.colour)
        h, w = self.y.shape
        rows, cols = np.arange(0, h, step), np.arange(0, w, step)
        if self.shift:
            ox, oy = self.offset
            cr = (rows + oy) // (2 if self.shift == 2 else 1)
            cc = (cols + ox) // 2
        else:
            cr, cc = rows, cols
        return FrameCrop(y=self.y[np.ix_(rows, cols)], u=self.u[np.ix_(cr, cc)], v=self.v[np.ix_(cr, cc)],
                         shift=0, colour=self.colour)

    def resized(self, size: tuple[int, int], *, precise: bool = False) -> FrameCrop:
        """This crop resampled (area average) to ``size`` = (w, h) as displayed, planes kept as
        coded: 8-bit video stays 8-bit (a crop held for every frame of a capture: memory first)
        unless ``precise``; 10/12-bit (and ``precise``) goes to 16 bits, keeping the precision
        the average of several codes has (the result's colour: ``bits=16``, same curve, matrix
        and range)."""
        import dataclasses

        import cv2

        w, h = (int(v) for v in size)
        if self.rgb_data is not None:
            return FrameCrop(y=None, rgb_data=cv2.resize(self.rgb_data, (w, h), interpolation=cv2.INTER_AREA),
                             colour=self.colour)
        cw, ch = (h, w) if self.turns % 2 else (w, h)
        eight = self.colour.bits == 8 and not precise
        up = 1.0 if eight else float(1 << (16 - self.colour.bits))

        def area(plane, dsize):
            if eight:
                return cv2.resize(plane, dsize, interpolation=cv2.INTER_AREA)  # rounds, stays uint8
            out = cv2.resize(plane.astype(np.float32), dsize, interpolation=cv2.INTER_AREA)
            return np.clip(np.round(out * up), 0, 65535).astype(np.uint16)

        if self.shift == 2:
            csize = ((cw + 1) // 2, (ch + 1) // 2)
        elif self.shift == 1:
            csize = ((cw + 1) // 2, ch)
        else:
            csize = (cw, ch)
        # The chroma planes cover the crop plus at most one luma column/row before it (offset):
        # under a downscale that is under half an output pixel, left as is.
        return FrameCrop(y=area(self.y, (cw, ch)), u=area(self.u, csize), v=area(self.v, csize), shift=self.shift,
                         colour=self.colour if eight else dataclasses.replace(self.colour, bits=16), turns=self.turns,
                         mirror=self.mirror)

    def _signal(self) -> np.ndarray:
        """(h, w, 3) float32 non-linear R'G'B' (0-1 nominal) in the stream's primaries, as coded."""
        import cv2

        h, w = self.y.shape
        planes = [self.y.astype(np.float32)]
        for c in (self.u, self.v):
            c = c.astype(np.float32)
            if self.shift:
                c = cv2.resize(c, (c.shape[1] * 2, c.shape[0] * (2 if self.shift == 2 else 1)),
                               interpolation=cv2.INTER_LINEAR)
                ox, oy = self.offset
                c = c[oy:oy + h, ox:ox + w]
            planes.append(c)
        # One affine colour transform of [Y, Cb, Cr, 1] (OpenCV: SIMD, threaded).
        return cv2.transform(cv2.merge(planes), ycbcr_matrix(self.colour))

    def rgb(self) -> np.ndarray:
        """(h, w, 3) uint8 sRGB as displayed, with the stream's matrix and range, chroma upsampled
        bilinearly; other curves and primaries through linear light
        (:func:`relight.video_colour.encode_display8`: HDR tone-mapped)."""
        import cv2

        if self.rgb_data is not None and self.rgb_data.dtype == np.uint8:
            return self.rgb_data
        if self.rgb_data is None and self.colour.plain_srgb8:
            sig = self._signal()
            sig *= 255.0
            np.maximum(sig, 0.0, out=sig)
            return self._shown(cv2.convertScaleAbs(sig))  # rounds and saturates at 255
        return encode_display8(self.linear(), self.colour.transfer)

    def linear(self) -> np.ndarray:
        """(h, w, 3) float32 linear Rec.709 as displayed, reference white 1.0 (HDR above it):
        exactly :func:`relight.colour.decode_srgb8` of :meth:`rgb` for 8-bit sRGB video."""
        if self.rgb_data is not None:
            if self.rgb_data.dtype == np.uint8:
                return decode_srgb8(self.rgb_data)
            if self.rgb_data.dtype == np.float32:
                return self.rgb_data
            return signal_to_linear(self.rgb_data.astype(np.float32) / 65535.0, self.colour)
        if self.colour.plain_srgb8:
            return decode_srgb8(self.rgb())
        return self._shown(signal_to_linear(self._signal(), self.colour))

    def clipped(self, level: float) -> np.ndarray:
        """(h, w) bool: pixels with a channel at or above ``level`` of the code range's top
        (sensor saturation), as displayed."""
        return self._clipped(level)[0]

    def linear_and_clipped(self, level: float) -> tuple[np.ndarray, np.ndarray]:
        """(:meth:`linear`, :meth:`clipped` at ``level``) from one colour conversion (a flash
        frame needs both: converting twice was most of the capture's per-sample time)."""
        clipped, converted = self._clipped(level)
        if self.rgb_data is not None:
            return self.linear(), clipped
        if self.colour.plain_srgb8:
            return decode_srgb8(converted), clipped
        return self._shown(signal_to_linear(converted, self.colour)), clipped

    def _clipped(self, level: float) -> tuple[np.ndarray, np.ndarray]:
        """(:meth:`clipped`, the values it was read from: the codes as displayed, or for video
        converted through linear light the signal as coded)."""
        if self.rgb_data is not None and self.rgb_data.dtype == np.float32:
            raise ValueError("a linear crop has no code range to be clipped at")
        if self.rgb_data is not None or self.colour.plain_srgb8:
            codes = self.rgb() if self.rgb_data is None else self.rgb_data
            return _channel_max(codes) >= level * (255.0 if codes.dtype == np.uint8 else 65535.0), codes
        sig = self._signal()
        return self._shown(_channel_max(sig) >= level), sig


def _channel_max(img: np.ndarray) -> np.ndarray:
    """(h, w) the largest of the three channels of (h, w, 3) (NumPy's max over a last axis of
    3 is ~10x slower than this)."""
    return np.maximum(np.maximum(img[..., 0], img[..., 1]), img[..., 2])


_LIMITED_TO_FULL = np.clip(np.round((np.arange(256) - 16) * 255.0 / 219.0), 0, 255).astype(np.uint8)


def _coded_box(box: tuple[int, int, int, int], turns: int, mirror: bool,
               coded: tuple[int, int]) -> tuple[int, int, int, int]:
    """The region (x, y, w, h) of the coded frame (size ``coded`` = (W, H)) that a region of the
    displayed frame shows, for a display orientation (:func:`display_orientation`)."""
    x, y, w, h = box
    turns %= 4
    size = coded if turns % 2 == 0 else (coded[1], coded[0])  # the displayed size
    if mirror:
        x = size[0] - x - w
    for _ in range(turns):
        # One counter-clockwise quarter turn undone: a box of the turned image (size (Wr, Hr))
        # is (Wp - y - h, x, h, w) in the image before it (size (Hr, Wr)).
        size = (size[1], size[0])
        x, y, w, h = size[0] - y - h, x, h, w
    return x, y, w, h


def crop_frame(frame, box: tuple[int, int, int, int]) -> FrameCrop:
    """Keep the region ``box`` (x, y, w, h, in the frame as displayed: :func:`display_orientation`)
    of a decoded frame in its native planes (8-bit codes as uint8, 10/12-bit as uint16)."""
    name = frame.format.name
    colour = video_colour(frame)
    if name not in PLANAR_FORMATS:
        x, y, w, h = box
        if colour.bits > 8:
            sig = orient(frame.to_ndarray(format="rgb48le"), *display_orientation(frame))
            return FrameCrop(y=None, rgb_data=np.ascontiguousarray(sig[y:y + h, x:x + w]), colour=colour)
        return FrameCrop(y=None, rgb_data=np.ascontiguousarray(frame_to_rgb(frame)[y:y + h, x:x + w]),
                         colour=colour)
    turns, mirror = display_orientation(frame)
    x, y, w, h = _coded_box(box, turns, mirror, (frame.width, frame.height))
    bits, shift = PLANAR_FORMATS[name]
    dtype = np.uint8 if bits == 8 else np.dtype("<u2")
    itemsize = np.dtype(dtype).itemsize
    ys = frame.planes[0]
    yp = np.frombuffer(ys, dtype=dtype).reshape(frame.height, ys.line_size // itemsize)[y:y + h, x:x + w].copy()
    if shift == 0:
        cx0, cx1, cy0, cy1 = x, x + w, y, y + h
    else:
        cx0, cx1 = x >> 1, (x + w + 1) >> 1
        cy0, cy1 = ((y >> 1), ((y + h + 1) >> 1)) if shift == 2 else (y, y + h)
    chroma = []
    rows = (frame.height + 1) >> 1 if shift == 2 else frame.height
    for k in (1, 2):
        pl = frame.planes[k]
        chroma.append(np.frombuffer(pl, dtype=dtype).reshape(-1, pl.line_size // itemsize)[:rows][cy0:cy1, cx0:cx1]
                      .copy())
    off = (x - 2 * cx0, (y - 2 * cy0) if shift == 2 else 0) if shift else (0, 0)
    return FrameCrop(y=yp, u=chroma[0], v=chroma[1], offset=off, shift=shift, colour=colour, turns=turns,
                     mirror=mirror)


def whole_frame(frame) -> FrameCrop:
    """The whole of a decoded frame as a :class:`FrameCrop` (as displayed)."""
    turns, _ = display_orientation(frame)
    return crop_frame(frame, (0, 0, frame.height, frame.width) if turns % 2 else (0, 0, frame.width, frame.height))


def read_frames_raw(path: str | os.PathLike, *, max_frames: int = MAX_VIDEO_FRAMES) -> Iterator:
    """Decoded frames as PyAV frames (convert with :func:`crop_frame` or :func:`frame_to_rgb`)."""
    import av

    info = probe_video(path)
    count = 0
    try:
        with av.open(str(path), metadata_errors=METADATA_ERRORS) as container:
            stream = container.streams.video[0]
            stream.thread_type = "AUTO"
            for frame in container.decode(stream):
                release_frames(frame)
                if (frame.width, frame.height) != info.coded_size:
                    raise InputError(f"{path}: frame {count} is {frame.width}x{frame.height}, the stream said "
                                     f"{info.coded_size[0]}x{info.coded_size[1]}; variable-size streams are not "
                                     "supported")
                count += 1
                if count > max_frames:
                    raise InputError(f"{path}: more than {max_frames} frames; trim the video")
                yield frame
    except av.error.FFmpegError as exc:
        raise InputError(f"{path}: decoding failed after {count} frame(s) ({exc}); the file is corrupt") from None


def frame_to_rgb(frame) -> np.ndarray:
    """A decoded frame -> (H, W, 3) uint8 sRGB as displayed (its container's display rotation and
    mirror applied: :func:`display_orientation`); the conversion :func:`read_frames` uses.

    8-bit SDR video in Rec.709 goes through swscale with the stream's matrix and range (codes
    kept as they are: what players show); 10/12-bit, HDR and wide-gamut video through linear
    light (:mod:`relight.video_colour`; HDR tone-mapped)."""
    colour = video_colour(frame)
    if colour.bits == 8 and colour.primaries == "bt709" and not colour.hdr:
        return np.ascontiguousarray(orient(_to_rgb(frame), *display_orientation(frame)))
    if frame.format.name in PLANAR_FORMATS:
        return np.ascontiguousarray(orient(frame_display_rgb(frame, colour), *display_orientation(frame)))
    return whole_frame(frame).rgb()


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


def read_frames(path: str | os.PathLike, *, max_frames: int = MAX_VIDEO_FRAMES) -> Iterator[np.ndarray]:
    """Decode the first video stream as (H, W, 3) uint8 sRGB frames, in order, as displayed (the
    container's display rotation and mirror applied: a phone's portrait video comes out upright).

    Raises :class:`InputError` for an unreadable file, a corrupt stream, or more than
    ``max_frames`` frames.
    """
    import av

    info = probe_video(path)
    count = 0
    try:
        with av.open(str(path), metadata_errors=METADATA_ERRORS) as container:
            stream = container.streams.video[0]
            stream.thread_type = "AUTO"
            for frame in container.decode(stream):
                release_frames(frame)
                if (frame.width, frame.height) != info.coded_size:
                    raise InputError(f"{path}: frame {count} is {frame.width}x{frame.height}, the stream said "
                                     f"{info.coded_size[0]}x{info.coded_size[1]}; variable-size streams are not "
                                     "supported")
                count += 1
                if count > max_frames:
                    raise InputError(f"{path}: more than {max_frames} frames; trim the video")
                yield frame_to_rgb(frame)
    except av.error.FFmpegError as exc:
        raise InputError(f"{path}: decoding failed after {count} frame(s) ({exc}); the file is corrupt") from None
