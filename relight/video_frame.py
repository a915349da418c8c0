"""One decoded video frame's pixels, as displayed: the whole frame as sRGB codes
(:func:`frame_to_rgb`), or a region kept in its native planes and converted only where colour
is needed (:func:`crop_frame` -> :class:`FrameCrop`).

The stream's colour tags decide the conversion (:mod:`relight.video_colour`), and the container's
display orientation is applied (:mod:`relight.video_orient`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .colour import decode_srgb8, luminance
from .video_colour import (
    PLANAR_FORMATS,
    VideoColour,
    encode_display8,
    frame_display_rgb,
    luma_table,
    signal_to_linear,
    video_colour,
    ycbcr_matrix,
)
from .video_orient import coded_box, display_orientation, orient


def sws_flags():
    from av.video.reformatter import Interpolation as I

    # swscale's default RGB <-> YUV paths round down: a measured bias of about -0.75 of an
    # 8-bit code per round trip (-2 with ACCURATE_RND alone). This combination measured
    # unbiased (|mean| < 0.1 code) on synthetic captures; tests/test_video.py keeps it so.
    return I.BICUBIC | I.ACCURATE_RND | I.FULL_CHR_H_INT


def _to_rgb(frame) -> np.ndarray:
    """A decoded frame -> RGB uint8, honouring its colour tags (untagged: BT.709 for HD, else
    BT.601; limited range), as FFmpeg-based players do."""
    from av.video.reformatter import ColorRange, Colorspace

    try:
        cs = Colorspace(int(frame.colorspace))
    except ValueError:
        cs = Colorspace.ITU709 if frame.height >= 720 else Colorspace.ITU601
    rng = frame.color_range if int(frame.color_range) in (1, 2) else ColorRange.MPEG
    return frame.reformat(format="rgb24", src_colorspace=cs, src_color_range=rng,
                          interpolation=sws_flags()).to_ndarray()


def frame_to_rgb(frame) -> np.ndarray:
    """A decoded frame -> (H, W, 3) uint8 sRGB as displayed (its container's display rotation and
    mirror applied: :func:`display_orientation`); the conversion :func:`relight.video_read.read_frames` uses.

    8-bit SDR video in Rec.709 goes through swscale with the stream's matrix and range (codes
    kept as they are: what players show); 10/12-bit, HDR and wide-gamut video through linear
    light (:mod:`relight.video_colour`; HDR tone-mapped)."""
    colour = video_colour(frame)
    if colour.bits == 8 and colour.primaries == "bt709" and not colour.hdr:
        return np.ascontiguousarray(orient(_to_rgb(frame), *display_orientation(frame)))
    if frame.format.name in PLANAR_FORMATS:
        return np.ascontiguousarray(orient(frame_display_rgb(frame, colour), *display_orientation(frame)))
    return whole_frame(frame).rgb()


#: Limited-range 8-bit luma codes (16-235) -> full range (0-255), rounded and clipped.
LIMITED_TO_FULL = np.clip(np.round((np.arange(256) - 16) * 255.0 / 219.0), 0, 255).astype(np.uint8)


@dataclass
class FrameCrop:
    """A region of a decoded frame kept in its native planes (YUV 4:2:0: 1.5 samples a pixel;
    uint8 for 8-bit video, uint16 for 10/12-bit).

    Convert with :meth:`linear` (float32 linear Rec.709, the stream's colour tags honoured:
    :mod:`relight.video_colour`) or :meth:`rgb` (uint8 sRGB for display and detection; HDR
    tone-mapped) only when colour is needed; :meth:`luma` is almost free.
    """

    y: np.ndarray | None           # (h, w) luma codes (None for an RGB crop)
    u: np.ndarray | None = None    # chroma planes covering the crop
    v: np.ndarray | None = None
    offset: tuple[int, int] = (0, 0)  # where the crop starts in the 2x-upsampled chroma block
    shift: int = 0                 # 2: 4:2:0, 1: 4:2:2, 0: 4:4:4
    colour: VideoColour = VideoColour()
    # (h, w, 3) as displayed, for frames not in planar Y'CbCr: uint8 sRGB codes, uint16
    # non-linear signal (65535 = 1) in the stream's primaries, or float32 linear Rec.709.
    rgb_data: np.ndarray | None = None
    turns: int = 0                 # the display orientation (:func:`display_orientation`) applied
    mirror: bool = False           # to every output; the planes stay as coded

    @property
    def shape(self) -> tuple[int, int]:
        if self.rgb_data is not None:
            return self.rgb_data.shape[:2]
        h, w = self.y.shape
        return (w, h) if self.turns % 2 else (h, w)

    def _shown(self, img: np.ndarray) -> np.ndarray:
        return np.ascontiguousarray(orient(img, self.turns, self.mirror))

    def luma(self, *, native: bool = False) -> np.ndarray:
        """(h, w) uint8 luma: sRGB-encoded grey (full range; HDR tone-mapped), or with ``native``
        the stored codes' top 8 bits, range as stored (cheapest: for tracking, which only
        needs relative brightness)."""
        import cv2

        if self.rgb_data is not None:
            return cv2.cvtColor(self.rgb(), cv2.COLOR_RGB2GRAY)
        if native:
            y = self.y if self.y.dtype == np.uint8 else (self.y >> (self.colour.bits - 8)).astype(np.uint8)
            return self._shown(y)
        if self.colour.plain_srgb8:
            return self._shown(self.y if self.colour.full_range else LIMITED_TO_FULL[self.y])
        return encode_display8(self.luma_linear(), self.colour.transfer)

    def luma_linear(self) -> np.ndarray:
        """(h, w) float32 linear grey of the luma codes (a brightness trace's input)."""
        if self.rgb_data is not None:
            return luminance(self.linear())
        if self.colour.plain_srgb8:
            return decode_srgb8(self.luma())
        return self._shown(luma_table(self.colour)[self.y])

    def sparse(self, step: int) -> FrameCrop:
        """Every ``step``-th pixel each way (nearest chroma), as displayed: cheap statistics."""
        if self.rgb_data is not None:
            return FrameCrop(y=None, rgb_data=self.rgb_data[::step, ::step], colour=self.colour)
        if self.turns % 4 or self.mirror:
            # The display grid, exactly (rare: turned videos): taken from the full conversion.
            return FrameCrop(y=None, rgb_data=self.linear()[::step, ::step], colour=self.colour)
        h, w = self.y.shape
        rows, cols = np.arange(0, h, step), np.arange(0, w, step)
        if self.shift:
            ox, oy = self.offset
            cr = (rows + oy) // (2 if self.shift == 2 else 1)
            cc = (cols + ox) // 2
        else:
            cr, cc = rows, cols
        return FrameCrop(y=self.y[np.ix_(rows, cols)], u=self.u[np.ix_(cr, cc)], v=self.v[np.ix_(cr, cc)],
                         shift=0, colour=self.colour)

    def resized(self, size: tuple[int, int], *, precise: bool = False) -> FrameCrop:
        """This crop resampled (area average) to ``size`` = (w, h) as displayed, planes kept as
        coded: 8-bit video stays 8-bit (a crop held for every frame of a capture: memory first)
        unless ``precise``; 10/12-bit (and ``precise``) goes to 16 bits, keeping the precision
        the average of several codes has (the result's colour: ``bits=16``, same curve, matrix
        and range)."""
        import dataclasses

        import cv2

        w, h = (int(v) for v in size)
        if self.rgb_data is not None:
            return FrameCrop(y=None, rgb_data=cv2.resize(self.rgb_data, (w, h), interpolation=cv2.INTER_AREA),
                             colour=self.colour)
        cw, ch = (h, w) if self.turns % 2 else (w, h)
        eight = self.colour.bits == 8 and not precise
        up = 1.0 if eight else float(1 << (16 - self.colour.bits))

        def area(plane, dsize):
            if eight:
                return cv2.resize(plane, dsize, interpolation=cv2.INTER_AREA)  # rounds, stays uint8
            out = cv2.resize(plane.astype(np.float32), dsize, interpolation=cv2.INTER_AREA)
            return np.clip(np.round(out * up), 0, 65535).astype(np.uint16)

        if self.shift == 2:
            csize = ((cw + 1) // 2, (ch + 1) // 2)
        elif self.shift == 1:
            csize = ((cw + 1) // 2, ch)
        else:
            csize = (cw, ch)
        # The chroma planes cover the crop plus at most one luma column/row before it (offset):
        # under a downscale that is under half an output pixel, left as is.
        return FrameCrop(y=area(self.y, (cw, ch)), u=area(self.u, csize), v=area(self.v, csize), shift=self.shift,
                         colour=self.colour if eight else dataclasses.replace(self.colour, bits=16), turns=self.turns,
                         mirror=self.mirror)

    def _signal(self) -> np.ndarray:
        """(h, w, 3) float32 non-linear R'G'B' (0-1 nominal) in the stream's primaries, as coded."""
        import cv2

        h, w = self.y.shape
        planes = [self.y.astype(np.float32)]
        for c in (self.u, self.v):
            c = c.astype(np.float32)
            if self.shift:
                c = cv2.resize(c, (c.shape[1] * 2, c.shape[0] * (2 if self.shift == 2 else 1)),
                               interpolation=cv2.INTER_LINEAR)
                ox, oy = self.offset
                c = c[oy:oy + h, ox:ox + w]
            planes.append(c)
        # One affine colour transform of [Y, Cb, Cr, 1] (OpenCV: SIMD, threaded).
        return cv2.transform(cv2.merge(planes), ycbcr_matrix(self.colour))

    def rgb(self) -> np.ndarray:
        """(h, w, 3) uint8 sRGB as displayed, with the stream's matrix and range, chroma upsampled
        bilinearly; other curves and primaries through linear light
        (:func:`relight.video_colour.encode_display8`: HDR tone-mapped)."""
        import cv2

        if self.rgb_data is not None and self.rgb_data.dtype == np.uint8:
            return self.rgb_data
        if self.rgb_data is None and self.colour.plain_srgb8:
            sig = self._signal()
            sig *= 255.0
            np.maximum(sig, 0.0, out=sig)
            return self._shown(cv2.convertScaleAbs(sig))  # rounds and saturates at 255
        return encode_display8(self.linear(), self.colour.transfer)

    def linear(self) -> np.ndarray:
        """(h, w, 3) float32 linear Rec.709 as displayed, reference white 1.0 (HDR above it):
        exactly :func:`relight.colour.decode_srgb8` of :meth:`rgb` for 8-bit sRGB video."""
        if self.rgb_data is not None:
            if self.rgb_data.dtype == np.uint8:
                return decode_srgb8(self.rgb_data)
            if self.rgb_data.dtype == np.float32:
                return self.rgb_data
            return signal_to_linear(self.rgb_data.astype(np.float32) / 65535.0, self.colour)
        if self.colour.plain_srgb8:
            return decode_srgb8(self.rgb())
        return self._shown(signal_to_linear(self._signal(), self.colour))

    def clipped(self, level: float) -> np.ndarray:
        """(h, w) bool: pixels with a channel at or above ``level`` of the code range's top
        (sensor saturation), as displayed."""
        return self._clipped(level)[0]

    def linear_and_clipped(self, level: float) -> tuple[np.ndarray, np.ndarray]:
        """(:meth:`linear`, :meth:`clipped` at ``level``) from one colour conversion (a flash
        frame needs both: converting twice was most of the capture's per-sample time)."""
        clipped, converted = self._clipped(level)
        if self.rgb_data is not None:
            return self.linear(), clipped
        if self.colour.plain_srgb8:
            return decode_srgb8(converted), clipped
        return self._shown(signal_to_linear(converted, self.colour)), clipped

    def _clipped(self, level: float) -> tuple[np.ndarray, np.ndarray]:
        """(:meth:`clipped`, the values it was read from: the codes as displayed, or for video
        converted through linear light the signal as coded)."""
        if self.rgb_data is not None and self.rgb_data.dtype == np.float32:
            raise ValueError("a linear crop has no code range to be clipped at")
        if self.rgb_data is not None or self.colour.plain_srgb8:
            codes = self.rgb() if self.rgb_data is None else self.rgb_data
            return _channel_max(codes) >= level * (255.0 if codes.dtype == np.uint8 else 65535.0), codes
        sig = self._signal()
        return self._shown(_channel_max(sig) >= level), sig


def _channel_max(img: np.ndarray) -> np.ndarray:
    """(h, w) the largest of the three channels of (h, w, 3) (NumPy's max over a last axis of
    3 is ~10x slower than this)."""
    return np.maximum(np.maximum(img[..., 0], img[..., 1]), img[..., 2])


def crop_frame(frame, box: tuple[int, int, int, int]) -> FrameCrop:
    """Keep the region ``box`` (x, y, w, h, in the frame as displayed: :func:`display_orientation`)
    of a decoded frame in its native planes (8-bit codes as uint8, 10/12-bit as uint16)."""
    name = frame.format.name
    colour = video_colour(frame)
    if name not in PLANAR_FORMATS:
        x, y, w, h = box
        if colour.bits > 8:
            sig = orient(frame.to_ndarray(format="rgb48le"), *display_orientation(frame))
            return FrameCrop(y=None, rgb_data=np.ascontiguousarray(sig[y:y + h, x:x + w]), colour=colour)
        return FrameCrop(y=None, rgb_data=np.ascontiguousarray(frame_to_rgb(frame)[y:y + h, x:x + w]),
                         colour=colour)
    turns, mirror = display_orientation(frame)
    x, y, w, h = coded_box(box, turns, mirror, (frame.width, frame.height))
    bits, shift = PLANAR_FORMATS[name]
    dtype = np.uint8 if bits == 8 else np.dtype("<u2")
    itemsize = np.dtype(dtype).itemsize
    ys = frame.planes[0]
    yp = np.frombuffer(ys, dtype=dtype).reshape(frame.height, ys.line_size // itemsize)[y:y + h, x:x + w].copy()
    if shift == 0:
        cx0, cx1, cy0, cy1 = x, x + w, y, y + h
    else:
        cx0, cx1 = x >> 1, (x + w + 1) >> 1
        cy0, cy1 = ((y >> 1), ((y + h + 1) >> 1)) if shift == 2 else (y, y + h)
    chroma = []
    rows = (frame.height + 1) >> 1 if shift == 2 else frame.height
    for k in (1, 2):
        pl = frame.planes[k]
        chroma.append(np.frombuffer(pl, dtype=dtype).reshape(-1, pl.line_size // itemsize)[:rows][cy0:cy1, cx0:cx1]
                      .copy())
    off = (x - 2 * cx0, (y - 2 * cy0) if shift == 2 else 0) if shift else (0, 0)
    return FrameCrop(y=yp, u=chroma[0], v=chroma[1], offset=off, shift=shift, colour=colour, turns=turns,
                     mirror=mirror)


def whole_frame(frame) -> FrameCrop:
    """The whole of a decoded frame as a :class:`FrameCrop` (as displayed)."""
    turns, _ = display_orientation(frame)
    return crop_frame(frame, (0, 0, frame.height, frame.width) if turns % 2 else (0, 0, frame.width, frame.height))
