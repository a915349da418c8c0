"""Stage 4: geometry without a face model.

The paper fits a morphable model (3DDFA) to get normals and self-shadowing; we have none and
need none: the flash samples, with their known directions, are a photometric-stereo capture.

* Normals and albedo: per pixel, a Lambertian fit ``I = albedo * max(0, n . l)`` by least
  squares on the samples that are neither shadowed nor specular (the darkest and the brightest
  of each pixel are left out, then samples facing away from the first fit or far from it are),
  with clipped samples never used.
* Mask: the head is much nearer to the flash than the wall behind it, so the flash adds far
  more light to it relative to the room light (inverse-square law), whatever its albedo.
* Depth: the normals' gradients integrated by sparse least squares inside the mask
  (a Poisson solve), in pixels toward the camera (orthographic).
* Mesh: a height-field mesh through trimesh; or a user's mesh rasterised instead.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage, sparse
from scipy.sparse.linalg import spsolve

from relight.colour import luminance
from relight.errors import InputError
from relight.numerics import EPS, EPS_NORM, EPS_VALUE

from .raster import rasterise

#: Share of each pixel's samples left out as shadowed (darkest) and as specular (brightest).
SHADOW_SHARE = 0.35
SPECULAR_SHARE = 0.10
#: Samples whose cosine under the first fit is below this are attached shadow.
MIN_COSINE = 0.1
#: Steepest slope integrated (|dz/dx| in pixels per pixel), i.e. normals at most ~81 degrees.
MAX_SLOPE = 6.0
#: Mask: share of the face's median flash-to-room-light ratio a head pixel must reach.
MASK_RATIO = 0.5


@dataclass
class Geometry:
    """Per-pixel geometry on the reference grid.

    normal : (h, w, 3) float32 unit normals (camera space, 0 off the mask).
    albedo : (h, w, 3) float32 linear Lambertian albedo (flash units: a white surface facing
    the flash reads 1). depth : (h, w) float32 height toward the camera, pixels (0 off the mask).
    mask : (h, w) bool head pixels. fit_residual : (h, w) float32 RMS relative residual of the fit.
    """

    normal: np.ndarray
    albedo: np.ndarray
    depth: np.ndarray
    mask: np.ndarray
    fit_residual: np.ndarray


#: Values (samples x pixels) per band of :func:`head_mask`'s median (bounds its temporaries).
MASK_BAND_VALUES = 1 << 22


#: Ambient light below this (linear) is too dark to tell the flash's share of a pixel.
AMBIENT_FLOOR = 1e-4
#: Tikhonov weight keeping the normal integration's sparse system well posed (the depth's
#: constant offset is otherwise free).
INTEGRATION_RIDGE = 1e-6


def head_mask(images: np.ndarray, ambient: np.ndarray, face_box_local=None) -> np.ndarray:
    """(h, w) bool: pixels the flash lights much more, relative to the room, than the wall.

    images : (K, h, w, 3) flash-only samples; ambient : (h, w, 3) no-flash average (linear).
    face_box_local : (x, y, w, h) of the face in these coordinates (its median sets the scale
    and its component is the one kept); defaults to the central third.
    """
    k, h, w = images.shape[:3]
    # The median over the samples, a band of rows at a time: the luminance of every sample and
    # the median's own copy of it were the capture's peak memory at phone sizes.
    flash = np.empty((h, w), dtype=np.float32)
    band = max(1, MASK_BAND_VALUES // max(k * w, 1))
    for r0 in range(0, h, band):
        flash[r0:r0 + band] = np.median(luminance(images[:, r0:r0 + band]), axis=0)
    amb = luminance(ambient)
    ratio = flash / np.maximum(amb, AMBIENT_FLOOR)
    ratio = ndimage.median_filter(ratio, size=5)
    if face_box_local is None:
        face_box_local = (w // 3, h // 3, w // 3, h // 3)
    fx, fy, fw, fh = (int(v) for v in face_box_local)
    face = ratio[max(fy, 0):fy + fh, max(fx, 0):fx + fw]
    ref = float(np.median(face)) if face.size else float(np.median(ratio))
    mask = (ratio > MASK_RATIO * ref) & (amb > AMBIENT_FLOOR)
    mask = ndimage.binary_opening(mask, iterations=2)
    labels, n = ndimage.label(mask)
    if n == 0:
        raise InputError("could not separate the head from the background: the flash must light the face "
                         "much more than the wall behind it")
    cy, cx = fy + fh // 2, fx + fw // 2
    keep = labels[min(max(cy, 0), h - 1), min(max(cx, 0), w - 1)]
    if keep == 0:
        keep = int(np.argmax(ndimage.sum(mask, labels, index=np.arange(1, n + 1)))) + 1
    return ndimage.binary_fill_holes(labels == keep)


#: Pixels per chunk of the photometric-stereo solve (bounds its temporaries).
PS_CHUNK = 16384


def photometric_stereo(images: np.ndarray, dirs: np.ndarray, mask: np.ndarray,
                       clipped: np.ndarray | None = None, progress=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Robust Lambertian normals and albedo inside ``mask``.

    images : (K, h, w, 3) linear flash-only samples (flash units). dirs : (K, 3) unit light
    directions. clipped : (K, h, w) bool samples to ignore. Returns normal (h, w, 3), albedo
    (h, w, 3) and the fit's RMS relative residual (h, w), all float32, zero off the mask.
    """
    k, h, w = images.shape[:3]
    if k < 3:
        raise InputError(f"photometric stereo needs at least 3 flash samples, got {k}")
    idx_all = np.flatnonzero(mask)
    normal = np.zeros((h * w, 3), dtype=np.float32)
    alb = np.zeros((h * w, 3), dtype=np.float32)
    resid = np.zeros(h * w, dtype=np.float32)
    flat = images.reshape(k, -1, 3)
    cflat = None if clipped is None else clipped.reshape(k, -1)
    for c0 in range(0, idx_all.size, PS_CHUNK):
        idx = idx_all[c0:c0 + PS_CHUNK]
        n, albedo, rel = _ps_chunk(flat[:, idx], dirs, None if cflat is None else cflat[:, idx])
        normal[idx], alb[idx], resid[idx] = n, np.clip(albedo, 0.0, None), rel
        if progress is not None:
            progress("geometry", min(c0 + PS_CHUNK, idx_all.size), idx_all.size)
    return normal.reshape(h, w, 3), alb.reshape(h, w, 3), resid.reshape(h, w)


