"""Host wrapper of ``field.cl``: the light field (:mod:`relight.engine.field`) applied to a frame
at its full resolution - an RGB frame or a decoded frame's Y'CbCr planes, in one pass over the
box the field reaches, in the frame's own codes (its NumPy twins: :mod:`relight.kernels.field_twin`).

Grids are (gh, gw, 32) float32: two affine maps of the frame's codes (Y', Cb, Cr for planes; R',
G', B' for RGB), each three rows out_c = m_c . (v0, v1, v2, 1) - the tangent at the cell's colour
and the chord through black (a pixel darker than the cell's knee takes the chord: ``field.cl``) -
then the share of the cell the change covers (0: nothing changes there), the knee in the frame's
codes and four zeros (:func:`relight.engine.field.code_grid` makes them). A field is placed by
its factor (frame pixels per cell) and corner (the frame pixel of its first cell's corner): a frame
pixel X reads grid position (X + 0.5) / factor - 0.5 - corner / factor. Boxes are (x0, y0, x1, y1)
frame pixels.
"""

from __future__ import annotations

import numpy as np

from relight.errors import InputError

from .runtime import aligned_copy, build_program, get_runtime

#: Work-group (x, y) of field_rgb, in tiles; each work item runs TILES tiles along a row.
GROUP = (16, 4)
TILES = 4
#: field_planes: a work item is a run of whole tiles along a chroma row, at most LANES samples (a
#: vector); its work-group (x, y) in runs and chroma rows. Its grid is laid out as rows of each
#: coefficient (:func:`soa_rows`), SOA_PAD cells carried on each side.
LANES = 8
GROUP_PLANES = (8, 8)
SOA_PAD = 16
#: Floats per cell of a field grid, and where its cover is.
CELL = 32
COVER = 24


