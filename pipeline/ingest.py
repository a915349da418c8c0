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

from relight import faces
from relight.colour import decode_srgb8
from relight.errors import InputError
from relight.video_colour import PLANAR_FORMATS, VideoColour, luma_table, video_colour
from relight.video_frame import crop_frame, frame_to_rgb, whole_frame
from relight.video_read import probe_video, read_frames_raw

from . import sphere

#: Seconds of frames held in full at the start (face and sphere are found there).
HEAD_SECONDS = 3.0
#: The stored face region: the detected face box grown by these factors (width, height), and
#: moved down a little (the chin, jaw and neck lie below a Haar box).
CROP_GROW = (2.0, 2.3)
CROP_SHIFT_DOWN = 0.15
#: ``relight capture --face-pixels``: the head is worked on at no more than about this many
#: pixels; larger captures (1080p, 4K phones) are downscaled as they are decoded. 100k is a head
#: in 720p video - what the live side shows it at - and keeps time and memory bounded.
DEFAULT_FACE_PIXELS = 100_000
#: Head pixels per pixel of the stored face region (measured on the synthetic heads: 0.28-0.31),
#: to tell the head's size from the region before there is a mask.
HEAD_SHARE_OF_CROP = 0.3
#: Face and sphere detection run on the first seconds at no more than this many pixels across
#: (4K frames are scaled down for it; the circles and Haar boxes are scaled back).
DETECT_MAX_SIDE = 1280
#: The first seconds' decoded frames are kept for the main pass when they take at most this
#: many bytes; otherwise the video is decoded again from the start (bounded memory at 4K).
HOLD_HEAD_BYTES = 512 << 20


@dataclass
class Ingested:
    """A capture video reduced to what the pipeline uses.

    frame_mean : (N,) mean linear luminance of each whole frame (0-1).
    crop : (x, y, w, h) of the stored face region; crops[i] its pixels as a
    :class:`relight.video_frame.FrameCrop` (native YUV planes; ``.rgb()`` / ``.luma()`` convert).
    sphere_box / sphere_crops : the same for the mirror sphere (None without a sphere).
    colour : how the stream's codes become linear light (:mod:`relight.video_colour`).
    scale : stored pixels per pixel of the video (< 1 when downscaled for ``face_pixels``); every
    coordinate here (size, boxes, crops, the sphere) is in the scaled frame.
    source_size : (W, H) of the video as displayed.
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
    scale: float = 1.0
    source_size: tuple[int, int] | None = None
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


def _scaled_box(box, s: float, size) -> tuple[int, int, int, int]:
    x, y, w, h = box
    return _clip_box((x * s, y * s, max(w * s, 1.0), max(h * s, 1.0)), size)


def ingest(path, *, face: tuple[int, int, int, int] | None = None,
           sphere_hint: tuple[float, float, float] | None = None,
           progress: Callable[[int], None] | None = None,
           face_pixels: int | None = DEFAULT_FACE_PIXELS) -> Ingested:
    """Decode ``path`` once (see the module docstring).

    face : a face box (x, y, w, h) to use instead of detection. sphere_hint : (cx, cy, r) of the
    mirror sphere instead of detection (both in pixels of the video as displayed).
    face_pixels : downscale the capture so the head has about this many pixels (None: never).
    """
    info = probe_video(path)
    if info.fps <= 0:
        raise InputError(f"{path}: the video does not state a frame rate")
    if face_pixels is not None and not (1000 <= int(face_pixels) <= 10_000_000):
        raise InputError(f"--face-pixels {face_pixels}: use 1000 to 10000000 (default {DEFAULT_FACE_PIXELS})")
    size = (info.width, info.height)
    frames = read_frames_raw(path)
    head_n = max(int(round(HEAD_SECONDS * info.fps)), 8)
    # The first seconds, for detection: at most DETECT_MAX_SIDE pixels across, and the darkest
    # frame (the background) kept as decoded.
    det = min(1.0, DETECT_MAX_SIDE / max(size))
    det_size = (max(int(round(size[0] * det)), 1), max(int(round(size[1] * det)), 1))
    hold = info.coded_size[0] * info.coded_size[1] * 3 * head_n <= HOLD_HEAD_BYTES
    lut = decode_srgb8(np.arange(256, dtype=np.uint8))
    head_raw, head_rgb, means, darkest, colour = _read_head(frames, head_n, det, det_size, hold, lut)
    if len(head_rgb) < 8:
        raise InputError(f"{path}: {len(head_rgb)} frames; a capture needs several seconds of video")
    notes: list[str] = [f"video colour: {colour.describe()}"] + [f"video colour: {n}" for n in colour.notes]
    order = np.argsort(means)
    face, face_source = _find_face(face, head_rgb, order, det, size)
    still_index = int(order[0])
    sphere_hint, sphere_source = _find_sphere(sphere_hint, head_rgb, order, still_index, face, darkest[1],
                                              det, det_size, size)
    still_rgb = head_rgb[still_index] if det == 1.0 else None
    del head_rgb

    lay = _layout(face, sphere_hint, size, face_pixels, notes)
    s, work, crop = lay.scale, lay.work, lay.crop
    face_w = None if face is None else _scaled_box(face, s, work)
    guess_w = None if sphere_hint is None else tuple(float(v) * s for v in sphere_hint)
    still = still_rgb if s == 1.0 and still_rgb is not None else whole_frame(darkest[1]).resized(work).rgb()
    del darkest

    if not hold:
        frames.close()  # the first seconds are decoded again: memory bounded at any frame size
    source = _chain(head_raw, frames) if hold else read_frames_raw(path)
    crops, scrops, fmean, trace, stamps = _decode_all(source, lay, _face_window(face_w or crop, crop), lut, progress)
    times = frame_times(stamps, info.fps)
    if times is None:
        notes.append("frame timestamps missing or not increasing; frames taken as evenly spaced at "
                     f"{info.fps:g} fps")
        times = np.arange(len(crops)) / info.fps
    return Ingested(path=str(path), fps=info.fps, size=work, frame_mean=np.asarray(fmean), crop=crop,
                    crops=crops, sphere_box=lay.sbox, sphere_crops=scrops, face_box=face_w, face_source=face_source,
                    sphere_guess=guess_w, sphere_source=sphere_source, still=still, still_index=still_index,
                    trace=np.asarray(trace), colour=colour, times=times, scale=s, source_size=size, notes=notes)


def _read_head(frames, head_n: int, det: float, det_size, hold: bool, lut):
    """Decode the first ``head_n`` frames: (raw frames kept when ``hold``, else empty; RGB copies
    (H, W, 3) uint8 at the detection scale ``det``; each frame's mean linear brightness; (index,
    raw frame) of the darkest; the stream's :class:`VideoColour`, None without frames)."""
    head_raw, head_rgb, means = [], [], []
    darkest, colour = None, None
    for f in frames:
        if colour is None:
            colour = video_colour(f)
        rgb = frame_to_rgb(f) if det == 1.0 else whole_frame(f).resized(det_size).rgb()
        head_rgb.append(rgb)
        means.append(float(lut[_luma(rgb)].mean()))
        if darkest is None or means[-1] < means[darkest[0]]:
            darkest = (len(means) - 1, f)
        if hold:
            head_raw.append(f)
        if len(head_rgb) >= head_n:
            break
    return head_raw, head_rgb, means, darkest, colour


