"""``relight filter`` from a video into a video (:func:`filter_video`): decoded on a thread,
each frame through the per-frame path, encoded on another thread - H.264 in .mp4/.mov/.mkv/.avi,
VP9 in .webm - with every frame's timestamp kept and the audio copied packet for packet
(re-encoded only when the output container cannot hold its codec)."""

from __future__ import annotations

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

    from relight.background import WriterThread, read_ahead
    from relight.video_frame import frame_to_rgb
    from relight.video_read import MAX_VIDEO_FRAMES, METADATA_ERRORS, probe_video, release_frames
    from relight.video_write import add_video_stream, encode_and_mux, encode_video_frame
    from relight.video_yuv import YuvFrame

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
        options = x264_options(crf, preset) if VIDEO_CODECS[suffix] == "libx264" else \
            {"crf": str(crf + 12), "b": "0", "deadline": "realtime", "cpu-used": "8"}
        vout = add_video_stream(dst, VIDEO_CODECS[suffix], rate, (info.width, info.height), tb, options)
        vout.time_base = tb
        aout, resampler = None, None
        if ain is not None:
            allowed = AUDIO_COPY.get(suffix)
            name = ain.codec_context.name
            if allowed is None or name in allowed:
                aout = dst.add_stream_from_template(ain)
                res.audio = f"copied ({name})"
            else:
                codec = "libopus" if suffix == ".webm" else "aac"
                aout = dst.add_stream(codec, rate=48000 if codec == "libopus" else (ain.rate or 48000))
                aout.codec_context.layout = "stereo" if (ain.channels or 1) > 1 else "mono"
                resampler = av.AudioResampler(format="fltp" if codec == "aac" else "s16",
                                              layout=aout.codec_context.layout.name, rate=aout.rate)
                res.audio = f"re-encoded ({name} -> {codec})"
        bar = tqdm(total=info.frame_count or None, desc="filter", unit="frame", disable=not progress)
        streams = [vin] + ([ain] if ain is not None else [])
        state = {"frames": 0}

        def read():
            """Demux + decode + RGB conversion (a thread: FFmpeg releases the GIL)."""
            last_pts = None
            try:
                for packet in src.demux(*streams):
                    if packet.stream is ain:
                        if packet.dts is not None:
                            yield ("audio", packet)
                        continue
                    for frame in packet.decode():
                        release_frames(frame)
                        if state["frames"] >= MAX_VIDEO_FRAMES:
                            raise InputError(f"{inp}: more than {MAX_VIDEO_FRAMES} frames; trim the video")
                        # Kept in its planes where it can be (only the face's box is converted: a
                        # third of the frame's CPU at 720p), else RGB as displayed (upright).
                        rgb = YuvFrame.from_av(frame)
                        if rgb is None:
                            rgb = frame_to_rgb(frame)
                        if rgb.shape[:2] != (info.height, info.width):
                            raise InputError(f"{inp}: frame {state['frames']} is {rgb.shape[1]}x{rgb.shape[0]}, the "
                                             f"stream said {info.width}x{info.height}; variable-size streams are not "
                                             "supported")
                        pts = frame.pts if frame.pts is not None else (last_pts + 1 if last_pts is not None else 0)
                        if last_pts is not None and pts <= last_pts:
                            pts = last_pts + 1  # broken timestamps: keep them increasing
                        last_pts = pts
                        state["frames"] += 1
                        yield ("video", rgb, pts)
            except av.error.FFmpegError as exc:
                if state["frames"] == 0:
                    raise InputError(f"{inp}: not a readable video ({exc})") from None
                res.notes.append(f"the input ended early at frame {state['frames']} ({exc}); the frames before it "
                                 "were written")

        def write(item):
            """RGB conversion + encode + mux, and audio (the writer thread owns the output)."""
            if item[0] == "audio":
                packet = item[1]
                if resampler is None:
                    packet.stream = aout
                    dst.mux(packet)
                else:
                    for af in packet.decode():
                        for rf in resampler.resample(af):
                            rf.pts = None
                            encode_and_mux(dst, aout, rf)
                return
            _, rgb, pts = item
            encode_video_frame(dst, vout, rgb, pts, tb)

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
        if index == 0:
            raise InputError(f"{inp}: the video has no frames")
        encode_and_mux(dst, vout)
        if resampler is not None:
            encode_and_mux(dst, aout)
