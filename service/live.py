"""``relight live``: a live camera in, relit frames out to a virtual camera, a preview page and/or
a recording.

Threads (no queue grows anywhere - the latest frame wins at each hand-over):

* the **camera reader** decodes the camera (FFmpeg's device inputs through PyAV: v4l2 on Linux,
  avfoundation on macOS, dshow on Windows) or a video file played at its own rate and looped,
  and leaves each frame in a one-frame slot (:class:`LatestFrame`); a frame the loop had no time
  for is replaced and counted as dropped;
* the **relight loop** (the caller's thread, plus the second stage of
  :class:`relight.service.filter.FramePipeline` on a worker) takes the newest frame, relights it
  and leaves the result in the output slot;
* the **output clock** ticks at the output rate and hands the newest relit frame to the sinks:
  the virtual camera (pyvirtualcam: v4l2loopback, OBS Virtual Camera), the recording (H.264,
  constant rate: a frame the loop did not renew in time is shown again, as a camera would) and
  the preview page (MJPEG on loopback).

Controls while running: keys on a terminal (``e`` next environment, ``[``/``]`` strength -/+
0.1, ``m`` next mode, ``q`` quit) or signals (``SIGUSR1`` next environment, ``SIGUSR2`` strength
1 -> 0.5 -> 0 -> 1; ``SIGINT``/``SIGTERM`` stop). A status line once a second: frames per second
in and out, dropped, latency (camera frame read -> relit frame ready), CPU share, the live light.

Units: frames are sRGB 8-bit RGB at the camera's size; times in seconds (``perf_counter``).
"""

from __future__ import annotations

import os
import platform
import signal
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from relight.errors import InputError
from relight.video import DEFAULT_CRF

from ..engine.composite import DEFAULT_MODE, DEFAULT_REGION, MODES
from .virtual_camera import VirtualCamera, check_virtual_camera_backend

#: Strength steps SIGUSR2 cycles through, and a key's strength step.
STRENGTH_CYCLE = (1.0, 0.5, 0.0)
STRENGTH_STEP = 0.1
#: Seconds between status lines (and the window the rates are measured over).
STATUS_PERIOD = 1.0
#: Largest camera frame accepted (pixels): 4K.
MAX_CAMERA_PIXELS = 3840 * 2160
#: x264 preset of a recording: the fastest (the relight needs the cores; ~2x the bytes of veryfast).
RECORD_PRESET = "ultrafast"
#: The MJPEG preview's JPEG quality.
PREVIEW_QUALITY = 80


# ---------------------------------------------------------------------------------- camera
def device_input(camera: str | None, system: str | None = None) -> tuple[str, str]:
    """(FFmpeg input format, device name) of ``camera`` on this OS: an index (``0``) or a device
    name/path as the OS's FFmpeg input takes it."""
    system = system or platform.system()
    camera = "0" if camera in (None, "") else str(camera)
    if system == "Linux":
        return "v4l2", f"/dev/video{camera}" if camera.isdigit() else camera
    if system == "Darwin":
        return "avfoundation", camera  # an index or a name; "none" audio is implied
    if system == "Windows":
        return "dshow", camera if camera.startswith("video=") else f"video={camera}"
    raise InputError(f"no camera input for {system}: pass a video file as --camera")


class LatestFrame:
    """A one-item slot: :meth:`put` replaces what is there (counting it as dropped when nobody
    took it), :meth:`take` waits for something newer than the last taken."""

    def __init__(self):
        self._cond = threading.Condition()
        self._item = None
        self._fresh = False
        self.put_count = 0
        self.dropped = 0

    def put(self, item) -> None:
        with self._cond:
            if self._fresh:
                self.dropped += 1
            self._item, self._fresh = item, True
            self.put_count += 1
            self._cond.notify_all()

    def wake(self) -> None:
        """Wake a waiting :meth:`take` (it returns None unless something fresh came)."""
        with self._cond:
            self._cond.notify_all()

    def take(self, timeout: float):
        """The newest item not taken before, or None after ``timeout`` seconds."""
        with self._cond:
            if not self._fresh:
                self._cond.wait(timeout)
            if not self._fresh:
                return None
            self._fresh = False
            return self._item

    def peek(self):
        """The newest item, taken or not (None before the first)."""
        with self._cond:
            return self._item