def _find_face(face, head_rgb: list, order: np.ndarray, det: float, size):
    """The face box (x, y, w, h) in video pixels and its source: given (clipped to the frame), Haar
    on the darkest early frames (no flash: the paper's reference), or (None, 'none')."""
    face_source = "given" if face is not None else "none"
    if face is None:
        for i in order[:8]:
            found = faces.detect_face(head_rgb[i])
            if found is not None:
                face = _scaled_box(found, 1.0 / det, size)
                face_source = "haar"
                break
    else:
        face = _clip_box(face, size)
    return face, face_source


def _find_sphere(sphere_hint, head_rgb: list, order: np.ndarray, still_index: int, face, darkest_frame,
                 det: float, det_size, size):
    """The mirror sphere (cx, cy, r) in video pixels and its source: given, or circles in the darkest
    frame checked against where the flashes appear in the brightest ones, or (None, 'none')."""
    sphere_source = "given" if sphere_hint is not None else "none"
    if sphere_hint is None:
        bright = [head_rgb[i] for i in order[::-1][:12]]
        exclude = None if face is None else _scaled_box(face, det, det_size)
        found = sphere.find_sphere(head_rgb[still_index], bright, exclude=exclude)
        if found is not None:
            sphere_hint = tuple(float(v) / det for v in found)
            sphere_source = "hough"
            if det < 1.0:
                # Found on a scaled-down copy: its outline refined on the video's own pixels (left
                # to the later, working-scale refinement, a guess 4 px off measured 2.2 deg mean
                # light-direction error on a downscaled synth capture; refined here, 0.85).
                sphere_hint = _refine_on(darkest_frame, sphere_hint, size)
    return sphere_hint, sphere_source


