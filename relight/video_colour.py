"""How a video's Y'CbCr codes become linear Rec.709 light: its colour tags, read and checked.

A decoded frame carries four tags (FFmpeg's enums): the Y'CbCr matrix, the colour primaries,
the transfer curve and the code range, plus the bit depth of its pixel format. Phones write
8-bit BT.709 SDR, 10-bit BT.2020 HLG (iPhone HDR) or PQ (many Androids); screen recorders and
our own writer tag the sRGB curve. :func:`video_colour` turns the tags into a
:class:`VideoColour`; :func:`decode_planes` turns Y'CbCr planes into float32 *linear Rec.709*:

- **Scale**: 1.0 is the reference (diffuse) white. SDR curves give 0-1; HDR gives more and the
  values above 1 are kept. HLG is scene-referred: its inverse OETF, scaled so the 75 % signal
  (BT.2408's reference white) is 1.0 (peak: about 3.8). PQ is display-referred: absolute
  luminance divided by BT.2408's reference white, 203 cd/m^2.
- **Curves**: sRGB (IEC 61966-2-1), BT.709/601/2020 (the camera OETF inverted: scene light,
  which is what reflectance needs), gamma 2.2/2.8, linear, HLG (ARIB STD-B67), PQ (ST 2084).
- **Gamut**: BT.2020 / Display-P3 / BT.601 primaries converted to Rec.709 by their normalised
  primary matrices (D65); colours outside Rec.709 are desaturated toward their own luminance
  until no channel is negative (luminance and hue kept, never clipped to NaN).
- **Untagged** (the documented default, as FFmpeg-based players assume): matrix BT.709 at
  720 lines and more, else BT.601; limited range (full for ``yuvj`` formats); primaries
  BT.2020 when the matrix is BT.2020, else BT.709; the sRGB transfer curve.
- **Contradictory or unsupported tags** are decoded by the nearest supported reading and
  described in :attr:`VideoColour.notes` (a capture's report lists them); never an error.

Codes are decoded at their own precision (10-bit planes as 16-bit integers, the transfer curve
through a 65536-entry table), never through 8-bit RGB.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from relight.errors import InputError

from .colour import LUMINANCE, srgb_to_linear
from .numerics import EPS, FLOAT

#: BT.709's OETF as published (ITU-R BT.709-6 item 1.2: 1.099 L^0.45 - 0.099 above 0.018, 4.5 L
#: below), as FFmpeg and colour-science have it (BT.2020's 1.0993 / 0.0181 are its 12-bit values).
BT709_ALPHA = 1.099
BT709_BETA = 0.018
#: BT.2408 reference white: HLG signal 0.75; PQ 203 cd/m^2.
HLG_REFERENCE_SIGNAL = 0.75
PQ_REFERENCE_NITS = 203.0
#: Entries of the transfer table (16-bit precision for 10- and 12-bit video).
TRANSFER_TABLE = 65536

#: Y'CbCr matrices: (Kr, Kb).
MATRICES = {"bt709": (0.2126, 0.0722), "bt601": (0.299, 0.114), "bt2020": (0.2627, 0.0593),
            "smpte240m": (0.212, 0.087), "fcc": (0.30, 0.11)}
#: Primaries: xy chromaticities of R, G, B (all with the D65 white point here).
PRIMARIES = {
    "bt709": ((0.640, 0.330), (0.300, 0.600), (0.150, 0.060)),
    "bt601-625": ((0.640, 0.330), (0.290, 0.600), (0.150, 0.060)),
    "bt601-525": ((0.630, 0.340), (0.310, 0.595), (0.155, 0.070)),
    "bt2020": ((0.708, 0.292), (0.170, 0.797), (0.131, 0.046)),
    "p3": ((0.680, 0.320), (0.265, 0.690), (0.150, 0.060)),
}
D65 = (0.3127, 0.3290)
TRANSFERS = ("srgb", "bt709", "gamma22", "gamma28", "linear", "pq", "hlg")
HDR_TRANSFERS = ("pq", "hlg")

# FFmpeg's enum values (libavutil/pixfmt.h).
_MATRIX_TAGS = {1: "bt709", 4: "fcc", 5: "bt601", 6: "bt601", 7: "smpte240m", 9: "bt2020", 10: "bt2020"}
_PRIMARY_TAGS = {1: "bt709", 5: "bt601-625", 6: "bt601-525", 7: "bt601-525", 9: "bt2020", 11: "p3", 12: "p3"}
_TRANSFER_TAGS = {1: "bt709", 4: "gamma22", 5: "gamma28", 6: "bt709", 7: "bt709", 8: "linear", 13: "srgb",
                  14: "bt709", 15: "bt709", 16: "pq", 18: "hlg"}
_UNSPECIFIED = (0, 2)
#: Planar Y'CbCr pixel formats read natively: name -> (bits, chroma shift: 2 4:2:0, 1 4:2:2, 0 4:4:4).
PLANAR_FORMATS = {"yuv420p": (8, 2), "yuvj420p": (8, 2), "yuv422p": (8, 1), "yuvj422p": (8, 1),
                  "yuv444p": (8, 0), "yuvj444p": (8, 0),
                  "yuv420p10le": (10, 2), "yuv422p10le": (10, 1), "yuv444p10le": (10, 0),
                  "yuv420p12le": (12, 2), "yuv422p12le": (12, 1), "yuv444p12le": (12, 0)}


#: Cameras' own 8-bit interleaved formats (their names hold digits that are not a bit depth: NV12).
EIGHT_BIT_PACKED = frozenset({"nv12", "nv21", "yuyv422", "uyvy422", "yvyu422"})


@dataclass(frozen=True)
class VideoColour:
    """How one stream's codes are read (see the module docstring)."""

    matrix: str = "bt709"
    primaries: str = "bt709"
    transfer: str = "srgb"
    full_range: bool = False
    bits: int = 8
    notes: tuple[str, ...] = ()

    @property
    def hdr(self) -> bool:
        return self.transfer in HDR_TRANSFERS

    @property
    def plain_srgb8(self) -> bool:
        """8-bit sRGB codes in Rec.709: decoded exactly per code through the sRGB table."""
        return self.bits == 8 and self.transfer == "srgb" and self.primaries == "bt709"

    def describe(self) -> str:
        rng = "full" if self.full_range else "limited"
        return f"{self.bits}-bit {rng}-range {self.matrix} Y'CbCr, {self.primaries} primaries, {self.transfer} transfer"


