"""Which work-groups of the composite kernels (``composite.cl``) can change a pixel: the rest are
skipped by the kernels, which leave them exactly as they are. Pure functions over the coarse
map, the face layer's reach and the person's grid (:func:`work_groups`, :func:`face_cells`)."""

from __future__ import annotations

import cv2
import numpy as np

#: The reference position the coarse map gives a grid point outside the warp (frame pixels
#: there read nothing: :mod:`relight.engine.warp` writes it, the composite kernels skip it).
OUTSIDE = -1.0e4
#: Reference positions below this mark grid points outside the warp (half of OUTSIDE: room for
#: bilinear blends toward it).
OUTSIDE_HALF = OUTSIDE / 2
#: The composite kernels' work-group (x, y): what nothing changes in is skipped per group (:func:`work_groups`).
GROUP = (16, 4)


def face_cells(coarse: np.ndarray, origin, reach_sat: np.ndarray) -> np.ndarray:
    """(gh - 1, gw - 1) bool: the cells of the coarse map (``coarse`` (gh, gw, 2) reference
    positions, ``OUTSIDE_HALF`` marking points outside the warp) where the face's layer may be
    non-zero - a cell's pixels take their reference position inside the box of its four corners
    (bilinear weights are convex), and the layer's bilinear sample reads the texels around it:
    the cell is kept where that box, grown by two texels (float32 rounding), holds a crop pixel
    the layer reaches. ``reach_sat``: (ch + 1, cw + 1) summed-area table of those pixels
    (``cv2.integral``); ``origin``: the crop's corner in the reference."""
    ch, cw = reach_sat.shape[0] - 1, reach_sat.shape[1] - 1
    x = coarse[..., 0].astype(np.float64) - origin[0]
    y = coarse[..., 1].astype(np.float64) - origin[1]
    inside = coarse[..., 0] >= OUTSIDE_HALF
    quad = np.s_[:-1, :-1], np.s_[:-1, 1:], np.s_[1:, :-1], np.s_[1:, 1:]
    ok = inside[quad[0]] & inside[quad[1]] & inside[quad[2]] & inside[quad[3]]
    x0 = np.floor(np.minimum.reduce([x[q] for q in quad])) - 2
    x1 = np.floor(np.maximum.reduce([x[q] for q in quad])) + 3
    y0 = np.floor(np.minimum.reduce([y[q] for q in quad])) - 2
    y1 = np.floor(np.maximum.reduce([y[q] for q in quad])) + 3
    ok &= (x1 >= 0) & (y1 >= 0) & (x0 < cw) & (y0 < ch)
    x0, x1 = (np.clip(np.where(ok, v, 0), 0, cw - 1).astype(np.int64) for v in (x0, x1))
    y0, y1 = (np.clip(np.where(ok, v, 0), 0, ch - 1).astype(np.int64) for v in (y0, y1))
    return ok & (_box_sums(reach_sat, y0, y1, x0, x1) > 0)



def _group_spans(lo: int, n: int, group: int, scale: float, clip, offset: float, step: float, cells: int):
    """Per work-group along one axis: (any pixel at a frame position in ``clip`` (lo, hi or None),
    first cell, last cell) - the group's pixels at frame positions X = (i + 0.5) scale - 0.5 read
    cell floor((X + offset) / step) and the next (a bilinear sample); one more each side
    (rounding), clipped to the ``cells``."""
    ng = -(-n // group)
    first = lo + np.arange(ng) * group
    last = np.minimum(first + group, lo + n) - 1
    a, b = (first + 0.5) * scale - 0.5, (last + 0.5) * scale - 0.5
    if clip is not None:
        a, b = np.maximum(a, clip[0]), np.minimum(b, clip[1])
    c0 = np.clip(np.floor((a + offset) / step) - 1, 0, max(cells - 1, 0)).astype(np.int64)
    c1 = np.clip(np.floor((b + offset) / step) + 2, 0, max(cells - 1, 0)).astype(np.int64)
    return a <= b, c0, c1



def _box_sums(sat: np.ndarray, y0, y1, x0, x1) -> np.ndarray:
    """Sums over the inclusive boxes rows y0..y1, columns x0..x1 (index arrays, broadcast) of the
    image whose summed-area table (``cv2.integral``: (h + 1, w + 1)) is ``sat``."""
    return sat[y1 + 1, x1 + 1] - sat[y0, x1 + 1] - sat[y1 + 1, x0] + sat[y0, x0]



def _any_in(flags: np.ndarray, ys, xs) -> np.ndarray:
    """(ny, nx) bool: any of ``flags`` (h, w) bool in the rectangles rows ys, columns xs (each
    (hit, first, last) per group from :func:`_group_spans`)."""
    (hy, y0, y1), (hx, x0, x1) = ys, xs
    if flags.size == 0:
        return np.zeros((hy.size, hx.size), bool)
    sat = cv2.integral(flags.astype(np.uint8))
    return (_box_sums(sat, y0[:, None], y1[:, None], x0[None, :], x1[None, :]) > 0) & hy[:, None] & hx[None, :]



def work_groups(box, scale, face_box, cells: np.ndarray | None, step: int, person: np.ndarray | None = None,
                person_sampling=None, floor: float = 0.0, gate: bool = False, group=GROUP) -> np.ndarray:
    """(ngy, ngx) uint8 flags of the composite kernels' work-groups over ``box`` (x0, y0, x1, y1
    of the image, its pixels at frame positions (i + 0.5) ``scale`` - 0.5): bit 0 - the face's
    composite may change a pixel of the group (its pixels inside ``face_box`` read the coarse
    map's ``cells``, from :func:`face_cells`); bit 1 - the person's change may (a grid cell it
    reads has a matte above ``floor``: ``person`` (gh, gw, 4), ``person_sampling`` ((sx, sy),
    (gox, goy)) as :func:`relight.kernels.compositor.person_sampling` gives); with ``gate`` the
    face's only where bit 1 is set (the face's composite is scaled by the matte there: nothing of
    it is left beyond). A group with neither keeps its bytes: the kernel skips it (exactly what
    the kernel would leave)."""
    bx0, by0, bx1, by1 = box
    flags = np.zeros((-(-(by1 - by0) // group[1]), -(-(bx1 - bx0) // group[0])), np.uint8)
    if cells is not None and face_box[2] > face_box[0] and face_box[3] > face_box[1]:
        # face_at: cell floor((fx + 0.5) / step + 0.5) of fx = X - fx0 in [0, fw - 1]
        xs = _group_spans(bx0, bx1 - bx0, group[0], scale[0], (face_box[0], face_box[2] - 1.0),
                          0.5 + 0.5 * step - face_box[0], step, cells.shape[1])
        ys = _group_spans(by0, by1 - by0, group[1], scale[1], (face_box[1], face_box[3] - 1.0),
                          0.5 + 0.5 * step - face_box[1], step, cells.shape[0])
        flags |= _any_in(cells, ys, xs).astype(np.uint8)
    if person is not None:
        (sx, sy), (gox, goy) = person_sampling
        # the grid at (X + go + 0.5) s - 0.5: cell floor(...) and the next, edges replicated
        gh, gw = person.shape[:2]
        xs = _group_spans(bx0, bx1 - bx0, group[0], scale[0], None, gox + 0.5 - 0.5 / sx, 1.0 / sx, gw)
        ys = _group_spans(by0, by1 - by0, group[1], scale[1], None, goy + 0.5 - 0.5 / sy, 1.0 / sy, gh)
        on = _any_in(person[..., 3] > floor, ys, xs)
        if gate:
            flags &= on
        flags |= on.astype(np.uint8) << 1
    return flags


