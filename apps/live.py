"""``relight live``: a live camera in, relit frames out to a virtual camera, a preview page and/or
a recording.

Threads (no queue grows anywhere - the latest frame wins at each hand-over):

* the **camera reader** decodes the camera (FFmpeg's device inputs through PyAV: v4l2 on Linux,
  avfoundation on macOS, dshow on Windows) or a video file played at its own rate and looped,
  and leaves each frame in a one-frame slot (:class:`LatestFrame`); a frame the loop had no time
  for is replaced and counted as dropped;
* the **relight loop** (the caller's thread, plus the second stage of
  :class:`relight.engine.frame_pipeline.FramePipeline` on a worker) takes the newest frame, relights it
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

The loop is here (:func:`run_live`); its parts live beside it: :mod:`live_camera` (the camera
reader, the one-frame slots), :mod:`live_controls` (keys and signals), :mod:`live_status` (the
status line, the run's result) and :mod:`live_preview` (the MJPEG page).
"""

from __future__ import annotations

import os
import threading
import time
from dataclasses import dataclass

import numpy as np

from relight.errors import InputError
from relight.video_write import DEFAULT_CRF

from ..engine.composite import DEFAULT_MODE, DEFAULT_REGION, MODES
from ..engine.frame_slot import LatestFrame
from ..engine.threads import frames_first
from .live_camera import CameraReader
from .live_controls import Controls, install_signals, key_reader
from .live_preview import PreviewServer
from .live_status import LiveResult, StatusLine, light_text
from .virtual_camera import VirtualCamera, check_virtual_camera_backend

#: x264 preset of a recording: the fastest (the relight needs the cores; ~2x the bytes of veryfast).
RECORD_PRESET = "ultrafast"
#: A light moved on the page (a key dragged) is relit as a draft until it rests this long (s).
SETTLE_S = 0.25
#: The run's result keeps at most this many of its switches and light latencies (the last ones).
MAX_RECORDS = 1000


@dataclass
class RelitFrame:
    rgb: object  # (H, W, 3) uint8 sRGB, or a relight.video_yuv.YuvFrame (as_rgb() converts it once)
    t_camera: float  # when the camera frame was read
    t_ready: float  # when its relit frame was ready
    index: int
    src: object = None  # the camera frame it was relit from (the page's before/after split)
    _rgb: np.ndarray | None = None

    def as_rgb(self) -> np.ndarray:
        """The frame as (H, W, 3) uint8 sRGB (a YuvFrame converted on first use, then kept)."""
        if self._rgb is None:
            from relight.video_yuv import as_rgb

            self._rgb = as_rgb(self.rgb)
        return self._rgb