def _tag(value) -> int:
    try:
        return int(value)
    except (TypeError, ValueError):
        return 2


@lru_cache(maxsize=64)
def colour_from_tags(fmt: str, matrix: int, primaries: int, transfer: int, rng: int, height: int) -> VideoColour:
    """The reading of one combination of tags (cached: every frame of a stream has the same)."""
    notes = []
    bits = PLANAR_FORMATS.get(fmt, (8, 0))[0]
    if fmt not in PLANAR_FORMATS and fmt not in EIGHT_BIT_PACKED:
        bits = 16 if any(s in fmt for s in ("10", "12", "16", "48", "64")) else 8
    full = fmt.startswith("yuvj") or rng == 2
    m = _read_tag(_MATRIX_TAGS, matrix, "colour matrix", "bt2020" if primaries == 9 else
                  ("bt709" if height >= 720 else "bt601"), notes if fmt in PLANAR_FORMATS else [])
    if matrix == 10:
        notes.append("BT.2020 constant-luminance matrix read as non-constant luminance")
    p = _read_tag(_PRIMARY_TAGS, primaries, "colour primaries", "bt2020" if m == "bt2020" else "bt709", notes)
    if primaries == 11:
        notes.append("DCI-P3 primaries read with the D65 white point (Display P3)")
    t = _read_tag(_TRANSFER_TAGS, transfer, "transfer curve", "srgb", notes)
    if transfer == 7:
        notes.append("SMPTE 240M transfer read as BT.709")
    if t in HDR_TRANSFERS and bits < 10:
        notes.append(f"HDR transfer ({t}) in {bits}-bit video: expect banding")
    if t in HDR_TRANSFERS and p != "bt2020":
        notes.append(f"HDR transfer ({t}) with {p} primaries (HDR is normally BT.2020): decoded as tagged")
    if m == "bt2020" and p != "bt2020" or p == "bt2020" and m != "bt2020":
        notes.append(f"the {m} matrix with {p} primaries is an unusual pairing: decoded as tagged")
    return VideoColour(matrix=m, primaries=p, transfer=t, full_range=full, bits=bits, notes=tuple(notes))