@dataclass
class CameraFrame:
    rgb: np.ndarray
    t: float  # perf_counter when read
    index: int


class CameraReader:
    """Reads a camera device or a video file into a :class:`LatestFrame` on its own thread."""

    def __init__(self, camera: str | None, *, size: tuple[int, int] | None, fps: float | None,
                 loop: bool = True):
        self.spec = camera
        self.size = size
        self.fps = fps
        self.loop = loop
        self.slot = LatestFrame()
        self.error: BaseException | None = None
        self.ended = threading.Event()
        self._stop = threading.Event()
        self.is_file = camera is not None and Path(camera).is_file()
        self.rate = None  # frames per second of the source (the file's, or the device's)
        self._open()
        self._thread = threading.Thread(target=self._run, name="relight-camera", daemon=True)

    def _open(self) -> None:
        import av

        if self.is_file:
            from relight.video import probe_video

            info = probe_video(self.spec)
            self.rate = float(info.fps) if info.fps else 30.0
            self.name = str(self.spec)
            return
        fmt, name = device_input(self.spec)
        options = {}
        if self.size:
            options["video_size"] = f"{self.size[0]}x{self.size[1]}"
        if self.fps:
            options["framerate"] = f"{self.fps:g}"
        try:
            self.container = av.open(name, format=fmt, options=options, timeout=5.0)
        except (av.FFmpegError, OSError) as exc:
            raise InputError(f"camera {name!r} ({fmt}) does not open: {exc}; name a device (--camera 0, "
                             f"/dev/video2, 'FaceTime HD Camera') or a video file") from None
        st = self.container.streams.video[0]
        self.rate = float(st.average_rate or st.guessed_rate or self.fps or 30)
        self.name = f"{name} ({fmt})"

    def start(self) -> CameraReader:
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)
        c = getattr(self, "container", None)
        if c is not None:
            c.close()

    def _fit(self, rgb):
        h, w = rgb.shape[:2]
        if h * w > MAX_CAMERA_PIXELS:
            raise InputError(f"camera frames of {w}x{h} are over {MAX_CAMERA_PIXELS} pixels: pass a smaller --size")
        if not isinstance(rgb, np.ndarray):  # a frame kept in its planes (relight.video_yuv)
            if not self.size or (w, h) == tuple(self.size):
                return rgb
            rgb = rgb.to_rgb()
        if self.size and (w, h) != tuple(self.size):
            import cv2

            rgb = cv2.resize(rgb, tuple(self.size), interpolation=cv2.INTER_AREA if w > self.size[0]
                             else cv2.INTER_LINEAR)
        return np.ascontiguousarray(rgb)

    def _frames(self):
        from relight.video import frame_to_rgb, read_frames_raw
        from relight.video_yuv import YuvFrame

        if not self.is_file:
            for frame in self.container.decode(video=0):
                yield frame_to_rgb(frame)
            return
        while True:
            n = 0
            # A file's frames kept in their planes where they can be (only the face's box is
            # converted: relight.video_yuv), else RGB as displayed.
            for frame in read_frames_raw(self.spec):
                n += 1
                yuv = YuvFrame.from_av(frame)
                yield yuv if yuv is not None else frame_to_rgb(frame)
            if not self.loop or n == 0:
                return

    def _run(self) -> None:
        period = 1.0 / self.rate if self.is_file else 0.0
        t0 = time.perf_counter()
        try:
            for i, rgb in enumerate(self._frames()):
                if self._stop.is_set():
                    return
                if period:  # a file plays at its own rate, as a camera would deliver it
                    wait = t0 + i * period - time.perf_counter()
                    if wait > 0:
                        self._stop.wait(wait)
                    if self._stop.is_set():
                        return
                self.slot.put(CameraFrame(self._fit(rgb), time.perf_counter(), i))
        except BaseException as exc:  # handed to the loop
            self.error = exc
        finally:
            self.ended.set()


