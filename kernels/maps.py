"""Host wrapper of ``reflectance.cl``: reflectance maps for many pixels on the OpenCL device.

NumPy twins: :func:`relight.kernels.interpolation.visibility_maps` and
:func:`relight.kernels.interpolation.build_maps` (same arguments, same maths).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from relight.errors import InputError
from relight.numerics import EPS_NORM, EPS_VALUE

from .layout import padded_texels
from .runtime import aligned_zeros, build_program, get_runtime

#: Pixels per launch (bounds the visibility scratch: PIXEL_CHUNK x texels floats, twice).
PIXEL_CHUNK = 8192
def neighbourhoods(map_size, texels: np.ndarray) -> np.ndarray:
    """(n, 9) texel ids of each texel's 3x3 neighbourhood (wrapping in azimuth, clamped at the poles)."""
    w, h = map_size
    y, x = np.divmod(np.asarray(texels, dtype=np.int64), w)
    out = np.empty((len(texels), 9), dtype=np.int64)
    j = 0
    for dy in (-1, 0, 1):
        yy = np.clip(y + dy, 0, h - 1)
        for dx in (-1, 0, 1):
            out[:, j] = yy * w + (x + dx) % w
            j += 1
    return out


def texel_azimuths(texel_dirs: np.ndarray, n_az: int) -> np.ndarray:
    """(T, 4) per texel: the two horizon columns around its azimuth, their blend, its elevation
    (8 for straight at the camera: always visible)."""
    s_xy = np.hypot(texel_dirs[:, 0], texel_dirs[:, 1])
    beta = np.mod(np.arctan2(texel_dirs[:, 1], texel_dirs[:, 0]), 2 * np.pi)
    pos = beta / (2 * np.pi) * n_az - 0.5
    i0 = np.floor(pos).astype(np.int64) % n_az
    return np.stack([i0, (i0 + 1) % n_az, pos - np.floor(pos),
                     np.where(s_xy < EPS_VALUE, 8.0, np.arctan2(texel_dirs[:, 2], np.maximum(s_xy, EPS_NORM)))], axis=1)


def _smoothed_visibility(queue, k_vis, k_box, b_hz, p_all: int, b_taz, map_size, vis_soft: float, p0: int, n: int,
                         raw, smooth, n_valid: int | None = None) -> None:
    """Enqueue soft_visibility then box3 for pixels [p0, p0 + n): ``smooth`` gets (T, n)
    (b_hz: the horizons planar, (n_az, p_all)); only the first ``n_valid`` are computed (the
    rest are padding, left as they are)."""
    w, h = map_size
    k_vis(queue, (n, w * h), None, b_hz, np.int32(p_all), b_taz, np.int32(w * h), np.float32(1.0 / vis_soft),
          np.int32(p0), np.int32(n if n_valid is None else n_valid), raw, np.int32(n))
    k_box(queue, (n, w, h), None, raw, np.int32(w), np.int32(h), np.int32(n), smooth)


