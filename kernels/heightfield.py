"""Height fields on the OpenCL device: horizon tables, with NumPy twins of the march.

A height field is (H, W) float32 heights toward the camera in pixels, ``NO_SURFACE`` where
there is no surface (it never occludes). See ``heightfield.h`` for the march and the horizon
slope: the kernels and the twins here take exactly the same samples.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import maximum_filter

from relight.numerics import EPS_VALUE

from .runtime import build_program, get_runtime

#: Tile size of the empty-space-skipping maxima (must match TILE in heightfield.h).
TILE = 8
#: Height of pixels without surface (never occludes); matches NO_SURFACE in heightfield.h.
NO_SURFACE = -1.0e30
#: Pixels per horizon-table launch (progress is reported per launch).
HORIZON_CHUNK = 8192
#: Image-plane directions of the horizon table a capture computes for visibility.
HORIZON_DIRS = 64


@dataclass(frozen=True)
class MarchSettings:
    """Shadow-ray marching in image-plane pixels: samples at t = start, then
    t += max(step, growth * t) (finer near the pixel, coarser far away); a sample occludes
    when the surface is more than ``bias`` pixels above the ray."""

    start: float = 1.0
    step: float = 1.0
    growth: float = 0.03
    bias: float = 0.1


def tile_maxima(height: np.ndarray) -> np.ndarray:
    """(ceil(H/TILE), ceil(W/TILE)) max height over each tile, its 1-pixel rim and the 8 tiles around it."""
    h, w = height.shape
    grown = maximum_filter(height, size=3, mode="constant", cval=NO_SURFACE)
    th, tw = -(-h // TILE), -(-w // TILE)
    padded = np.full((th * TILE, tw * TILE), NO_SURFACE, dtype=np.float32)
    padded[:h, :w] = grown
    tiles = padded.reshape(th, TILE, tw, TILE).max(axis=(1, 3))
    return maximum_filter(tiles, size=3, mode="constant", cval=NO_SURFACE).astype(np.float32)


def _sample_height(height: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    h, w = height.shape
    inside = (x >= 0) & (y >= 0) & (x <= w - 1) & (y <= h - 1)
    xc = np.clip(x, 0, w - 1)
    yc = np.clip(y, 0, h - 1)
    x0 = np.minimum(xc.astype(np.int64), w - 2)
    y0 = np.minimum(yc.astype(np.int64), h - 2)
    fx = (xc - x0).astype(np.float32)
    fy = (yc - y0).astype(np.float32)
    a = height[y0, x0] + (height[y0, x0 + 1] - height[y0, x0]) * fx
    b = height[y0 + 1, x0] + (height[y0 + 1, x0 + 1] - height[y0 + 1, x0]) * fx
    return np.where(inside, a + (b - a) * fy, np.float32(NO_SURFACE))


def march_samples(march: MarchSettings, tend: float) -> np.ndarray:
    """The march's sample distances t (float32, as the kernel computes them)."""
    ts = []
    t = np.float32(march.start)
    step, growth = np.float32(march.step), np.float32(march.growth)
    while t < tend:
        ts.append(t)
        t = np.float32(t + max(step, np.float32(growth * t)))
    return np.array(ts, dtype=np.float32)


def visibility_numpy(height: np.ndarray, px: np.ndarray, py: np.ndarray, pz: np.ndarray,
                     light: np.ndarray, march: MarchSettings) -> np.ndarray:
    """(P,) bool: does the ray from each (px, py, pz) toward ``light`` leave the height field?

    The plain march, every sample tested (the kernel's empty-space skipping and horizon
    tables only avoid samples that cannot occlude).
    """
    h, w = height.shape
    l = np.asarray(light, dtype=np.float32)
    s = np.float32(np.sqrt(l[0] * l[0] + l[1] * l[1]))
    vis = np.ones(px.shape, dtype=bool)
    if s < EPS_VALUE:
        return vis
    dx, dy, dz = l[0] / s, -l[1] / s, l[2] / s
    active = np.ones(px.shape, dtype=bool)
    for t in march_samples(march, 2.0 * (w + h)):
        if not active.any():
            break
        idx = np.nonzero(active)[0]
        x = px[idx] + t * dx
        y = py[idx] + t * dy
        z = pz[idx] + t * dz
        out = (x < 0) | (y < 0) | (x > w - 1) | (y > h - 1)
        hit = ~out & (_sample_height(height, x, y) > z + np.float32(march.bias))
        vis[idx[hit]] = False
        active[idx[out | hit]] = False
    return vis


