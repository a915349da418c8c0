"""``relight filter`` from a video into a video (:func:`filter_video`): decoded on a thread,
each frame through the per-frame path, encoded on another thread - H.264 in .mp4/.mov/.mkv/.avi,
VP9 in .webm - with every frame's timestamp kept and the audio copied packet for packet
(re-encoded only when the output container cannot hold its codec)."""

from __future__ import annotations

import functools
from dataclasses import dataclass
from fractions import Fraction

from relight.errors import InputError
from relight.imageio import atomic_path
from relight.video_write import DEFAULT_PRESET, x264_options

#: Output containers and their video codecs.
VIDEO_CODECS = {".mp4": "libx264", ".mov": "libx264", ".mkv": "libx264", ".avi": "libx264", ".webm": "libvpx-vp9"}
#: Audio codecs each container takes as they are (others are re-encoded).
AUDIO_COPY = {".mp4": {"aac", "mp3", "alac", "opus"}, ".mov": {"aac", "mp3", "alac", "pcm_s16le"},
              ".mkv": None, ".webm": {"opus", "vorbis"}, ".avi": {"mp3", "pcm_s16le", "aac"}}


def filter_video(inp, out, pipeline, crf, res, progress, tqdm, preset: str = DEFAULT_PRESET):
    """Relight the video ``inp`` into the video ``out`` (its suffix picks the codec: VIDEO_CODECS;
    H.264 at x264's ``preset``) through ``pipeline`` (a :class:`FramePipeline`), booking the audio's
    fate in ``res``."""
    import av

    import relight.video_yuv  # noqa: F401 (OpenCV loaded here, before the reader thread needs it)
    from relight.video_read import METADATA_ERRORS, probe_video
    from relight.video_write import add_video_stream, encode_and_mux

    info = probe_video(inp)
    suffix = out.suffix.lower()
    if suffix not in VIDEO_CODECS:
        raise InputError(f"{out}: write {', '.join(VIDEO_CODECS)} (or give a folder for PNG frames)")
    if info.width % 2 or info.height % 2:
        raise InputError(f"{inp}: {info.width}x{info.height}; the output codec needs even sizes (crop the video)")
    with atomic_path(out) as tmp, av.open(str(inp), metadata_errors=METADATA_ERRORS) as src, \
            av.open(str(tmp), mode="w") as dst:
        vin = src.streams.video[0]
        vin.thread_type = "AUTO"
        ain = src.streams.audio[0] if src.streams.audio else None
        rate = vin.average_rate or vin.guessed_rate or Fraction(30)
        tb = vin.time_base or Fraction(1, 90000)
        vout = add_video_stream(dst, VIDEO_CODECS[suffix], rate, (info.width, info.height), tb,
                                _video_options(suffix, crf, preset))
        vout.time_base = tb
        aout, resampler = _audio_stream(dst, ain, suffix, res) if ain is not None else (None, None)
        bar = tqdm(total=info.frame_count or None, desc="filter", unit="frame", disable=not progress)
        streams = [vin] + ([ain] if ain is not None else [])
        output = _Output(dst, vout, aout, resampler, tb)
        index = _relight_frames(functools.partial(_read, src, streams, ain, inp, info, res), output.write,
                                pipeline, tb, bar)
        if index == 0:
            raise InputError(f"{inp}: the video has no frames")
        encode_and_mux(dst, vout)
        if resampler is not None:
            encode_and_mux(dst, aout)


def _video_options(suffix: str, crf: int, preset: str) -> dict:
    """The video encoder's options: x264's for H.264, realtime VP9's (crf + 12) for .webm."""
    return x264_options(crf, preset) if VIDEO_CODECS[suffix] == "libx264" else \
        {"crf": str(crf + 12), "b": "0", "deadline": "realtime", "cpu-used": "8"}


def _audio_stream(dst, ain, suffix: str, res):
    """The output's audio stream for the input's ``ain``: copied when the container takes its codec,
    else re-encoded (Opus in .webm, AAC elsewhere) through a resampler; (stream, resampler or None)."""
    import av

    allowed = AUDIO_COPY.get(suffix)
    name = ain.codec_context.name
    if allowed is None or name in allowed:
        aout = dst.add_stream_from_template(ain)
        res.audio = f"copied ({name})"
        return aout, None
    codec = "libopus" if suffix == ".webm" else "aac"
    aout = dst.add_stream(codec, rate=48000 if codec == "libopus" else (ain.rate or 48000))
    aout.codec_context.layout = "stereo" if (ain.channels or 1) > 1 else "mono"
    resampler = av.AudioResampler(format="fltp" if codec == "aac" else "s16",
                                  layout=aout.codec_context.layout.name, rate=aout.rate)
    res.audio = f"re-encoded ({name} -> {codec})"
    return aout, resampler


