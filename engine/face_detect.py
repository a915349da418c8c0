"""Faces as webcams see them - turned, tilted, lit from one side, small or large - found in a
frame with six keypoints each: MediaPipe's short-range face detector (BlazeFace, Bazarevsky et
al. 2019; shipped in ``models/face-detection/`` with its Apache 2.0 licence, see NOTICE), run
through OpenCV's TFLite importer.

Why this one (measured here, issue 49): on synthetic live clips turning +-45 deg in yaw and +-30
in pitch it found the face on every frame where OpenCV's frontal Haar cascade found 0-89 % per
10-degree bin; on the ten real Yale faces under each of their 47-49 lights (camera-linear, the
face lit from one side to the other) every photo, where the cascade missed 10-35 %; a run of its
model costs 4-6 ms of one core (a 16:9 frame takes three, on two threads: 13 ms at 640x360)
against the cascade's 24-29 ms a search. OpenCV's YuNet, the other
candidate the issue names, is stored in the model zoo behind Git LFS and in no package this
machine can install, so its file could not be checked against its published sha256.

The model sees a 128x128 square. :meth:`FaceDetector.detect` runs it on overlapping squares of
the frame's shorter side (faces down to ~1/8 of it - the model finds faces down to ~15 of its
128 px; the whole frame letterboxed into one square saw a small face a frame in two, its box a
third too large, on the tests' 320x180 head beside another face) and, only when those find
nothing and ``small`` is asked, on overlapping
squares of :data:`SMALL_TILES` of the frame's height (faces down to ~1/18 of the height: a 60
px face in a 1080p frame; 15 runs of the model at 16:9). Detections are decoded from the
model's 896 anchors (16x16 cells x 2 at stride 8, 8x8 x 6 at stride 16, fixed unit size), kept
above :data:`MIN_SCORE`, and merged as MediaPipe merges them (weighted non-maximum suppression:
the boxes and keypoints that overlap the best one are averaged by score).

Arrays: frames (H, W) uint8 grey or (H, W, 3) uint8 RGB (sRGB codes); boxes (x0, y0, x1, y1) and
keypoints (6, 2) in frame pixels (x right, y down); keypoints in the model's order
:data:`KEYPOINTS` (the person's right eye is on the image's left).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from relight.errors import InputError

from .tflite import load_net, manifest

MODEL_DIR = Path(__file__).parent / "models" / "face-detection"
#: The model's square input (pixels).
INPUT = 128
#: The keypoints' order in the model's output.
KEYPOINTS = ("right_eye", "left_eye", "nose_tip", "mouth", "right_ear", "left_ear")
#: The keypoints a first head pose is solved from (:meth:`relight.engine.pose.PoseEstimator.few_points_pose`):
#: the eyes, the nose's tip and the mouth. The ears are left out: the model places a hidden ear
#: where it guesses, and the reference's may lie off the bundle's face, where its depth is the
#: nearest face pixel's (measured on the scanned head at yaw -45..45, pitch -30..30: the first
#: pose 2-18 deg off with these four, 2-25 with all six, and with all six the search that follows
#: lost it at four of the 35 poses).
POSE_KEYPOINTS = (0, 1, 2, 3)
#: A detection's least score (MediaPipe's own threshold for this model).
MIN_SCORE = 0.5
#: Detections overlapping the best one by more than this (intersection over union) are merged into it.
MERGE_IOU = 0.3
#: The squares searched for small faces, as shares of the frame's height, and their least overlap.
SMALL_TILES = (0.45,)
TILE_OVERLAP = 0.25


def model_info() -> dict:
    """The shipped model's manifest (model.json)."""
    return manifest(MODEL_DIR)


def _anchors() -> np.ndarray:
    """(896, 2) anchor centres in the input's unit square (SSD anchors of the model's graph:
    strides 8 and 16, 2 and 6 anchors a cell, all of unit size)."""
    out = []
    for stride, per_cell in ((8, 2), (16, 6)):
        cells = INPUT // stride
        c = (np.arange(cells, dtype=np.float32) + 0.5) / cells
        xy = np.stack(np.meshgrid(c, c), axis=-1).reshape(-1, 2)
        out.append(np.repeat(xy, per_cell, axis=0))
    return np.concatenate(out)


_ANCHORS = _anchors()


@dataclass(frozen=True)
class Face:
    """A face found: ``score`` (0-1), ``box`` (x0, y0, x1, y1) and ``keypoints`` (6, 2) frame px."""

    score: float
    box: np.ndarray
    keypoints: np.ndarray

    @property
    def size(self) -> float:
        """The box's diagonal (px)."""
        return float(np.hypot(self.box[2] - self.box[0], self.box[3] - self.box[1]))