def _read_tag(table: dict, value: int, what: str, default: str, notes: list) -> str:
    """``table[value]``, or ``default`` when the tag is unspecified or not supported (then said
    in ``notes``)."""
    name = table.get(value)
    if name is not None:
        return name
    if value not in _UNSPECIFIED:
        notes.append(f"{what} tag {value} is not supported; read as {default}")
    return default


def video_colour(frame) -> VideoColour:
    """The :class:`VideoColour` of a decoded PyAV frame, from its tags."""
    return colour_from_tags(frame.format.name, _tag(getattr(frame, "colorspace", 2)),
                            _tag(getattr(frame, "color_primaries", 2)), _tag(getattr(frame, "color_trc", 2)),
                            _tag(getattr(frame, "color_range", 0)), int(frame.height))


# ---------------------------------------------------------------- transfer curves
def to_linear(encoded: np.ndarray, transfer: str) -> np.ndarray:
    """Non-linear signal (0-1) -> linear light with reference white 1.0 (module docstring)."""
    e = np.clip(np.asarray(encoded, dtype=np.float64), 0.0, 1.0)
    if transfer == "srgb":
        return srgb_to_linear(e).astype(np.float64)
    if transfer == "bt709":  # the camera OETF's inverse, with BT.709's published constants
        a, b = BT709_ALPHA, BT709_BETA
        knee = a * b ** 0.45 - (a - 1.0)  # the OETF's upper branch at b (0.0812: the rounded constants leave a step)
        return np.where(e < knee, e / 4.5, ((e + (a - 1.0)) / a) ** (1.0 / 0.45))
    if transfer == "gamma22":
        return e ** 2.2
    if transfer == "gamma28":
        return e ** 2.8
    if transfer == "linear":
        return e
    if transfer == "pq":
        m1, m2 = 2610.0 / 16384.0, 2523.0 / 4096.0 * 128.0
        c1, c2, c3 = 3424.0 / 4096.0, 2413.0 / 4096.0 * 32.0, 2392.0 / 4096.0 * 32.0
        p = e ** (1.0 / m2)
        nits = 10000.0 * (np.maximum(p - c1, 0.0) / (c2 - c3 * p)) ** (1.0 / m1)
        return nits / PQ_REFERENCE_NITS
    if transfer == "hlg":
        return _hlg_inverse_oetf(e) / _hlg_inverse_oetf(np.array(HLG_REFERENCE_SIGNAL))
    raise InputError(f"unknown transfer {transfer!r}; use one of {', '.join(TRANSFERS)}")


def from_linear(linear: np.ndarray, transfer: str) -> np.ndarray:
    """The inverse of :func:`to_linear` (for writing test videos and HDR output), 0-1 signal."""
    x = np.maximum(np.asarray(linear, dtype=np.float64), 0.0)
    if transfer == "srgb":
        x = np.minimum(x, 1.0)
        return np.where(x <= 0.0031308, x * 12.92, 1.055 * x ** (1.0 / 2.4) - 0.055)
    if transfer == "bt709":
        x = np.minimum(x, 1.0)
        a, b = BT709_ALPHA, BT709_BETA
        return np.where(x < b, 4.5 * x, a * x ** 0.45 - (a - 1.0))
    if transfer in ("gamma22", "gamma28"):
        return np.minimum(x, 1.0) ** (1.0 / (2.2 if transfer == "gamma22" else 2.8))
    if transfer == "linear":
        return np.minimum(x, 1.0)
    if transfer == "pq":
        m1, m2 = 2610.0 / 16384.0, 2523.0 / 4096.0 * 128.0
        c1, c2, c3 = 3424.0 / 4096.0, 2413.0 / 4096.0 * 32.0, 2392.0 / 4096.0 * 32.0
        y = np.minimum(x * PQ_REFERENCE_NITS / 10000.0, 1.0) ** m1
        return ((c1 + c2 * y) / (1.0 + c3 * y)) ** m2
    if transfer == "hlg":
        a, b, c = _HLG
        e = np.minimum(x * _hlg_inverse_oetf(np.array(HLG_REFERENCE_SIGNAL)), 1.0)
        return np.where(e <= 1.0 / 12.0, np.sqrt(3.0 * e), a * np.log(np.maximum(12.0 * e - b, EPS)) + c)
    raise InputError(f"unknown transfer {transfer!r}; use one of {', '.join(TRANSFERS)}")


_HLG = (0.17883277, 0.28466892, 0.55991073)


