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

import functools
import os
import threading
import time
from dataclasses import dataclass

import numpy as np

from relight.errors import InputError
from relight.video_write import DEFAULT_CRF, VideoWriter

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


def _check_request(mode: str, duration: float | None) -> None:
    """The run's mode and duration checked (InputError saying what to change)."""
    if mode not in MODES:
        raise InputError(f"mode {mode!r}: use one of {', '.join(MODES)}")
    if duration is not None and not (np.isfinite(duration) and duration > 0):
        raise InputError(f"--duration {duration}: use a positive number of seconds")


def _record_frame(rgb, frame_out, info, index):
    """What the pipeline hands to ``done`` for a frame: (relit frame, its info, camera index, camera frame)."""
    return frame_out, info, index, rgb


def _set_light(fp, new_env, moved, mode_now, strength_now, ev, turn, spin, spun) -> None:
    """A change of the page's light applied to the frame path (on the pipeline's second stage)."""
    if new_env is not None:
        fp.set_environment(new_env, moved=moved)
    fp.set_mode(mode_now)
    fp.set_strength(strength_now)
    fp.set_exposure(ev)
    fp.set_env_turn(turn)
    if spun:
        fp.set_env_spin(spin)


class _LiveRun:
    """One run's state shared by its threads: the relight loop (the caller's thread) leaves relit
    frames in ``relit_slot``, the output clock's thread sends them to the sinks it opens (the
    virtual camera, the recording) and closes them; the counts feed the run's result."""

    def __init__(self, controls, reader, fp, res, status, out_fps: float, *, virtual_camera: bool, record, crf: int):
        self.controls, self.reader, self.fp, self.res, self.status = controls, reader, fp, res, status
        self.out_fps = out_fps
        self.virtual_camera, self.record, self.crf = virtual_camera, record, crf
        self.relit_slot = LatestFrame()
        self.cam = self.writer = None  # the sinks, opened (and closed) by the output clock's thread
        self.latencies: list[float] = []
        self.frames_relit = self.faces = self.frames_out = 0
        self.light_mark: list = []  # (first camera frame index under a change, when it was asked for)
        self.clock_error: list = []
        self.loop_error: list = []
        self.t_start = time.perf_counter()
        self.cpu_start = time.process_time()

    # ------------------------------------------------------------------ the relight loop's side
    def done(self, item, t_cam) -> None:
        """A relit frame (``_record_frame``'s tuple; ``t_cam``: the camera frame's read time, the
        pipeline's pts) left in the output slot, with its latency and the light's."""
        frame_out, info, index, src = item
        now = time.perf_counter()
        res = self.res
        if self.light_mark and index >= self.light_mark[0][0]:  # the first frame relit with the page's change
            res.light_ms.append(round((now - self.light_mark.pop()[1]) * 1e3, 1))
            del res.light_ms[:-MAX_RECORDS]
        self.relit_slot.put(RelitFrame(frame_out, t_cam, now, self.frames_relit, src))
        self.frames_relit += 1
        self.faces += int(info.face)
        lat = (now - t_cam) * 1e3
        self.latencies.append(lat)
        self.status.latencies.append(lat)
        self.status.light = light_text(info.light)

    def relight_loop(self, pipe, duration: float | None, applied) -> None:
        """Until a stop: the page's changes applied, the newest camera frame into ``pipe`` (a
        :class:`FramePipeline`), the status line shown. ``applied``: ``controls.wanted()`` in use."""
        controls = self.controls
        next_index = 0  # the next camera frame's index
        drafting = False  # a moved light relit as a draft, until it rests (SETTLE_S)
        while not controls.stop.is_set():
            if duration is not None and time.perf_counter() - self.t_start >= duration:
                controls.quit("duration")
                break
            if controls.changed.is_set():
                controls.changed.clear()
                want = controls.wanted()
                if want != applied:
                    draft = self._apply_change(pipe, want, applied, next_index)
                    drafting = drafting or draft
                    applied = want
            if drafting and not controls.changed.is_set() and \
                    time.perf_counter() - controls.changed_at > SETTLE_S:
                pipe.apply(self.fp.settle)  # the light rests: relit in full from the next frame
                drafting = False
            next_index = self._feed(pipe, next_index)
            if self.status.due():
                self.res.cpu_percent = self.status.show(self.reader.slot.put_count, self.frames_relit,
                                                        self.reader.slot.dropped, controls)

    def _apply_change(self, pipe, want, applied, next_index: int) -> bool:
        """The wanted light (``controls.wanted()``) queued on the pipeline's second stage and
        booked; True when it is a key light moved (relit as a draft until it rests)."""
        controls = self.controls
        src, mode_now, strength_now, ev, turn, spin = want
        new_env = controls.environment(src) if src != applied[0] else None
        # a key light moved keeps its exposure (the same light)
        moved = src.startswith("builtin:key") and applied[0].startswith("builtin:key")
        spun = spin != applied[5]  # (a spin counts from when it is set)
        # on the second stage's thread, before the next frame's
        pipe.apply(functools.partial(_set_light, self.fp, new_env, moved, mode_now, strength_now, ev, turn, spin,
                                     spun))
        self.light_mark[:] = [(next_index, controls.changed_at)]
        self.res.switches.append({"t": round(time.perf_counter() - self.t_start, 3), "env": src,
                                  "mode": mode_now, "strength": strength_now, "exposure": ev,
                                  "turn": turn, "spin": spin})
        del self.res.switches[:-MAX_RECORDS]
        return new_env is not None and moved

    def _feed(self, pipe, next_index: int) -> int:
        """The newest camera frame (waiting up to 0.1 s) into ``pipe``, a finished frame handed on;
        returns the next camera frame's index (InputError when the camera failed)."""
        reader = self.reader
        item = reader.slot.take(timeout=0.1)
        pipe.poll()
        if item is None:
            if reader.ended.is_set():
                if reader.error is not None:
                    raise InputError(f"camera {reader.name}: {reader.error}") from reader.error
                self.controls.quit("camera ended")
        else:
            self.res.size = (item.rgb.shape[1], item.rgb.shape[0])
            next_index = item.index + 1
            pipe.put(item.rgb, item.t, item.index, item.t)
        return next_index

    # ------------------------------------------------------------------ the output clock's thread
    def clock_run(self) -> None:
        """The output clock's thread owns the sinks it opens: it closes them too (the recording
        kept when the run ends well, removed when it or the loop failed)."""
        try:
            self.output_clock()
        except BaseException as exc:
            self.clock_error.append(exc)
            self.controls.quit("output error")
        finally:
            exc = (self.clock_error + self.loop_error + [None])[0]
            try:
                if self.cam is not None:
                    self.cam.close()
            finally:
                if self.writer is not None:
                    self.writer.__exit__(type(exc) if exc is not None else None, exc,
                                         exc.__traceback__ if exc is not None else None)

    def output_clock(self) -> None:
        """Ticks at out_fps: the newest relit frame to every sink (the same one again when none is newer)."""
        period = 1.0 / self.out_fps
        t_next = time.perf_counter()
        while not self.controls.stop.is_set():
            item = self.relit_slot.peek()
            if item is not None:
                self._open_sinks(item)
                self._send(item)
            t_next += period
            wait = t_next - time.perf_counter()
            if wait > 0:
                self.controls.stop.wait(wait)
            else:
                t_next = time.perf_counter()  # behind: no burst to catch up

    def _open_sinks(self, item: RelitFrame) -> None:
        """The virtual camera and the recording opened at the first relit frame's size."""
        if self.virtual_camera and self.cam is None:  # (frames kept in their planes go as I420: no RGB made)
            self.cam = VirtualCamera((item.rgb.shape[1], item.rgb.shape[0]), self.out_fps,
                                     planes=not isinstance(item.rgb, np.ndarray))
            self.res.virtual_camera = self.cam.device
        if self.record is not None and self.writer is None:
            self.writer = VideoWriter(self.record, self.out_fps,
                                      (item.rgb.shape[1] // 2 * 2, item.rgb.shape[0] // 2 * 2),
                                      crf=self.crf, preset=RECORD_PRESET).__enter__()
            self.res.record = str(self.record)

    def _send(self, item: RelitFrame) -> None:
        """One relit frame to the open sinks (the recording's cropped to even sizes), counted."""
        rgb = item.rgb
        if self.cam is not None:
            self.cam.send(item.rgb)
        if self.writer is not None:  # a YuvFrame (even-sized) goes to the encoder as it is
            self.writer.write(np.ascontiguousarray(rgb[:rgb.shape[0] // 2 * 2, :rgb.shape[1] // 2 * 2])
                              if isinstance(rgb, np.ndarray) else rgb)
        self.frames_out += 1

    # ------------------------------------------------------------------ the end
    def result(self) -> LiveResult:
        """The run's result filled in: counts, rates (per second of wall time), CPU share, latencies (ms)."""
        res, reader = self.res, self.reader
        wall = max(time.perf_counter() - self.t_start, 1e-6)
        res.wall_s = wall
        res.frames_in = reader.slot.put_count
        res.camera_format, res.frames_in_planes = reader.pixel_format, reader.in_planes
        res.dropped = reader.slot.dropped
        res.frames_relit = self.frames_relit
        res.frames_out = self.frames_out
        res.faces = self.faces
        res.fps_in, res.fps_relit, res.fps_out = res.frames_in / wall, res.frames_relit / wall, res.frames_out / wall
        res.cpu_percent = 100.0 * (time.process_time() - self.cpu_start) / wall
        if self.latencies:
            v = np.asarray(self.latencies)
            res.latency_ms = {"median": float(np.median(v)), "p95": float(np.percentile(v, 95)),
                              "p99": float(np.percentile(v, 99)), "max": float(v.max())}
        res.stopped_by = self.controls.stop_reason
        return res


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
    from ..engine.frame_path import FramePath
    from ..engine.frame_pipeline import FramePipeline
    from ..engine.frame_settings import FrameSettings

    _check_request(mode, duration)
    if virtual_camera:
        check_virtual_camera_backend()  # before the camera or the bundle's kernels are touched
    controls = Controls(envs, mode, strength, exposure=exposure, turn=env_turn, spin=env_spin)
    controls.environment()  # the first environment, checked before the camera is opened
    reader = CameraReader(camera, size=size, fps=fps)
    controls.wake = reader.slot.wake  # a change from the page is applied at once, not at the next frame
    res = LiveResult(camera=reader.name)
    out_fps = float(fps or reader.rate or 30.0)
    # a live source: the person's maps made beside the frames, not in one of them
    settings = FrameSettings(mode=mode, strength=strength, focal=focal, region=region, live_source=True,
                             exposure=exposure, env_turn=env_turn, env_spin=env_spin)
    fp = FramePath(bundle, controls.environment(), settings)
    # every kernel built and run once, at the camera's size, before its first frame is read: no
    # frame waits for a compile
    res.warm_up_s = fp.warm_up(reader.frame_size)
    status = status if status is not None else StatusLine()
    restore_keys = key_reader(controls)
    restore_signals = install_signals(controls)
    run = _LiveRun(controls, reader, fp, res, status, out_fps, virtual_camera=virtual_camera, record=record, crf=crf)
    pv = None
    clock = threading.Thread(target=run.clock_run, name="relight-output", daemon=True)
    # the frames' threads wait less for the interpreter behind the slow stages' Python (restored after)
    with frames_first():
        try:
            if preview:
                pv = PreviewServer(run.relit_slot, preview_port, controls=controls, status=status, result=res,
                                   lights_dir=lights_dir)
                res.preview = pv.url
            reader.start()
            clock.start()
            if on_ready is not None:
                on_ready(res)
            applied = controls.wanted()
            with FramePipeline(fp, _record_frame) as pipe:
                pipe.done = run.done
                pipe.wake = reader.slot.wake  # a finished frame ends the wait for the next camera frame
                run.relight_loop(pipe, duration, applied)
                pipe.drain()
        except BaseException as exc:
            run.loop_error.append(exc)
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
    if run.clock_error:
        raise run.clock_error[0]
    return run.result()