def _ps_chunk(col: np.ndarray, dirs: np.ndarray, clipped: np.ndarray | None):
    """Photometric stereo of the pixels in ``col`` (K, P, 3): normals, albedo, residual (P, ...)."""
    k = col.shape[0]
    lum = luminance(col).T.astype(np.float64)  # (P, K)
    valid = np.isfinite(lum)
    if clipped is not None:
        valid &= ~clipped.T
    # Per-pixel rank thresholds among the valid samples (a sort is far faster than nanpercentile).
    srt = np.sort(np.where(valid, lum, np.inf), axis=1)
    nvalid = valid.sum(axis=1)
    rows = np.arange(lum.shape[0])
    lo = srt[rows, np.clip((SHADOW_SHARE * nvalid).astype(int), 0, k - 1)][:, None]
    hi = srt[rows, np.clip(np.ceil((1 - SPECULAR_SHARE) * nvalid).astype(int) - 1, 0, k - 1)][:, None]
    val = np.where(valid, lum, 0.0)
    wgt = (valid & (val >= lo) & (val <= hi) & (val > 0)).astype(np.float64)
    L = np.asarray(dirs, dtype=np.float64)
    b = _weighted_lstsq(L, val, wgt)
    # Second round: drop samples facing away from the first fit (attached shadow, wrap light)
    # and those far above or below it (specular, cast shadow).
    n1 = b / np.maximum(np.linalg.norm(b, axis=1, keepdims=True), EPS)
    cos = n1 @ L.T
    pred = b @ L.T
    res = val - pred
    scale = np.sqrt(np.sum(wgt * res**2, axis=1, keepdims=True) / np.maximum(wgt.sum(axis=1, keepdims=True), 1))
    wgt2 = (valid & (cos > MIN_COSINE) & (np.abs(res) < 2.5 * scale + EPS_VALUE) & (val > 0)).astype(np.float64)
    few = wgt2.sum(axis=1) < 6
    wgt2[few] = wgt[few]
    b = _weighted_lstsq(L, val, wgt2)
    rho = np.linalg.norm(b, axis=1)
    n = b / np.maximum(rho, EPS)[:, None]
    bad = ~np.isfinite(n).all(axis=1) | (rho < EPS_NORM)
    n[bad] = (0.0, 0.0, 1.0)
    n[n[:, 2] < 0] *= -1.0  # a visible surface faces the camera
    cos = np.clip(n @ L.T, 0.0, None)
    wc = wgt2 * cos
    num = np.einsum("pk,kpc->pc", wc, np.nan_to_num(col).astype(np.float64), optimize=True)
    den = np.einsum("pk,pk->p", wc, cos)[:, None]
    albedo = np.where(den > EPS_NORM, num / np.maximum(den, EPS_NORM), 0.0)
    pred = rho[:, None] * cos
    rel = np.sqrt(np.sum(wgt2 * (val - pred) ** 2, axis=1) / np.maximum(wgt2.sum(axis=1), 1))
    rel /= np.maximum(rho, EPS_VALUE)
    return n, albedo, rel