# ---------------------------------------------------------------------------------- preview
class PreviewServer:
    """The relit frames as MJPEG on loopback (``http://127.0.0.1:PORT/``): a browser shows it."""

    def __init__(self, slot: LatestFrame, port: int = 0):
        from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

        self.slot = slot
        preview = self

        class Handler(BaseHTTPRequestHandler):
            def log_message(self, *args):  # quiet
                pass

            def do_GET(self):  # noqa: N802 (http.server's name)
                if self.path == "/":
                    body = (b"<!doctype html><title>relight live</title><body style='margin:0;background:#000'>"
                            b"<img src='/stream.mjpg' style='width:100%'></body>")
                    self.send_response(200)
                    self.send_header("Content-Type", "text/html")
                    self.send_header("Content-Length", str(len(body)))
                    self.end_headers()
                    self.wfile.write(body)
                    return
                if self.path != "/stream.mjpg":
                    self.send_error(404)
                    return
                self.send_response(200)
                self.send_header("Content-Type", "multipart/x-mixed-replace; boundary=frame")
                self.end_headers()
                last = None
                try:
                    while not preview.closed.is_set():
                        item = preview.slot.peek()
                        if item is None or item is last:
                            preview.closed.wait(0.01)
                            continue
                        last = item
                        jpeg = preview.encode(item.as_rgb())
                        self.wfile.write(b"--frame\r\nContent-Type: image/jpeg\r\nContent-Length: "
                                         + str(len(jpeg)).encode() + b"\r\n\r\n" + jpeg + b"\r\n")
                except (BrokenPipeError, ConnectionResetError):
                    return

        self.closed = threading.Event()
        self.httpd = ThreadingHTTPServer(("127.0.0.1", port), Handler)
        self.httpd.daemon_threads = True
        self.url = f"http://127.0.0.1:{self.httpd.server_address[1]}/"
        self._thread = threading.Thread(target=self.httpd.serve_forever, name="relight-preview", daemon=True)
        self._thread.start()

    @staticmethod
    def encode(rgb: np.ndarray) -> bytes:
        import cv2

        bgr = cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)
        ok, buf = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, PREVIEW_QUALITY])
        return buf.tobytes() if ok else b""

    def close(self) -> None:
        self.closed.set()
        self.httpd.shutdown()
        self.httpd.server_close()


# ---------------------------------------------------------------------------------- the loop
@dataclass
class RelitFrame:
    rgb: object  # (H, W, 3) uint8 sRGB, or a relight.video_yuv.YuvFrame (as_rgb() converts it once)
    t_camera: float  # when the camera frame was read
    t_ready: float  # when its relit frame was ready
    index: int
    _rgb: np.ndarray | None = None

    def as_rgb(self) -> np.ndarray:
        """The frame as (H, W, 3) uint8 sRGB (a YuvFrame converted on first use, then kept)."""
        if self._rgb is None:
            from relight.video_yuv import as_rgb

            self._rgb = as_rgb(self.rgb)
        return self._rgb


@dataclass
class LiveResult:
    """What a ``relight live`` run did (``--stats-json`` writes it)."""

    camera: str = ""
    size: tuple[int, int] = (0, 0)
    wall_s: float = 0.0
    frames_in: int = 0
    frames_relit: int = 0
    frames_out: int = 0  # frames the sinks got (the output clock's ticks once a frame existed)
    dropped: int = 0
    faces: int = 0
    fps_in: float = 0.0
    fps_relit: float = 0.0
    fps_out: float = 0.0
    latency_ms: dict = field(default_factory=dict)
    cpu_percent: float = 0.0
    virtual_camera: str | None = None
    record: str | None = None
    preview: str | None = None
    stopped_by: str = ""
    switches: list = field(default_factory=list)

    def as_json(self) -> dict:
        from dataclasses import asdict

        return asdict(self)


