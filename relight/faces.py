"""The capture's face detection (the reference frame's face, and a head mesh's front view in the
studio): OpenCV's frontal-face Haar cascade (Viola-Jones, as the paper) - its box sizes the
capture's crop and the studio's placement. Live frames are searched with a detector made for
webcams (:mod:`relight.engine.face_detect`)."""

from __future__ import annotations

import cv2
import numpy as np

HAAR_CASCADE = "haarcascade_frontalface_default.xml"


def detect_face(rgb: np.ndarray) -> tuple[int, int, int, int] | None:
    """The largest frontal face (x, y, w, h) found by OpenCV's Haar cascade in an (H, W, 3) uint8
    sRGB frame, or None."""
    return detect_face_grey(cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY))


def detect_face_grey(grey: np.ndarray, rows: int | None = None) -> tuple[int, int, int, int] | None:
    """The largest frontal face (x, y, w, h) in an (H, W) uint8 grey frame, or None; detected on
    a copy scaled down to ``rows`` rows when the frame has more (the box in the frame's pixels).
    Faces smaller than a twelfth of the (scaled) height, or 24 px, are not looked for."""
    h, w = grey.shape
    s = min(1.0, rows / h) if rows else 1.0
    small = cv2.resize(grey, (max(int(w * s), 1), max(int(h * s), 1)), interpolation=cv2.INTER_AREA) if s < 1 else grey
    faces = face_cascade().detectMultiScale(small, scaleFactor=1.1, minNeighbors=5,
                                            minSize=(max(small.shape[0] // 12, 24),) * 2)
    if len(faces) == 0:
        return None
    x, y, fw, fh = max(faces, key=lambda f: f[2] * f[3])
    return int(x / s), int(y / s), int(fw / s), int(fh / s)


_CASCADE = None


def face_cascade():
    """OpenCV's frontal-face Haar cascade, loaded once."""
    global _CASCADE
    if _CASCADE is None:
        path = cv2.data.haarcascades + HAAR_CASCADE
        _CASCADE = cv2.CascadeClassifier(path)
        if _CASCADE.empty():  # pragma: no cover - the wheel ships the file (opencv < 5)
            raise RuntimeError(f"OpenCV's Haar cascade {path} is missing; install opencv-contrib-python-headless<5")
    return _CASCADE
