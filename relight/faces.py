"""Face detection shared by the capture (the reference frame's face) and the live side (a face
entering the frame): OpenCV's frontal-face Haar cascade (Viola-Jones, as the paper)."""

from __future__ import annotations

import cv2
import numpy as np

HAAR_CASCADE = "haarcascade_frontalface_default.xml"


def detect_face(rgb: np.ndarray) -> tuple[int, int, int, int] | None:
    """The largest frontal face (x, y, w, h) found by OpenCV's Haar cascade, or None."""
    cascade = face_cascade()
    grey = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
    h = grey.shape[0]
    faces = cascade.detectMultiScale(grey, scaleFactor=1.1, minNeighbors=5, minSize=(max(h // 12, 24),) * 2)
    if len(faces) == 0:
        return None
    x, y, w, hh = max(faces, key=lambda f: f[2] * f[3])
    return int(x), int(y), int(w), int(hh)


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
