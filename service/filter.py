"""``relight filter``: a virtual-camera-style batch filter over a video or an image sequence.

Decodes any container FFmpeg reads (PyAV), relights each frame with :class:`FramePath`, and
writes the result: H.264 in .mp4/.mov/.mkv/.avi, VP9 in .webm, or PNG frames when OUT is a
folder. The audio stream is copied packet for packet (re-encoded to AAC only when the output
container cannot hold its codec) and every frame keeps its timestamp, so variable frame rate
survives. OUT appears only complete (temporary file + rename). Frames where nothing can be done
(no face) pass through unchanged and are counted.

The per-frame timings cover the per-frame path only (track + pose + relight + warp +
composite); decoding and encoding run beside it and are reported separately.
"""

from __future__ import annotations

import json
import os
import queue
import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from fractions import Fraction
from pathlib import Path

import numpy as np

from relight.errors import InputError, OutputError, os_reason
from relight.imageio import atomic_path, clean_stale_temps, dir_mode, temp_prefix
from relight.numerics import EPS_NORM
from relight.video import DEFAULT_CRF

from ..engine.composite import DEFAULT_MODE, DEFAULT_REGION

#: Image files read as a sequence when IN is a folder.
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".exr", ".tif", ".tiff", ".bmp")
MAX_SEQUENCE = 100_000
#: Output containers and their video codecs.
VIDEO_CODECS = {".mp4": "libx264", ".mov": "libx264", ".mkv": "libx264", ".avi": "libx264", ".webm": "libvpx-vp9"}
#: Audio codecs each container takes as they are (others are re-encoded).
AUDIO_COPY = {".mp4": {"aac", "mp3", "alac", "opus"}, ".mov": {"aac", "mp3", "alac", "pcm_s16le"},
              ".mkv": None, ".webm": {"opus", "vorbis"}, ".avi": {"mp3", "pcm_s16le", "aac"}}


@dataclass
class FilterResult:
    out: Path
    frames: int = 0
    faces: int = 0
    passed_through: int = 0
    audio: str = "none"
    head_rotation: dict = field(default_factory=dict)
    live_light: dict = field(default_factory=dict)
    timings_ms: dict = field(default_factory=dict)
    wall_s: float = 0.0
    start_s: float = 0.0
    notes: list = field(default_factory=list)

    def summary(self) -> str:
        t = self.timings_ms.get("total", {})
        return (f"{self.frames} frames ({self.faces} with a face, {self.passed_through} passed through), audio "
                f"{self.audio}; a frame's latency through the per-frame path median "
                f"{t.get('median', 0):.1f} ms, p99 {t.get('p99', 0):.1f} ms; {self.wall_s:.1f} s in all (start "
                f"{self.start_s:.1f} s, {self.frames / max(self.wall_s - self.start_s, EPS_NORM):.1f} frames per "
                "second "
                "after it)")


def _stats(values) -> dict:
    v = np.asarray(values, dtype=np.float64)
    if not v.size:
        return {}
    return {"median": float(np.median(v)), "p90": float(np.percentile(v, 90)), "p99": float(np.percentile(v, 99)),
            "max": float(v.max()), "mean": float(v.mean())}


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


def _threaded(gen_fn, maxsize: int = 4):
    """Run the generator ``gen_fn()`` on a thread and yield its items here (its exceptions are
    re-raised here; leaving early stops it)."""
    q: queue.Queue = queue.Queue(maxsize)
    stop = threading.Event()

    def run():
        try:
            for item in gen_fn():
                while not stop.is_set():
                    try:
                        q.put(("item", item), timeout=0.1)
                        break
                    except queue.Full:
                        continue
                if stop.is_set():
                    return
            q.put(("end", None))
        except BaseException as exc:  # handed to the consumer
            q.put(("error", exc))

    th = threading.Thread(target=run, name="relight-filter-reader", daemon=True)
    th.start()
    try:
        while True:
            kind, item = q.get()
            if kind == "end":
                return
            if kind == "error":
                raise item
            yield item
    finally:
        stop.set()
        while th.is_alive():
            try:
                q.get_nowait()
            except queue.Empty:
                th.join(timeout=0.05)


class _Writer:
    """Calls ``fn(item)`` for each item put, in order, on its own thread (bounded queue); an
    error there is raised in the caller at the next put or at exit."""

    def __init__(self, fn, maxsize: int = 4):
        self.fn = fn
        self.q: queue.Queue = queue.Queue(maxsize)
        self.error: BaseException | None = None
        self.th = threading.Thread(target=self._run, name="relight-filter-writer", daemon=True)

    def _run(self):
        while True:
            item = self.q.get()
            if item is None:
                return
            if self.error is None:
                try:
                    self.fn(item)
                except BaseException as exc:
                    self.error = exc

    def __enter__(self):
        self.th.start()
        return self

    def put(self, item):
        if self.error is not None:
            raise self.error
        self.q.put(item)

    def __exit__(self, exc_type, exc, tb):
        self.q.put(None)
        self.th.join()
        if exc_type is None and self.error is not None:
            raise self.error


