"""One decoding pass over a capture video, keeping only what the later stages need.

Decoding dominates the cost of a capture (about 10 ms a frame at 960x540 here), so the video
is read once: the first seconds are held in full to find the face and the mirror sphere, then
every frame contributes its mean brightness and two crops (the face region and the sphere
region), converted from YUV without converting the rest of the frame.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from relight.colour import decode_srgb8
from relight.errors import InputError
from relight.video import crop_frame, frame_to_rgb, probe_video, read_frames_raw
from relight.video_colour import PLANAR_FORMATS, VideoColour, luma_table, video_colour

from . import registration, sphere

#: Seconds of frames held in full at the start (face and sphere are found there).
HEAD_SECONDS = 3.0
#: The stored face region: the detected face box grown by these factors (width, height), and
#: moved down a little (the chin, jaw and neck lie below a Haar box).
CROP_GROW = (2.0, 2.3)
CROP_SHIFT_DOWN = 0.15


@dataclass
class Ingested:
    """A capture video reduced to what the pipeline uses.

    frame_mean : (N,) mean linear luminance of each whole frame (0-1).
    crop : (x, y, w, h) of the stored face region; crops[i] its pixels as a
    :class:`relight.video.FrameCrop` (native YUV planes; ``.rgb()`` / ``.luma()`` convert).
    sphere_box / sphere_crops : the same for the mirror sphere (None without a sphere).
    colour : how the stream's codes become linear light (:mod:`relight.video_colour`).
    times : (N,) each frame's presentation time in seconds from the first (variable frame rate
    is common on phones: the stages that reason in time use these, not frame numbers).
    face_box : the face in frame coordinates; face_source: 'haar', 'given' or 'none'.
    sphere_guess : (cx, cy, r) from the first seconds (refined later), sphere_source likewise.
    still : the darkest early frame in full (H, W, 3) uint8, and still_index its frame number.
    """

    path: str
    fps: float
    size: tuple[int, int]
    frame_mean: np.ndarray
    crop: tuple[int, int, int, int]
    crops: list
    sphere_box: tuple[int, int, int, int] | None
    sphere_crops: list | None
    face_box: tuple[int, int, int, int] | None
    face_source: str
    sphere_guess: tuple[float, float, float] | None
    sphere_source: str
    still: np.ndarray
    still_index: int
    trace: np.ndarray
    colour: VideoColour = VideoColour()
    times: np.ndarray | None = None
    notes: list = field(default_factory=list)

    @property
    def frame_count(self) -> int:
        return len(self.crops)

    @property
    def crop_shape(self) -> tuple[int, int]:
        return self.crop[3], self.crop[2]

    def face_trace(self) -> np.ndarray:
        """(N,) mean linear luminance over the face (the whole stored region without a face)."""
        return self.trace


def _clip_box(box, size):
    x, y, w, h = (int(round(v)) for v in box)
    W, H = size
    x0, y0 = max(x, 0), max(y, 0)
    x1, y1 = min(x + w, W), min(y + h, H)
    if x1 <= x0 or y1 <= y0:
        raise InputError(f"region {box} lies outside the {W}x{H} frame")
    return x0, y0, x1 - x0, y1 - y0


def face_crop(face_box, size):
    """The stored region around a face box (grown, moved down, clipped to the frame)."""
    x, y, w, h = face_box
    cw, ch = w * CROP_GROW[0], h * CROP_GROW[1]
    cx, cy = x + w / 2, y + h / 2 + CROP_SHIFT_DOWN * h
    return _clip_box((cx - cw / 2, cy - ch / 2, cw, ch), size)


def ingest(path, *, face: tuple[int, int, int, int] | None = None,
           sphere_hint: tuple[float, float, float] | None = None,
           progress: Callable[[int], None] | None = None) -> Ingested:
    """Decode ``path`` once (see the module docstring).

    face : a face box (x, y, w, h) to use instead of detection. sphere_hint : (cx, cy, r) of the
    mirror sphere instead of detection.
    """
    info = probe_video(path)
    if info.fps <= 0:
        raise InputError(f"{path}: the video does not state a frame rate")
    size = (info.width, info.height)
    frames = read_frames_raw(path)
    head_n = max(int(round(HEAD_SECONDS * info.fps)), 8)
    head_raw = []
    for f in frames:
        head_raw.append(f)
        if len(head_raw) >= head_n:
            break
    if len(head_raw) < 8:
        raise InputError(f"{path}: {len(head_raw)} frames; a capture needs several seconds of video")
    head_rgb = [frame_to_rgb(f) for f in head_raw]
    colour = video_colour(head_raw[0])
    notes: list[str] = [f"video colour: {colour.describe()}"] + [f"video colour: {n}" for n in colour.notes]
    lut = decode_srgb8(np.arange(256, dtype=np.uint8))
    means = [float(lut[_luma(r)].mean()) for r in head_rgb]
    order = np.argsort(means)

    # The face: given, or Haar on the darkest early frames (no flash: the paper's reference).
    face_source = "given" if face is not None else "none"
    if face is None:
        for i in order[:8]:
            face = registration.detect_face(head_rgb[i])
            if face is not None:
                face_source = "haar"
                break
    else:
        face = _clip_box(face, size)
    still_index = int(order[0])
    still = head_rgb[still_index]

    # The sphere: given, or circles in the darkest frame checked against where the flashes
    # appear in the brightest ones.
    sphere_source = "given" if sphere_hint is not None else "none"
    if sphere_hint is None:
        bright = [head_rgb[i] for i in order[::-1][:12]]
        sphere_hint = sphere.find_sphere(still, bright, exclude=face)
        if sphere_hint is not None:
            sphere_source = "hough"
    if face is None:
        notes.append("no face detected in the first seconds; using features over the whole frame outside the "
                     "sphere (give --face x,y,w,h to choose the region)")
        crop = (0, 0, size[0], size[1])
    else:
        crop = face_crop(face, size)
    sbox = None
    if sphere_hint is not None:
        cx, cy, r = sphere_hint
        pad = max(0.35 * r, 6)
        sbox = _clip_box((cx - r - pad, cy - r - pad, 2 * (r + pad), 2 * (r + pad)), size)

    # The face's brightness trace is read from the luma as frames pass (decoded as if grey:
    # monotone in the brightness and exact on grey, which is all a trace needs).
    fx, fy, fw, fh = face or crop
    fx, fy = fx - crop[0], fy - crop[1]
    face_rows, face_cols = slice(max(fy, 0), fy + fh), slice(max(fx, 0), fx + fw)
    crops, scrops, fmean, trace, stamps = [], [] if sbox else None, [], [], []
    for f in _chain(head_raw, frames):
        c = crop_frame(f, crop)
        crops.append(c)
        trace.append(float(c.luma_linear()[face_rows, face_cols].mean()))
        if sbox is not None:
            scrops.append(crop_frame(f, sbox))
        fmean.append(_frame_mean(f, lut))
        stamps.append(f.time)
        if progress is not None:
            progress(1)
    times = frame_times(stamps, info.fps)
    if times is None:
        notes.append("frame timestamps missing or not increasing; frames taken as evenly spaced at "
                     f"{info.fps:g} fps")
        times = np.arange(len(crops)) / info.fps
    return Ingested(path=str(path), fps=info.fps, size=size, frame_mean=np.asarray(fmean), crop=crop,
                    crops=crops, sphere_box=sbox, sphere_crops=scrops, face_box=face, face_source=face_source,
                    sphere_guess=sphere_hint, sphere_source=sphere_source, still=still, still_index=still_index,
                    trace=np.asarray(trace), colour=colour, times=times, notes=notes)


def _chain(first, rest):
    yield from first
    yield from rest


def _luma(rgb: np.ndarray) -> np.ndarray:
    import cv2

    return cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)


def _frame_mean(frame, lut) -> float:
    """Mean linear brightness of a whole frame from its luma plane (subsampled 4x: it is a trace)."""
    name = frame.format.name
    if name in PLANAR_FORMATS:
        colour = video_colour(frame)
        p = frame.planes[0]
        if colour.plain_srgb8:
            y = np.frombuffer(p, dtype=np.uint8).reshape(frame.height, p.line_size)[::4, :frame.width:4]
            if not colour.full_range:
                y = np.clip((y.astype(np.int32) - 16) * 255 // 219, 0, 255).astype(np.uint8)
            return float(lut[y].mean())
        dtype = np.uint8 if colour.bits == 8 else np.dtype("<u2")
        y = np.frombuffer(p, dtype=dtype).reshape(frame.height, -1)[::4, :frame.width:4]
        return float(luma_table(colour)[np.minimum(y, (1 << colour.bits) - 1)].mean())
    return float(lut[_luma(frame_to_rgb(frame))[::4, ::4]].mean())


#: Frame-to-frame gaps a timestamp track may show before it is distrusted, as a share of the
#: stated frame period (a gap of 0 or below is always distrusted).
MAX_GAP_PERIODS = 50.0


def frame_times(stamps, fps: float) -> np.ndarray | None:
    """(N,) seconds from the first frame, from the frames' presentation times (PyAV's
    ``frame.time``), or None when they are missing, not increasing, or have gaps longer than
    :data:`MAX_GAP_PERIODS` frame periods (a broken track, not a variable frame rate)."""
    if not stamps or any(t is None for t in stamps):
        return None
    t = np.asarray(stamps, dtype=np.float64)
    if not np.isfinite(t).all():
        return None
    t = t - t[0]
    if t.size > 1:
        gaps = np.diff(t)
        if (gaps <= 0).any() or (fps > 0 and gaps.max() > MAX_GAP_PERIODS / fps):
            return None
    return t
