"""Frames to a virtual camera (pyvirtualcam: v4l2loopback on Linux, OBS Virtual Camera on macOS
and Windows), for ``relight live`` and ``relight filter --virtual-camera``; when no backend is
present, what to install for this OS. Frames: RGB uint8 at a fixed size and rate."""

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


class VirtualCamera:
    """Frames to a virtual camera through pyvirtualcam (RGB, fixed size and rate)."""

    def __init__(self, size: tuple[int, int], fps: float):
        check_virtual_camera_backend()
        import pyvirtualcam

        try:
            self.cam = pyvirtualcam.Camera(width=size[0], height=size[1], fps=fps)
        except Exception as exc:  # pyvirtualcam raises RuntimeError and others when no device exists
            raise VirtualCameraMissing(f"no virtual camera device ({exc}): {backend_hint()}") from None
        self.device = self.cam.device

    def send(self, rgb: np.ndarray) -> None:
        self.cam.send(rgb)

    def close(self) -> None:
        self.cam.close()