def run_filter(inp, out, bundle, env, *, mode: str = DEFAULT_MODE, fixed_env: bool = False, strength: float = 1.0,
               exposure: float = 0.0, focal: float | None = None, fps: float = 30.0, crf: int = DEFAULT_CRF,
               region: str = DEFAULT_REGION,
               report_dir=None, virtual_camera: bool = False, progress: bool = True, frame_path=None,
               start_time: float | None = None) -> FilterResult:
    """Relight the faces of ``inp`` (a video file or a folder of images) into ``out``."""
    from tqdm import tqdm

    from ..engine.frame_path import FramePath

    t_start = time.perf_counter() if start_time is None else start_time
    inp, out = Path(inp), Path(out)
    if inp.resolve() == out.resolve():
        raise InputError(f"{out}: the output would overwrite the input; choose another name")
    fp = frame_path or FramePath(bundle, env, mode=mode, strength=strength, fixed_env=fixed_env, focal=focal,
                                 exposure=exposure, region=region)
    res = FilterResult(out=out)
    res.start_s = time.perf_counter() - t_start
    stages: dict[str, list] = {k: [] for k in ("track", "pose", "relight", "light", "warp", "composite", "total")}
    cam = None

    def handle(rgb, t, index):
        return record(rgb, *fp.process(rgb, t), index)

    def record(rgb, frame_out, info, index):
        nonlocal cam
        res.frames += 1
        if info.face:
            res.faces += 1
            res.head_rotation[str(index)] = [round(a, 3) for a in info.angles]
            if info.light is not None:
                res.live_light[str(index)] = info.light.as_json()
        else:
            res.passed_through += 1
        for k in stages:
            stages[k].append(info.timings.get(k, 0.0))
        if virtual_camera:
            if cam is None:
                from .virtual_camera import VirtualCamera

                cam = VirtualCamera((rgb.shape[1], rgb.shape[0]), fps)
            cam.send(frame_out if isinstance(frame_out, np.ndarray) else frame_out.to_rgb())
        return frame_out

    try:
        if inp.is_dir():
            _filter_sequence(inp, out, handle, fps, crf, res, progress, tqdm)
        elif is_folder_output(out):
            _filter_video_frames(inp, out, FramePipeline(fp, record), res, progress, tqdm)
        else:
            _filter_video(inp, out, FramePipeline(fp, record), crf, res, progress, tqdm)
    finally:
        if cam is not None:
            cam.close()
    if res.frames == 0:
        raise InputError(f"{inp}: no frames could be read")
    res.timings_ms = {k: _stats(v) for k, v in stages.items()}
    res.wall_s = time.perf_counter() - t_start
    if res.faces == 0:
        res.notes.append("no face was found in any frame: the output is the input, unchanged")
    if report_dir is not None:
        write_report(Path(report_dir), res, inp)
    return res


def _light_summary(lights: dict) -> dict:
    """Median residual and the count of each status over the frames with a light estimate."""
    if not lights:
        return {}
    res = [v["residual"] for v in lights.values() if v["residual"] == v["residual"]]
    status: dict = {}
    for v in lights.values():
        status[v["status"]] = status.get(v["status"], 0) + 1
    return {"frames": len(lights), "median_residual": float(np.median(res)) if res else None, "status": status}


def write_report(folder: Path, res: FilterResult, inp: Path) -> Path:
    """``report.json``: head_rotation {frame index: [yaw, pitch, roll] deg}, timings, counts."""
    folder.mkdir(parents=True, exist_ok=True)
    doc = {"input": str(inp), "output": str(res.out), "frames": res.frames, "faces": res.faces,
           "passed_through": res.passed_through, "audio": res.audio,
           "head_rotation": res.head_rotation,
           "live_light": res.live_light,
           "live_light_summary": _light_summary(res.live_light),
           "live_light_convention": "mode transfer, per frame: direction (unit, camera space: +X right, +Y up, +Z "
                                    "toward the camera) the light comes from, intensity (flashes of power, the live "
                                    "exposure), colour (linear rgb, luminance 1), residual (RMS of the fit relative to "
                                    "the face's), pixels fitted, status (ok | dark | clipped | few pixels)",
           "head_rotation_convention": "yaw, pitch, roll in degrees, R = Ry(yaw) Rx(pitch) Rz(roll) about camera "
                                       "+Y, +X, +Z (relight camera space), relative to the bundle's reference pose",
           "timings_ms": res.timings_ms, "wall_s": res.wall_s, "start_s": res.start_s, "notes": res.notes}
    path = folder / "report.json"
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(doc, indent=1))
    return path


