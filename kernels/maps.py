"""Host wrapper of ``reflectance.cl``: reflectance maps for many pixels on the OpenCL device.

NumPy twins: :func:`relight.pipeline.reflectance.visibility_maps` and
:func:`relight.pipeline.reflectance.build_maps` (same arguments, same maths).
"""

from __future__ import annotations

import numpy as np

from .runtime import aligned_zeros, build_program, get_runtime

#: Pixels per launch (bounds the visibility scratch: PIXEL_CHUNK x texels floats, twice).
PIXEL_CHUNK = 8192
#: Stored texel counts are padded to a multiple of this (the relighting kernels read 16 at once).
TEXEL_ALIGN = 16


def padded_texels(n: int) -> int:
    """``n`` rounded up to a multiple of TEXEL_ALIGN (at least TEXEL_ALIGN)."""
    return max((n + TEXEL_ALIGN - 1) // TEXEL_ALIGN * TEXEL_ALIGN, TEXEL_ALIGN)


def _texel_azimuths(texel_dirs: np.ndarray, n_az: int) -> np.ndarray:
    """(T, 4) per texel: the two horizon columns around its azimuth, their blend, its elevation
    (8 for straight at the camera: always visible)."""
    s_xy = np.hypot(texel_dirs[:, 0], texel_dirs[:, 1])
    beta = np.mod(np.arctan2(texel_dirs[:, 1], texel_dirs[:, 0]), 2 * np.pi)
    pos = beta / (2 * np.pi) * n_az - 0.5
    i0 = np.floor(pos).astype(np.int64) % n_az
    return np.stack([i0, (i0 + 1) % n_az, pos - np.floor(pos),
                     np.where(s_xy < 1e-6, 8.0, np.arctan2(texel_dirs[:, 2], np.maximum(s_xy, 1e-9)))], axis=1)


def _smoothed_visibility(queue, k_vis, k_box, b_hz, n_az: int, b_taz, map_size, vis_soft: float, p0: int, n: int,
                         raw, smooth) -> None:
    """Enqueue soft_visibility then box3 for pixels [p0, p0 + n): ``smooth`` gets (n, T)."""
    w, h = map_size
    k_vis(queue, (w * h, n), None, b_hz, np.int32(n_az), b_taz, np.int32(w * h), np.float32(1.0 / vis_soft),
          np.int32(p0), np.int32(n), raw)
    k_box(queue, (w, h, n), None, raw, np.int32(w), np.int32(h), np.int32(n), smooth)


def visibility_at_cl(horizon: np.ndarray, n_az: int, map_size: tuple[int, int], texel_dirs: np.ndarray,
                     columns: np.ndarray, vis_soft: float) -> np.ndarray:
    """(P, len(columns)) float32 smoothed visibility of the given map texels for each pixel:
    ``visibility_maps(horizon, n_az, map_size).reshape(P, -1)[:, columns]`` on the device (the
    maps' own soft_visibility and box3 kernels). texel_dirs : (T, 3) the map's texel directions."""
    import pyopencl as cl

    rt = get_runtime()
    ctx, queue = rt.context, rt.queue
    mf = cl.mem_flags
    prg = build_program("reflectance", ())
    k_vis = cl.Kernel(prg, "soft_visibility")
    k_box = cl.Kernel(prg, "box3")
    p = horizon.shape[0]
    w, h = map_size
    n_tex = w * h
    cols = np.asarray(columns, dtype=np.int64)
    out = np.empty((p, cols.size), dtype=np.float32)
    if p == 0 or cols.size == 0:
        return out
    chunk = min(PIXEL_CHUNK, p)
    b_hz = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=np.ascontiguousarray(horizon, dtype=np.float32))
    b_taz = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR,
                      hostbuf=np.ascontiguousarray(_texel_azimuths(texel_dirs, n_az), dtype=np.float32))
    raw = cl.Buffer(ctx, mf.READ_WRITE, chunk * n_tex * 4)
    smooth = cl.Buffer(ctx, mf.READ_WRITE, chunk * n_tex * 4)
    host = np.empty((chunk, n_tex), dtype=np.float32)
    for p0 in range(0, p, chunk):
        n = min(chunk, p - p0)
        _smoothed_visibility(queue, k_vis, k_box, b_hz, n_az, b_taz, map_size, vis_soft, p0, n, raw, smooth)
        cl.enqueue_copy(queue, host[:n], smooth)
        out[p0:p0 + n] = host[:n][:, cols]
    return out