def _weighted_lstsq(L: np.ndarray, val: np.ndarray, wgt: np.ndarray) -> np.ndarray:
    """Per-row weighted least squares b = argmin sum_k w_k (L_k . b - v_k)^2, rows batched."""
    # As matrix products (BLAS): a three-operand einsum runs as one naive loop, ~20x slower.
    ata = (wgt @ (L[:, :, None] * L[:, None, :]).reshape(len(L), 9)).reshape(-1, 3, 3)
    atb = (wgt * val) @ L
    ata += np.eye(3) * EPS_NORM * np.maximum(np.trace(ata, axis1=1, axis2=2), EPS)[:, None, None]
    return np.linalg.solve(ata, atb[..., None])[..., 0]


def integrate_normals(normal: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Height field (h, w) float32, pixels toward the camera, whose gradients best match ``normal``.

    Sparse least squares over the mask's neighbour pairs (a Poisson problem); the mean height
    along the mask's outline is zero.
    """
    h, w = mask.shape
    idx = -np.ones((h, w), dtype=np.int64)
    ys, xs = np.nonzero(mask)
    n = ys.size
    if n < 4:
        raise InputError("the head mask is too small to build a depth map")
    idx[ys, xs] = np.arange(n)
    nz = np.maximum(normal[..., 2], 1.0 / np.hypot(MAX_SLOPE, 1.0))
    p = np.clip(-normal[..., 0] / nz, -MAX_SLOPE, MAX_SLOPE)  # dz/dx
    q = np.clip(normal[..., 1] / nz, -MAX_SLOPE, MAX_SLOPE)   # dz/d(row): rows grow downward, +Y is up
    rows, cols, vals, rhs = [], [], [], []
    eq = 0
    for dy, dx, g in ((0, 1, p), (1, 0, q)):
        a = idx[: h - dy, : w - dx]
        b = idx[dy:, dx:]
        ok = (a >= 0) & (b >= 0)
        ga = g[: h - dy, : w - dx][ok]
        gb = g[dy:, dx:][ok]
        m = ok.sum()
        e = np.arange(eq, eq + m)
        rows += [e, e]
        cols += [b[ok], a[ok]]
        vals += [np.ones(m), -np.ones(m)]
        rhs.append(0.5 * (ga + gb))
        eq += m
    a = sparse.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(eq, n))
    bvec = np.concatenate(rhs)
    # A whisper of Tikhonov pins the free constant (and any island) without bending the shape;
    # the outline's mean height is then set to zero.
    lhs = (a.T @ a + sparse.identity(n) * INTEGRATION_RIDGE).tocsc()
    z = spsolve(lhs, a.T @ bvec)
    edge = mask & ~ndimage.binary_erosion(mask)
    z -= z[idx[edge]].mean()
    depth = np.zeros((h, w), dtype=np.float32)
    depth[ys, xs] = z
    return depth


def estimate_geometry(images, dirs, ambient, clipped=None, face_box_local=None, progress=None) -> Geometry:
    """Mask, photometric-stereo normals and albedo, and the integrated depth."""
    mask = head_mask(images, ambient, face_box_local)
    normal, albedo, resid = photometric_stereo(images, dirs, mask, clipped, progress)
    depth = integrate_normals(normal, mask)
    return Geometry(normal=normal, albedo=albedo, depth=depth, mask=mask, fit_residual=resid)


def height_field_mesh(depth: np.ndarray, mask: np.ndarray, origin=(0, 0)):
    """A trimesh mesh of the height field: vertices (column, -row, height) in frame pixels."""
    import trimesh

    h, w = mask.shape
    idx = -np.ones((h, w), dtype=np.int64)
    ys, xs = np.nonzero(mask)
    idx[ys, xs] = np.arange(ys.size)
    verts = np.stack([xs + origin[0], -(ys + origin[1]), depth[ys, xs]], axis=1).astype(np.float64)
    a, b, c, d = idx[:-1, :-1], idx[:-1, 1:], idx[1:, :-1], idx[1:, 1:]
    quad = (a >= 0) & (b >= 0) & (c >= 0) & (d >= 0)
    faces = np.concatenate([np.stack([a[quad], c[quad], b[quad]], 1), np.stack([b[quad], c[quad], d[quad]], 1)])
    return trimesh.Trimesh(vertices=verts, faces=faces, process=False)


def rasterize_mesh(mesh, shape: tuple[int, int], origin=(0, 0)) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Orthographic z-buffer of a mesh aligned to the reference camera.

    Vertices are (column, -row, height) in frame pixels, +Z toward the camera (the convention
    of :func:`height_field_mesh`). Returns depth (h, w), normal (h, w, 3) and coverage mask for
    the grid of ``shape`` whose top-left pixel is frame pixel ``origin``.
    """
    h, w = shape
    v = np.asarray(mesh.vertices, dtype=np.float64)
    f = np.asarray(mesh.faces, dtype=np.int64)
    if v.size == 0 or f.size == 0:
        raise InputError("the mesh has no faces")
    if not np.isfinite(v).all():
        raise InputError("the mesh has non-finite vertex coordinates")
    px = v[:, 0] - origin[0]
    py = -v[:, 1] - origin[1]
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    fn /= np.maximum(np.linalg.norm(fn, axis=1, keepdims=True), EPS)
    fn[fn[:, 2] < 0] *= -1
    # Fragments at the pixel centres (the one rasteriser), then a z-buffer: the nearest fragment
    # (largest z: toward the camera) of each pixel wins.
    cells, z, tri, _, _ = rasterise(np.ascontiguousarray(f.T), px, py, v[:, 2], w, h)
    zbuf = np.full(h * w, -np.inf)
    np.maximum.at(zbuf, cells, z.astype(np.float64))
    win = z >= zbuf[cells]
    nbuf = np.zeros((h * w, 3))
    nbuf[cells[win]] = fn[tri[win]]
    cover = np.isfinite(zbuf)
    depth = np.where(cover, zbuf, 0.0).reshape(h, w).astype(np.float32)
    return depth, nbuf.reshape(h, w, 3).astype(np.float32), cover.reshape(h, w)