def tile_geometry(factor: int, corner: float, step: int) -> tuple[int, float, int]:
    """Along one axis, (T, O, s0): a tile's samples - pixels (``step`` 1) or chroma samples (2) -
    between two cell centres, the first one's weight offset (its weight toward the next cell is
    (i + O) / T), and the sample tile 0 starts at, for a field of ``factor`` pixels per cell whose
    corner is at ``corner`` (a multiple of ``step``)."""
    t = factor // step
    lead = -(-(t - 1) // 2)  # ceil((T - 1) / 2)
    return t, lead - (t - 1) / 2.0, int(corner) // step + lead


def tile_range(lo: int, hi: int, t: int, s0: int) -> tuple[int, int]:
    """(first tile, count) of the tiles of ``t`` samples from ``s0`` holding samples [lo, hi)."""
    first = (lo - s0) // t
    return first, (hi - 1 - s0) // t - first + 1


def check_grid(grid: np.ndarray) -> np.ndarray:
    """The grid as C-ordered float32 (gh, gw, 16), finite (else InputError)."""
    grid = np.ascontiguousarray(grid, dtype=np.float32)
    if grid.ndim != 3 or grid.shape[2] != CELL or grid.shape[0] < 1 or grid.shape[1] < 1:
        raise InputError(f"light field of shape {grid.shape}: expected (gh, gw, {CELL})")
    if not np.isfinite(grid).all():
        raise InputError("light field: non-finite coefficients")
    return grid


def soa_rows(grid: np.ndarray, pad: int = SOA_PAD) -> np.ndarray:
    """(gh, 32, sw) float32: ``grid`` (gh, gw, 32) as rows of each coefficient - row r's
    coefficient k at [r, k, pad + c] for cell c - the edge cells carried on ``pad`` cells each side
    and beyond, to a width ``sw`` of whole vectors (:data:`LANES`) of at least gw + 2 pad: what
    ``field_planes`` reads 8 cells at a time."""
    gh, gw, n = grid.shape
    sw = -(-(gw + 2 * pad) // LANES) * LANES
    out = np.empty((gh, n, sw), np.float32)
    out[:, :, pad:pad + gw] = grid.transpose(0, 2, 1)
    out[:, :, :pad] = grid[:, :1, :].transpose(0, 2, 1)
    out[:, :, pad + gw:] = grid[:, -1:, :].transpose(0, 2, 1)
    return out


def check_placement(factor: int, corner, step: int = 1) -> tuple[int, int, int]:
    """(factor, corner x, corner y) as ints: the factor a whole number, even but for an RGB frame's
    1 (``step`` 1), the corner a multiple of ``step`` (else InputError)."""
    f, cx, cy = int(factor), float(corner[0]), float(corner[1])
    if f != factor or f < 1 or f > 64 or (step == 2 and f % 2):
        raise InputError(f"light field of {factor} pixels per cell: use 1 to 64 (even for planes)")
    if not (cx == int(cx) and cy == int(cy) and int(cx) % step == 0 and int(cy) % step == 0):
        raise InputError(f"light field corner {corner}: whole pixels, a multiple of {step}")
    return f, int(cx), int(cy)


def chroma_box(box, size: tuple[int, int], cy: int):
    """(cx0, cy0, cx1, cy1): the chroma samples (2 x ``cy`` luma pixels each) that hold a pixel of
    ``box`` in a frame of ``size`` (w, h)."""
    w, h = size
    x0, y0, x1, y1 = (int(v) for v in box)
    return (max(x0, 0) // 2, max(y0, 0) // cy, -(-min(x1, w) // 2), -(-min(y1, h) // cy))


class FieldApplier:
    """The ``field_rgb`` and ``field_planes`` kernels (built per factor and chroma layout, kept;
    device buffers kept by size). A field is placed by its ``factor`` (frame pixels per cell) and
    ``corner`` (the frame pixel of its first cell's corner): a frame pixel X reads the grid at
    (X + 0.5) / factor - 0.5 - corner / factor."""

    def __init__(self):
        import pyopencl as cl

        self.rt = get_runtime()
        # its own queue: a frame's pass waits for nothing the relighter or the compositor queued
        # (a live source makes its next field on a worker meanwhile)
        self.queue = cl.CommandQueue(self.rt.context, self.rt.device)
        self._kernels: dict = {}
        self._bufs: dict = {}
        self._grid_key = None  # (the grid array last sent, its buffer): a read-only grid reused is not sent again
        self._soa_key = None  # (the grid, its rows, their buffer) last sent to field_planes
        self._prepared = None  # (a grid, its rows) laid out ahead (:meth:`prepare`)

    def _kernel(self, name: str, factor: int, cy: int = 0):
        """The kernel ``name`` built for ``factor`` and ``cy`` (0: RGB)."""
        import pyopencl as cl

        from .compositor import KNEE_RAMP

        key = (name, factor, cy)
        k = self._kernels.get(key)
        if k is None:
            step_x, step_y = (1, 1) if cy == 0 else (2, cy)
            tx, ox, _ = tile_geometry(factor, 0, step_x)
            ty, oy, _ = tile_geometry(factor, 0, step_y)
            opts = ("-cl-denorms-are-zero", f"-DKNEE_RAMP={float(np.float32(KNEE_RAMP)):.9e}f", f"-DTX={tx}",
                    f"-DTY={ty}", f"-DOX={ox:.1f}f", f"-DOY={oy:.1f}f", f"-DCY={max(cy, 1)}", f"-DTILES={TILES}")
            k = self._kernels[key] = cl.Kernel(build_program("field", opts), name)
        return k

    def _buf(self, key, nbytes: int):
        import pyopencl as cl

        buf = self._bufs.get(key)
        if buf is None or buf.size < nbytes:
            if len(self._bufs) >= 8:
                self._bufs.clear()
                self._grid_key = self._soa_key = None
            buf = self._bufs[key] = cl.Buffer(self.rt.context, cl.mem_flags.READ_WRITE, max(nbytes, 1))
        return buf

    def _grid(self, grid: np.ndarray):
        """The device copy of ``grid`` (a read-only array handed again is not sent again)."""
        import pyopencl as cl

        if self._grid_key is not None and self._grid_key[0] is grid and not grid.flags.writeable:
            return self._grid_key[1]
        g = check_grid(grid)
        buf = self._buf("grid", g.nbytes)
        cl.enqueue_copy(self.queue, buf, g, is_blocking=False)
        self._grid_key = (grid, buf)
        return buf

    @staticmethod
    def _launch_size(ntx: int, nty: int) -> tuple[int, int]:
        gx, gy = GROUP
        items = -(-ntx // TILES)
        return -(-items // gx) * gx, -(-nty // gy) * gy

    def rgb(self, img: np.ndarray, box, grid: np.ndarray, factor: int, corner) -> np.ndarray:
        """``img`` ((H, W, 3) uint8 sRGB) with the field applied over ``box`` (a new array)."""
        img = np.asarray(img, dtype=np.uint8)
        h, w = img.shape[:2]
        x0, y0, x1, y1 = (int(v) for v in box)
        x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, w), min(y1, h)
        out = aligned_copy(img)
        if x1 <= x0 or y1 <= y0:
            return out
        f, cx, cy = check_placement(factor, corner)
        t, _, px0 = tile_geometry(f, cx, 1)
        _, _, py0 = tile_geometry(f, cy, 1)
        ta0, nta = tile_range(x0, x1, t, px0)
        tb0, ntb = tile_range(y0, y1, t, py0)
        gbuf = self._grid(grid)
        q = self.queue
        buf = self._wrap(out)
        self._kernel("field_rgb", f)(q, self._launch_size(nta, ntb), GROUP, buf, np.int32(w), np.int32(x0),
                                     np.int32(y0), np.int32(x1), np.int32(y1), np.int32(ta0), np.int32(tb0),
                                     np.int32(nta), np.int32(ntb), np.int32(px0), np.int32(py0), gbuf,
                                     np.int32(grid.shape[1]), np.int32(grid.shape[0]))
        self._finish([(buf, out)])
        return out

    def _wrap(self, a: np.ndarray):
        """A device buffer over the host array ``a`` (aligned: PoCL works in it in place)."""
        import pyopencl as cl

        return cl.Buffer(self.rt.context, cl.mem_flags.READ_WRITE | cl.mem_flags.USE_HOST_PTR, hostbuf=a)

    def _finish(self, pairs) -> None:
        """Wait for the queue and make each (buffer, host array) pair's device writes the host's
        (a map and unmap: no copy where the device works in the host's memory)."""
        import pyopencl as cl

        q = self.queue
        for buf, a in pairs:
            m, _ = cl.enqueue_map_buffer(q, buf, cl.map_flags.READ, 0, a.shape, a.dtype, is_blocking=True)
            m.base.release(q)
        q.finish()

    def planes(self, y: np.ndarray, u: np.ndarray, v: np.ndarray, box, grid: np.ndarray, factor: int,
               corner) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """New planes: ``y`` (H, W), ``u``, ``v`` (H / cy, W / 2) uint8 (cy = 2: 4:2:0, 1: 4:2:2) with
        the field (its maps of (Y', Cb, Cr) codes; ``factor`` even, ``corner`` even) applied over
        ``box`` (grown to whole chroma samples)."""
        h, w = y.shape
        ch_, cw_ = u.shape
        if w % 2 or cw_ * 2 != w or v.shape != u.shape or ch_ not in (h, h // 2) or (ch_ != h and h % 2):
            raise InputError(f"planes {y.shape}, {u.shape}, {v.shape}: expected 4:2:0 or 4:2:2 of an even width "
                             "(and an even height for 4:2:0)")
        cy = h // ch_
        yo, uo, vo = aligned_copy(y), aligned_copy(u), aligned_copy(v)
        cx0, cy0, cx1, cy1 = chroma_box(box, (w, h), cy)
        if cx1 <= cx0 or cy1 <= cy0:
            return yo, uo, vo
        f, gx, gy = check_placement(factor, corner, 2)
        if f > 2 * LANES:
            raise InputError(f"light field of {factor} pixels per cell on planes: use at most {2 * LANES}")
        tx, _, sx0 = tile_geometry(f, gx, 2)
        _, _, sy0 = tile_geometry(f, gy, cy)
        ta0, nta = tile_range(cx0, cx1, tx, sx0)
        items = -(-nta // (LANES // tx))
        soa, sbuf = self._soa(grid)
        by, bu, bv = self._wrap(yo), self._wrap(uo), self._wrap(vo)
        gx_, gy_ = GROUP_PLANES
        size = (-(-items // gx_) * gx_, -(-(cy1 - cy0) // gy_) * gy_)
        self._kernel("field_planes", f, cy)(self.queue, size, GROUP_PLANES, by, np.int32(w), bu, bv, np.int32(cw_),
                                            np.int32(cx0), np.int32(cy0), np.int32(cx1), np.int32(cy1),
                                            np.int32(ta0), np.int32(items), np.int32(sx0), np.int32(sy0), sbuf,
                                            np.int32(grid.shape[1]), np.int32(grid.shape[0]), np.int32(soa.shape[2]),
                                            np.int32(SOA_PAD))
        self._finish([(by, yo), (bu, uo), (bv, vo)])
        return yo, uo, vo

    def prepare(self, grid: np.ndarray) -> None:
        """Lay a read-only ``grid`` out for :meth:`planes` ahead (:func:`soa_rows`: ~2 ms at 720p)
        - on the thread that made it (a live source's worker), not the frame's. Touches nothing
        but the one slot :meth:`planes` reads."""
        if not grid.flags.writeable:
            self._prepared = (grid, soa_rows(check_grid(grid)))

    def _soa(self, grid: np.ndarray):
        """(:func:`soa_rows` of ``grid``, its device copy): a read-only grid handed again is not
        laid out and sent again."""
        import pyopencl as cl

        if self._soa_key is not None and self._soa_key[0] is grid and not grid.flags.writeable:
            return self._soa_key[1:]
        ready = self._prepared
        soa = ready[1] if ready is not None and ready[0] is grid else soa_rows(check_grid(grid))
        buf = self._buf("soa", soa.nbytes)
        cl.enqueue_copy(self.queue, buf, soa, is_blocking=False)
        self._soa_key = (grid, soa, buf)
        return soa, buf