def run_live(bundle, envs: list[str], *, camera: str | None = None, size: tuple[int, int] | None = None,
             fps: float | None = None, duration: float | None = None, mode: str = DEFAULT_MODE,
             region: str = DEFAULT_REGION, strength: float = 1.0, focal=None, virtual_camera: bool = False,
             preview: bool = False, preview_port: int = 0, record: str | os.PathLike | None = None,
             crf: int = DEFAULT_CRF, status=None, on_ready=None, exposure: float = 0.0, env_turn: float = 0.0,
             env_spin: float = 0.0, lights_dir: str | os.PathLike | None = None) -> LiveResult:
    """Relight a live camera (or a looped file) until ``duration`` seconds pass, ``q``, or a stop
    signal. ``bundle``: a loaded :class:`relight.kernels.bundle.Bundle`; ``envs``: environments
    (paths or ``builtin:NAME``) switched in turn. ``on_ready(result)`` is called once the sinks
    are open (the preview's URL is known)."""
    from relight.video_write import VideoWriter

    from ..engine.frame_path import FramePath
    from ..engine.frame_pipeline import FramePipeline

    if mode not in MODES:
        raise InputError(f"mode {mode!r}: use one of {', '.join(MODES)}")
    if duration is not None and not (np.isfinite(duration) and duration > 0):
        raise InputError(f"--duration {duration}: use a positive number of seconds")
    if virtual_camera:
        check_virtual_camera_backend()  # before the camera or the bundle's kernels are touched
    controls = Controls(envs, mode, strength, exposure=exposure, turn=env_turn, spin=env_spin)
    controls.environment()  # the first environment, checked before the camera is opened
    reader = CameraReader(camera, size=size, fps=fps)
    controls.wake = reader.slot.wake  # a change from the page is applied at once, not at the next frame
    res = LiveResult(camera=reader.name)
    out_fps = float(fps or reader.rate or 30.0)
    # a live source: the person's maps made beside the frames, not in one of them
    fp = FramePath(bundle, controls.environment(), mode=mode, strength=strength, focal=focal, region=region,
                   live_source=True, exposure=exposure, env_turn=env_turn, env_spin=env_spin)
    # every kernel built and run once, at the camera's size, before its first frame is read: no
    # frame waits for a compile
    res.warm_up_s = fp.warm_up(reader.frame_size)
    relit_slot = LatestFrame()
    status = status if status is not None else StatusLine()
    restore_keys = key_reader(controls)
    restore_signals = install_signals(controls)
    cam = writer = pv = None
    latencies: list[float] = []
    stage = {"relit": 0, "faces": 0, "out": 0}
    t_start = time.perf_counter()
    cpu_start = time.process_time()

    light_mark: list = []  # (first camera frame index under a change, when it was asked for)

    def record_frame(rgb, frame_out, info, index):
        return frame_out, info, index, rgb

    def done(item, t_cam):  # the pipeline's pts: the camera frame's read time
        frame_out, info, index, src = item
        now = time.perf_counter()
        if light_mark and index >= light_mark[0][0]:  # the first frame relit with the page's change
            res.light_ms.append(round((now - light_mark.pop()[1]) * 1e3, 1))
            del res.light_ms[:-MAX_RECORDS]
        relit_slot.put(RelitFrame(frame_out, t_cam, now, stage["relit"], src))
        stage["relit"] += 1
        stage["faces"] += int(info.face)
        lat = (now - t_cam) * 1e3
        latencies.append(lat)
        status.latencies.append(lat)
        status.light = light_text(info.light)

    def output_clock():
        """Ticks at out_fps: the newest relit frame to every sink (the same one again when none is newer)."""
        nonlocal cam, writer
        period = 1.0 / out_fps
        t_next = time.perf_counter()
        while not controls.stop.is_set():
            item = relit_slot.peek()
            if item is not None:
                if virtual_camera and cam is None:  # (frames kept in their planes go as I420: no RGB made)
                    cam = VirtualCamera((item.rgb.shape[1], item.rgb.shape[0]), out_fps,
                                        planes=not isinstance(item.rgb, np.ndarray))
                    res.virtual_camera = cam.device
                if record is not None and writer is None:
                    writer = VideoWriter(record, out_fps, (item.rgb.shape[1] // 2 * 2, item.rgb.shape[0] // 2 * 2),
                                         crf=crf, preset=RECORD_PRESET).__enter__()
                    res.record = str(record)
                rgb = item.rgb
                if cam is not None:
                    cam.send(item.rgb)
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
    # the frames' threads wait less for the interpreter behind the slow stages' Python (restored after)
    with frames_first():
        try:
            if preview:
                pv = PreviewServer(relit_slot, preview_port, controls=controls, status=status, result=res,
                                   lights_dir=lights_dir)
                res.preview = pv.url
            reader.start()
            clock.start()
            if on_ready is not None:
                on_ready(res)
            applied = controls.wanted()
            next_index = 0  # the next camera frame's index
            drafting = False  # a moved light relit as a draft, until it rests (SETTLE_S)
            with FramePipeline(fp, record_frame) as pipe:
                pipe.done = done
                pipe.wake = reader.slot.wake  # a finished frame ends the wait for the next camera frame
                while not controls.stop.is_set():
                    if duration is not None and time.perf_counter() - t_start >= duration:
                        controls.quit("duration")
                        break
                    if controls.changed.is_set():
                        controls.changed.clear()
                        want = controls.wanted()
                        if want != applied:
                            src, mode_now, strength_now, ev, turn, spin = want
                            new_env = controls.environment(src) if src != applied[0] else None
                            # a key light moved keeps its exposure (the same light)
                            moved = src.startswith("builtin:key") and applied[0].startswith("builtin:key")
                            spun = spin != applied[5]  # (a spin counts from when it is set)

                            def change(new_env=new_env, moved=moved, mode_now=mode_now, strength_now=strength_now,
                                       ev=ev, turn=turn, spin=spin, spun=spun):
                                if new_env is not None:
                                    fp.set_environment(new_env, moved=moved)
                                fp.set_mode(mode_now)
                                fp.set_strength(strength_now)
                                fp.set_exposure(ev)
                                fp.set_env_turn(turn)
                                if spun:
                                    fp.set_env_spin(spin)

                            pipe.apply(change)  # on the second stage's thread, before the next frame's
                            drafting = drafting or (new_env is not None and moved)
                            light_mark[:] = [(next_index, controls.changed_at)]
                            res.switches.append({"t": round(time.perf_counter() - t_start, 3), "env": src,
                                                 "mode": mode_now, "strength": strength_now, "exposure": ev,
                                                 "turn": turn, "spin": spin})
                            del res.switches[:-MAX_RECORDS]
                            applied = want
                    if drafting and not controls.changed.is_set() and \
                            time.perf_counter() - controls.changed_at > SETTLE_S:
                        pipe.apply(fp.settle)  # the light rests: relit in full from the next frame
                        drafting = False
                    item = reader.slot.take(timeout=0.1)
                    pipe.poll()
                    if item is None:
                        if reader.ended.is_set():
                            if reader.error is not None:
                                raise InputError(f"camera {reader.name}: {reader.error}") from reader.error
                            controls.quit("camera ended")
                    else:
                        res.size = (item.rgb.shape[1], item.rgb.shape[0])
                        next_index = item.index + 1
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
            fp.close()
    if clock_error:
        raise clock_error[0]
    wall = max(time.perf_counter() - t_start, 1e-6)
    res.wall_s = wall
    res.frames_in = reader.slot.put_count
    res.camera_format, res.frames_in_planes = reader.pixel_format, reader.in_planes
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