def visibility_at_cl(horizon: np.ndarray, n_az: int, map_size: tuple[int, int], texel_dirs: np.ndarray,
                     columns: np.ndarray, vis_soft: float) -> np.ndarray:
    """(P, len(columns)) float32 smoothed visibility of the given map texels for each pixel:
    ``visibility_maps(horizon, n_az, map_size).reshape(P, -1)[:, columns]`` on the device (the
    3x3 mean of the soft visibility at those texels only: kernel visibility_at).
    texel_dirs : (T, 3) the map's texel directions."""
    import pyopencl as cl

    rt = get_runtime()
    ctx, queue = rt.context, rt.queue
    mf = cl.mem_flags
    prg = build_program("reflectance", ())
    k_at = cl.Kernel(prg, "visibility_at")
    p = horizon.shape[0]
    cols = np.asarray(columns, dtype=np.int64)
    out = np.empty((p, cols.size), dtype=np.float32)
    if p == 0 or cols.size == 0:
        return out
    m_all = -(-p // LANES) * LANES
    hz = aligned_zeros((horizon.shape[1], m_all), np.float32)  # planar, padded to whole vectors
    hz[:, :p] = np.asarray(horizon, np.float32).T
    b_hz = cl.Buffer(ctx, mf.READ_ONLY | mf.USE_HOST_PTR, hostbuf=hz)
    b_taz = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR,
                      hostbuf=np.ascontiguousarray(texel_azimuths(texel_dirs, n_az), dtype=np.float32))
    b_nb = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR,
                     hostbuf=np.ascontiguousarray(neighbourhoods(map_size, cols), dtype=np.int32))
    chunk = min(PIXEL_CHUNK, m_all)
    host = aligned_zeros((cols.size * chunk,), np.float32)
    b_host = cl.Buffer(ctx, mf.WRITE_ONLY | mf.USE_HOST_PTR, hostbuf=host)
    for p0 in range(0, p, chunk):
        n = min(chunk, p - p0)
        m = -(-n // LANES) * LANES
        k_at(queue, (m // LANES, cols.size), None, b_hz, np.int32(m_all), np.int32(p0), b_taz, b_nb,
             np.float32(1.0 / vis_soft), np.int32(m), b_host)
        mapped, _ = cl.enqueue_map_buffer(queue, b_host, cl.map_flags.READ, 0, host.shape, host.dtype)
        mapped.base.release()  # the map is the sync: on the CPU the values are already in ``host``
        out[p0:p0 + n] = host[:cols.size * m].reshape(cols.size, m)[:, :n].T
    return out


#: Pixels per work-item of build_maps (its LANES: one float16 vector) and per work-group.
LANES = 16
GROUP_PIXELS = 64
#: Spline texels per exact-sum block (with PIXEL_CHUNK pixels: 256 x 3 x 8192 x 8 B = 50 MB of float64).
EXACT_ROWS = 256


def _texel_tables(vertices, vertex_texel, texel_vertices, texel_weights, texel_dirs, act,
                  k: int, spline_rows: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Per active texel what build_maps reads (the same for a work-group's pixels): (A, 8) int32
    - its triangle's rows of the vertex values (K past the samples), its row of spline values
    (-1: none), its vertices' texels, its own texel - and (A, 20) float32 - barycentric weights,
    0, its vertices' directions, its direction, its half vector with the view +Z (0 straight
    away from the camera), 0."""
    tv = np.asarray(texel_vertices, np.int64)[act]
    ints = np.zeros((act.size, 8), np.int32)
    ints[:, :3] = np.minimum(tv, k)
    ints[:, 3] = -1
    if spline_rows is not None:
        ints[spline_rows, 3] = np.arange(len(spline_rows))
    ints[:, 4:7] = np.asarray(vertex_texel, np.int64)[tv]
    ints[:, 7] = act
    d = np.asarray(texel_dirs, np.float64)[act]
    hv = d + np.array([0.0, 0.0, 1.0])
    hn = np.linalg.norm(hv, axis=1, keepdims=True)
    floats = np.zeros((act.size, 20), np.float32)
    floats[:, :3] = np.asarray(texel_weights)[act]
    floats[:, 4:13] = np.asarray(vertices)[tv].reshape(-1, 9)
    floats[:, 13:16] = d
    floats[:, 16:19] = np.where(hn > EPS_VALUE, hv / np.maximum(hn, EPS_VALUE), 0.0)  # as lobe()
    return ints, floats


def _maps_options(spec_exponent, adaptation: bool, use_vis: bool, use_trend: bool, use_spline: bool,
                  root25: bool) -> tuple[str, ...]:
    """The build options of ``reflectance.cl`` for one build_maps_cl call (spec_exponent checked)."""
    if not 0 <= int(spec_exponent) < 256:
        raise InputError(f"spec_exponent {spec_exponent}: a whole number in [0, 256)")
    return (f"-DSPEC_EXP={int(spec_exponent)}", f"-DADAPT={int(bool(adaptation))}", f"-DUSE_VIS={int(use_vis)}",
            f"-DUSE_TREND={int(use_trend)}", f"-DUSE_SPLINE={int(use_spline)}",
            f"-DSPLINE_ROOT25={int(root25)}")


def _read_only(ctx, a, dtype=None):
    """A read-only device buffer holding a contiguous copy of ``a`` (in ``dtype`` when given)."""
    import pyopencl as cl

    return cl.Buffer(ctx, cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR,
                     hostbuf=np.ascontiguousarray(a, dtype=dtype))


def _planar(ctx, rows: int, m: int, fill: float = 0.0):
    """An aligned (rows, m) float32 array and a buffer the device reads in place (no copy)."""
    import pyopencl as cl

    a = aligned_zeros((rows, m), np.float32)
    if fill:
        a[:] = fill
    return a, cl.Buffer(ctx, cl.mem_flags.READ_ONLY | cl.mem_flags.USE_HOST_PTR, hostbuf=a)


def _wait_mapped(queue, buf, host: np.ndarray) -> None:
    """Map ``buf`` (a host-pointer buffer over ``host``) for reading and release it: the map is
    the sync - on the CPU the device's results are already in ``host``."""
    import pyopencl as cl

    mapped, _ = cl.enqueue_map_buffer(queue, buf, cl.map_flags.READ, 0, host.shape, host.dtype)
    mapped.base.release()


def _chunk_inputs(ctx, samples: np.ndarray, normals: np.ndarray, trend, ps: slice, n: int, m: int):
    """Buffers of one chunk's planar inputs, pixels innermost (n pixels padded to m with zeros):
    the vertex values (K + 1, 3, m) (the last row zero: black lights read it), normals (3, m) and
    the trend (9, m) (1 row without one)."""
    k = samples.shape[0]
    vals, b_vals = _planar(ctx, (k + 1) * 3, m)
    vals.reshape(k + 1, 3, m)[:k, :, :n] = np.asarray(samples[:, ps], np.float32).transpose(0, 2, 1)
    norm, b_norm = _planar(ctx, 3, m)
    norm[:, :n] = np.asarray(normals[ps], np.float32).T
    tr, b_trend = _planar(ctx, 9 if trend is not None else 1, m)
    if trend is not None:
        for j, part in enumerate(trend[:3]):
            tr[3 * j:3 * j + 3, :n] = np.asarray(part[ps], np.float32).T
    return b_vals, b_norm, b_trend


@dataclass(frozen=True)
class _SplineChunks:
    """build_maps_cl's ``spline`` (None: no spline) and what its chunks share: n_q spline texels,
    k_raw samples, the codes' fixed-point weights and power-domain units (P, 3) when exact."""

    spline: tuple | None
    root25: bool
    n_q: int = 0
    k_raw: int = 0
    codes: tuple | None = None
    w_fixed: np.ndarray | None = None
    code_unit: np.ndarray | None = None

    @classmethod
    def of(cls, spline, root25: bool) -> _SplineChunks:
        """The shared part of ``spline`` (exact sums from its codes need root25)."""
        from .spline import SPLINE_GAMMA, fixed_point_weights

        if spline is None:
            return cls(None, root25)
        n_q = len(spline[1])
        k_raw = int(spline[0].shape[0])
        codes = spline[4] if len(spline) > 4 else None
        if codes is None:
            return cls(spline, root25, n_q, k_raw)
        if not root25:
            raise InputError("exact spline sums from codes need SPLINE_GAMMA = SAMPLE_GAMMA = 0.4")
        w_fixed = fixed_point_weights(spline[2])
        # the codes' power domain: x ** 0.4 = (q / 255) * scale ** 0.4 (float64: rounded once below)
        code_unit = np.power(np.asarray(codes[1], np.float64), SPLINE_GAMMA) / 255.0  # (P, 3)
        return cls(spline, root25, n_q, k_raw, codes, w_fixed, code_unit)

    def inputs(self, ctx, ps: slice, n: int, m: int):
        """Buffers of one chunk's planar spline inputs: its values (Q x 3, m) in the power domain
        (raised to 2.5 by the kernel: SPLINE_ROOT25, else here), the samples (K' + 1, 3, m), the
        blend (1, m) (1 in the padding and without a spline)."""
        from .spline import spline_power_sum, spline_root

        n_q, k_raw = self.n_q, self.k_raw
        spl, b_spl = _planar(ctx, max(n_q * 3, 1), m)
        own, b_raw = _planar(ctx, (k_raw + 1) * 3, m)
        wt, b_wt = _planar(ctx, 1, m, fill=1.0)
        if self.spline is not None:
            own.reshape(k_raw + 1, 3, m)[:k_raw, :, :n] = \
                np.asarray(self.spline[0][:, ps], np.float32).transpose(0, 2, 1)
            wt[0, :n] = self.spline[3][ps]
            # The spline in its power domain by BLAS; the kernel clips it and raises it to 2.5
            # (SPLINE_ROOT25), or it is done here for another exponent.
            if self.codes is not None:
                self._exact_sums(spl, ps, n, m)
            else:
                spline_power_sum(own[:3 * k_raw].reshape(k_raw, 3 * m), self.spline[2], out=spl.reshape(n_q, 3 * m))
            if not self.root25:
                spline_root(spl)
        return b_spl, b_raw, b_wt

    def _exact_sums(self, spl: np.ndarray, ps: slice, n: int, m: int) -> None:
        """Into ``spl`` (Q x 3, m): the chunk's spline sums made exactly from the codes, in
        blocks of EXACT_ROWS texels (bounded float64 scratch)."""
        from .spline import exact_code_sums

        n_q, k_raw = self.n_q, self.k_raw
        q = np.zeros((k_raw, 3, m), np.uint8)
        q[:, :, :n] = np.asarray(self.codes[0][:, ps]).transpose(0, 2, 1)
        unit = np.zeros((3, m), np.float64)
        unit[:, :n] = self.code_unit[ps].T
        for q0 in range(0, n_q, EXACT_ROWS):
            sums = exact_code_sums(q.reshape(k_raw, 3 * m), self.w_fixed[q0:q0 + EXACT_ROWS])
            sums *= unit.reshape(1, 3 * m)
            spl.reshape(n_q, 3 * m)[q0:q0 + EXACT_ROWS] = sums


class _MapsOut:
    """Where build_maps_cl's maps come back: ``out``, pixel-major (transposed into it on the
    device) or texel-major (copied from each chunk's (A, 3, m) host array, or written there by
    the kernel itself when ``out`` is one float32 chunk of whole work-groups: ``direct``)."""

    def __init__(self, ctx, prg, out: np.ndarray, n_act: int, chunk: int, texel_major: bool, half: bool):
        import pyopencl as cl

        mf = cl.mem_flags
        p = out.shape[2] if texel_major else out.shape[0]
        self.out, self.n_act, self.texel_major = out, n_act, texel_major
        self.t_pad = padded_texels(n_act)
        # the kernel writes the (float32, texel-major, one-chunk) result itself
        self.direct = texel_major and not half and p <= chunk and p % GROUP_PIXELS == 0
        self.host = out.reshape(-1) if self.direct else aligned_zeros((max(n_act, 1) * 3 * chunk,), np.float32)
        self.b_host = cl.Buffer(ctx, mf.READ_WRITE | mf.USE_HOST_PTR, hostbuf=self.host)
        self.b_out = None if texel_major else cl.Buffer(ctx, mf.WRITE_ONLY | mf.USE_HOST_PTR, hostbuf=out)
        self.k_pm = None if texel_major else cl.Kernel(prg, "pixel_major_f16" if half else "pixel_major_f32")

    def collect(self, queue, p0: int, n: int, m: int) -> None:
        """The chunk's maps (A, 3, m) in ``b_host`` into ``out``'s pixels [p0, p0 + n)."""
        if self.texel_major:
            _wait_mapped(queue, self.b_host, self.host)
            if not self.direct:
                a = self.n_act
                self.out[:a, :, p0:p0 + n] = self.host[:a * 3 * m].reshape(a, 3, m)[:, :, :n]
        else:  # transposed on the device (a NumPy transpose of this size is ~5x slower)
            self.k_pm(queue, (n, self.t_pad // 16, 3), None, self.b_host, np.int32(self.n_act), np.int32(m),
                      np.int32(p0), np.int32(self.t_pad), self.b_out)

    def finish(self, queue) -> None:
        """Wait for the pixel-major transposes (nothing more for texel-major maps)."""
        if self.b_out is not None:
            _wait_mapped(queue, self.b_out, self.out)


def build_maps_cl(samples: np.ndarray, normals: np.ndarray, *, vertices: np.ndarray, vertex_texel: np.ndarray,
                  texel_vertices: np.ndarray, texel_weights: np.ndarray, texel_dirs: np.ndarray,
                  active: np.ndarray, map_size: tuple[int, int], horizon: np.ndarray | None, n_az: int,
                  vis_soft: float, adaptation: bool = True, half: bool = False, trend=None,
                  spec_exponent: int, texel_major: bool = False, spline=None, progress=None) -> np.ndarray:
    """(P, 3, T_pad) reflectance maps, pixel-major (T_pad: active texels rounded up to 16, zero
    padded), or with ``texel_major`` (T_pad, 3, P): float32, or float16 with ``half``.

    samples : (K, P, 3) float32 linear sample colours. normals : (P, 3). vertices : (V, 3)
    directions (the K samples first, then black lights); vertex_texel : (V,) texel of each
    vertex (for its visibility). texel_vertices / texel_weights : (T, 3) each texel's triangle.
    texel_dirs : (T, 3). active : (T,) bool texels to compute. horizon : (P, n_az) elevations, or None
    to skip visibility. vis_soft : width (radians of elevation) of the visibility step.
    trend : None, or (offset (P, 3), coef (P, 3)[, spec (P, 3)]): each texel becomes
    ``interpolation - offset + (coef x max(n . l, 0) + spec x lobe(l)) x visibility(l)`` (the
    shading model added back; lobe: ``max(n . h, 0) ** spec_exponent`` where ``n . l > 0``, h the
    half vector of l and the view +Z, as :func:`relight.kernels.interpolation.lobe`), then clipped at 0.
    spline : None, or (raw (K', P, 3) the samples themselves, rows (Q,) indices into the active
    texels, weights (Q, K') their spline weights, blend (P,)[, codes]): at those texels each map
    becomes ``blend x map + (1 - blend) x min(spline, brightest of the triangle's samples)``,
    clipped at 0 (:func:`relight.kernels.reflectance.blend_spline`; spline values from
    :func:`relight.kernels.spline.spline_values`, by BLAS per chunk). ``codes``: None, or the
    samples' storage codes (codes (K', P, 3) uint8, scale (P, 3)) they were decoded from
    (:func:`relight.kernels.recipe.decode_samples`): then the spline's sums are made exactly from
    the codes (:func:`relight.kernels.spline.exact_code_sums`), so a pixel's maps are the same
    bits whichever pixels it is made with, on any CPU (BLAS's float32 sums round by its blocking).
    """
    import pyopencl as cl

    from .spline import SPLINE_GAMMA

    rt = get_runtime()
    ctx, queue = rt.context, rt.queue
    use_vis = horizon is not None
    root25 = SPLINE_GAMMA == 0.4  # the kernel takes the spline's root as x * x * sqrt(x)
    prg = build_program("reflectance", _maps_options(spec_exponent, adaptation, use_vis, trend is not None,
                                                     spline is not None, root25))
    k_vis, k_box, k_maps = (cl.Kernel(prg, name) for name in ("soft_visibility", "box3", "build_maps"))
    k, p = samples.shape[:2]
    act = np.flatnonzero(active).astype(np.int32)
    t_pad = padded_texels(act.size)
    out = aligned_zeros((t_pad, 3, p) if texel_major else (p, 3, t_pad), np.float16 if half else np.float32)
    if p == 0:
        return out
    tables = [_read_only(ctx, t) for t in _texel_tables(vertices, vertex_texel, texel_vertices, texel_weights,
                                                        texel_dirs, act, k, None if spline is None else spline[1])]
    b_taz = _read_only(ctx, texel_azimuths(texel_dirs, n_az), np.float32)
    wg = GROUP_PIXELS
    chunk = min(PIXEL_CHUNK, -(-p // wg) * wg)  # a whole number of work-groups
    scratch = chunk * map_size[0] * map_size[1] * 4  # bytes: a float32 per pixel and map texel
    raw, smooth = cl.Buffer(ctx, cl.mem_flags.READ_WRITE, scratch), cl.Buffer(ctx, cl.mem_flags.READ_WRITE, scratch)
    b_hz = _read_only(ctx, np.asarray(horizon, np.float32).T if use_vis else np.zeros(1), np.float32)
    splines = _SplineChunks.of(spline, root25)
    dest = _MapsOut(ctx, prg, out, act.size, chunk, texel_major, half)
    for p0 in range(0, p, chunk):
        n = min(chunk, p - p0)
        m = -(-n // wg) * wg
        ps = slice(p0, p0 + n)
        # Per chunk, planar with the pixels innermost (padded to whole work-groups, the padding
        # zero); the maps come back as (A, 3, m).
        b_vals, b_norm, b_trend = _chunk_inputs(ctx, samples, normals, trend, ps, n, m)
        b_spl, b_raw, b_wt = splines.inputs(ctx, ps, n, m)
        if use_vis:  # (the padding pixels read the next ones' horizons or are cut off: never used)
            _smoothed_visibility(queue, k_vis, k_box, b_hz, p, b_taz, map_size, vis_soft, p0, m, raw, smooth,
                                 n_valid=n)
        if act.size:
            k_maps(queue, (m // LANES, act.size), (wg // LANES, 1), b_vals, b_norm, *tables, smooth, b_trend,
                   b_spl, b_raw, b_wt, np.int32(m), dest.b_host)
        dest.collect(queue, p0, n, m)
        queue.finish()  # the chunk's host arrays are read in place until here
        if progress is not None:
            progress(n)
    dest.finish(queue)
    return out