def _hlg_inverse_oetf(e: np.ndarray) -> np.ndarray:
    a, b, c = _HLG
    return np.where(e <= 0.5, e * e / 3.0, (np.exp((e - c) / a) + b) / 12.0)


@lru_cache(maxsize=16)
def transfer_table(transfer: str) -> np.ndarray:
    """(TRANSFER_TABLE,) float32: linear light at signal i / (TRANSFER_TABLE - 1)."""
    return to_linear(np.arange(TRANSFER_TABLE) / (TRANSFER_TABLE - 1.0), transfer).astype(FLOAT)


@lru_cache(maxsize=16)
def luma_table(colour: VideoColour) -> np.ndarray:
    """(2**bits,) float32: the linear grey a luma code stands for (brightness traces)."""
    codes = np.arange(1 << colour.bits, dtype=np.float64)
    y0, ys, _, _ = code_scale(colour)
    return to_linear((codes - y0) / ys, colour.transfer).astype(FLOAT)


def code_scale(colour: VideoColour) -> tuple[float, float, float, float]:
    """(luma offset, luma span, chroma offset, chroma span) in codes of ``colour.bits``."""
    k = float(1 << (colour.bits - 8))
    if colour.full_range:
        top = float((1 << colour.bits) - 1)
        return 0.0, top, 128.0 * k, top
    return 16.0 * k, 219.0 * k, 128.0 * k, 224.0 * k


# ---------------------------------------------------------------- primaries
def _rgb_to_xyz(primaries: str) -> np.ndarray:
    xy = np.array(PRIMARIES[primaries], dtype=np.float64)
    xyz = np.stack([xy[:, 0] / xy[:, 1], np.ones(3), (1.0 - xy[:, 0] - xy[:, 1]) / xy[:, 1]])  # columns R, G, B
    wx, wy = D65
    white = np.array([wx / wy, 1.0, (1.0 - wx - wy) / wy])
    return xyz * np.linalg.solve(xyz, white)[None, :]


@lru_cache(maxsize=8)
def primaries_to_rec709(primaries: str) -> np.ndarray:
    """(3, 3) float64 matrix taking linear RGB in ``primaries`` to linear Rec.709 (rows sum to 1)."""
    return np.linalg.solve(_rgb_to_xyz("bt709"), _rgb_to_xyz(primaries))


def gamut_map(rgb: np.ndarray) -> np.ndarray:
    """Linear Rec.709 (..., 3) float32 with negative channels (colours outside Rec.709) moved
    toward their own luminance until the smallest channel is 0; in place, returned."""
    low = np.minimum(np.minimum(rgb[..., 0], rgb[..., 1]), rgb[..., 2])  # (a reduction over the
    out = np.nonzero(low < 0.0)  # last axis of three is several times slower)
    if out[0].size:
        px = rgb[out]
        y = np.maximum(px @ LUMINANCE, 0.0)
        t = y / np.maximum(y - low[out], EPS)  # y - min > 0 as min < 0 <= y
        rgb[out] = np.maximum(y[:, None] + t[:, None] * (px - y[:, None]), 0.0)
    return rgb


# ---------------------------------------------------------------- planes -> light
def ycbcr_matrix(colour: VideoColour) -> np.ndarray:
    """(3, 4) float32: codes [Y, Cb, Cr, 1] -> non-linear R'G'B' (0-1 nominal)."""
    kr, kb = MATRICES[colour.matrix]
    kg = 1.0 - kr - kb
    y0, ys, c0, cs = code_scale(colour)
    crk, cbk = 2.0 * (1.0 - kr) / cs, 2.0 * (1.0 - kb) / cs
    m = np.array([[1.0 / ys, 0.0, crk], [1.0 / ys, -kb / kg * cbk, -kr / kg * crk], [1.0 / ys, cbk, 0.0]])
    off = -m @ np.array([y0, c0, c0])
    return np.hstack([m, off[:, None]]).astype(FLOAT)


def decode_planes(y: np.ndarray, cb: np.ndarray, cr: np.ndarray, colour: VideoColour) -> np.ndarray:
    """Full-resolution Y, Cb, Cr code planes (h, w) -> (h, w, 3) float32 linear Rec.709."""
    import cv2

    ycc = cv2.merge([np.asarray(p, dtype=FLOAT) for p in (y, cb, cr)])
    return signal_to_linear(cv2.transform(ycc, ycbcr_matrix(colour)), colour)


