"""Host wrapper and NumPy twin of ``sensor.cl``: linear scene -> noisy 8-bit sRGB frame."""

from __future__ import annotations

import numpy as np

from relight.colour import encode_lut

from .runtime import build_program, get_runtime

_SUM4_MEAN = np.float32(131070.0)
_SUM4_INV_STD = np.float32(1.0 / 37837.23)


def frame_key(seed: int, frame: int) -> int:
    """The per-frame noise key (uint32) for ``seed`` and ``frame``."""
    s = lowbias32(np.array([seed & 0xFFFFFFFF], dtype=np.uint32))
    return int(lowbias32(np.array([frame & 0xFFFFFFFF], dtype=np.uint32) ^ s)[0])


def lowbias32(x: np.ndarray) -> np.ndarray:
    """Chris Wellons' 32-bit integer hash, on uint32 arrays (wrapping arithmetic)."""
    x = np.asarray(x, dtype=np.uint32).copy()
    x ^= x >> np.uint32(16)
    x *= np.uint32(0x7FEB352D)
    x ^= x >> np.uint32(15)
    x *= np.uint32(0x846CA68B)
    x ^= x >> np.uint32(16)
    return x


def hash_normal(k: np.ndarray, key: int) -> np.ndarray:
    """Standard-normal-like deviates (float32) for element indices ``k`` (twin of the kernel's)."""
    k = np.asarray(k, dtype=np.uint32)
    key32 = np.uint32(key)
    a = lowbias32((np.uint32(2) * k) ^ key32)
    b = lowbias32((np.uint32(2) * k + np.uint32(1)) ^ key32)
    m = np.uint32(0xFFFF)
    s = ((a & m).astype(np.float32) + (a >> np.uint32(16)).astype(np.float32)
         + (b & m).astype(np.float32) + (b >> np.uint32(16)).astype(np.float32))
    return (s - _SUM4_MEAN) * _SUM4_INV_STD


def expose_numpy(scene: np.ndarray, gains: np.ndarray, read_noise: float, shot_gain: float,
                 key: int | None) -> np.ndarray:
    """NumPy twin of :meth:`SensorKernel.expose`. scene : (H, W, 3) float32 linear."""
    x = scene.astype(np.float32) * np.asarray(gains, dtype=np.float32)
    if key is not None:
        k = np.arange(x.size, dtype=np.uint32).reshape(x.shape)
        sigma = np.sqrt(np.float32(read_noise**2) + np.float32(shot_gain) * np.maximum(x, 0.0))
        x = x + sigma * hash_normal(k, key)
    lut, n = encode_lut()
    idx = np.clip(x * np.float32(n) + np.float32(0.5), 0.0, np.float32(n)).astype(np.int32)
    return lut[idx]


class SensorKernel:
    """Exposes frames of one size on the OpenCL device (buffers kept between frames)."""

    def __init__(self, shape: tuple[int, int]):
        import pyopencl as cl

        self.rt = get_runtime()
        self.shape = (int(shape[0]), int(shape[1]), 3)
        self.n = int(np.prod(self.shape))
        self._kernel = cl.Kernel(build_program("sensor"), "expose")
        lut, self.lut_n = encode_lut()
        mf = cl.mem_flags
        ctx = self.rt.context
        self._lut = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=lut)
        self._scene = cl.Buffer(ctx, mf.READ_ONLY, self.n * 4)
        self._out = cl.Buffer(ctx, mf.WRITE_ONLY, self.n)

    def expose(self, scene: np.ndarray, gains: np.ndarray, read_noise: float, shot_gain: float,
               key: int | None) -> np.ndarray:
        """(H, W, 3) float32 linear scene -> (H, W, 3) uint8 sRGB; noise when ``key`` is given."""
        import pyopencl as cl

        q = self.rt.queue
        g = np.asarray(gains, dtype=np.float32).reshape(3)
        cl.enqueue_copy(q, self._scene, np.ascontiguousarray(scene, dtype=np.float32))
        self._kernel(q, (self.n,), None, self._scene, np.int32(self.n), g[0], g[1], g[2],
                     np.float32(read_noise**2), np.float32(shot_gain), np.uint32(key or 0),
                     np.int32(key is not None), self._lut, np.int32(self.lut_n), self._out)
        out = np.empty(self.shape, dtype=np.uint8)
        cl.enqueue_copy(q, out, self._out)
        return out
