"""``relight.Relighter``: relight a bundle's face under environments, on the OpenCL device.

The one stateful object of the relighting engine: it holds the bundle's arrays on the device
(memory-mapped from the bundle, not copied, where the device allows), the built kernels and
the output frame, and caches the last environment's lights and the last result (nothing is
recomputed when neither the environment nor the rotation changed).

Per call: the environment's lights (computed once per environment) are turned by the head
rotation and splatted into the map's texels (:mod:`relight.kernels.transport`); then one kernel
launch either evaluates the compact transport (a rank-k basis plus the brightest texels
exactly) or, with ``exact=True``, the full sum over the maps. Only the head's pixels are
computed; the output is the full reference frame, linear RGB, zero outside ``bundle.mask``.
"""

from __future__ import annotations

import numpy as np

from relight.errors import InputError

from . import transport
from .runtime import build_program, get_runtime

#: Largest accepted deviation of a rotation matrix from orthonormal.
ROTATION_TOL = 1e-3
#: Work-group sizes (PoCL picks poorly for odd global sizes: measured 2-3x slower with None).
COMPACT_GROUP = 4
PIXEL_GROUP = 64


def _round_up(n: int, m: int) -> int:
    return (n + m - 1) // m * m


def relight_compact_numpy(v: np.ndarray, rank: int, coef: np.ndarray, rows: np.ndarray, direct_tex: np.ndarray,
                          direct_lp: np.ndarray) -> np.ndarray:
    """NumPy twin of ``relight_compact``: (P, 3) float32.

    v : (P / 16, 3, Kp, 16) blocked basis images; coef : (rank, 3); rows : (T, 3, P) texel-major maps.
    """
    p = rows.shape[2]
    vv = np.asarray(v[:, :, :rank], dtype=np.float32)  # (B, 3, k, 16)
    out = np.einsum("bcks,kc->bsc", vv, coef[:rank].astype(np.float32)).reshape(-1, 3)[:p]
    for t, lp in zip(direct_tex, direct_lp, strict=True):
        out += np.asarray(rows[t], dtype=np.float32).T * lp.astype(np.float32)
    return out


def relight_exact_numpy(maps: np.ndarray, lp: np.ndarray) -> np.ndarray:
    """NumPy twin of ``relight_exact``: (P, 3) float32 = sum over texels of maps (P, 3, Tp) x lp (T, 3)."""
    t = lp.shape[0]
    out = np.zeros(maps.shape[:2], dtype=np.float32)
    for p0 in range(0, maps.shape[0], 8192):
        blk = np.asarray(maps[p0:p0 + 8192, :, :t], dtype=np.float32)
        out[p0:p0 + 8192] = np.einsum("pct,tc->pc", blk, lp.astype(np.float32))
    return out


def check_rotation(rotation) -> np.ndarray | None:
    """A valid 3x3 rotation as float64, or None; InputError for anything else."""
    if rotation is None:
        return None
    r = np.asarray(rotation, dtype=np.float64)
    if r.shape != (3, 3) or not np.isfinite(r).all():
        raise InputError(f"rotation must be a finite 3x3 matrix, got shape {r.shape}")
    if np.abs(r @ r.T - np.eye(3)).max() > ROTATION_TOL or np.linalg.det(r) < 0:
        raise InputError("rotation must be a proper rotation matrix (orthonormal, determinant +1); "
                         "build one with relight.directions.rotation_matrix(yaw, pitch, roll)")
    return r


def _as_blocks(values: np.ndarray, padded: int) -> np.ndarray:
    """(n, 3) values -> (3 * padded,) float32: per channel, zero padded (the kernels' float16 blocks)."""
    out = np.zeros((3, padded), dtype=np.float32)
    out[:, :values.shape[0]] = values.T
    return out.ravel()