def _iou(box: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    x0 = np.maximum(box[0], boxes[:, 0])
    y0 = np.maximum(box[1], boxes[:, 1])
    x1 = np.minimum(box[2], boxes[:, 2])
    y1 = np.minimum(box[3], boxes[:, 3])
    inter = np.clip(x1 - x0, 0, None) * np.clip(y1 - y0, 0, None)
    area = lambda b: np.clip(b[..., 2] - b[..., 0], 0, None) * np.clip(b[..., 3] - b[..., 1], 0, None)  # noqa: E731
    return inter / np.maximum(area(box) + area(boxes) - inter, 1e-9)


def merge_detections(scores: np.ndarray, boxes: np.ndarray, keypoints: np.ndarray) -> list[Face]:
    """Weighted non-maximum suppression: best first, each with the detections overlapping it by
    more than :data:`MERGE_IOU` averaged in by score (their box and keypoints)."""
    order = np.argsort(-scores)
    scores, boxes, keypoints = scores[order], boxes[order], keypoints[order]
    left = np.ones(len(scores), bool)
    out = []
    for i in range(len(scores)):
        if not left[i]:
            continue
        near = left & (_iou(boxes[i], boxes) > MERGE_IOU)
        near[i] = True
        w = scores[near].astype(np.float64)
        w = w / w.sum()
        out.append(Face(score=float(scores[i]), box=(w @ boxes[near]).astype(np.float32),
                        keypoints=np.tensordot(w, keypoints[near], axes=1).astype(np.float32)))
        left &= ~near
    return out


class FaceDetector:
    """The faces in frames (see the module docstring). Not thread-safe: one per thread that uses
    it (OpenCV's network keeps its buffers)."""

    def __init__(self):
        self.net = load_net(MODEL_DIR, "face detection")
        self._net2 = None  # the model's second copy, for the squares run on a helper thread
        self.runs = 0  # the model's runs so far (what a search cost)

    def _square(self, img: np.ndarray, x0: int, y0: int, side: int, net=None):
        """The model's outputs for the square (x0, y0, side) of ``img`` (letterboxed where the
        square passes the frame, zeros there): (scores (896,), boxes (896, 4), keypoints (896, 6, 2))
        in frame px."""
        h, w = img.shape[:2]
        crop = img[max(y0, 0):min(y0 + side, h), max(x0, 0):min(x0 + side, w)]
        s = INPUT / side
        ch, cw = crop.shape[:2]
        nw, nh = max(1, min(INPUT, round(cw * s))), max(1, min(INPUT, round(ch * s)))
        small = cv2.resize(crop, (nw, nh), interpolation=cv2.INTER_AREA if s < 1 else cv2.INTER_LINEAR)
        ox, oy = round((max(x0, 0) - x0) * s), round((max(y0, 0) - y0) * s)
        square = np.zeros((INPUT, INPUT, 3), np.float32)
        if small.ndim == 2:
            small = small[:, :, None]
        square[oy:oy + nh, ox:ox + nw] = small[:INPUT - oy, :INPUT - ox].astype(np.float32) * np.float32(1 / 127.5) - 1
        net = self.net if net is None else net
        net.setInput(np.ascontiguousarray(square.transpose(2, 0, 1)[None]))
        cls, reg = net.forward(["classificators", "regressors"])
        raw = np.clip(np.nan_to_num(cls.reshape(-1).astype(np.float64), nan=-100.0), -100.0, 100.0)
        score = 1.0 / (1.0 + np.exp(-raw))
        reg = np.nan_to_num(reg.reshape(-1, 16).astype(np.float64)) / INPUT
        keep = np.flatnonzero(score >= MIN_SCORE)
        centre = _ANCHORS[keep] + reg[keep, 0:2]
        half = 0.5 * np.abs(reg[keep, 2:4])
        boxes = np.concatenate([centre - half, centre + half], axis=1) * (INPUT / s) + [x0, y0, x0, y0]
        kps = (_ANCHORS[keep, None, :] + reg[keep, 4:].reshape(-1, 6, 2)) * (INPUT / s) + [x0, y0]
        return score[keep], boxes, kps

    def _squares(self, frame: np.ndarray, side: int) -> list:
        """The model's outputs (:meth:`_square`) over squares of ``side`` covering the frame,
        overlapping by at least :data:`TILE_OVERLAP` of a side, in their order - two or more on
        both cores: the later half on a helper thread with the model's second copy (OpenCV runs
        a network without the interpreter's lock; a network keeps its buffers, so one per
        thread). Measured on the bench's frames (3 squares): 640x360 16.1 -> 13.3 ms a search, 720p
        22.6 -> 16.2."""
        from concurrent.futures import ThreadPoolExecutor

        h, w = frame.shape[:2]
        step = max(int(side * (1.0 - TILE_OVERLAP)), 1)
        places = [(x0, y0) for y0 in _starts(h, side, step) for x0 in _starts(w, side, step)]
        self.runs += len(places)
        if len(places) < 2:
            return [self._square(frame, x0, y0, side) for x0, y0 in places]
        if self._net2 is None:
            self._net2 = load_net(MODEL_DIR, "face detection")
        half = (len(places) + 1) // 2
        with ThreadPoolExecutor(1, thread_name_prefix="relight-detect") as helper:
            later = helper.submit(lambda: [self._square(frame, x0, y0, side, self._net2) for x0, y0 in places[half:]])
            first = [self._square(frame, x0, y0, side) for x0, y0 in places[:half]]
            return first + later.result()

    def detect(self, frame: np.ndarray, *, small: bool = False) -> list[Face]:
        """The faces in ``frame`` ((H, W) grey or (H, W, 3) RGB uint8), best first: searched in
        squares of its shorter side (1 run of the model for a square frame, 3 for 16:9) and, with
        ``small``, when those show none, in squares of :data:`SMALL_TILES` of its height (a face
        far from the camera; ~15 more runs)."""
        frame = np.asarray(frame)
        if frame.dtype != np.uint8 or frame.ndim not in (2, 3) or (frame.ndim == 3 and frame.shape[2] != 3):
            raise InputError(f"frame of shape {frame.shape} and type {frame.dtype}: expected (H, W) grey or "
                             "(H, W, 3) RGB uint8")
        h, w = frame.shape[:2]
        if min(h, w) < 8:
            return []
        found = self._squares(frame, min(h, w))
        if small and not sum(len(f[0]) for f in found):
            for share in SMALL_TILES:
                found += self._squares(frame, max(int(round(h * share)), 16))
                if sum(len(f[0]) for f in found):
                    break
        scores = np.concatenate([f[0] for f in found])
        if not len(scores):
            return []
        return merge_detections(scores, np.concatenate([f[1] for f in found]), np.concatenate([f[2] for f in found]))


def _starts(length: int, side: int, step: int) -> list[int]:
    """Starts of windows ``side`` long, evenly spaced at most ``step`` apart, covering [0, length)
    (the first flush with the start, the last with the end)."""
    if side >= length:
        return [(length - side) // 2]
    n = -(-(length - side) // step) + 1
    return [int(round(v)) for v in np.linspace(0, length - side, n)]


def face_similarity(src: Face, dst: Face) -> np.ndarray | None:
    """The (2, 3) similarity (rotation, uniform scale, shift) taking the face ``src`` to ``dst``:
    the scale of their boxes (the geometric mean of width and height), the roll of the line
    between the eyes, the boxes' centres matched - the box is the detector's steadiest output; its
    keypoints move with the light (measured on a side-lit synthetic face: a least-squares fit to
    the eyes, nose and mouth was 12 deg off in roll where the eyes' line was right). None when a
    box or the eyes are degenerate."""
    wa, ha = float(src.box[2] - src.box[0]), float(src.box[3] - src.box[1])
    wb, hb = float(dst.box[2] - dst.box[0]), float(dst.box[3] - dst.box[1])
    ea = src.keypoints[1] - src.keypoints[0]
    eb = dst.keypoints[1] - dst.keypoints[0]
    if not (min(wa, ha, wb, hb) > 1e-3 and np.hypot(*ea) > 1e-3 and np.hypot(*eb) > 1e-3):
        return None
    scale = float(np.sqrt((wb * hb) / (wa * ha)))
    roll = float(np.arctan2(eb[1], eb[0]) - np.arctan2(ea[1], ea[0]))
    m = scale * np.array([[np.cos(roll), -np.sin(roll)], [np.sin(roll), np.cos(roll)]])
    ca = 0.5 * (src.box[:2] + src.box[2:]).astype(np.float64)
    cb = 0.5 * (dst.box[:2] + dst.box[2:]).astype(np.float64)
    sim = np.concatenate([m, (cb - m @ ca)[:, None]], axis=1)
    return sim if np.isfinite(sim).all() else None