def horizon_numpy(height: np.ndarray, px: np.ndarray, py: np.ndarray, pz: np.ndarray,
                  direction: np.ndarray, march: MarchSettings) -> np.ndarray:
    """(P,) largest slope (h(q) - z - bias) / t along image direction (dx, dy) (twin of ``horizon``)."""
    h, w = height.shape
    dx, dy = (np.float32(v) for v in direction)
    m = np.full(px.shape, -1.0e30, dtype=np.float32)
    for t in march_samples(march, 2.0 * (w + h)):
        x = px + t * dx
        y = py + t * dy
        ok = (x >= 0) & (y >= 0) & (x <= w - 1) & (y <= h - 1)
        slope = (_sample_height(height, x, y) - pz - np.float32(march.bias)) / t
        m = np.where(ok, np.maximum(m, slope), m)
    return m


def grid_directions(n_dir: int) -> np.ndarray:
    """(n_dir, 2) unit image-plane directions (x right, y down) of a camera-axis grid's azimuths.

    Azimuth ``beta_k = 2 pi (k + 0.5) / n_dir`` around +Z, measured from +X toward +Y (up); see
    :func:`camera_grid`.
    """
    beta = 2.0 * np.pi * (np.arange(n_dir) + 0.5) / n_dir
    return np.stack([np.cos(beta), -np.sin(beta)], axis=1).astype(np.float32)


class HorizonTable:
    """Horizon slopes of one height field along ``n_dir`` image-plane directions, on the device.

    ``table`` is the device buffer (P, n_dir) float32 for kernels that read it; :meth:`read`
    copies it to the host.
    """

    def __init__(self, height: np.ndarray, pix: np.ndarray, n_dir: int, *,
                 march: MarchSettings | None = None, progress=None):
        import pyopencl as cl

        march = march or MarchSettings()
        self.rt = get_runtime()
        ctx, queue = self.rt.context, self.rt.queue
        mf = cl.mem_flags
        kernel = cl.Kernel(build_program("horizon"), "horizon")
        hgt = np.ascontiguousarray(height, dtype=np.float32)
        tiles = tile_maxima(hgt)
        self.n_pix = int(pix.size)
        self.n_dir = int(n_dir)

        def buf(a):
            return cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=np.ascontiguousarray(a))

        hbuf, tbuf = buf(hgt), buf(tiles)
        pbuf = buf(np.asarray(pix, dtype=np.int32))
        dbuf = buf(grid_directions(n_dir))
        self.table = cl.Buffer(ctx, mf.READ_WRITE, max(self.n_pix * n_dir * 4, 4))
        m = march
        for start in range(0, self.n_pix, HORIZON_CHUNK):
            count = min(HORIZON_CHUNK, self.n_pix - start)
            kernel(queue, (count,), None, hbuf, np.int32(hgt.shape[1]), np.int32(hgt.shape[0]),
                   tbuf, np.int32(tiles.shape[1]), np.int32(tiles.shape[0]), pbuf, np.int32(self.n_pix),
                   dbuf, np.int32(n_dir), np.float32(m.start), np.float32(m.step), np.float32(m.growth),
                   np.float32(m.bias), np.float32(hgt.max()), self.table, global_offset=(start,))
            queue.finish()
            if progress is not None:
                progress.update(count)

    def read(self) -> np.ndarray:
        """(P, n_dir) float32 copy of the table."""
        import pyopencl as cl

        out = np.empty((self.n_pix, self.n_dir), dtype=np.float32)
        cl.enqueue_copy(self.rt.queue, out, self.table)
        return out


def horizon_table(height: np.ndarray, pix: np.ndarray, n_dir: int, **kwargs) -> np.ndarray:
    """(P, n_dir) horizon slopes of pixels ``pix`` (flat indices) along :func:`grid_directions`."""
    return HorizonTable(height, pix, n_dir, **kwargs).read()
