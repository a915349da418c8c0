"""A decoded video frame kept in its Y'CbCr planes, converted only where it is touched.

Converting a whole 1280x720 frame to RGB costs 11.7 ms of CPU here and back to Y'CbCr for the
encoder 8.7 ms (swscale with :func:`relight.video.sws_flags`, as :func:`relight.video.frame_to_rgb`
and :func:`relight.video.to_yuv` do) - more than the per-frame path's own work. :class:`YuvFrame`
keeps the decoder's planes: the tracker gets a small grey image made from them, the light field a
small copy of a box (:meth:`YuvFrame.small_box`), the live light a few samples
(:func:`sample_codes`), and the light field is applied in the planes themselves
(:meth:`YuvFrame.with_field`) - the rest of the frame leaves bit for bit as it came.

Which frames: 8-bit 4:2:0 (``yuv420p``), Rec.709 primaries, SDR, no display rotation or mirror,
and - because the output is tagged so - the BT.709 matrix (or untagged at 720 lines and more,
which players read as BT.709) in limited range. Anything else takes the RGB path
(:func:`YuvFrame.from_av` returns None).

Planes: ``y`` (H, W), ``u`` and ``v`` (H/2, W/2) uint8, limited range (16-235 / 16-240). Boxes
are (x0, y0, x1, y1) pixels, x1/y1 exclusive, aligned to even numbers where the chroma needs it.
"""

from __future__ import annotations

import cv2
import numpy as np

#: BT.709 luma weights (Kr, Kb) and the limited range's scales (8-bit codes).
_KR, _KB = 0.2126, 0.0722
_Y_SCALE, _C_SCALE = 255.0 / 219.0, 255.0 / 224.0
#: OpenCV's RGB -> grey weights (``cv2.COLOR_RGB2GRAY``: BT.601's), which the tracker's
#: reference grey uses.
_GREY = (0.299, 0.587, 0.114)


