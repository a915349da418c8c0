"""The person's pixels in a live frame: a soft matte (0-1) of the head, hair, ears, neck and
shoulders - what the live frame relights; nothing off it may change.

MediaPipe's selfie segmentation model (landscape: 256x144 input; shipped in
``models/selfie-segmentation/`` with its Apache 2.0 licence, see NOTICE) runs through OpenCV's
TFLite importer on the frame scaled to its input (letterboxed: the frame's aspect kept, the
border replicated). Its 256x144 probability is brought up to the frame edge-aware: a guided
filter (He et al. 2013; ``cv2.ximgproc``) with the frame's grey as the guide at
:data:`WORK_ROWS` rows makes the matte's edge follow the frame's own edges (hair against a wall),
then bilinear to full size.

Arrays: frames (H, W, 3) uint8 sRGB; the matte (H, W) float32 in [0, 1].
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from relight.errors import InputError

from .tflite import load_net, manifest

MODEL_DIR = Path(__file__).parent / "models" / "selfie-segmentation"
#: The model's input (width, height).
MODEL_SIZE = (256, 144)
#: Rows of the guided filter's work (the matte is refined there, then resized to the frame).
WORK_ROWS = 270
#: Guided filter: radius (px at WORK_ROWS) and regulariser (grey 0-1, squared): edges of more
#: than ~sqrt(eps) contrast pull the matte's edge onto them.
GUIDE_RADIUS = 4
GUIDE_EPS = 2e-3


def model_info() -> dict:
    """The shipped model's manifest (model.json)."""
    return manifest(MODEL_DIR)


def _letterbox(rgb: np.ndarray) -> tuple[np.ndarray, tuple[int, int, int, int]]:
    """The frame scaled into the model's input keeping its aspect, the rest the replicated
    border: (input (144, 256, 3) uint8, the frame's box (x0, y0, w, h) in it)."""
    mw, mh = MODEL_SIZE
    h, w = rgb.shape[:2]
    s = min(mw / w, mh / h)
    nw, nh = max(1, min(mw, round(w * s))), max(1, min(mh, round(h * s)))
    small = cv2.resize(rgb, (nw, nh), interpolation=cv2.INTER_AREA)
    x0, y0 = (mw - nw) // 2, (mh - nh) // 2
    boxed = cv2.copyMakeBorder(small, y0, mh - nh - y0, x0, mw - nw - x0, cv2.BORDER_REPLICATE)
    return boxed, (x0, y0, nw, nh)


class PersonMatte:
    """The person's matte in frames (see the module docstring). Not thread-safe: one per thread
    that uses it (OpenCV's network keeps its buffers)."""

    def __init__(self):
        self.net = load_net(MODEL_DIR, "person segmentation")

    def probability(self, rgb: np.ndarray) -> np.ndarray:
        """The model's person probability over the frame, at the model's scale: (h, w) float32
        with the frame's aspect (the letterbox removed)."""
        rgb = np.asarray(rgb)
        if rgb.dtype != np.uint8 or rgb.ndim != 3 or rgb.shape[2] != 3:
            raise InputError(f"frame of shape {rgb.shape} and type {rgb.dtype}: expected (H, W, 3) uint8 RGB")
        boxed, (x0, y0, w, h) = _letterbox(rgb)
        blob = np.ascontiguousarray((boxed.astype(np.float32) * np.float32(1.0 / 255.0)).transpose(2, 0, 1)[None])
        self.net.setInput(blob)
        prob = self.net.forward().reshape(MODEL_SIZE[1], MODEL_SIZE[0])
        prob = np.nan_to_num(prob, nan=0.0, posinf=1.0, neginf=0.0)
        return np.clip(prob[y0:y0 + h, x0:x0 + w], 0.0, 1.0).astype(np.float32)

    def __call__(self, rgb: np.ndarray, *, work: bool = False) -> np.ndarray:
        """(H, W) float32 matte in [0, 1] (``work``: at :data:`WORK_ROWS` rows instead)."""
        h, w = rgb.shape[:2]
        s = min(1.0, WORK_ROWS / h)
        ww, wh = max(1, round(w * s)), max(1, round(h * s))
        small = cv2.resize(rgb, (ww, wh), interpolation=cv2.INTER_AREA) if s < 1 else rgb
        fine = self.refine(small, self.probability(rgb))
        if work or s == 1:
            return fine
        return cv2.resize(fine, (w, h), interpolation=cv2.INTER_LINEAR)

    @staticmethod
    def refine(small: np.ndarray, prob: np.ndarray, box=None) -> np.ndarray:
        """The matte at the scale of ``small`` (h, w, 3) uint8 (the frame at :data:`WORK_ROWS`
        rows): the model's ``prob`` (:meth:`probability`) brought up to it bilinearly and
        refined by the guided filter with ``small``'s grey as the guide - over ``box`` (x0, y0,
        x1, y1) of it alone when given (the person and a margin: the work is the box's)."""
        h, w = small.shape[:2]
        x0, y0, x1, y1 = (0, 0, w, h) if box is None else (int(v) for v in box)
        coarse = cv2.resize(prob, (w, h), interpolation=cv2.INTER_LINEAR)[y0:y1, x0:x1]
        grey = cv2.cvtColor(np.ascontiguousarray(small[y0:y1, x0:x1]), cv2.COLOR_RGB2GRAY)
        guide = grey.astype(np.float32) * np.float32(1.0 / 255.0)
        fine = cv2.ximgproc.guidedFilter(guide, np.ascontiguousarray(coarse), GUIDE_RADIUS, GUIDE_EPS)
        return np.clip(fine, 0.0, 1.0)