class Controls:
    """The settings a running loop takes from keys and signals (applied between frames)."""

    def __init__(self, envs: list[str], mode: str, strength: float):
        if not envs:
            raise InputError("no environment: pass --env (a .exr/.hdr/.png file or builtin:NAME)")
        self.envs = list(envs)
        self.env_i = 0
        self.mode = mode
        self.strength = float(strength)
        self.stop_reason = ""
        self.changed = threading.Event()
        self.stop = threading.Event()

    def next_env(self, *_):
        self.env_i = (self.env_i + 1) % len(self.envs)
        self.changed.set()

    def cycle_strength(self, *_):
        later = [s for s in STRENGTH_CYCLE if s < self.strength - 1e-6]
        self.strength = later[0] if later else STRENGTH_CYCLE[0]
        self.changed.set()

    def step_strength(self, step: float):
        self.strength = float(np.clip(round(self.strength + step, 2), 0.0, 1.0))
        self.changed.set()

    def next_mode(self):
        self.mode = MODES[(MODES.index(self.mode) + 1) % len(MODES)]
        self.changed.set()

    def quit(self, reason: str):
        self.stop_reason = self.stop_reason or reason
        self.stop.set()

    def key(self, ch: str) -> None:
        {"e": self.next_env, "]": lambda: self.step_strength(STRENGTH_STEP),
         "[": lambda: self.step_strength(-STRENGTH_STEP), "m": self.next_mode,
         "q": lambda: self.quit("key q")}.get(ch, lambda: None)()


def _key_reader(controls: Controls):
    """Read single keys from a terminal (POSIX) until stopped; returns a restore function."""
    if not sys.stdin.isatty() or os.name != "posix":
        return lambda: None
    import select
    import termios
    import tty

    fd = sys.stdin.fileno()
    saved = termios.tcgetattr(fd)
    tty.setcbreak(fd)

    def run():
        while not controls.stop.is_set():
            r, _, _ = select.select([fd], [], [], 0.2)
            if r:
                controls.key(os.read(fd, 1).decode(errors="ignore"))

    threading.Thread(target=run, name="relight-keys", daemon=True).start()
    return lambda: termios.tcsetattr(fd, termios.TCSADRAIN, saved)


def _install_signals(controls: Controls):
    """SIGINT/SIGTERM stop, SIGUSR1/SIGUSR2 switch (main thread only); returns a restore function."""
    if threading.current_thread() is not threading.main_thread():
        return lambda: None
    saved = {}

    def stop(signum, _frame):
        controls.quit(signal.Signals(signum).name)

    handlers = {signal.SIGINT: stop, signal.SIGTERM: stop}
    if hasattr(signal, "SIGUSR1"):
        handlers[signal.SIGUSR1] = controls.next_env
        handlers[signal.SIGUSR2] = controls.cycle_strength
    for s, h in handlers.items():
        saved[s] = signal.signal(s, h)

    def restore():
        for s, h in saved.items():
            signal.signal(s, h)
    return restore


class StatusLine:
    """One status line a second: rewritten in place on a terminal, a line per period in a log."""

    def __init__(self, stream=None, period: float = STATUS_PERIOD):
        self.stream = stream or sys.stderr
        self.tty = self.stream.isatty()
        self.period = period
        self.t_last = time.perf_counter()
        self.cpu_last = time.process_time()
        self.counts_last = (0, 0)
        self.latencies: list[float] = []
        self.light = ""

    def due(self) -> bool:
        return time.perf_counter() - self.t_last >= self.period

    def show(self, frames_in: int, relit: int, dropped: int, controls: Controls) -> float:
        now, cpu = time.perf_counter(), time.process_time()
        dt = max(now - self.t_last, 1e-6)
        cpu_share = 100.0 * (cpu - self.cpu_last) / dt
        a, b = self.counts_last
        lat = f"{np.median(self.latencies):.0f} ms" if self.latencies else "-"
        env = Path(controls.envs[controls.env_i]).name if not controls.envs[controls.env_i].startswith("builtin:") \
            else controls.envs[controls.env_i]
        line = (f"in {(frames_in - a) / dt:5.1f} fps  out {(relit - b) / dt:5.1f} fps  dropped {dropped}  "
                f"latency {lat}  CPU {cpu_share:3.0f}%  {env} x{controls.strength:.2f} {controls.mode}"
                f"{'  light ' + self.light if self.light else ''}")
        self.stream.write(("\r\x1b[2K" + line) if self.tty else line + "\n")
        self.stream.flush()
        self.t_last, self.cpu_last, self.counts_last = now, cpu, (frames_in, relit)
        self.latencies = []
        return cpu_share

    def close(self):
        if self.tty:
            self.stream.write("\n")
            self.stream.flush()


