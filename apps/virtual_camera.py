"""Frames to a virtual camera (pyvirtualcam: v4l2loopback on Linux, OBS Virtual Camera on macOS
and Windows), for ``relight live`` and ``relight filter --virtual-camera``; when no backend is
present, what to install for this OS. Frames at a fixed size and rate: a frame kept in its planes
(:class:`relight.video_yuv.YuvFrame`) goes as I420 - a webcam's own Y'CbCr (BT.601, limited
range), converted plane to plane, never through RGB - an RGB array as RGB."""

from __future__ import annotations

import platform

import numpy as np

from relight.errors import InputError


class VirtualCameraMissing(InputError):
    """No virtual-camera backend on this machine (``relight live`` exits 2 with :func:`backend_hint`)."""


def backend_hint(system: str | None = None) -> str:
    """What to install for a virtual camera on this OS (``platform.system()`` names)."""
    system = system or platform.system()
    pip = "pip install 'relight[virtualcam]' (pyvirtualcam)"
    if system == "Linux":
        return (f"{pip}, and the v4l2loopback kernel module: sudo apt install v4l2loopback-dkms && "
                "sudo modprobe v4l2loopback devices=1 exclusive_caps=1 card_label=relight")
    if system == "Darwin":
        return (f"{pip}, and OBS Studio 30 or later: start its Virtual Camera once (Tools > Start Virtual "
                "Camera) so macOS registers the camera extension, then stop it")
    if system == "Windows":
        return f"{pip}, and OBS Studio 26.1 or later (its Virtual Camera) or Unity Capture"
    return f"{pip}; pyvirtualcam has no backend for {system}: use --record or --preview"


def check_virtual_camera_backend() -> None:
    """Raise :class:`VirtualCameraMissing` unless pyvirtualcam imports (the device itself is
    opened, and checked, once the first frame's size is known)."""
    try:
        import pyvirtualcam  # noqa: F401
    except ImportError:
        raise VirtualCameraMissing(f"no virtual-camera backend: {backend_hint()}") from None


def webcam_i420(frame) -> np.ndarray:
    """(3H/2, W) uint8: a :class:`relight.video_yuv.YuvFrame` as I420 in a webcam's codes (BT.601,
    limited range): its planes converted by swscale, matrix to matrix (no RGB)."""
    from av.video.reformatter import ColorRange, Colorspace

    from relight.video_frame import sws_flags

    if frame.cy == 2 and frame.codes.matrix == "bt601" and not frame.codes.full:
        return frame.to_av_planes()  # (already a webcam's own)
    cs, rng = frame.codes.av_tags
    return frame.av_frame().reformat(format="yuv420p", src_colorspace=cs, src_color_range=rng,
                                     dst_colorspace=Colorspace.ITU601, dst_color_range=ColorRange.MPEG,
                                     interpolation=sws_flags()).to_ndarray()


class VirtualCamera:
    """Frames to a virtual camera through pyvirtualcam (fixed size and rate): I420 when ``planes``
    (the frames are YuvFrames: :func:`webcam_i420`), else RGB."""

    def __init__(self, size: tuple[int, int], fps: float, planes: bool = False):
        check_virtual_camera_backend()
        import pyvirtualcam

        self.planes = bool(planes)
        fmt = pyvirtualcam.PixelFormat.I420 if self.planes else pyvirtualcam.PixelFormat.RGB
        try:
            self.cam = pyvirtualcam.Camera(width=size[0], height=size[1], fps=fps, fmt=fmt)
        except Exception as exc:  # pyvirtualcam raises RuntimeError and others when no device exists
            raise VirtualCameraMissing(f"no virtual camera device ({exc}): {backend_hint()}") from None
        self.device = self.cam.device

    def send(self, frame) -> None:
        """Send a frame: a YuvFrame (``planes``) or an (H, W, 3) uint8 RGB array."""
        if self.planes and not isinstance(frame, np.ndarray):
            self.cam.send(webcam_i420(frame))
        else:
            from relight.video_yuv import as_rgb

            rgb = as_rgb(frame)
            self.cam.send(rgb if not self.planes else _rgb_i420(rgb))

    def close(self) -> None:
        self.cam.close()


def _rgb_i420(rgb: np.ndarray) -> np.ndarray:
    """An RGB frame as I420 (BT.601 limited) for a camera opened for planes (a frame of another kind)."""
    import av
    from av.video.reformatter import ColorRange, Colorspace

    f = av.VideoFrame.from_ndarray(np.ascontiguousarray(rgb), format="rgb24")
    return f.reformat(format="yuv420p", dst_colorspace=Colorspace.ITU601, dst_color_range=ColorRange.MPEG).to_ndarray()
