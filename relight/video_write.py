"""Video out through PyAV (FFmpeg): frames encoded as H.264 (or VP9) yuv420p, converted
(:func:`to_yuv`) and tagged (:data:`OUTPUT_COLOUR_TAGS`) one way for every video relight writes;
:class:`VideoWriter` writes a file atomically, encoding on a thread of its own, with an optional
AAC audio track.
"""

from __future__ import annotations

import os
from fractions import Fraction
from pathlib import Path

import numpy as np

from .background import WriterThread
from .errors import InputError
from .imageio import atomic_path
from .video_frame import sws_flags

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
#: The colour tags (FFmpeg's enums) of every video relight writes - :class:`VideoWriter`'s and
#: ``relight filter``'s: the BT.709 Y'CbCr matrix in limited range (what :func:`to_yuv` converts
#: to, and what a :class:`relight.video_yuv.YuvFrame` keeps), BT.709 primaries, and the sRGB
#: transfer curve (IEC 61966-2-1: the frames carry sRGB codes).
OUTPUT_COLOUR_TAGS = {"colorspace": 1, "color_range": 1, "color_primaries": 1, "color_trc": 13}


def to_yuv(rgb: np.ndarray):
    """RGB uint8 -> a yuv420p frame, BT.709 matrix, limited range (what players assume for HD;
    the output's tags: :data:`OUTPUT_COLOUR_TAGS`)."""
    import av

    frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(rgb), format="rgb24")
    return frame.reformat(format="yuv420p", dst_colorspace=OUTPUT_COLOUR_TAGS["colorspace"],
                          dst_color_range=OUTPUT_COLOUR_TAGS["color_range"], interpolation=sws_flags())


def add_video_stream(container, codec: str, rate, size: tuple[int, int], time_base, options: dict):
    """A yuv420p video stream of ``size`` (w, h) added to ``container`` (open for writing):
    ``codec`` at frame rate ``rate``, the encoder's time base ``time_base`` and ``options``,
    tagged as every video relight writes is (:data:`OUTPUT_COLOUR_TAGS`)."""
    stream = container.add_stream(codec, rate=rate)
    stream.width, stream.height = size
    stream.pix_fmt = "yuv420p"
    stream.codec_context.time_base = time_base
    stream.options = options
    for tag, value in OUTPUT_COLOUR_TAGS.items():
        setattr(stream.codec_context, tag, value)
    return stream


def encode_and_mux(container, stream, frame=None) -> None:
    """Encode ``frame`` (video or audio) on ``stream`` - None: flush the encoder - and mux the
    packets into ``container``."""
    for packet in stream.encode(frame):
        container.mux(packet)


def encode_video_frame(container, stream, rgb, pts: int, time_base) -> None:
    """Encode one frame - an (H, W, 3) uint8 sRGB array (:func:`to_yuv`) or a
    :class:`relight.video_yuv.YuvFrame` (its planes as they are) - at ``pts`` (in ``time_base``)
    on ``stream``, and mux it."""
    frame = to_yuv(rgb) if isinstance(rgb, np.ndarray) else rgb.to_av()
    frame.pts = pts
    frame.time_base = time_base
    encode_and_mux(container, stream, frame)


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


#: The H.264 encoder's settings ``relight filter --preset`` (and :class:`VideoWriter`) takes:
#: x264's own presets (the fastest first) and REALTIME, ``relight filter``'s default - x264's
#: ultrafast with CABAC, three B-frames, the deblocking filter and sub-pixel refinement 1 back on.
#: Measured at crf 18 (issue 48, docs/performance.md): a 1280x720 frame in 18 ms of CPU against
#: superfast's 32 (after the decoder the costliest stage of a filter run) and ultrafast's 11; on
#: two real faces' clips (Yale B01, B02: a photo moving) 0.33 / 0.32 Mbit/s at 49.9 / 50.2 dB
#: luma PSNR against superfast's 0.29 / 0.27 at 48.9 and ultrafast's 0.72 / 0.63 at 49.1; on the
#: noisy synthetic clips about half superfast's bits (its sensor noise coded less).
REALTIME = "realtime"
X264_PRESETS = (REALTIME, "ultrafast", "superfast", "veryfast", "faster", "fast", "medium", "slow", "slower",
                "veryslow")
DEFAULT_PRESET = REALTIME
_REALTIME_OPTIONS = {"preset": "ultrafast", "x264-params": "cabac=1:bframes=3:deblock=0,0:subme=1"}


def x264_options(crf: int, preset: str) -> dict:
    """libx264's options for ``crf`` and ``preset`` (one of :data:`X264_PRESETS`)."""
    return {"crf": str(crf), **(_REALTIME_OPTIONS if preset == REALTIME else {"preset": check_preset(preset)})}


def check_preset(preset: str) -> str:
    """``preset`` if x264 has it (:data:`X264_PRESETS`), else an InputError saying which it has."""
    if preset not in X264_PRESETS:
        raise InputError(f"preset {preset!r}: use one of {', '.join(X264_PRESETS)}")
    return preset


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
        options = {"crf": str(self.crf), "preset": self.preset}
        if self.codec == "libx264":
            options = x264_options(self.crf, self.preset)
            # x264's macroblock-tree rate control was measured to give different bytes for
            # identical input from run to run (even on one thread); same-seed captures must be
            # identical, so it is off (a few percent more bits at the same quality).
            options["x264-params"] = ":".join(filter(None, (options.get("x264-params"), "mbtree=0")))
        self._stream = add_video_stream(self._container, self.codec, self.fps, self.size, 1 / self.fps, options)
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
        self._writer = WriterThread(self._encode, maxsize=4, name="relight-video-writer",
                                    wrap=lambda err: OSError(f"{self.path}: encoding failed ({err})"))
        self._writer.__enter__()
        return self

    def _encode(self, item) -> None:
        """One frame (on the writer's thread), and the audio up to its end."""
        index, rgb = item
        encode_video_frame(self._container, self._stream, rgb, index, 1 / self.fps)
        if self._audio_stream is not None:
            self._encode_audio(int(round((index + 1) / self.fps * self.audio_rate)))

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
            encode_and_mux(self._container, stream, frame)
            self._audio_done = a + chunk.size
        if until is None:
            encode_and_mux(self._container, stream)

    def write(self, rgb) -> None:
        """Append one (H, W, 3) uint8 sRGB frame (do not modify the array afterwards), or a
        :class:`relight.video_yuv.YuvFrame` of the writer's size (encoded as it is)."""
        if not isinstance(rgb, np.ndarray) and hasattr(rgb, "to_av"):
            if rgb.shape != (self.size[1], self.size[0], 3):
                raise InputError(f"frame must be {self.size[0]}x{self.size[1]}, got {rgb.shape[1]}x{rgb.shape[0]}")
        elif rgb.shape != (self.size[1], self.size[0], 3) or rgb.dtype != np.uint8:
            raise InputError(f"frame must be ({self.size[1]}, {self.size[0]}, 3) uint8, got {rgb.shape} {rgb.dtype}")
        self._writer.put((self.frames, rgb))
        self.frames += 1

    def __exit__(self, exc_type, exc, tb) -> None:
        try:
            self._writer.__exit__(exc_type, exc, tb)  # every frame encoded; raises its error if the block had none
            if exc_type is None:
                encode_and_mux(self._container, self._stream)
                if self._audio_stream is not None:
                    self._encode_audio(None)
        except BaseException as err:
            self._container.close()
            self._atomic.__exit__(type(err), err, err.__traceback__)
            raise
        self._container.close()
        self._atomic.__exit__(exc_type, exc, tb)
