"""Host wrapper of ``field.cl``: the light field (:mod:`relight.engine.field`) applied to a frame
at its full resolution - an RGB frame or a decoded frame's Y'CbCr planes, in one pass over the
box the field reaches, in the frame's own codes (its NumPy twins: :mod:`relight.kernels.field_twin`).

Grids are (gh, gw, 32) float32: two affine maps of the frame's codes (Y', Cb, Cr for planes; R',
G', B' for RGB), each three rows out_c = m_c . (v0, v1, v2, 1) - the tangent at the cell's colour
and the chord through black (a pixel darker than the cell's knee takes the chord: ``field.cl``) -
then the share of the cell the change covers (0: nothing changes there), the knee in the frame's
codes and four zeros (:func:`relight.engine.field.code_grid` makes them). ``sampling`` = ((sx,
sy), (gox, goy)): the grid's cells per frame pixel and its first cell's position in those units (a
frame pixel X reads grid position (X + 0.5) sx - 0.5 - gox). Boxes are (x0, y0, x1, y1) frame
pixels.
"""

from __future__ import annotations

import numpy as np

from relight.errors import InputError

from .runtime import build_program, get_runtime

#: Work-group (x, y) of both kernels.
GROUP = (16, 4)
#: Floats per cell of a field grid, and where its cover is.
CELL = 32
COVER = 24


def check_grid(grid: np.ndarray) -> np.ndarray:
    """The grid as C-ordered float32 (gh, gw, 16), finite (else InputError)."""
    grid = np.ascontiguousarray(grid, dtype=np.float32)
    if grid.ndim != 3 or grid.shape[2] != CELL or grid.shape[0] < 1 or grid.shape[1] < 1:
        raise InputError(f"light field of shape {grid.shape}: expected (gh, gw, {CELL})")
    if not np.isfinite(grid).all():
        raise InputError("light field: non-finite coefficients")
    return grid


def check_sampling(sampling):
    """((sx, sy), (gox, goy)) as four float32 (scales positive, offsets finite; else InputError)."""
    (sx, sy), (gox, goy) = sampling
    vals = (float(sx), float(sy), float(gox), float(goy))
    if not (np.isfinite(vals).all() and vals[0] > 0 and vals[1] > 0):
        raise InputError(f"light field sampling {sampling}: positive scales, finite offsets")
    return tuple(np.float32(v) for v in vals)