def signal_to_linear(signal: np.ndarray, colour: VideoColour) -> np.ndarray:
    """Non-linear R'G'B' (h, w, 3) float32 in the stream's primaries -> linear Rec.709 (the
    transfer curve through its 16-bit table, the primaries converted, the gamut mapped)."""
    import cv2

    idx = np.clip(signal, 0.0, 1.0)
    idx *= TRANSFER_TABLE - 1
    idx += 0.5
    lin = transfer_table(colour.transfer)[idx.astype(np.int32)]
    if colour.primaries != "bt709":
        lin = cv2.transform(lin, primaries_to_rec709(colour.primaries).astype(FLOAT))
        gamut_map(lin)
    return lin


#: Linear values above this knee are compressed smoothly toward 1.0 when HDR is shown as SDR.
TONEMAP_KNEE = 0.8


def tonemap(linear: np.ndarray) -> np.ndarray:
    """Linear (reference white 1.0, HDR above) -> linear 0-1 for an SDR display: identity up to
    :data:`TONEMAP_KNEE`, then an exponential shoulder (continuous slope) approaching 1.0."""
    x = np.asarray(linear, dtype=FLOAT)
    span = np.float32(1.0 - TONEMAP_KNEE)
    over = np.nonzero(x > TONEMAP_KNEE)
    if not over[0].size:
        return x
    out = x.copy()
    out[over] = TONEMAP_KNEE + span * (1.0 - np.exp((TONEMAP_KNEE - x[over]) / span))
    return out


#: Entries of the display table (HDR linear -> tone-mapped sRGB code): finer than half the
#: darkest sRGB code step (3e-4 linear) up to PQ's peak (10000 / 203 = 49).
DISPLAY_TABLE = 1 << 19


@lru_cache(maxsize=8)
def _display_table(transfer: str) -> tuple[np.ndarray, float]:
    from .colour import linear_to_srgb

    hdr = transfer in HDR_TRANSFERS
    peak = max(float(to_linear(np.array(1.0), transfer)), 1.0) if hdr else 1.0
    x = (np.arange(DISPLAY_TABLE, dtype=np.float64) * (peak / (DISPLAY_TABLE - 1))).astype(FLOAT)
    codes = np.round(linear_to_srgb(tonemap(x) if hdr else x) * 255.0).astype(np.uint8)
    return codes, (DISPLAY_TABLE - 1) / peak


def encode_display8(linear: np.ndarray, transfer: str) -> np.ndarray:
    """Linear Rec.709 (reference white 1.0) -> uint8 sRGB for an SDR display through one table:
    HDR curves tone-mapped (:func:`tonemap`, up to the curve's peak), SDR clipped at 1."""
    table, scale = _display_table(transfer)
    idx = np.asarray(linear, dtype=FLOAT) * np.float32(scale)
    np.clip(idx, 0, DISPLAY_TABLE - 1, out=idx)
    idx += 0.5
    return table[idx.astype(np.int32)]


def frame_display_rgb(frame, colour: VideoColour) -> np.ndarray:
    """A decoded 10/12-bit, HDR or wide-gamut frame -> (H, W, 3) uint8 sRGB as coded (not
    turned), for display: FFmpeg's swscale does the matrix, range and chroma to 16-bit R'G'B'
    (its ~2-code limited-range offset is below what 8-bit output shows), the curve is one
    65536-entry table lookup, then primaries, gamut and :func:`encode_display8`."""
    import cv2
    from av.video.reformatter import ColorRange, Colorspace

    cs = {"bt709": Colorspace.ITU709, "bt601": Colorspace.ITU601, "bt2020": Colorspace.BT2020,
          "smpte240m": Colorspace.SMPTE240M, "fcc": Colorspace.FCC}[colour.matrix]
    rng = ColorRange.JPEG if colour.full_range else ColorRange.MPEG
    # swscale's default filter: its FULL_CHR_H_INT path was measured to zero two channels of
    # 10-bit 4:2:0 -> rgb48 (FFmpeg in PyAV 18.1), so no extra flags here.
    sig = frame.reformat(format="rgb48le", src_colorspace=cs, src_color_range=rng,
                         dst_color_range=ColorRange.JPEG).to_ndarray()
    lin = np.take(transfer_table(colour.transfer), sig)
    if colour.primaries != "bt709":
        lin = gamut_map(cv2.transform(lin, primaries_to_rec709(colour.primaries).astype(FLOAT)))
    return encode_display8(lin, colour.transfer)
