"""The one triangle rasteriser: fragments of a mesh's triangles on an integer sample grid,
vectorised by grouping triangles of equal bounding-box size. The synthetic live head renders
with it (:mod:`relight.pipeline.synth.render`) and a user's mesh becomes depth and normals with
it (:func:`relight.pipeline.geometry.rasterize_mesh`)."""

from __future__ import annotations

import numpy as np

from relight.numerics import EPS_NORM

#: Triangles per rasterisation batch times candidate samples (bounds memory).
RASTER_BATCH = 2_000_000

#: Barycentric slack (float32) that keeps samples on a shared edge in both triangles.
EDGE_EPS = 1e-5


def rasterise(corners: np.ndarray, sx: np.ndarray, sy: np.ndarray, sz: np.ndarray, gw: int, gh: int):
    """Fragments of all triangles on the integer sample grid [0, gw) x [0, gh).

    corners : (3, T) int vertex ids of each triangle's corners; sx, sy : (V,) float64 vertex
    positions in samples; sz : (V,) depth. Returns per fragment: sample index (row-major),
    depth, the triangle's index into ``corners`` and the barycentric weights of its first two
    corners. Edges
    are inclusive (a sample on an edge shared by two triangles is produced by both, never by
    neither). Triangles are grouped by bounding-box size; each is tested at every sample of
    its box (boxes larger than 4x4 samples are rounded up to squares).
    """
    ax, bx, cx = sx[corners]
    ay, by, cy = sy[corners]
    xmin = np.maximum(np.ceil(np.minimum(np.minimum(ax, bx), cx)), 0.0)
    xmax = np.minimum(np.floor(np.maximum(np.maximum(ax, bx), cx)), gw - 1.0)
    ymin = np.maximum(np.ceil(np.minimum(np.minimum(ay, by), cy)), 0.0)
    ymax = np.minimum(np.floor(np.maximum(np.maximum(ay, by), cy)), gh - 1.0)
    area = (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)
    live = (xmax >= xmin) & (ymax >= ymin) & (np.abs(area) > EPS_NORM)
    nx = (xmax - xmin).astype(np.int64) + 1
    ny = (ymax - ymin).astype(np.int64) + 1
    # Barycentric weights are affine in the sample position: l = base + A dx + B dy from the
    # bounding box's first sample (coefficients in float64, per-sample work in float32).
    inv = np.where(live, 1.0 / np.where(live, area, 1.0), 0.0)
    a0, b0 = (by - cy) * inv, (cx - bx) * inv
    a1, b1 = (cy - ay) * inv, (ax - cx) * inv
    base0 = a0 * xmin + b0 * ymin + (bx * cy - by * cx) * inv
    base1 = a1 * xmin + b1 * ymin + (cx * ay - cy * ax) * inv
    coef = np.stack([a0, b0, a1, b1, base0, base1]).astype(np.float32)
    xmin, ymin = xmin.astype(np.int32), ymin.astype(np.int32)
    # Group key: exact box size up to 4x4, else the power-of-two square that holds the box.
    small = (nx <= 4) & (ny <= 4)
    side = 2 ** np.ceil(np.log2(np.maximum(np.maximum(nx, ny), 1))).astype(np.int64)
    key = np.where(small, (nx - 1) * 4 + (ny - 1), 16 + side)
    sel = np.flatnonzero(live)
    order = sel[np.argsort(key[sel], kind="stable")]
    keys = key[order]
    # Per-triangle data in group order, so each group is a contiguous slice.
    coef, xmin, ymin = coef[:, order], xmin[order], ymin[order]
    starts = np.flatnonzero(np.r_[True, keys[1:] != keys[:-1]]) if order.size else np.zeros(0, np.int64)
    ends = np.r_[starts[1:], order.size]
    eps = np.float32(-EDGE_EPS)
    out = []
    for s0, s1 in zip(starts, ends, strict=True):
        kk = int(keys[s0])
        gx_n, gy_n = (kk // 4 + 1, kk % 4 + 1) if kk < 16 else (kk - 16, kk - 16)
        m = gx_n * gy_n
        dy, dx = np.divmod(np.arange(m, dtype=np.int32), np.int32(gx_n))
        fdx, fdy = dx.astype(np.float32), dy.astype(np.float32)
        step = max(RASTER_BATCH // m, 1)
        for c0 in range(s0, s1, step):
            c1 = min(c0 + step, s1)
            fa0, fb0, fa1, fb1, fc0, fc1 = coef[:, c0:c1, None]
            l0 = fa0 * fdx
            l0 += fc0
            l0 += fb0 * fdy
            l1 = fa1 * fdx
            l1 += fc1
            l1 += fb1 * fdy
            ok = (l0 >= eps) & (l1 >= eps) & (l0 + l1 <= 1.0 - eps)
            flat = np.flatnonzero(ok)
            r, q = np.divmod(flat, m)
            px = xmin[c0:c1][r] + dx[q]
            py = ymin[c0:c1][r] + dy[q]
            if kk >= 16:  # rounded-up boxes can reach past the grid's edge
                inb = (px < gw) & (py < gh)
                flat, r, px, py = flat[inb], r[inb], px[inb], py[inb]
            l0, l1 = l0.ravel()[flat], l1.ravel()[flat]
            ti = order[c0 + r]
            t = corners[:, ti]
            z0, z1, z2 = sz[t[0]], sz[t[1]], sz[t[2]]
            out.append((py * gw + px, z2 + l0 * (z0 - z2) + l1 * (z1 - z2), ti, l0, l1))
    if not out:
        return (np.zeros(0, np.int32), np.zeros(0, np.float32), np.zeros(0, np.int64),
                np.zeros(0, np.float32), np.zeros(0, np.float32))
    cells, depth, tri, l0, l1 = zip(*out, strict=True)
    return np.concatenate(cells), np.concatenate(depth), np.concatenate(tri), np.concatenate(l0), np.concatenate(l1)