def build_maps_cl(samples: np.ndarray, normals: np.ndarray, *, vertices: np.ndarray, vertex_texel: np.ndarray,
                  texel_vertices: np.ndarray, texel_weights: np.ndarray, texel_dirs: np.ndarray,
                  active: np.ndarray, map_size: tuple[int, int], horizon: np.ndarray | None, n_az: int,
                  vis_soft: float, adaptation: bool = True, half: bool = False, trend=None,
                  spec_exponent: int, progress=None) -> np.ndarray:
    """(P, 3, T_pad) reflectance maps, pixel-major (T_pad: active texels rounded up to 16, zero
    padded): float32, or float16 with ``half`` (stored that way).

    samples : (K, P, 3) float32 linear sample colours. normals : (P, 3). vertices : (V, 3)
    directions (the K samples first, then black lights); vertex_texel : (V,) texel of each
    vertex (for its visibility). texel_vertices / texel_weights : (T, 3) each texel's triangle.
    texel_dirs : (T, 3). active : (T,) bool texels to compute. horizon : (P, n_az) elevations, or None
    to skip visibility. vis_soft : width (radians of elevation) of the visibility step.
    trend : None, or (offset (P, 3), coef (P, 3)[, spec (P, 3)]): each texel becomes
    ``interpolation - offset + (coef x max(n . l, 0) + spec x lobe(l)) x visibility(l)`` (the
    shading model added back; lobe: ``max(n . h, 0) ** spec_exponent`` where ``n . l > 0``, h the
    half vector of l and the view +Z, as :func:`relight.pipeline.reflectance.lobe`), then clipped at 0.
    """
    import pyopencl as cl

    rt = get_runtime()
    ctx, queue = rt.context, rt.queue
    mf = cl.mem_flags
    prg = build_program("reflectance", ("-DOUT_HALF",) if half else ())
    k_vis = cl.Kernel(prg, "soft_visibility")
    k_box = cl.Kernel(prg, "box3")
    k_maps = cl.Kernel(prg, "build_maps")
    k, p = samples.shape[:2]
    w, h = map_size
    n_tex = w * h
    act = np.flatnonzero(active).astype(np.int32)

    held = []  # host arrays the device reads in place: alive until the kernels are done

    def buf(a, dtype):
        a = np.ascontiguousarray(a, dtype=dtype)
        if a.nbytes < (1 << 20):
            return cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=a)
        held.append(a)  # large inputs (samples, horizons): no device copy on the CPU
        return cl.Buffer(ctx, mf.READ_ONLY | mf.USE_HOST_PTR, hostbuf=a)

    def f4(a):
        out = np.zeros((len(a), 4), dtype=np.float32)
        out[:, :3] = a
        return out

    def i4(a):
        out = np.zeros((len(a), 4), dtype=np.int32)
        out[:, :3] = a
        return out

    b_samples = buf(samples, np.float32)
    b_normal = buf(f4(normals), np.float32)
    b_vdir = buf(f4(vertices), np.float32)
    b_vtex = buf(vertex_texel, np.int32)
    b_tv = buf(i4(texel_vertices[act]), np.int32)
    b_tw = buf(f4(texel_weights[act]), np.float32)
    b_tdir_act = buf(f4(texel_dirs[act]), np.float32)
    b_tidx = buf(act, np.int32)
    b_taz = buf(_texel_azimuths(texel_dirs, n_az), np.float32)
    use_vis = horizon is not None
    chunk = min(PIXEL_CHUNK, p)
    raw = cl.Buffer(ctx, mf.READ_WRITE, max(chunk * n_tex * 4, 4))
    smooth = cl.Buffer(ctx, mf.READ_WRITE, max(chunk * n_tex * 4, 4))
    b_hz = buf(horizon if use_vis else np.zeros(1), np.float32)
    use_trend = trend is not None
    b_toff = buf(f4(trend[0]) if use_trend else np.zeros(4), np.float32)
    b_tcoef = buf(f4(trend[1]) if use_trend else np.zeros(4), np.float32)
    b_tspec = buf(f4(trend[2]) if use_trend and len(trend) > 2 else np.zeros((max(p, 1), 4)), np.float32)
    t_pad = padded_texels(act.size)
    # The kernel writes straight into the result (host memory used in place by PoCL on the CPU):
    # a device copy of the maps - the capture's largest array - would double its memory.
    out = aligned_zeros((max(p, 1), 3, t_pad), np.float16 if half else np.float32)[:p]
    b_out = cl.Buffer(ctx, mf.WRITE_ONLY | mf.USE_HOST_PTR, hostbuf=out) if p else None
    for p0 in range(0, p, chunk):
        n = min(chunk, p - p0)
        if use_vis:
            _smoothed_visibility(queue, k_vis, k_box, b_hz, n_az, b_taz, map_size, vis_soft, p0, n, raw, smooth)
        k_maps(queue, (n,), None, b_samples, np.int32(k), np.int32(p), b_normal, b_vdir, b_vtex, b_tv, b_tw,
               b_tdir_act, b_tidx, np.int32(act.size), smooth, np.int32(n_tex), np.int32(use_vis),
               np.int32(adaptation), b_toff, b_tcoef, b_tspec, np.int32(spec_exponent), np.int32(use_trend),
               np.int32(p0), np.int32(n),
               np.int32(t_pad), b_out)
        queue.finish()
        if progress is not None:
            progress(n)
    if b_out is not None:
        mapped, _ = cl.enqueue_map_buffer(queue, b_out, cl.map_flags.READ, 0, out.shape, out.dtype)
        mapped.base.release()  # the map is the sync: on the CPU the data are already in ``out``
    return out