def _light_text(light) -> str:
    if light is None or light.status != "ok":
        return ""
    x, y, z = light.direction
    az, el = np.degrees(np.arctan2(x, z)), np.degrees(np.arcsin(np.clip(y, -1, 1)))
    return f"from az {az:+.0f} el {el:+.0f} deg"


def run_live(bundle, envs: list[str], *, camera: str | None = None, size: tuple[int, int] | None = None,
             fps: float | None = None, duration: float | None = None, mode: str = DEFAULT_MODE,
             region: str = DEFAULT_REGION, strength: float = 1.0, focal=None, virtual_camera: bool = False,
             preview: bool = False, preview_port: int = 0, record: str | os.PathLike | None = None,
             crf: int = DEFAULT_CRF, status=None, on_ready=None) -> LiveResult:
    """Relight a live camera (or a looped file) until ``duration`` seconds pass, ``q``, or a stop
    signal. ``bundle``: a loaded :class:`relight.kernels.bundle.Bundle`; ``envs``: environments
    (paths or ``builtin:NAME``) switched in turn. ``on_ready(result)`` is called once the sinks
    are open (the preview's URL is known)."""
    import relight
    from relight.video import VideoWriter

    from ..engine.frame_path import FramePath
    from .filter import FramePipeline

    if mode not in MODES:
        raise InputError(f"mode {mode!r}: use one of {', '.join(MODES)}")
    if duration is not None and not (np.isfinite(duration) and duration > 0):
        raise InputError(f"--duration {duration}: use a positive number of seconds")
    if virtual_camera:
        check_virtual_camera_backend()  # before the camera or the bundle's kernels are touched
    controls = Controls(envs, mode, strength)
    env_arrays = {}

    def env_array(i):
        if i not in env_arrays:
            env_arrays[i] = relight.load_environment(controls.envs[i])
        return env_arrays[i]

    env_array(0)
    reader = CameraReader(camera, size=size, fps=fps)
    res = LiveResult(camera=reader.name)
    out_fps = float(fps or reader.rate or 30.0)
    # a live source: the person's maps made beside the frames, not in one of them
    fp = FramePath(bundle, env_array(0), mode=mode, strength=strength, focal=focal, region=region,
                   live_source=True)
    relit_slot = LatestFrame()
    status = status if status is not None else StatusLine()
    restore_keys = _key_reader(controls)
    restore_signals = _install_signals(controls)
    cam = writer = pv = None
    latencies: list[float] = []
    stage = {"relit": 0, "faces": 0, "out": 0}
    t_start = time.perf_counter()
    cpu_start = time.process_time()

    def record_frame(rgb, frame_out, info, index):
        return frame_out, info

    def done(item, t_cam):  # the pipeline's pts: the camera frame's read time
        frame_out, info = item
        now = time.perf_counter()
        relit_slot.put(RelitFrame(frame_out, t_cam, now, stage["relit"]))
        stage["relit"] += 1
        stage["faces"] += int(info.face)
        lat = (now - t_cam) * 1e3
        latencies.append(lat)
        status.latencies.append(lat)
        status.light = _light_text(info.light)

    def output_clock():
        """Ticks at out_fps: the newest relit frame to every sink (the same one again when none is newer)."""
        nonlocal cam, writer
        period = 1.0 / out_fps
        t_next = time.perf_counter()
        while not controls.stop.is_set():
            item = relit_slot.peek()
            if item is not None:
                if virtual_camera and cam is None:
                    cam = VirtualCamera((item.rgb.shape[1], item.rgb.shape[0]), out_fps)
                    res.virtual_camera = cam.device
                if record is not None and writer is None:
                    writer = VideoWriter(record, out_fps, (item.rgb.shape[1] // 2 * 2, item.rgb.shape[0] // 2 * 2),
                                         crf=crf, preset=RECORD_PRESET).__enter__()
                    res.record = str(record)
                rgb = item.rgb
                if cam is not None:
                    cam.send(item.as_rgb())
                if writer is not None:  # a YuvFrame (even-sized) goes to the encoder as it is
                    writer.write(np.ascontiguousarray(rgb[:rgb.shape[0] // 2 * 2, :rgb.shape[1] // 2 * 2])
                                 if isinstance(rgb, np.ndarray) else rgb)
                stage["out"] += 1
            t_next += period
            wait = t_next - time.perf_counter()
            if wait > 0:
                controls.stop.wait(wait)
            else:
                t_next = time.perf_counter()  # behind: no burst to catch up

    clock_error: list = []
    loop_error: list = []

    def clock_run():
        """The output clock's thread owns the sinks it opens: it closes them too (the recording
        kept when the run ends well, removed when it or the loop failed)."""
        try:
            output_clock()
        except BaseException as exc:
            clock_error.append(exc)
            controls.quit("output error")
        finally:
            exc = (clock_error + loop_error + [None])[0]
            try:
                if cam is not None:
                    cam.close()
            finally:
                if writer is not None:
                    writer.__exit__(type(exc) if exc is not None else None, exc,
                                    exc.__traceback__ if exc is not None else None)

    clock = threading.Thread(target=clock_run, name="relight-output", daemon=True)
    try:
        if preview:
            pv = PreviewServer(relit_slot, preview_port)
            res.preview = pv.url
        reader.start()
        clock.start()
        if on_ready is not None:
            on_ready(res)
        applied = (0, controls.mode, controls.strength)
        with FramePipeline(fp, record_frame) as pipe:
            pipe.done = done
            pipe.wake = reader.slot.wake  # a finished frame ends the wait for the next camera frame
            while not controls.stop.is_set():
                if duration is not None and time.perf_counter() - t_start >= duration:
                    controls.quit("duration")
                    break
                if controls.changed.is_set():
                    controls.changed.clear()
                    want = (controls.env_i, controls.mode, controls.strength)
                    if want != applied:
                        pipe.drain()
                        fp.set_environment(env_array(controls.env_i))
                        fp.set_mode(controls.mode)
                        fp.set_strength(controls.strength)
                        res.switches.append({"t": round(time.perf_counter() - t_start, 3),
                                             "env": controls.envs[controls.env_i], "mode": controls.mode,
                                             "strength": controls.strength})
                        applied = want
                item = reader.slot.take(timeout=0.1)
                pipe.poll()
                if item is None:
                    if reader.ended.is_set():
                        if reader.error is not None:
                            raise InputError(f"camera {reader.name}: {reader.error}") from reader.error
                        controls.quit("camera ended")
                else:
                    res.size = (item.rgb.shape[1], item.rgb.shape[0])
                    pipe.put(item.rgb, item.t, item.index, item.t)
                if status.due():
                    res.cpu_percent = status.show(reader.slot.put_count, stage["relit"],
                                                  reader.slot.dropped, controls)
            pipe.drain()
    except BaseException as exc:
        loop_error.append(exc)
        raise
    finally:
        controls.stop.set()
        restore_signals()
        restore_keys()
        reader.stop()
        if clock.is_alive():
            clock.join()  # it closes the virtual camera and the recording it opened
        status.close()
        if pv is not None:
            pv.close()
    if clock_error:
        raise clock_error[0]
    wall = max(time.perf_counter() - t_start, 1e-6)
    res.wall_s = wall
    res.frames_in = reader.slot.put_count
    res.dropped = reader.slot.dropped
    res.frames_relit = stage["relit"]
    res.frames_out = stage["out"]
    res.faces = stage["faces"]
    res.fps_in, res.fps_relit, res.fps_out = res.frames_in / wall, res.frames_relit / wall, res.frames_out / wall
    res.cpu_percent = 100.0 * (time.process_time() - cpu_start) / wall
    if latencies:
        v = np.asarray(latencies)
        res.latency_ms = {"median": float(np.median(v)), "p95": float(np.percentile(v, 95)),
                          "p99": float(np.percentile(v, 99)), "max": float(v.max())}
    res.stopped_by = controls.stop_reason
    return res
