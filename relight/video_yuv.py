"""A decoded video frame kept in its Y'CbCr planes, converted only where it is touched.

Converting a whole 1280x720 frame to RGB costs 11.7 ms of CPU here and back to Y'CbCr for the
encoder 8.7 ms (swscale with :func:`relight.video_frame.sws_flags`, as :func:`relight.video_frame.frame_to_rgb`
and :func:`relight.video_write.to_yuv` do) - more than the per-frame path's own work. :class:`YuvFrame`
keeps the decoder's planes: the tracker gets a small grey image made from them, the light field a
small copy of a box (:meth:`YuvFrame.small_box`), the live light a few samples
(:func:`sample_codes`), and the light field is applied in the planes themselves
(:meth:`YuvFrame.with_field`) - the rest of the frame leaves bit for bit as it came.

Which frames (:meth:`YuvFrame.from_av`): 8-bit 4:2:0 or 4:2:2 - planar (``yuv420p``,
``yuv422p``, their full-range JPEG forms ``yuvj420p``/``yuvj422p``: a webcam's MJPEG), or a
camera's own interleaved forms, unpacked (``nv12``, ``yuyv422``) - with the BT.709 or BT.601
matrix in limited or full range (:class:`Codes`), Rec.709 primaries, SDR, no display rotation or
mirror. Anything else takes the RGB path (``from_av`` returns None).

Planes: ``y`` (H, W), ``u`` and ``v`` (H/2, W/2) for 4:2:0 or (H, W/2) for 4:2:2, uint8. Boxes
are (x0, y0, x1, y1) pixels, x1/y1 exclusive.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

#: OpenCV's RGB -> grey weights (``cv2.COLOR_RGB2GRAY``: BT.601's), which the tracker's
#: reference grey uses.
_GREY = (0.299, 0.587, 0.114)
#: Luma weights (Kr, Kb) of the matrices a kept frame may have.
_K = {"bt709": (0.2126, 0.0722), "bt601": (0.299, 0.114)}
#: Pixel formats kept in their planes: (chroma rows per luma row: 2 for 4:2:0, 1 for 4:2:2,
#: full range by the format itself - the JPEG forms).
KEPT_FORMATS = {"yuv420p": (2, False), "yuvj420p": (2, True), "nv12": (2, False), "yuv422p": (1, False),
                "yuvj422p": (1, True), "yuyv422": (1, False)}


def _halve_then(img: np.ndarray, size: tuple[int, int], rest: int) -> np.ndarray:
    """``img`` halved by area while that stays at least ``size`` (w, h), then scaled the rest of
    the way (less than a halving) with OpenCV's interpolation ``rest``."""
    w, h = size
    while img.shape[1] >= 2 * w and img.shape[0] >= 2 * h:
        img = cv2.resize(img, (img.shape[1] // 2, img.shape[0] // 2), interpolation=cv2.INTER_AREA)
    if (img.shape[1], img.shape[0]) == (w, h):
        return img
    return cv2.resize(img, (w, h), interpolation=rest)


def downscale_fast(img: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """``img`` scaled down to ``size`` (w, h): halved by area while that stays at least ``size``,
    then the rest (less than a halving) bilinearly - OpenCV's area filter at a non-integer scale
    costs 1.6 ms a 640x360 plane here, the bilinear step 0.3 (the tracker's copy: what is left to
    scale after the halvings aliases little)."""
    return _halve_then(img, size, cv2.INTER_LINEAR)


def downscale_area(img: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """``img`` scaled down to ``size`` (w, h) by area: halved by area while that stays at least
    ``size``, then the rest (OpenCV's area filter at a non-integer scale costs 2.5 ms on a 720p
    plane, 0.9 this way; within a code or two of it on average)."""
    return _halve_then(img, size, cv2.INTER_AREA)


@dataclass(frozen=True)
class Codes:
    """What a frame's Y'CbCr codes are: its ``matrix`` ('bt709' or 'bt601') and whether they are
    ``full`` range (0-255) or limited (16-235, chroma 16-240)."""

    matrix: str = "bt709"
    full: bool = False

    def maps(self) -> tuple[np.ndarray, np.ndarray]:
        """((3, 4), (3, 4)) float32 affine maps of 8-bit codes (Y', Cb, Cr, 1) -> R'G'B' (0-255)
        and back."""
        kr, kb = _K[self.matrix]
        kg = 1.0 - kr - kb
        ys, cs = (1.0, 1.0) if self.full else (255.0 / 219.0, 255.0 / 224.0)
        # R' = Y' + 2 (1 - Kr) Cr, B' = Y' + 2 (1 - Kb) Cb, G' = Y' - (2 Kb (1 - Kb) Cb + 2 Kr (1 - Kr) Cr) / Kg
        m = np.array([[ys, 0.0, 2.0 * (1.0 - kr) * cs],
                      [ys, -2.0 * kb * (1.0 - kb) / kg * cs, -2.0 * kr * (1.0 - kr) / kg * cs],
                      [ys, 2.0 * (1.0 - kb) * cs, 0.0]])
        off = np.array([0.0 if self.full else 16.0, 128.0, 128.0])
        to_rgb = np.hstack([m, -(m @ off)[:, None]]).astype(np.float32)
        to_ycc = np.hstack([np.linalg.inv(m), off[:, None]]).astype(np.float32)
        return to_rgb, to_ycc

    def grey_weights(self) -> tuple[float, float, float, float]:
        """(a, b, c, d): cv2's grey of the RGB a pixel decodes to, as a Y + b (Cb - 128) + c (Cr -
        128) + d (before clipping) - the conversion is linear."""
        to_rgb, _ = self.maps()
        m = to_rgb[:, :3].astype(np.float64)
        a, b, c = np.asarray(_GREY) @ m
        return float(a), float(b), float(c), float(np.asarray(_GREY) @ (to_rgb[:, 3] + m[:, 1:] @ [128.0, 128.0]))

    @property
    def av_tags(self):
        """(swscale's colourspace, range) of these codes."""
        from av.video.reformatter import ColorRange, Colorspace

        return (Colorspace.ITU709 if self.matrix == "bt709" else Colorspace.ITU601,
                ColorRange.JPEG if self.full else ColorRange.MPEG)


#: The codes relight writes (H.264, tagged so) and :func:`planes_to_rgb` / :func:`rgb_to_planes` use.
BT709 = Codes("bt709", False)
_TO_RGB, _TO_YCBCR = BT709.maps()


def planes_to_rgb(y: np.ndarray, u: np.ndarray, v: np.ndarray, codes: Codes = BT709) -> np.ndarray:
    """(h, w, 3) uint8 sRGB codes of 4:2:0 or 4:2:2 planes (``y`` (h, w), even width and, for
    4:2:0, height; ``u``, ``v`` (h/2 or h, w/2)): the chroma upsampled bilinearly (samples centred
    on their blocks), ``codes``' matrix applied and rounded to the nearest code (OpenCV's vector
    paths: 0.65 ms for a 440x610 box here, where swscale's exact settings take 4.4; within a code
    of them on average - their chroma filter is bicubic - and as unbiased: tests/test_video.py)."""
    h, w = y.shape
    to_rgb, _ = codes.maps() if codes is not BT709 else (_TO_RGB, _TO_YCBCR)
    up = cv2.resize(cv2.merge([u, v]), (w, h), interpolation=cv2.INTER_LINEAR)
    return cv2.transform(cv2.merge([y, up]), to_rgb)


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


def block_means(plane: np.ndarray, box, fx: int, fy: int) -> np.ndarray:
    """The mean of each ``fx`` x ``fy`` block of ``plane``'s ``box`` ((H, W) or (H, W, C); its far
    edges beyond the plane: its last row and column replicated)."""
    bx0, by0, bx1, by1 = box
    ph, pw = plane.shape[:2]
    crop = plane[by0:min(by1, ph), bx0:min(bx1, pw)]
    if bx1 > pw or by1 > ph:
        crop = cv2.copyMakeBorder(crop, 0, max(by1 - ph, 0), 0, max(bx1 - pw, 0), cv2.BORDER_REPLICATE)
    if fx == 1 and fy == 1:
        return np.ascontiguousarray(crop)
    return cv2.resize(crop, ((bx1 - bx0) // fx, (by1 - by0) // fy), interpolation=cv2.INTER_AREA)


class YuvFrame:
    """One 8-bit 4:2:0 or 4:2:2 frame as decoded (see the module docstring); ``codes`` its
    :class:`Codes` (BT.709 limited range unless told)."""

    def __init__(self, y: np.ndarray, u: np.ndarray, v: np.ndarray, codes: Codes = BT709):
        h, w = y.shape
        cy = 2 if u.shape[0] * 2 == h else 1
        if w % 2 or (cy == 2 and h % 2) or u.shape != (h // cy, w // 2) or v.shape != u.shape:
            raise ValueError(f"planes {y.shape}, {u.shape}, {v.shape}: not 4:2:0 or 4:2:2 of an even-sized frame")
        self.y, self.u, self.v = y, u, v
        self.codes = codes
        self.cy = cy  # chroma rows per luma row: 2 (4:2:0) or 1 (4:2:2)

    # ------------------------------------------------------------------ in and out
    @classmethod
    def from_av(cls, frame) -> YuvFrame | None:
        """The frame's planes (copied; an interleaved camera format unpacked), or None when the
        frame is not one this path keeps."""
        from .video_colour import video_colour
        from .video_orient import display_orientation

        name = frame.format.name
        if name not in KEPT_FORMATS or frame.width % 2:
            return None
        cy, jpeg = KEPT_FORMATS[name]
        colour = video_colour(frame)
        if colour.bits != 8 or colour.primaries != "bt709" or colour.hdr or colour.matrix not in _K:
            return None
        if (cy == 2 and frame.height % 2) or display_orientation(frame) != (0, False):
            return None
        y, u, v = _unpack(frame, name, cy)
        return cls(y, u, v, Codes(colour.matrix, colour.full_range or jpeg))

    def to_av(self):
        """An ``av.VideoFrame`` (yuv420p) of these planes: as they are for BT.709 limited 4:2:0
        (tagged so), else converted by swscale to it (never through RGB)."""
        import av
        from av.video.reformatter import ColorRange, Colorspace

        from .video_frame import sws_flags

        if self.cy == 2 and self.codes == BT709:
            frame = av.VideoFrame.from_ndarray(_packed(self.y, self.u, self.v), format="yuv420p")
            frame.colorspace, frame.color_range = Colorspace.ITU709, ColorRange.MPEG
            return frame
        src = self.av_frame()
        cs, rng = self.codes.av_tags
        out = src.reformat(format="yuv420p", src_colorspace=cs, src_color_range=rng, dst_colorspace=Colorspace.ITU709,
                           dst_color_range=ColorRange.MPEG, interpolation=sws_flags())
        out.colorspace, out.color_range = Colorspace.ITU709, ColorRange.MPEG
        return out

    def to_av_planes(self) -> np.ndarray:
        """The planes packed as PyAV's yuv420p/yuv422p arrays are ((rows, W): one after the other)."""
        return _packed(self.y, self.u, self.v)

    def av_frame(self):
        """These planes as an ``av.VideoFrame`` in their own format (yuv420p or yuv422p), untagged."""
        import av

        return av.VideoFrame.from_ndarray(_packed(self.y, self.u, self.v),
                                          format="yuv420p" if self.cy == 2 else "yuv422p")

    @property
    def shape(self) -> tuple[int, int, int]:
        """(H, W, 3): the shape of the RGB frame this is."""
        return (self.y.shape[0], self.y.shape[1], 3)

    @property
    def space(self) -> tuple:
        """What its codes are (a light field made for them maps them)."""
        return ("ycbcr", self.codes)

    def code_maps(self) -> tuple[np.ndarray, np.ndarray]:
        """((3, 4), (3, 4)) float32 affine maps of its codes (Y', Cb, Cr, 1) -> R'G'B' codes and back."""
        return (_TO_RGB, _TO_YCBCR) if self.codes == BT709 else self.codes.maps()

    def to_rgb(self) -> np.ndarray:
        """The whole frame as (H, W, 3) uint8 sRGB codes (what :func:`relight.video_frame.frame_to_rgb` gives)."""
        from .video_frame import sws_flags

        cs, rng = self.codes.av_tags
        return self.av_frame().reformat(format="rgb24", src_colorspace=cs, src_color_range=rng,
                                   interpolation=sws_flags()).to_ndarray()

    # ------------------------------------------------------------------ what the frame path touches
    def tracking_grey(self, size: tuple[int, int]) -> np.ndarray:
        """(h, w) uint8: ``cv2.COLOR_RGB2GRAY`` of the RGB frame, scaled to ``size`` (w, h) - made
        from the planes halved to the chroma's size (the conversion is linear; clipping aside, the
        same), then the rest of the way as :func:`downscale_fast` does it."""
        w, h = size
        a, b, c, d = self.codes.grey_weights()
        cw, ch = self.u.shape[1], self.u.shape[0]
        if w <= cw and h <= ch:  # the grey at the chroma's size: each plane's halvings, none of them non-integer
            ys = downscale_area(self.y, (cw, ch)) if self.y.shape != self.u.shape else self.y
            us, vs = self.u, self.v
        else:
            ys = self.y
            us = cv2.resize(self.u, ys.shape[::-1], interpolation=cv2.INTER_LINEAR)
            vs = cv2.resize(self.v, ys.shape[::-1], interpolation=cv2.INTER_LINEAR)
        g = cv2.addWeighted(ys, a, us, b, d - 128.0 * (b + c), dtype=cv2.CV_32F)
        g = cv2.scaleAdd(vs.astype(np.float32), c, g)
        _, g = cv2.threshold(g, 0.0, 0.0, cv2.THRESH_TOZERO)  # below 0 -> 0
        return downscale_fast(cv2.convertScaleAbs(g), (w, h))  # rounded, saturated at 255

    def small_rgb(self, size: tuple[int, int]) -> np.ndarray:
        """(h, w, 3) uint8 sRGB of the frame scaled down to ``size`` (w, h) by
        :func:`downscale_area`: the planes scaled first, then converted (the conversion is linear:
        clipping aside, the same). An odd size, or one not smaller than the frame, from the RGB."""
        w, h = size
        if w % 2 or h % 2 or w >= self.y.shape[1] or h >= self.y.shape[0]:
            return downscale_area(self.to_rgb(), (w, h))
        ch = h // 2 if self.cy == 2 else h
        return planes_to_rgb(downscale_area(self.y, (w, h)), downscale_area(self.u, (w // 2, ch)),
                             downscale_area(self.v, (w // 2, ch)), self.codes)

    def small_box(self, box: tuple[int, int, int, int], factor: int) -> np.ndarray:
        """(h, w, 3) uint8 sRGB of the frame's ``box`` - its corner a multiple of the ``factor``
        (even, or 1: then of 2), its size too (its far edges may pass the frame's: the last pixels
        are replicated) - scaled down by ``factor``: each plane's blocks averaged, then converted
        (the conversion is linear); at factor 1 the box itself (:func:`planes_to_rgb`)."""
        x0, y0, x1, y1 = box
        ys = block_means(self.y, box, factor, factor)
        cy = self.cy
        half = (x0 // 2, y0 // cy, -(-x1 // 2), -(-y1 // cy))
        if factor == 1:  # (the box's corner and size even: whole chroma samples)
            return planes_to_rgb(ys, block_means(self.u, half, 1, 1), block_means(self.v, half, 1, 1), self.codes)
        fy = factor // cy
        to_rgb, _ = self.code_maps()
        return cv2.transform(cv2.merge([ys, block_means(self.u, half, factor // 2, fy),
                                        block_means(self.v, half, factor // 2, fy)]), to_rgb)

    def with_field(self, applier, box, grid: np.ndarray, factor: int, corner) -> YuvFrame:
        """A new frame: this one with a light field (maps of its codes: :meth:`code_maps`; ``factor``
        pixels per cell from ``corner``) applied over ``box`` in its planes
        (:meth:`relight.kernels.field_apply.FieldApplier.planes`)."""
        y, u, v = applier.planes(self.y, self.u, self.v, box, grid, factor, corner)
        return YuvFrame(y, u, v, self.codes)


def _unpack(frame, name: str, cy: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The planes (y, u, v) of a decoded frame of a kept format (copies)."""
    h, w = frame.height, frame.width

    def plane(i, ph, pw, channels=1):
        p = frame.planes[i]
        a = np.frombuffer(p, np.uint8).reshape(ph, p.line_size)[:, :pw * channels]
        return a.reshape(ph, pw, channels) if channels > 1 else a.copy()

    if name == "nv12":  # luma, then one plane of interleaved (Cb, Cr) at 4:2:0
        uv = plane(1, h // 2, w // 2, 2)
        return plane(0, h, w), np.ascontiguousarray(uv[..., 0]), np.ascontiguousarray(uv[..., 1])
    if name == "yuyv422":  # one plane: Y0 Cb Y1 Cr per pair of pixels
        packed = plane(0, h, w // 2, 4)
        y = np.ascontiguousarray(packed[..., [0, 2]].reshape(h, w))
        return y, np.ascontiguousarray(packed[..., 1]), np.ascontiguousarray(packed[..., 3])
    ch = h // cy
    return plane(0, h, w), plane(1, ch, w // 2), plane(2, ch, w // 2)


def _packed(y: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """The planes packed as PyAV's yuv420p/yuv422p arrays are: the planes one after the other,
    shaped (rows, W)."""
    w = y.shape[1]
    return np.concatenate([y.ravel(), u.ravel(), v.ravel()]).reshape(-1, w)


def sample_codes(frame, xy: np.ndarray) -> np.ndarray:
    """(N, 3) uint8 sRGB codes of ``frame`` ((H, W, 3) uint8 sRGB or a :class:`YuvFrame`) read
    bilinearly at frame positions ``xy`` (N, 2) float (edges replicated) - for a YuvFrame its
    planes read there (the chroma at its own siting, centred on its block) and converted."""
    xy = np.asarray(xy, np.float32).reshape(-1, 1, 2)
    if xy.shape[0] == 0:
        return np.zeros((0, 3), np.uint8)
    mx, my = np.ascontiguousarray(xy[..., 0]), np.ascontiguousarray(xy[..., 1])
    if isinstance(frame, np.ndarray):
        return cv2.remap(frame, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).reshape(-1, 3)
    ys = cv2.remap(frame.y, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    cx = (mx - np.float32(0.5)) * np.float32(0.5)
    cy = (my - np.float32(0.5)) * np.float32(0.5) if frame.cy == 2 else my
    us = cv2.remap(frame.u, cx, cy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    vs = cv2.remap(frame.v, cx, cy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    to_rgb, _ = frame.code_maps()
    return cv2.transform(cv2.merge([ys, us, vs]), to_rgb).reshape(-1, 3)


def view_rgb(frame) -> np.ndarray:
    """(H, W, 3) uint8 sRGB of a frame for a viewer: an array as it is, a :class:`YuvFrame` by
    OpenCV's fast conversion (:func:`planes_to_rgb`: bilinear chroma, ~6x swscale's exact one;
    within a code of it on average)."""
    if isinstance(frame, YuvFrame):
        return planes_to_rgb(frame.y, frame.u, frame.v, frame.codes)
    return frame


def as_rgb(frame) -> np.ndarray:
    """(H, W, 3) uint8 sRGB of a frame: an array as it is, a :class:`YuvFrame` converted whole."""
    return frame.to_rgb() if isinstance(frame, YuvFrame) else frame