def downscale_area(img: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """``img`` scaled down to ``size`` (w, h) by area: halved by area while that stays at least
    ``size``, then the rest (OpenCV's area filter at a non-integer scale costs 2.5 ms on a 720p
    plane, 0.9 this way; within a code or two of it on average)."""
    w, h = size
    while img.shape[1] >= 2 * w and img.shape[0] >= 2 * h:
        img = cv2.resize(img, (img.shape[1] // 2, img.shape[0] // 2), interpolation=cv2.INTER_AREA)
    if (img.shape[1], img.shape[0]) == (w, h):
        return img
    return cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA)


def _ycbcr_matrix() -> np.ndarray:
    """(3, 3) float64: limited-range BT.709 8-bit codes (Y', Cb - 128, Cr - 128) -> R'G'B' codes."""
    kg = 1.0 - _KR - _KB
    # R' = Y' + 2 (1 - Kr) Cr, B' = Y' + 2 (1 - Kb) Cb, G' = Y' - (2 Kb (1 - Kb) Cb + 2 Kr (1 - Kr) Cr) / Kg
    return np.array([[_Y_SCALE, 0.0, 2.0 * (1.0 - _KR) * _C_SCALE],
                     [_Y_SCALE, -2.0 * _KB * (1.0 - _KB) / kg * _C_SCALE, -2.0 * _KR * (1.0 - _KR) / kg * _C_SCALE],
                     [_Y_SCALE, 2.0 * (1.0 - _KB) * _C_SCALE, 0.0]])


_YCBCR = _ycbcr_matrix()
_OFFSET = np.array([16.0, 128.0, 128.0])
#: (3, 4) float32 affine maps for cv2.transform: codes (Y', Cb, Cr) -> R'G'B', and back.
_TO_RGB = np.hstack([_YCBCR, -(_YCBCR @ _OFFSET)[:, None]]).astype(np.float32)
_TO_YCBCR = np.hstack([np.linalg.inv(_YCBCR), _OFFSET[:, None]]).astype(np.float32)


def planes_to_rgb(y: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(h, w, 3) uint8 sRGB codes of 4:2:0 limited-range BT.709 planes (``y`` (h, w) even-sized,
    ``u``, ``v`` (h/2, w/2)): the chroma upsampled bilinearly (samples centred on their 2x2
    block), the matrix applied and rounded to the nearest code (OpenCV's vector paths: 0.65 ms for
    a 440x610 box here, where swscale's exact settings take 4.4; within a code of them on average
    - their chroma filter is bicubic - and as unbiased: tests/test_video.py)."""
    h, w = y.shape
    up = cv2.resize(cv2.merge([u, v]), (w, h), interpolation=cv2.INTER_LINEAR)
    return cv2.transform(cv2.merge([y, up]), _TO_RGB)


def rgb_to_planes(rgb: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(y, u, v) uint8 4:2:0 limited-range BT.709 planes of (h, w, 3) uint8 sRGB codes (even
    sizes): the matrix in float, luma rounded, chroma averaged over each 2x2 block then rounded -
    the inverse of :func:`planes_to_rgb` (the same siting)."""
    h, w = rgb.shape[:2]
    rgb = np.ascontiguousarray(rgb)
    y = cv2.transform(rgb, _TO_YCBCR[:1])  # rounded to the nearest code
    # the matrix is linear: the 2x2 blocks' mean RGB gives their mean chroma (codes 16-240:
    # convertScaleAbs rounds them as they are)
    small = cv2.resize(rgb.astype(np.float32), (w // 2, h // 2), interpolation=cv2.INTER_AREA)
    u, v = cv2.split(cv2.convertScaleAbs(cv2.transform(small, _TO_YCBCR[1:])))
    return y.reshape(h, w), u, v


def _grey_weights() -> tuple[float, float, float, float]:
    """(a, b, c, d): cv2's grey of the RGB a limited-range BT.709 pixel decodes to, as
    a Y + b (Cb - 128) + c (Cr - 128) + d (before clipping) - the conversion is linear."""
    _, b, c = np.asarray(_GREY) @ _YCBCR
    a = _Y_SCALE  # the grey weights sum to 1
    return a, float(b), float(c), -16.0 * _Y_SCALE


class YuvFrame:
    """One 8-bit 4:2:0 frame as decoded (see the module docstring)."""

    def __init__(self, y: np.ndarray, u: np.ndarray, v: np.ndarray, colorspace: int = 1, color_range: int = 1):
        h, w = y.shape
        if h % 2 or w % 2 or u.shape != (h // 2, w // 2) or v.shape != u.shape:
            raise ValueError(f"planes {y.shape}, {u.shape}, {v.shape}: not 4:2:0 of an even-sized frame")
        self.y, self.u, self.v = y, u, v
        self.colorspace, self.color_range = int(colorspace), int(color_range)

    # ------------------------------------------------------------------ in and out
    @classmethod
    def from_av(cls, frame) -> YuvFrame | None:
        """The frame's planes (copied), or None when the frame is not one this path keeps."""
        from .video_colour import video_colour
        from .video_orient import display_orientation

        if frame.format.name != "yuv420p" or frame.width % 2 or frame.height % 2:
            return None
        colour = video_colour(frame)
        if colour.bits != 8 or colour.primaries != "bt709" or colour.hdr or colour.full_range:
            return None
        if colour.matrix != "bt709" or display_orientation(frame) != (0, False):
            return None
        h, w = frame.height, frame.width

        def plane(i, ph, pw):
            p = frame.planes[i]
            return np.frombuffer(p, np.uint8).reshape(ph, p.line_size)[:, :pw].copy()

        return cls(plane(0, h, w), plane(1, h // 2, w // 2), plane(2, h // 2, w // 2))

    def to_av(self):
        """An ``av.VideoFrame`` (yuv420p) of these planes, tagged BT.709 limited range."""
        import av

        frame = av.VideoFrame.from_ndarray(self._i420(self.y, self.u, self.v), format="yuv420p")
        frame.colorspace, frame.color_range = self.colorspace, self.color_range
        return frame

    @staticmethod
    def _i420(y, u, v) -> np.ndarray:
        """The planes packed as PyAV's yuv420p arrays are: (3H/2, W), the planes one after the other."""
        h, w = y.shape
        return np.concatenate([y.ravel(), u.ravel(), v.ravel()]).reshape(h * 3 // 2, w)

    @property
    def shape(self) -> tuple[int, int, int]:
        """(H, W, 3): the shape of the RGB frame this is."""
        return (self.y.shape[0], self.y.shape[1], 3)

    def to_rgb(self) -> np.ndarray:
        """The whole frame as (H, W, 3) uint8 sRGB codes (what :func:`relight.video.frame_to_rgb` gives)."""
        return self._rgb(self.y, self.u, self.v)

    def _rgb(self, y, u, v) -> np.ndarray:
        import av
        from av.video.reformatter import ColorRange, Colorspace

        from .video_frame import sws_flags

        frame = av.VideoFrame.from_ndarray(self._i420(y, u, v), format="yuv420p")
        return frame.reformat(format="rgb24", src_colorspace=Colorspace.ITU709, src_color_range=ColorRange.MPEG,
                              interpolation=sws_flags()).to_ndarray()

    # ------------------------------------------------------------------ what the frame path touches
    def tracking_grey(self, size: tuple[int, int]) -> np.ndarray:
        """(h, w) uint8: ``cv2.COLOR_RGB2GRAY`` of the RGB frame, scaled to ``size`` (w, h) by
        :func:`downscale_area` - made from the planes scaled first (the conversion is linear;
        clipping aside, the same)."""
        w, h = size
        a, b, c, d = _grey_weights()
        ys = downscale_area(self.y, (w, h))
        if w <= self.u.shape[1]:
            us, vs = downscale_area(self.u, (w, h)), downscale_area(self.v, (w, h))
        else:
            us = cv2.resize(self.u, (w, h), interpolation=cv2.INTER_LINEAR)
            vs = cv2.resize(self.v, (w, h), interpolation=cv2.INTER_LINEAR)
        g = cv2.addWeighted(ys, a, us, b, d - 128.0 * (b + c), dtype=cv2.CV_32F)
        g = cv2.scaleAdd(vs.astype(np.float32), c, g)
        _, g = cv2.threshold(g, 0.0, 0.0, cv2.THRESH_TOZERO)  # below 0 -> 0
        return cv2.convertScaleAbs(g)  # rounded, saturated at 255

    def small_rgb(self, size: tuple[int, int]) -> np.ndarray:
        """(h, w, 3) uint8 sRGB of the frame scaled down to ``size`` (w, h) by
        :func:`downscale_area`: the planes scaled first, then converted (the conversion is linear:
        clipping aside, the same). An odd size, or one not smaller than the frame, from the RGB."""
        w, h = size
        if w % 2 or h % 2 or w >= self.y.shape[1] or h >= self.y.shape[0]:
            return downscale_area(self.to_rgb(), (w, h))
        return planes_to_rgb(downscale_area(self.y, (w, h)), downscale_area(self.u, (w // 2, h // 2)),
                             downscale_area(self.v, (w // 2, h // 2)))

    def small_box(self, box: tuple[int, int, int, int], factor: int) -> np.ndarray:
        """(h, w, 3) uint8 sRGB of the frame's ``box`` - its corner a multiple of the ``factor``
        (even, or 1: then of 2), its size too (its far edges may pass the frame's: the last pixels
        are replicated) - scaled down by ``factor``: each plane's blocks averaged, then converted
        (the conversion is linear); at factor 1 the box itself (:func:`planes_to_rgb`)."""
        x0, y0, x1, y1 = box

        def shrink(plane, b, f):
            bx0, by0, bx1, by1 = b
            ph, pw = plane.shape
            crop = plane[by0:min(by1, ph), bx0:min(bx1, pw)]
            if bx1 > pw or by1 > ph:
                crop = cv2.copyMakeBorder(crop, 0, max(by1 - ph, 0), 0, max(bx1 - pw, 0), cv2.BORDER_REPLICATE)
            if f == 1:
                return np.ascontiguousarray(crop)
            return cv2.resize(crop, ((bx1 - bx0) // f, (by1 - by0) // f), interpolation=cv2.INTER_AREA)

        ys = shrink(self.y, box, factor)
        half = (x0 // 2, y0 // 2, -(-x1 // 2), -(-y1 // 2))
        if factor == 1:  # (the box's corner and size even: whole chroma samples)
            return planes_to_rgb(ys, shrink(self.u, half, 1), shrink(self.v, half, 1))
        return cv2.transform(cv2.merge([ys, shrink(self.u, half, factor // 2), shrink(self.v, half, factor // 2)]),
                             _TO_RGB)

    @property
    def space(self) -> tuple:
        """What its codes are: the planes' matrix and range (a light field made for them maps them)."""
        return ("ycbcr", self.colorspace, self.color_range)

    def code_maps(self) -> tuple[np.ndarray, np.ndarray]:
        """((3, 4), (3, 4)) float32 affine maps of its codes (Y', Cb, Cr, 1) -> R'G'B' codes and back."""
        return _TO_RGB, _TO_YCBCR

    def with_field(self, applier, box, grid: np.ndarray, sampling) -> YuvFrame:
        """A new frame: this one with a light field (maps of its codes: :meth:`code_maps`) applied
        over ``box`` in its planes (:meth:`relight.kernels.field_apply.FieldApplier.planes`)."""
        y, u, v = applier.planes(self.y, self.u, self.v, box, grid, sampling)
        return YuvFrame(y, u, v, self.colorspace, self.color_range)


def sample_codes(frame, xy: np.ndarray) -> np.ndarray:
    """(N, 3) uint8 sRGB codes of ``frame`` ((H, W, 3) uint8 sRGB or a :class:`YuvFrame`) read
    bilinearly at frame positions ``xy`` (N, 2) float (edges replicated) - for a YuvFrame its
    planes read there (the chroma at its own siting, centred on its 2x2 block) and converted."""
    xy = np.asarray(xy, np.float32).reshape(-1, 1, 2)
    if xy.shape[0] == 0:
        return np.zeros((0, 3), np.uint8)
    mx, my = np.ascontiguousarray(xy[..., 0]), np.ascontiguousarray(xy[..., 1])
    if isinstance(frame, np.ndarray):
        return cv2.remap(frame, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).reshape(-1, 3)
    ys = cv2.remap(frame.y, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    cx, cy = (mx - np.float32(0.5)) * np.float32(0.5), (my - np.float32(0.5)) * np.float32(0.5)
    us = cv2.remap(frame.u, cx, cy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    vs = cv2.remap(frame.v, cx, cy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return cv2.transform(cv2.merge([ys, us, vs]), _TO_RGB).reshape(-1, 3)


def as_rgb(frame) -> np.ndarray:
    """(H, W, 3) uint8 sRGB of a frame: an array as it is, a :class:`YuvFrame` converted whole."""
    return frame.to_rgb() if isinstance(frame, YuvFrame) else frame