def chroma_box(box, size: tuple[int, int], cy: int):
    """(cx0, cy0, cx1, cy1): the chroma samples (2 x ``cy`` luma pixels each) that hold a pixel of
    ``box`` in a frame of ``size`` (w, h)."""
    w, h = size
    x0, y0, x1, y1 = (int(v) for v in box)
    return (max(x0, 0) // 2, max(y0, 0) // cy, -(-min(x1, w) // 2), -(-min(y1, h) // cy))


class FieldApplier:
    """The ``field_rgb`` and ``field_planes`` kernels (built once; device buffers kept by size)."""

    def __init__(self):
        import pyopencl as cl

        self.rt = get_runtime()
        from .compositor import KNEE_RAMP

        prg = build_program("field", ("-cl-denorms-are-zero", f"-DKNEE_RAMP={float(np.float32(KNEE_RAMP)):.9e}f"))
        self._k_rgb = cl.Kernel(prg, "field_rgb")
        self._k_planes = cl.Kernel(prg, "field_planes")
        self._bufs: dict = {}
        self._grid_key = None  # (the grid array last sent, its buffer): a read-only grid reused is not sent again

    def _buf(self, key, nbytes: int):
        import pyopencl as cl

        buf = self._bufs.get(key)
        if buf is None or buf.size < nbytes:
            if len(self._bufs) >= 8:
                self._bufs.clear()
                self._grid_key = None
            buf = self._bufs[key] = cl.Buffer(self.rt.context, cl.mem_flags.READ_WRITE, max(nbytes, 1))
        return buf

    def _grid(self, grid: np.ndarray):
        """The device copy of ``grid`` (a read-only array handed again is not sent again)."""
        import pyopencl as cl

        if self._grid_key is not None and self._grid_key[0] is grid and not grid.flags.writeable:
            return self._grid_key[1]
        g = check_grid(grid)
        buf = self._buf("grid", g.nbytes)
        cl.enqueue_copy(self.rt.queue, buf, g, is_blocking=False)
        self._grid_key = (grid, buf)
        return buf

    def rgb(self, img: np.ndarray, box, grid: np.ndarray, sampling) -> np.ndarray:
        """``img`` ((H, W, 3) uint8 sRGB) with the field applied over ``box`` (a new array)."""
        import pyopencl as cl

        img = np.ascontiguousarray(img, dtype=np.uint8)
        h, w = img.shape[:2]
        x0, y0, x1, y1 = (int(v) for v in box)
        x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, w), min(y1, h)
        out = img.copy()
        if x1 <= x0 or y1 <= y0:
            return out
        sx, sy, gox, goy = check_sampling(sampling)
        gbuf = self._grid(grid)
        q = self.rt.queue
        row = w * 3
        buf = self._buf(("rgb", img.shape), img.nbytes)
        cl.enqueue_copy(q, buf, img[y0:y1], dst_offset=y0 * row, is_blocking=False)
        bw, bh = x1 - x0, y1 - y0
        gx, gy = GROUP
        self._k_rgb(q, (-(-bw // gx) * gx, -(-bh // gy) * gy), GROUP, buf, np.int32(w), np.int32(x0), np.int32(y0),
                    np.int32(bw), np.int32(bh), gbuf, np.int32(grid.shape[1]), np.int32(grid.shape[0]), sx, sy, gox,
                    goy)
        cl.enqueue_copy(q, out[y0:y1], buf, src_offset=y0 * row, is_blocking=True)
        return out

    def planes(self, y: np.ndarray, u: np.ndarray, v: np.ndarray, box, grid: np.ndarray,
               sampling) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """New planes: ``y`` (H, W), ``u``, ``v`` (H / cy, W / 2) uint8 (cy = 2: 4:2:0, 1: 4:2:2) with
        the field (its maps of (Y', Cb, Cr) codes) applied over ``box`` (grown to whole chroma
        samples)."""
        import pyopencl as cl

        h, w = y.shape
        ch_, cw_ = u.shape
        if w % 2 or cw_ * 2 != w or v.shape != u.shape or ch_ not in (h, h // 2) or (ch_ != h and h % 2):
            raise InputError(f"planes {y.shape}, {u.shape}, {v.shape}: expected 4:2:0 or 4:2:2 of an even width "
                             "(and an even height for 4:2:0)")
        cy = h // ch_
        yo, uo, vo = y.copy(), u.copy(), v.copy()
        cx0, cy0, cx1, cy1 = chroma_box(box, (w, h), cy)
        if cx1 <= cx0 or cy1 <= cy0:
            return yo, uo, vo
        sx, sy, gox, goy = check_sampling(sampling)
        gbuf = self._grid(grid)
        q = self.rt.queue
        ly0, ly1 = cy0 * cy, cy1 * cy
        ry0, ry1 = max(cy0 - 1, 0), min(cy1 + 1, ch_)  # the chroma rows read (the box's and a neighbour each side)
        by = self._buf(("y", y.shape), y.nbytes)
        cl.enqueue_copy(q, by, np.ascontiguousarray(y[ly0:ly1]), dst_offset=ly0 * w, is_blocking=False)
        chroma = []
        for name, plane in (("u", u), ("v", v)):
            rows = np.ascontiguousarray(plane[ry0:ry1])
            src, dst = self._buf((name, u.shape), u.nbytes), self._buf((name + " out", u.shape), u.nbytes)
            for b in (src, dst):  # (the samples nothing changes in are not written: they keep the input's)
                cl.enqueue_copy(q, b, rows, dst_offset=ry0 * cw_, is_blocking=False)
            chroma += [src, dst]
        bw, bh = cx1 - cx0, cy1 - cy0
        gx, gy = GROUP
        self._k_planes(q, (-(-bw // gx) * gx, -(-bh // gy) * gy), GROUP, by, np.int32(w), chroma[0], chroma[2],
                       chroma[1], chroma[3], np.int32(cw_), np.int32(cw_), np.int32(ch_), np.int32(cy), np.int32(cx0),
                       np.int32(cy0), np.int32(bw), np.int32(bh), gbuf, np.int32(grid.shape[1]),
                       np.int32(grid.shape[0]), sx, sy, gox, goy)
        cl.enqueue_copy(q, yo[ly0:ly1], by, src_offset=ly0 * w, is_blocking=False)
        cl.enqueue_copy(q, uo[cy0:cy1], chroma[1], src_offset=cy0 * cw_, is_blocking=False)
        cl.enqueue_copy(q, vo[cy0:cy1], chroma[3], src_offset=cy0 * cw_, is_blocking=True)
        return yo, uo, vo