@dataclass
class _Layout:
    """The working scale and the stored regions (x, y, w, h), in video pixels (``*_full``) and in
    the working frame's (``crop``, ``sbox``).

    scale : working pixels per video pixel. work : (W, H) of the working frame.
    sbox_full / sbox : the sphere's region, None without a sphere.
    """

    scale: float
    work: tuple[int, int]
    crop_full: tuple[int, int, int, int]
    crop: tuple[int, int, int, int]
    sbox_full: tuple[int, int, int, int] | None
    sbox: tuple[int, int, int, int] | None


def _layout(face, sphere_hint, size, face_pixels: int | None, notes: list[str]) -> _Layout:
    """The working scale (the head at about ``face_pixels`` pixels) and the face and sphere regions;
    notes a downscale and a missing face in ``notes``."""
    crop_full = (0, 0, size[0], size[1]) if face is None else face_crop(face, size)
    head_est = HEAD_SHARE_OF_CROP * crop_full[2] * crop_full[3]
    s = 1.0 if face_pixels is None or head_est <= face_pixels else float(np.sqrt(face_pixels / head_est))
    work = (max(int(round(size[0] * s)), 1), max(int(round(size[1] * s)), 1))
    if s < 1.0:
        notes.append(f"downscaled by {s:.3f} to {work[0]}x{work[1]} (head ~{head_est:.0f} px, --face-pixels "
                     f"{face_pixels})")
    if face is None:
        notes.append("no face detected in the first seconds; using features over the whole frame outside the "
                     "sphere (give --face x,y,w,h to choose the region)")
        crop = (0, 0, work[0], work[1])
    else:
        crop = _scaled_box(crop_full, s, work)
    sbox_full = sbox = None
    if sphere_hint is not None:
        cx, cy, r = sphere_hint
        pad = max(0.35 * r, 6 / s)
        sbox_full = _clip_box((cx - r - pad, cy - r - pad, 2 * (r + pad), 2 * (r + pad)), size)
        sbox = _scaled_box(sbox_full, s, work)
    return _Layout(scale=s, work=work, crop_full=crop_full, crop=crop, sbox_full=sbox_full, sbox=sbox)


def _face_window(face_w, crop) -> tuple[slice, slice]:
    """(rows, cols) of the face box ``face_w`` (working frame) inside the stored region ``crop``."""
    fx, fy, fw, fh = face_w
    fx, fy = fx - crop[0], fy - crop[1]
    return slice(max(fy, 0), fy + fh), slice(max(fx, 0), fx + fw)


def _decode_all(source, lay: _Layout, face_window: tuple[slice, slice], lut, progress):
    """The main pass over every frame: (face crops, sphere crops or None, each frame's mean linear
    brightness, the face's brightness trace, presentation times)."""
    # The face's brightness trace is read from the luma as frames pass (decoded as if grey:
    # monotone in the brightness and exact on grey, which is all a trace needs).
    s, crop, crop_full, sbox, sbox_full = lay.scale, lay.crop, lay.crop_full, lay.sbox, lay.sbox_full
    face_rows, face_cols = face_window
    crops, scrops, fmean, trace, stamps = [], [] if sbox else None, [], [], []
    for f in source:
        if s == 1.0:
            c = crop_frame(f, crop)
        else:
            c = crop_frame(f, crop_full).resized(crop[2:])
        crops.append(c)
        trace.append(float(c.luma_linear()[face_rows, face_cols].mean()))
        if sbox is not None:
            # The sphere keeps the averaged codes' precision: its highlight is located to a
            # fraction of a (downscaled) pixel.
            scrops.append(crop_frame(f, sbox) if s == 1.0 else crop_frame(f, sbox_full).resized(sbox[2:], precise=True))
        fmean.append(_frame_mean(f, lut))
        stamps.append(f.time)
        if progress is not None:
            progress(1)
    return crops, scrops, fmean, trace, stamps


def _refine_on(frame, circle, size, rounds: int = 2):
    """``circle`` (cx, cy, r) refined on a decoded frame's luminance near it (only that region
    converted); ``size``: the frame as displayed."""
    from relight.colour import luminance

    cx, cy, r = circle
    pad = 0.8 * r + 4
    x0, y0, w, h = _clip_box((cx - r - pad, cy - r - pad, 2 * (r + pad) + 1, 2 * (r + pad) + 1), size)
    local = luminance(crop_frame(frame, (x0, y0, w, h)).linear())
    guess = (cx - x0, cy - y0, r)
    for _ in range(rounds):
        guess = sphere.refine_circle(local, guess)
    return (guess[0] + x0, guess[1] + y0, guess[2])


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