def _read(src, streams, ain, inp, info, res):
    """Demux + decode + RGB conversion (a thread: FFmpeg releases the GIL): yields ("audio",
    packet) and ("video", frame - a YuvFrame or (H, W, 3) uint8 RGB -, pts)."""
    import av

    from relight.video_read import release_frames

    frames = 0
    last_pts = None
    try:
        for packet in src.demux(*streams):
            if packet.stream is ain:
                if packet.dts is not None:
                    yield ("audio", packet)
                continue
            for frame in packet.decode():
                release_frames(frame)
                rgb = _frame_in(frame, frames, inp, info)
                pts = frame.pts if frame.pts is not None else (last_pts + 1 if last_pts is not None else 0)
                if last_pts is not None and pts <= last_pts:
                    pts = last_pts + 1  # broken timestamps: keep them increasing
                last_pts = pts
                frames += 1
                yield ("video", rgb, pts)
    except av.error.FFmpegError as exc:
        if frames == 0:
            raise InputError(f"{inp}: not a readable video ({exc})") from None
        res.notes.append(f"the input ended early at frame {frames} ({exc}); the frames before it "
                         "were written")


def _frame_in(frame, index: int, inp, info):
    """The decoded frame number ``index`` kept in its planes (a YuvFrame) where it can be, else
    (H, W, 3) uint8 RGB as displayed; InputError past MAX_VIDEO_FRAMES or at a size the stream did not say."""
    from relight.video_frame import frame_to_rgb
    from relight.video_read import MAX_VIDEO_FRAMES
    from relight.video_yuv import YuvFrame

    if index >= MAX_VIDEO_FRAMES:
        raise InputError(f"{inp}: more than {MAX_VIDEO_FRAMES} frames; trim the video")
    # Kept in its planes where it can be (only the face's box is converted: a
    # third of the frame's CPU at 720p), else RGB as displayed (upright).
    rgb = YuvFrame.from_av(frame)
    if rgb is None:
        rgb = frame_to_rgb(frame)
    if rgb.shape[:2] != (info.height, info.width):
        raise InputError(f"{inp}: frame {index} is {rgb.shape[1]}x{rgb.shape[0]}, the "
                         f"stream said {info.width}x{info.height}; variable-size streams are not "
                         "supported")
    return rgb


@dataclass
class _Output:
    """The output file's streams (the writer thread owns them): ``resampler`` None when the audio is copied."""

    dst: object
    vout: object
    aout: object
    resampler: object
    tb: Fraction

    def write(self, item) -> None:
        """RGB conversion + encode + mux, and audio (the writer thread owns the output)."""
        from relight.video_write import encode_and_mux, encode_video_frame

        if item[0] == "audio":
            packet = item[1]
            if self.resampler is None:
                packet.stream = self.aout
                self.dst.mux(packet)
            else:
                for af in packet.decode():
                    for rf in self.resampler.resample(af):
                        rf.pts = None
                        encode_and_mux(self.dst, self.aout, rf)
            return
        _, rgb, pts = item
        encode_video_frame(self.dst, self.vout, rgb, pts, self.tb)


def _relight_frames(read, write, pipeline, tb, bar) -> int:
    """The frames of ``read()`` (a generator, run on a reader thread) through ``pipeline``, written
    by ``write`` on a writer thread with the audio between them in order; returns the video frames read."""
    from relight.background import WriterThread, read_ahead

    index = 0
    try:
        with WriterThread(write, name="relight-filter-writer") as writer, pipeline:
            pipeline.done = lambda frame_out, pts: writer.put(("video", frame_out, pts))
            for item in read_ahead(read, name="relight-filter-reader"):
                if item[0] == "video":
                    _, rgb, pts = item
                    pipeline.put(rgb, float(pts * tb), index, pts)
                    index += 1
                    bar.update(1)
                else:
                    writer.put(item)
            pipeline.drain()
    finally:
        bar.close()
    return index