def _filter_sequence(folder, out, handle, fps, crf, res, progress, tqdm):
    from relight.imageio import write_image
    from relight.video import VideoWriter

    files = _sequence(folder)
    first = _read_rgb8(files[0])
    size = (first.shape[1], first.shape[0])
    if out.suffix.lower() in VIDEO_CODECS:
        if size[0] % 2 or size[1] % 2:
            raise InputError(f"{folder}: images are {size[0]}x{size[1]}; H.264 needs even sizes (crop them)")
        with VideoWriter(out, fps, size, crf=crf) as wr:
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


def _filter_video_frames(inp, out, pipeline, res, progress, tqdm):
    """A video into a folder of PNG frames (no second encode: what a measurement wants; the
    audio is left out)."""
    import av

    from relight.imageio import write_image
    from relight.video import METADATA_ERRORS, probe_video, read_frames

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


class FramePipeline:
    """The per-frame path in two stages on two threads: :meth:`FramePath.front` (track, pose)
    of frame N+1 on the calling thread beside :meth:`FramePath.back` (relight, live light, warp,
    composite) of frame N on a worker - OpenCV, PoCL and BLAS release the GIL, so the second
    core does work the serial path left it idle for (measured on the synthetic live clips:
    25-27 -> 21 ms a frame at 640x360, 40 -> 34 at 1280x720). The tracker takes the live-lit
    reference a frame later than in the serial path (it is handed over between frames:
    :meth:`FramePath.commit_reference`), so runs are repeatable. ``record(rgb, out, info,
    index)`` books a finished frame and returns the frame to write; ``done(out, pts)`` writes it."""

    def __init__(self, fp, record):
        from concurrent.futures import ThreadPoolExecutor

        self.fp, self.record = fp, record
        self.done = None
        self._pool = ThreadPoolExecutor(1, thread_name_prefix="relight-back")
        self._pending = None
        self.wake = None  # called (on the worker) when a frame's second stage ends: see poll()

    def put(self, rgb, t: float, index: int, pts) -> None:
        front = self.fp.front(rgb, t)
        self.drain()
        fut = self._pool.submit(self.fp.back, front, True)
        if self.wake is not None:
            fut.add_done_callback(lambda _f: self.wake())
        self._pending = (fut, rgb, index, pts)

    def poll(self) -> bool:
        """Hand the frame in flight to ``done`` if its second stage has ended (a live source
        does not wait for the next frame to deliver this one: a frame's less latency)."""
        if self._pending is not None and self._pending[0].done():
            self.drain()
            return True
        return False

    def drain(self) -> None:
        """Finish the frame in flight (if any) and hand it to ``done``."""
        if self._pending is None:
            return
        fut, rgb, index, pts = self._pending
        self._pending = None
        frame_out, info = fut.result()
        self.fp.commit_reference()
        self.done(self.record(rgb, frame_out, info, index), pts)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        if self._pending is not None:  # an error elsewhere: let the worker finish, drop its frame
            self._pending[0].exception()
            self._pending = None
        self._pool.shutdown(wait=True)
        return False


def _filter_video(inp, out, pipeline, crf, res, progress, tqdm):
    import av

    from relight.video import MAX_VIDEO_FRAMES, METADATA_ERRORS, frame_to_rgb, probe_video, release_frames, to_yuv
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
        vout = dst.add_stream(VIDEO_CODECS[suffix], rate=rate)
        vout.width, vout.height = info.width, info.height
        vout.pix_fmt = "yuv420p"
        tb = vin.time_base or Fraction(1, 90000)
        vout.time_base = tb
        vout.codec_context.time_base = tb
        vout.options = {"crf": str(crf), "preset": "superfast"} if VIDEO_CODECS[suffix] == "libx264" else \
            {"crf": str(crf + 12), "b": "0", "deadline": "realtime", "cpu-used": "8"}
        cc = vout.codec_context
        cc.colorspace, cc.color_range, cc.color_primaries, cc.color_trc = 1, 1, 1, 13
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
                            for p in aout.encode(rf):
                                dst.mux(p)
                return
            _, rgb, pts = item
            outf = to_yuv(rgb) if isinstance(rgb, np.ndarray) else rgb.to_av()
            outf.pts = pts
            outf.time_base = tb
            for p in vout.encode(outf):
                dst.mux(p)

        index = 0
        try:
            with _Writer(write) as writer, pipeline:
                pipeline.done = lambda frame_out, pts: writer.put(("video", frame_out, pts))
                for item in _threaded(read):
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
        for p in vout.encode(None):
            dst.mux(p)
        if resampler is not None:
            for p in aout.encode(None):
                dst.mux(p)
