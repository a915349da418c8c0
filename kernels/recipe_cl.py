"""Host wrapper of ``recipe.cl``: texel rows of a recipe bundle on the OpenCL device.

NumPy twin: :func:`relight.kernels.recipe.texel_rows` (same recipe, same maths). A
:class:`RecipeRows` puts a recipe's per-pixel arrays on the device once (the bundle's sample
and horizon codes used in place) and makes rows of up to ``MAX_T`` texels per launch straight
into a (slots, 3, P) float16 array the relighting kernel reads.
"""

from __future__ import annotations

import numpy as np

from .maps import texel_azimuths
from .runtime import build_program, get_runtime

#: Texels per launch, and the kernel's bounds on visibility positions and model vertices.
MAX_T = 8
MAX_POS = 112
MAX_MV = 96
#: Work-group size (each work item holds ~4 KB of private arrays).
GROUP = 16


class RecipeRows:
    """Makes texel rows of one recipe (:class:`relight.kernels.recipe.Recipe`) into ``rows``
    ((slots, 3, P) float16 host memory, used in place through ``rows_buf``)."""

    def __init__(self, recipe, rows: np.ndarray, rows_buf=None):
        import pyopencl as cl

        from . import interpolation as interp
        from . import recipe as rcp
        from . import reflectance as rf

        self.recipe = recipe
        rt = get_runtime()
        ctx = rt.context
        self.queue = rt.queue
        mf = cl.mem_flags
        self.kernel = cl.Kernel(build_program("recipe", ("-cl-denorms-are-zero",)), "texel_rows")
        p = recipe.n_pixels
        self.n_pix = p

        def dev(a, dtype=None):
            a = np.ascontiguousarray(a, dtype=dtype)
            return cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=a if a.size else np.zeros(4, a.dtype))

        def f4(a):
            out = np.zeros((max(len(a), 1), 4), np.float32)
            out[:len(a), :3] = a
            return out

        codes = recipe.codes
        if isinstance(codes, np.ndarray) and codes.flags.c_contiguous and codes.dtype == np.uint8 and codes.size:
            self._codes = cl.Buffer(ctx, mf.READ_ONLY | mf.USE_HOST_PTR, hostbuf=codes)  # the bundle's, in place
        else:
            self._codes = dev(codes, np.uint8)
        self._scale = dev(np.asarray(recipe.scale, np.float32))
        self._normal = dev(f4(np.asarray(recipe.normals, np.float32)))
        self.use_vis = recipe.horizon is not None
        if self.use_vis:
            h = np.asarray(recipe.horizon)
            if h.dtype != np.uint8:
                h = rcp.encode_horizon(h)
            if recipe.horizon_index is not None:
                h = h[np.asarray(recipe.horizon_index)]  # a row per pixel on the device
            self._horizon = dev(h, np.uint8)
        else:
            self._horizon = dev(np.zeros(4, np.uint8))
        self._albedo = dev(f4(np.asarray(recipe.albedo, np.float32)))
        self._spec = dev(f4(np.asarray(recipe.spec, np.float32)))
        self._trust = dev(np.asarray(recipe.trust, np.float32))
        self._blend = dev(np.asarray(recipe.blend, np.float32))
        self._decode = dev(rcp._DECODE)
        self._elevation = dev(rcp.decode_horizon(np.arange(256, dtype=np.uint8)))
        w, h_ = recipe.tri.map_size
        self._taz = texel_azimuths(recipe.tri.texel_dirs, recipe.n_az).astype(np.float32)
        self.inv_soft = 1.0 / (interp.VIS_SOFT_TEXELS * np.pi / h_)
        self.open_elev = float(interp.OPEN_SKY)
        self.rows = rows
        self.rows_buf = rows_buf if rows_buf is not None else cl.Buffer(
            ctx, mf.READ_WRITE | mf.USE_HOST_PTR, hostbuf=rows)
        self._carry = rf.carry_weights(recipe.tri.vertices, recipe.n_samples) \
            if len(recipe.tri.vertices) > recipe.n_samples else (None, None)
        self._spline_cache: dict[int, np.ndarray | None] = {}
        self._kernels: dict = {}  # a kernel object per extra queue (make(queue=...))

    def _spline_rows(self, texels: np.ndarray) -> list[np.ndarray | None]:
        """Per texel its (K,) spline weights in the code domain, or None (outside the hull / no spline)."""
        from . import reflectance as rf
        from .spline import spline_weights

        r = self.recipe
        k = r.n_samples
        todo = [int(t) for t in texels if int(t) not in self._spline_cache]
        if todo:
            dirs = r.tri.texel_dirs[todo]
            res: list[np.ndarray | None] = [None] * len(todo)
            if r.spline:
                inside = np.flatnonzero(rf.spline_texels(r.tri.texel_vertices[todo], k))
                if inside.size:
                    w_ = spline_weights(r.tri.vertices[:k], dirs[inside])
                    if w_ is not None:
                        for j, i in enumerate(inside):
                            res[i] = w_[j].astype(np.float32)
            for t, v in zip(todo, res, strict=True):
                self._spline_cache[t] = v
        return [self._spline_cache[int(t)] for t in texels]

    def make(self, texels: np.ndarray, slots: np.ndarray, queue=None) -> None:
        """Rows of the map texels ``texels`` (ids in the map, all active) into ``rows[slots]``,
        on the runtime's queue or on ``queue`` (a command queue of its own, for another thread:
        each queue gets its own kernel object - a kernel's arguments are not shared safely)."""
        texels = np.asarray(texels, dtype=np.int64).ravel()
        slots = np.asarray(slots, dtype=np.int64).ravel()
        q = self.queue if queue is None else queue
        kernel = self.kernel
        if queue is not None:
            import pyopencl as cl

            kernel = self._kernels.get(queue)
            if kernel is None:
                kernel = self._kernels[queue] = cl.Kernel(self.kernel.program, "texel_rows")
        for i in range(0, texels.size, MAX_T):
            self._launch(texels[i:i + MAX_T], slots[i:i + MAX_T], q, kernel)
        q.finish()

    def _launch(self, texels: np.ndarray, slots: np.ndarray, queue, kernel) -> None:
        import pyopencl as cl

        from . import recipe as rcp
        from .interpolation import SPEC_EXPONENT
        from .spline import SPLINE_GAMMA

        if SPLINE_GAMMA != 0.4:  # the kernel undoes the spline's power as x * x * sqrt(x)
            raise RuntimeError("recipe.cl assumes SPLINE_GAMMA = 0.4")
        r = self.recipe
        k = r.n_samples
        tri = r.tri
        ctx = get_runtime().context
        mf = cl.mem_flags
        tv = tri.texel_vertices[texels]
        need = list(dict.fromkeys(int(v) for v in tv.ravel()))
        carry_ids, carry_w = self._carry
        extra = []
        if r.extrapolate and carry_ids is not None:
            for v in need:
                if v >= k:
                    extra += [int(c) for c in carry_ids[v - k]]
        verts = sorted(set(need) | set(extra), key=lambda v: (v >= k, v))  # samples first
        index = {v: i for i, v in enumerate(verts)}
        vtex = tri.vertex_texel
        positions = list(dict.fromkeys([int(t) for t in texels] + [int(vtex[v]) for v in verts]))
        pos_of = {t: i for i, t in enumerate(positions)}
        if len(positions) > MAX_POS or len(verts) > MAX_MV:
            raise RuntimeError("texel_rows: too many vertices for one launch; this is a bug, please report it")
        az = np.ascontiguousarray(self._taz[rcp.neighbourhoods(tri.map_size, np.asarray(positions)).ravel()])
        mv_dir = np.zeros((len(verts), 4), np.float32)
        mv_kind = -np.ones((len(verts), 4), np.int32)
        mv_carry = np.zeros((len(verts), 4), np.float32)
        for i, v in enumerate(verts):
            mv_dir[i, :3] = tri.vertices[v]
            mv_dir[i, 3] = pos_of[int(vtex[v])]
            if v < k:
                mv_kind[i, 0] = v
            elif not r.extrapolate:
                mv_kind[i, 0] = -2
            else:
                mv_kind[i, 1:] = [index[int(c)] for c in carry_ids[v - k]]
                mv_carry[i, :3] = carry_w[v - k]
        n = texels.size
        t_dir = np.zeros((n, 4), np.float32)
        t_vert = -np.ones((n, 4), np.int32)
        t_wt = np.zeros((n, 4), np.float32)
        t_corner = np.zeros((n, 4), np.int32)
        spl = self._spline_rows(texels)
        spline_w = [s for s in spl if s is not None]
        row = 0
        for j, t in enumerate(texels):
            t_dir[j, :3] = tri.texel_dirs[t]
            t_dir[j, 3] = pos_of[int(t)]
            t_vert[j, :3] = [index[int(v)] for v in tv[j]]
            t_wt[j, :3] = tri.texel_weights[t]
            if spl[j] is not None:
                t_vert[j, 3] = row
                row += 1
                t_corner[j, :3] = np.minimum(tv[j], k - 1)  # inside the hull: samples
        sw = np.ascontiguousarray(np.stack(spline_w) if spline_w else np.zeros((1, max(k, 1))), np.float32)

        def buf(a):
            a = np.ascontiguousarray(a)
            return cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=a)

        kernel(queue, (-(-self.n_pix // GROUP) * GROUP,), (GROUP,), self._codes, np.int32(k),
                    np.int32(self.n_pix), self._scale, self._decode, self._normal, self._horizon, np.int32(r.n_az),
                    np.int32(self.use_vis), self._elevation,
                    self._albedo, self._spec, self._trust, self._blend, buf(az), np.int32(len(positions)),
                    buf(mv_dir), buf(mv_kind), buf(mv_carry), np.int32(len(verts)), buf(t_dir), buf(t_vert),
                    buf(t_wt), buf(t_corner), np.int32(n), buf(sw), np.int32(r.trend),
                    np.int32(bool(spline_w)), np.int32(SPEC_EXPONENT), np.float32(self.inv_soft),
                    np.float32(self.open_elev), buf(slots.astype(np.int32)),
                    self.rows_buf)

