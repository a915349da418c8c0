"""The light field: a frame's change of light as a coarse grid of per-channel gains in linear
light, made at low resolution and applied to the frame at its own (:mod:`relight.kernels.
field_apply`) - the way real-time image pipelines are built (HDRnet, Gharbi et al. 2017: a grid
of local colour transforms computed small and applied to the full frame; Chen et al. 2016,
bilateral guided upsampling).

The field is made (:func:`small_copy`, then the compositor's ``person_gain`` kernel) from a copy
of the frame's box the person reaches, scaled down by an even integer factor (:func:`field_factor`:
about :data:`FIELD_ROWS` rows of the frame; the copy's pixel k covers frame pixels [k f, k f + f)):
each cell holds the composite's own change of that pixel, split as ``out = G f + B`` per channel
in linear light (G the share of the live pixel kept times its ratio, B what the bundle's
prediction adds where the live pixel is not trusted), and its cover, the share of the cell that
changes. :func:`code_grid` turns that into an affine map of the frame's own codes - the sRGB curve
linearised at the cell's colour (exact for a gain on the curve's power part, which an offset of
the codes carries; a pixel far from its cell's colour keeps its own departure from it, scaled:
glasses' rims stay rims) and, for a decoded frame, composed with its Y'CbCr matrix - so the full
frame is mapped in its planes without going through RGB or linear light (HDRnet's local affine
colour transforms). Between its remakes it is carried with the head (:meth:`LightField.moved`).

Boxes are (x0, y0, x1, y1) frame pixels; frames (H, W, 3) uint8 sRGB or a
:class:`relight.video_yuv.YuvFrame`.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from relight.video_yuv import block_means

#: The field's rows: a frame is scaled down by the even factor that leaves it about this many
#: rows (720p: 4, 1080p: 6; issue 48's table, docs/performance.md "The light field": on the live
#: frame's truth at 640x360 a field of 180 rows is within 0.1 dB of the composite made at every
#: pixel, 90 rows lose 0.6 dB).
FIELD_ROWS = 180
#: Largest gain a cell carries (the composite's own ratio bound).
GAIN_MAX = 6.0
#: A field is carried with the head only once it moved this far (frame px at 540 rows, scaled)
#: from where the field is: a still head's tracking noise (a tenth of a pixel or two) would
#: otherwise shift it every frame, and its edges flicker by codes.
CARRY_DEAD_AT_540 = 0.5


#: The most frame pixels a cell spans (the planes' kernel runs whole tiles of at most 8 chroma
#: samples: :mod:`relight.kernels.field_apply`); a taller frame's field has more rows.
MAX_FACTOR = 16


def field_factor(size: tuple[int, int], rows: int = FIELD_ROWS) -> int:
    """The factor for a frame of ``size`` (w, h): the even number of frame pixels per cell that
    leaves about ``rows`` rows (4:2:0 chroma is half the luma's; at most :data:`MAX_FACTOR`) - or
    1, a cell a pixel, for a frame of fewer than 1.5 ``rows`` rows (its field is the composite
    itself, and as cheap)."""
    w, h = size
    rows = max(int(rows), 1)
    return 1 if h < 1.5 * rows else min(max(2, 2 * int(round(h / (2.0 * rows)))), MAX_FACTOR)


def code_grid(cells: np.ndarray, colour: np.ndarray, to_rgb: np.ndarray | None = None,
              to_ycc: np.ndarray | None = None) -> np.ndarray:
    """NumPy twin of the compositor's ``field_cells`` kernel (:meth:`relight.kernels.compositor.
    Compositor.person_gain` with ``code_maps``): the field's cells as maps of the frame's codes,
    (gh, gw, 32) float32 (the layout of :mod:`relight.kernels.field_apply`: the tangent, the chord
    through black, the cover, the knee in the frame's codes). ``cells`` (gh, gw, 8):
    ``person_gain``'s (G, cover, B, 0) - linear light, per channel; ``colour`` (gh, gw, 3) uint8:
    the small copy's sRGB codes (what each cell's change is linearised at). Per channel, in sRGB
    codes x (0-255): ``out = k x + n``, k the slope of enc(G dec(x) + B) at the cell's colour - G
    dec'(x) / dec'(e), e = enc(G dec(x) + B), the encode curve's slope being the decode curve's
    inverse (the tables :func:`relight.kernels.compositor.decode_slope_table` and
    ``encode_table``, interpolated; bounded by SLOPE_MAX) - and n what makes it exact there; and the
    chord through black and the tangent at the knee q = x_c - KNEE_GAP, x (k q + n) / q, which
    pixels darker than the knee take (a cell darker than the gap: no knee, the chord its tangent).
    ``to_rgb``, ``to_ycc`` (3, 4): a decoded frame's affine
    maps of codes (Y', Cb, Cr) -> R'G'B' and back - the maps composed with them (v -> to_ycc(k
    to_rgb(v) + n)); None: an RGB frame's. Cells that change nothing map to themselves."""
    from relight.colour import decode_lut8
    from relight.kernels.compositor import ENCODE_STEPS, KNEE_GAP, SLOPE_MAX, decode_slope_table, encode_table

    code = np.asarray(colour, np.uint8)
    g, b = cells[..., :3].astype(np.float32), cells[..., 4:7].astype(np.float32)
    cover = cells[..., 3].astype(np.float32)
    v = np.clip(g * decode_lut8()[code] + b, 0.0, 1.0) * np.float32(ENCODE_STEPS)
    k0 = np.minimum(v.astype(np.int64), ENCODE_STEPS - 1)
    enc, slope = encode_table(), decode_slope_table()
    e = (enc[k0] + (v - k0).astype(np.float32) * (enc[k0 + 1] - enc[k0])).astype(np.float32)
    c0 = np.minimum(e.astype(np.int64), 254)
    se = slope[c0] + (e - c0).astype(np.float32) * (slope[c0 + 1] - slope[c0])
    k = np.clip(g * slope[code] / np.maximum(se, np.float32(1e-12)), 0.0, np.float32(SLOPE_MAX)).astype(np.float32)
    x = code.astype(np.float32)
    n = (e - k * x).astype(np.float32)
    q = (x - np.float32(KNEE_GAP)).astype(np.float32)
    has = q > 0
    knee = np.where(has, q, np.float32(-1.0)).astype(np.float32)
    chord = np.where(has, np.clip((k * q + n) / np.where(has, q, 1.0), 0.0, np.float32(SLOPE_MAX)), k)
    chord = chord.astype(np.float32)
    chord_n = np.where(has, 0.0, n).astype(np.float32)
    eye = np.hstack([np.eye(3), np.zeros((3, 1))]).astype(np.float32)
    r = eye if to_rgb is None else np.asarray(to_rgb, np.float32)
    q = eye if to_ycc is None else np.asarray(to_ycc, np.float32)
    gh, gw = cover.shape
    out = np.zeros((gh, gw, 32), np.float32)
    off = ~(cover > 0)
    for at, kk, nn in ((0, k, n), (12, chord, chord_n)):
        m = _compose(kk, nn, r, q)
        m[off] = eye
        out[..., at:at + 12] = m.reshape(gh, gw, 12)
    out[..., 24] = cover
    for row in range(3):  # the knee in the frame's codes
        out[..., 25 + row] = q[row, 0] * knee[..., 0] + q[row, 1] * knee[..., 1] + q[row, 2] * knee[..., 2] + q[row, 3]
    return out


def _compose(k: np.ndarray, n: np.ndarray, r: np.ndarray, q: np.ndarray) -> np.ndarray:
    """(gh, gw, 3, 4) float32: v -> q(diag(k) r(v) + n) per cell, as the kernel sums it."""
    gh, gw = k.shape[:2]
    m = np.empty((gh, gw, 3, 4), np.float32)
    for row in range(3):
        for col in range(3):
            acc = np.zeros((gh, gw), np.float32)
            for j in range(3):
                acc += q[row, j] * k[..., j] * r[j, col]
            m[..., row, col] = acc
        t = np.full((gh, gw), q[row, 3], np.float32)
        for j in range(3):
            t += q[row, j] * (k[..., j] * r[j, 3] + n[..., j])
        m[..., row, 3] = t
    return m


class LightField(NamedTuple):
    """A frame's change of light (module docstring): ``grid`` (gh, gw, 32) float32 read-only -
    maps of the frame's codes and the cell's cover (:func:`code_grid`); ``space`` the codes they
    map ("rgb", or a decoded frame's matrix and range); ``factor`` frame pixels per cell;
    ``corner`` (x, y) the frame pixel of the grid's first cell's corner (a multiple of the
    factor when made; carried with the head after); ``box`` the frame's box it may change;
    ``anchor`` (x, y) the head's place (frame px) when made; ``made`` the index of the frame it
    was made on."""

    grid: np.ndarray
    space: object
    factor: int
    corner: tuple[float, float]
    box: tuple[int, int, int, int]
    anchor: tuple[float, float]
    made: int

    def moved(self, anchor, size: tuple[int, int]) -> LightField:
        """The field carried to the head at ``anchor`` (frame px) in a frame of ``size`` (w, h):
        shifted by the head's move from where the field is, in whole even pixels (the field stays
        on whole chroma samples: its tiles' weights are fixed), with its box - once that move passes
        :data:`CARRY_DEAD_AT_540` (else the field stays)."""
        from relight.numerics import px_at

        dx, dy = float(anchor[0]) - self.anchor[0], float(anchor[1]) - self.anchor[1]
        if dx * dx + dy * dy < px_at(CARRY_DEAD_AT_540, size[1]) ** 2:
            return self
        ix, iy = 2 * int(round(dx / 2.0)), 2 * int(round(dy / 2.0))
        if ix == 0 and iy == 0:
            return self
        x0, y0, x1, y1 = self.box
        w, h = size
        box = (max(x0 + ix, 0), max(y0 + iy, 0), min(x1 + ix, w), min(y1 + iy, h))
        return self._replace(corner=(self.corner[0] + ix, self.corner[1] + iy), box=box,
                             anchor=(self.anchor[0] + ix, self.anchor[1] + iy))


def aligned_box(box, size: tuple[int, int], factor: int) -> tuple[int, int, int, int]:
    """``box`` grown to multiples of ``factor`` (the far edges may pass the frame's ``size``
    (w, h): the copy replicates its last pixels there)."""
    x0, y0, x1, y1 = box
    w, h = size
    x0, y0 = max(int(x0), 0) // factor * factor, max(int(y0), 0) // factor * factor
    x1, y1 = -(-min(int(x1), w) // factor) * factor, -(-min(int(y1), h) // factor) * factor
    return x0, y0, max(x1, x0 + factor), max(y1, y0 + factor)


def small_copy(frame, box, factor: int) -> np.ndarray:
    """(h, w, 3) uint8 sRGB: the frame's ``box`` (aligned: :func:`aligned_box`) scaled down by
    ``factor`` (block means) - for a :class:`relight.video_yuv.YuvFrame` its planes scaled first,
    then converted (the conversion is linear)."""
    if isinstance(frame, np.ndarray):
        return block_means(frame, box, factor, factor)
    return frame.small_box(box, factor)


def cover_box(cover: np.ndarray, corner, factor: int, size: tuple[int, int]):
    """The frame's box (x0, y0, x1, y1) of the cells whose ``cover`` (gh, gw) is above 0, grown by
    a cell (the bilinear sample's reach), clipped to ``size`` (w, h); None when none is."""
    ys, xs = np.nonzero(cover > 0)
    if ys.size == 0:
        return None
    w, h = size
    x0 = int(np.floor(corner[0] + (xs.min() - 1) * factor))
    y0 = int(np.floor(corner[1] + (ys.min() - 1) * factor))
    x1 = int(np.ceil(corner[0] + (xs.max() + 2) * factor))
    y1 = int(np.ceil(corner[1] + (ys.max() + 2) * factor))
    return max(x0, 0), max(y0, 0), min(x1, w), min(y1, h)
