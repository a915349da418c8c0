"""Host wrapper and NumPy twin of ``synth_shade.cl``: many directional lights, cast shadows.

The synthetic studio renders its ground truth with this: a head given as a height field
(pixels, +Z toward the camera) with per-pixel normals and skin parameters, lit by directional
lights whose power (radiance x solid angle, per output) is summed into several outputs at
once - every truth environment and one-light image in one pass, visibility computed once per
pixel and light.

Units: ``power`` is radiance times solid angle (for a flash, pi); an output pixel is the
reflected radiance toward the camera, so a white Lambertian pixel facing a light of power
pi reads 1.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from relight.errors import InputError
from relight.numerics import EPS_NORM

from .heightfield import (
    HorizonTable,
    MarchSettings,
    tile_maxima,
    visibility_numpy,
)
from .runtime import build_program, get_runtime

#: Most outputs one pass accumulates (MAX_OUT in the kernel).
MAX_OUT = 16
SKIN_F0 = 0.028


@dataclass(frozen=True)
class Surface:
    """A height-field surface to shade.

    height : (H, W) float32, pixels, +Z toward the camera; ``NO_SURFACE`` where empty.
    pix : (P,) int32 flat indices of the pixels to shade.
    normal : (P, 3) float32 unit normals. albedo : (P, 3) float32 linear diffuse albedo.
    specular : (P,) float32 specular scale. roughness : (P,) float32 GGX roughness (0-1].
    wrap : (P, 3) float32 per-channel wrap (0 = Lambert; larger = softer terminator).
    """

    height: np.ndarray
    pix: np.ndarray
    normal: np.ndarray
    albedo: np.ndarray
    specular: np.ndarray
    roughness: np.ndarray
    wrap: np.ndarray


def _check(surface: Surface, dirs: np.ndarray, power: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    dirs = np.asarray(dirs, dtype=np.float64).reshape(-1, 3)
    power = np.asarray(power, dtype=np.float64)
    if power.ndim == 2:
        power = power[:, None, :]
    if power.shape[0] != dirs.shape[0] or power.ndim != 3 or power.shape[2] != 3:
        raise InputError(f"power must be (L, E, 3) for {dirs.shape[0]} lights, got {power.shape}")
    if power.shape[1] > MAX_OUT:
        raise InputError(f"at most {MAX_OUT} outputs per pass, got {power.shape[1]}; split the call")
    if not (np.isfinite(dirs).all() and np.isfinite(power).all()):
        raise InputError("light directions and powers must be finite")
    norm = np.linalg.norm(dirs, axis=1, keepdims=True)
    if (norm < EPS_NORM).any():
        raise InputError("a light direction has zero length")
    return dirs / norm, power


def _view(view) -> np.ndarray:
    """The unit direction toward the camera (3,) float64: +Z by default (the studio's camera); a
    head turned by R is shaded in its own frame from ``R.T @ z``."""
    v = np.asarray(view, dtype=np.float64).reshape(-1)
    if v.shape != (3,) or not np.isfinite(v).all() or np.linalg.norm(v) < EPS_NORM:
        raise InputError(f"view must be a finite non-zero 3-vector, got {view!r}")
    return v / np.linalg.norm(v)


# --------------------------------------------------------------------------------------
# NumPy twin (reference for the tests; same maths as the kernel, float32 where it is)
# --------------------------------------------------------------------------------------

def skin_brdf_cos_numpy(n: np.ndarray, l: np.ndarray, albedo: np.ndarray, specular: np.ndarray,
                        roughness: np.ndarray, wrap: np.ndarray, view=(0.0, 0.0, 1.0)) -> np.ndarray:
    """(P, 3) f * cos for one light ``l`` (3,) seen from the unit direction ``view`` (3,), per
    pixel parameters (see :class:`Surface`)."""
    v = np.asarray(view, dtype=np.float64)
    c = n @ l
    diffuse = albedo / np.pi * np.maximum(c[:, None] + wrap, 0.0) / (1.0 + wrap)
    nv = n @ v
    hv = l + v
    hv = hv / np.linalg.norm(hv)
    nh = np.maximum(n @ hv, 0.0)
    vh = max(float(v @ hv), 0.0)
    a = roughness**2
    a2 = a * a
    nxh = np.cross(n, hv)
    d = np.sum(nxh * nxh, axis=1) + nh * nh * a2
    D = a2 / (np.pi * d * d)
    k = 0.5 * a
    ok = (c > 0) & (nv > 0) & (specular > 0)
    cs = np.where(ok, c, 1.0)
    nvs = np.where(ok, nv, 1.0)
    G = (cs / (cs * (1 - k) + k)) * (nvs / (nvs * (1 - k) + k))
    F = SKIN_F0 + (1 - SKIN_F0) * (1 - vh) ** 5
    spec = np.where(ok, specular * D * G * F / (4.0 * nvs), 0.0)
    return diffuse + spec[:, None]


def shade_lights_numpy(surface: Surface, dirs: np.ndarray, power: np.ndarray, *,
                       march: MarchSettings | None = None, shadows: bool = True, view=(0.0, 0.0, 1.0)) -> np.ndarray:
    """NumPy twin of :meth:`LightShader.shade`: (E, P, 3) float32 outputs."""
    march = march or MarchSettings()
    view = _view(view)
    dirs, power = _check(surface, dirs, power)
    hgt = surface.height.astype(np.float32)
    w = hgt.shape[1]
    pix = surface.pix.astype(np.int64)
    px = (pix % w).astype(np.float32)
    py = (pix // w).astype(np.float32)
    pz = hgt.ravel()[pix]
    n = surface.normal.astype(np.float64)
    out = np.zeros((power.shape[1], pix.size, 3), dtype=np.float64)
    wrap_max = surface.wrap.max(axis=1)
    for l, pw in zip(dirs, power, strict=True):
        lit = (n @ l + wrap_max) > 0
        if shadows and lit.any():
            idx = np.nonzero(lit)[0]
            lit[idx] = visibility_numpy(hgt, px[idx], py[idx], pz[idx], l, march)
        if not lit.any():
            continue
        f = skin_brdf_cos_numpy(n[lit], l, surface.albedo[lit], surface.specular[lit],
                                surface.roughness[lit], surface.wrap[lit], view)
        out[:, lit, :] += f[None, :, :] * pw[:, None, :]
    return out.astype(np.float32)


# --------------------------------------------------------------------------------------
# OpenCL
# --------------------------------------------------------------------------------------

class LightShader:
    """Shades one fixed :class:`Surface` under batches of lights on the OpenCL device.

    The surface's buffers are uploaded once; :meth:`shade` only moves lights in and outputs
    back. :meth:`prepare_horizons` tabulates visibility along ``n_dir`` image-plane
    directions, after which lights tagged with a direction index cost no ray march.
    """

    def __init__(self, surface: Surface, *, march: MarchSettings | None = None):
        import pyopencl as cl

        march = march or MarchSettings()
        self.rt = get_runtime()
        self.surface = surface
        self.march = march
        prg = build_program("synth_shade", (f"-DMAX_OUT={MAX_OUT}",))
        self._shade = cl.Kernel(prg, "shade_lights")
        ctx = self.rt.context
        mf = cl.mem_flags
        hgt = np.ascontiguousarray(surface.height, dtype=np.float32)
        self.h, self.w = hgt.shape
        tiles = tile_maxima(hgt)
        self.th, self.tw = tiles.shape
        self.hmax = np.float32(hgt.max())
        p = surface.pix.size
        self.n_pix = p

        def f4(a3, w=None):
            a = np.zeros((p, 4), dtype=np.float32)
            a[:, :3] = a3
            if w is not None:
                a[:, 3] = w
            return a

        def buf(a):
            return cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=np.ascontiguousarray(a))

        mat = np.zeros((p, 4), dtype=np.float32)
        mat[:, 0] = surface.roughness
        mat[:, 1:] = surface.wrap
        self._bufs = dict(
            height=buf(hgt), tiles=buf(tiles), pix=buf(surface.pix.astype(np.int32)),
            normal=buf(f4(surface.normal)), albedo=buf(f4(surface.albedo, surface.specular)),
            material=buf(mat),
        )
        self.n_dir = 0
        self._horizons = buf(np.zeros(1, dtype=np.float32))

    def prepare_horizons(self, n_dir: int, *, progress=None) -> None:
        """Tabulate horizon slopes along the ``n_dir`` directions of :func:`grid_directions`.

        progress : optional object with ``update(n_pixels)`` (a tqdm bar), called per chunk.
        """
        self._table = HorizonTable(self.surface.height, self.surface.pix, n_dir, march=self.march,
                                   progress=progress)
        self._horizons = self._table.table
        self.n_dir = n_dir

    def horizons(self) -> np.ndarray:
        """(P, n_dir) float32 copy of the horizon table (for tests and plots)."""
        return self._table.read()

    def _geometry(self) -> tuple:
        b = self._bufs
        return (b["height"], np.int32(self.w), np.int32(self.h), b["tiles"], np.int32(self.tw),
                np.int32(self.th), b["pix"], np.int32(self.n_pix))

    def shade(self, dirs: np.ndarray, power: np.ndarray, *, direction_index: np.ndarray | None = None,
              shadows: bool = True, view=(0.0, 0.0, 1.0)) -> np.ndarray:
        """(E, P, 3) float32 outputs for lights ``dirs`` (L, 3) with ``power`` (L, E, 3) or (L, 3).

        direction_index : (L,) int, the :func:`grid_directions` column each light lies along
        (its visibility is then read from the horizon table), or -1 to march the light.
        view : unit direction toward the camera in the surface's frame (default +Z).
        """
        import pyopencl as cl
        from pyopencl import cltypes

        dirs, power = _check(self.surface, dirs, power)
        v4 = np.zeros(4, dtype=np.float32)
        v4[:3] = _view(view)
        n_l, n_e = power.shape[:2]
        if n_l == 0:
            return np.zeros((n_e, self.n_pix, 3), dtype=np.float32)
        idx = np.full(n_l, -1, dtype=np.int32) if direction_index is None else \
            np.asarray(direction_index, dtype=np.int32).reshape(n_l)
        if (idx >= self.n_dir).any():
            raise InputError(f"direction index beyond the {self.n_dir} prepared horizon directions")
        ctx, queue = self.rt.context, self.rt.queue
        mf = cl.mem_flags
        l4 = np.zeros((n_l, 4), dtype=np.float32)
        l4[:, :3] = dirs
        p4 = np.zeros((n_l, n_e, 4), dtype=np.float32)
        p4[..., :3] = power
        out = np.empty((n_e, self.n_pix, 4), dtype=np.float32)
        lbuf = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=l4)
        ibuf = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=idx)
        pbuf = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=p4)
        obuf = cl.Buffer(ctx, mf.WRITE_ONLY, out.nbytes)
        b = self._bufs
        m = self.march
        self._shade(
            queue, (self.n_pix,), None, *self._geometry(),
            b["normal"], b["albedo"], b["material"],
            lbuf, np.int32(n_l), ibuf, self._horizons, np.int32(max(self.n_dir, 1)), pbuf, np.int32(n_e),
            np.float32(m.start), np.float32(m.step), np.float32(m.growth), np.float32(m.bias), self.hmax,
            np.int32(1 if shadows else 0), cltypes.make_float4(*v4), obuf,
        )
        cl.enqueue_copy(queue, out, obuf)
        return out[..., :3]
