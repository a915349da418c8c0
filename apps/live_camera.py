"""``relight live``'s camera: the **camera reader** thread - a camera device (FFmpeg's device
inputs through PyAV: v4l2 on Linux, avfoundation on macOS, dshow on Windows) or a video file
played at its own rate and looped - into the one-frame slot each hand-over of the live path goes
through (:class:`relight.engine.frame_slot.LatestFrame`: the newest frame wins)."""

from __future__ import annotations

import platform
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from relight.errors import InputError

from ..engine.frame_slot import LatestFrame

#: Largest camera frame accepted (pixels): 4K.
MAX_CAMERA_PIXELS = 3840 * 2160


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
        self.frame_size = None  # (w, h) of its frames as delivered, when known before the first
        self.pixel_format = None  # the decoder's pixel format of its first frame
        self.in_planes = 0  # frames delivered in their Y'CbCr planes (relight.video_yuv: no RGB made)
        self._open()
        self._thread = threading.Thread(target=self._run, name="relight-camera", daemon=True)

    def _open(self) -> None:
        import av

        if self.is_file:
            from relight.video_read import probe_video

            info = probe_video(self.spec)
            self.rate = float(info.fps) if info.fps else 30.0
            self.name = str(self.spec)
            self.frame_size = tuple(self.size) if self.size else (info.width, info.height)
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
        cc = st.codec_context
        self.frame_size = tuple(self.size) if self.size else ((cc.width, cc.height) if cc.width and cc.height
                                                               else None)

    def start(self) -> CameraReader:
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop the reader (and close the camera); safe before :meth:`start` - a run that failed
        while starting stops it too, and must not hide its error behind this one's."""
        self._stop.set()
        if self._thread.ident is not None:
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
        from relight.video_read import read_frames_raw

        if not self.is_file:
            for frame in self.container.decode(video=0):
                yield self._kept(frame)
            return
        while True:
            n = 0
            # A file's frames kept in their planes where they can be (only the face's box is
            # converted: relight.video_yuv), else RGB as displayed.
            for frame in read_frames_raw(self.spec):
                n += 1
                yield self._kept(frame)
            if not self.loop or n == 0:
                return

    def _kept(self, frame):
        """A decoded frame kept in its planes where it can be (the camera's own format: 4:2:0,
        4:2:2, NV12, YUYV, MJPEG's full-range planes - only what is touched is converted:
        relight.video_yuv), else RGB as displayed."""
        from relight.video_frame import frame_to_rgb
        from relight.video_yuv import YuvFrame

        if self.pixel_format is None:
            self.pixel_format = frame.format.name
        yuv = YuvFrame.from_av(frame)
        return frame_to_rgb(frame) if yuv is None else yuv

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
                fitted = self._fit(rgb)
                self.in_planes += not isinstance(fitted, np.ndarray)
                self.slot.put(CameraFrame(fitted, time.perf_counter(), i))
        except BaseException as exc:  # handed to the loop
            self.error = exc
        finally:
            self.ended.set()