class Relighter:
    """Relights one bundle.

    tolerance : relative L2 error allowed against the exact path; the compact rank is the
    smallest whose error on the capture's validation environments meets it (no rank does: the
    exact path is used). exact : always evaluate the full maps.
    """

    def __init__(self, bundle, tolerance: float = 0.01, exact: bool = False):
        import pyopencl as cl

        if not (np.isfinite(tolerance) and tolerance > 0):
            raise InputError(f"tolerance {tolerance}: use a positive number such as 0.01 (1 %)")
        self.bundle = bundle
        self.rt = get_runtime()
        ctx, queue = self.rt.context, self.rt.queue
        mf = cl.mem_flags
        prg = build_program("relight")
        self._k_compact = cl.Kernel(prg, "relight_compact")
        self._k_exact = cl.Kernel(prg, "relight_exact")
        self._k_rows = cl.Kernel(prg, "relight_rows")
        self.texels = np.asarray(bundle.map_texels, dtype=np.int64)
        self.map_size = bundle.map_size
        self.maps = bundle.maps
        self.rows = bundle.maps_rows
        self.n_pix, _, self.t_pad = self.maps.shape
        w, h = bundle.frame_size
        x0, y0 = bundle.crop_origin
        cw = bundle.mask_crop.shape[1]
        pix = np.asarray(bundle.pixels, dtype=np.int64)
        self.frame_index = ((pix // cw + y0) * w + (pix % cw + x0)).astype(np.int32)
        self.transport = self._load_transport(bundle)
        self.tolerance = float(tolerance)
        self.rank = None if exact else self.transport.rank_for(self.tolerance)
        self.exact = self.rank is None
        self.frame = np.zeros((h, w, 3), dtype=np.float32)

        def shared(a):
            # The bundle's arrays are used in place where the device can (PoCL on the CPU: the
            # host's memory-mapped file, no copy).
            a = np.asarray(a)
            if a.flags.c_contiguous:
                return cl.Buffer(ctx, mf.READ_ONLY | mf.USE_HOST_PTR, hostbuf=a)
            return cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=np.ascontiguousarray(a))

        self._maps_buf = shared(self.maps)
        self._rows_buf = shared(self.rows)
        # Only the chosen rank of the basis, packed densely: the kernel streams nothing it does not use.
        from .maps import padded_texels

        kp = padded_texels(self.rank or 1)
        self._v = np.ascontiguousarray(self.transport.v[:, :, :kp])
        self._v_buf = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=self._v)
        self._fidx = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=self.frame_index)
        # The frame lives in host memory the device writes into directly (no copy back).
        self._frame_buf = cl.Buffer(ctx, mf.READ_WRITE | mf.USE_HOST_PTR, hostbuf=self.frame)
        self._coef = cl.Buffer(ctx, mf.READ_ONLY, kp * 16)
        nd = max(self.transport.direct, 4)
        self._dtex = cl.Buffer(ctx, mf.READ_ONLY, nd * 4)
        self._dlp = cl.Buffer(ctx, mf.READ_ONLY, nd * 16)
        self._lp = cl.Buffer(ctx, mf.READ_ONLY, 3 * self.t_pad * 4)
        self._blocks = cl.Buffer(ctx, mf.READ_ONLY, (self.t_pad // 16) * 4)
        self._queue = queue
        self._env_key = None
        self._env_lights = None
        self._last_key = None

    @staticmethod
    def _load_transport(bundle) -> transport.Transport:
        arrays = bundle.arrays
        if "transport_u" in arrays:
            return transport.Transport(u=np.asarray(arrays["transport_u"]), v=arrays["transport_v"],
                                       rank_errors=np.asarray(arrays["transport_errors"]),
                                       sigma=np.asarray(arrays.get("transport_sigma", np.zeros(1))),
                                       direct=int(bundle.meta.get("transport_direct", transport.DIRECT_TEXELS)))
        return transport.factorize(bundle.maps, bundle.map_size, np.asarray(bundle.map_texels))

    # ------------------------------------------------------------------ direction space
    def lights(self, env: np.ndarray) -> transport.EnvLights:
        """The environment's lights, cached while the same array is passed again."""
        arr = np.asarray(env)
        key = (id(env), arr.shape, float(np.asarray(arr[::17, ::13], dtype=np.float64).sum()))
        if key != self._env_key:
            self._env_lights = transport.environment_lights(arr)
            self._env_key = key
        return self._env_lights

    def texel_light(self, env, rotation=None, exposure: float = 1.0) -> np.ndarray:
        """(T, 3) ``Lp``: the environment in the map's texels for a head turned by ``rotation``."""
        return transport.texel_light(self.lights(env), check_rotation(rotation), self.map_size, self.texels,
                                     exposure)

    # ------------------------------------------------------------------ relighting
    def relight(self, env: np.ndarray, rotation=None, *, exposure: float = 1.0) -> np.ndarray:
        """The reference frame relit: (H, W, 3) float32 linear RGB, the face inside ``bundle.mask``.

        env : (H, 2H, 3) linear radiance (see :func:`relight.load_environment`). rotation : 3x3
        head rotation (camera from head) or None. exposure : linear scale of the environment.
        The returned array is owned by the Relighter (read-only) until the next call.
        """
        if not (np.isfinite(exposure) and exposure > 0):
            raise InputError(f"exposure {exposure}: must be a positive finite scale")
        r = check_rotation(rotation)
        lights = self.lights(env)
        key = (self._env_key, None if r is None else r.round(12).tobytes(), float(exposure))
        if key == self._last_key:
            return self._view()
        lp = transport.texel_light(lights, r, self.map_size, self.texels, exposure)
        if self.exact:
            self._run_exact(lp)
        else:
            self._run_compact(lp)
        self._last_key = key
        return self._view()

    def relight_light(self, direction, *, exposure: float = 1.0) -> np.ndarray:
        """The reference frame under one directional light as strong as the capture flash.

        Reads only the (up to four) map texels around ``direction`` - no environment needed.
        """
        d = np.asarray(direction, dtype=np.float64)
        if d.shape != (3,) or not np.isfinite(d).all() or np.linalg.norm(d) < 1e-9:
            raise InputError(f"light direction {direction}: three finite numbers, not all zero")
        lp = transport.point_light(d, self.map_size, self.texels) * exposure
        self._run_rows(lp)
        self._last_key = None
        return self._view()

    def _view(self) -> np.ndarray:
        out = self.frame.view()
        out.flags.writeable = False
        return out

    def _finish(self) -> None:
        import pyopencl as cl

        # The one host sync per frame: mapping a host-pointer buffer waits for the kernel and,
        # on a CPU device, moves nothing.
        mapped, _ = cl.enqueue_map_buffer(self._queue, self._frame_buf, cl.map_flags.READ, 0, self.frame.shape,
                                          self.frame.dtype)
        mapped.base.release()

    def _run_compact(self, lp: np.ndarray) -> None:
        import pyopencl as cl

        k = self.rank
        kp = self._v.shape[2]
        direct, rest = transport.split_direct(lp, self.transport.direct)
        coef = np.zeros((k, 4), dtype=np.float32)
        coef[:, :3] = self.transport.u[:, :k].T.astype(np.float64) @ rest
        dlp = np.zeros((max(direct.size, 1), 4), dtype=np.float32)
        dlp[:direct.size, :3] = lp[direct]
        q = self._queue
        cl.enqueue_copy(q, self._coef, coef, is_blocking=False)
        cl.enqueue_copy(q, self._dtex, direct.astype(np.int32) if direct.size else np.zeros(1, np.int32),
                        is_blocking=False)
        cl.enqueue_copy(q, self._dlp, dlp, is_blocking=False)
        blocks = -(-self.n_pix // 16)
        self._k_compact(q, (_round_up(blocks, COMPACT_GROUP),), (COMPACT_GROUP,), self._v_buf, np.int32(k),
                        np.int32(kp), np.int32(self.n_pix), self._coef, self._rows_buf, np.int32(self.n_pix),
                        self._dtex, self._dlp, np.int32(direct.size), self._fidx, self._frame_buf)
        self._finish()

    def _run_exact(self, lp: np.ndarray) -> None:
        import pyopencl as cl

        blocks = np.flatnonzero(np.abs(_as_blocks(lp, self.t_pad).reshape(3, -1, 16)).sum(axis=(0, 2)) > 0)
        q = self._queue
        cl.enqueue_copy(q, self._lp, _as_blocks(lp, self.t_pad), is_blocking=False)
        cl.enqueue_copy(q, self._blocks, blocks.astype(np.int32) if blocks.size else np.zeros(1, np.int32),
                        is_blocking=False)
        grid = (_round_up(self.n_pix, PIXEL_GROUP),), (PIXEL_GROUP,)
        self._k_exact(q, *grid, self._maps_buf, np.int32(self.t_pad), np.int32(self.n_pix), self._lp,
                      self._blocks, np.int32(blocks.size), self._fidx, self._frame_buf)
        self._finish()

    def _run_rows(self, lp: np.ndarray) -> None:
        import pyopencl as cl

        lit = np.flatnonzero(np.abs(lp).sum(axis=1) > 0)
        if lit.size > self.transport.direct and lit.size > 4:  # more than a few texels: the exact path
            self._run_exact(lp)
            return
        l4 = np.zeros((max(lit.size, 1), 4), dtype=np.float32)
        l4[:lit.size, :3] = lp[lit]
        q = self._queue
        cl.enqueue_copy(q, self._dtex, lit.astype(np.int32) if lit.size else np.zeros(1, np.int32), is_blocking=False)
        cl.enqueue_copy(q, self._dlp, l4, is_blocking=False)
        grid = (_round_up(self.n_pix, PIXEL_GROUP),), (PIXEL_GROUP,)
        self._k_rows(q, *grid, self._rows_buf, np.int32(self.n_pix), self._dtex, self._dlp,
                     np.int32(lit.size), self._fidx, self._frame_buf)
        self._finish()

    # ------------------------------------------------------------------ references
    def relight_numpy(self, env, rotation=None, *, exposure: float = 1.0, exact: bool | None = None) -> np.ndarray:
        """The same relight computed by the NumPy twins: (H, W, 3) float32 (for tests and benchmarks)."""
        lp = self.texel_light(env, rotation, exposure)
        use_exact = self.exact if exact is None else exact
        if use_exact:
            vals = relight_exact_numpy(self.maps, lp)
        else:
            k = self.rank
            direct, rest = transport.split_direct(lp, self.transport.direct)
            coef = self.transport.u[:, :k].T.astype(np.float64) @ rest
            vals = relight_compact_numpy(self.transport.v, k, coef, self.rows, direct, lp[direct])
        out = np.zeros_like(self.frame)
        out.reshape(-1, 3)[self.frame_index] = vals
        return out
