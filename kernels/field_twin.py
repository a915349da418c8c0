"""NumPy twins of ``field.cl``'s kernels (:mod:`relight.kernels.field_apply` runs them):
``field_rgb`` -> :func:`field_rgb_numpy`, ``field_planes`` -> :func:`field_planes_numpy`. The same
arithmetic in float32, pixel by pixel, from the same arguments (grids, sampling and boxes as
:mod:`relight.kernels.field_apply` documents them)."""

from __future__ import annotations

import numpy as np

from .field_apply import COVER, chroma_box


def sample_field_numpy(grid: np.ndarray, gx: np.ndarray, gy: np.ndarray) -> np.ndarray:
    """(..., 32) bilinear samples of ``grid`` (gh, gw, 32) at grid positions gx, gy (the grid's
    edge cells carried on beyond it), the cover replaced by the four cells' summed cover."""
    gh, gw = grid.shape[:2]
    gx = np.asarray(gx, np.float32)
    gy = np.asarray(gy, np.float32)
    x0, y0 = np.floor(gx).astype(np.int64), np.floor(gy).astype(np.int64)
    ax, ay = (gx - x0).astype(np.float32)[..., None], (gy - y0).astype(np.float32)[..., None]
    xa, xb = np.clip(x0, 0, gw - 1), np.clip(x0 + 1, 0, gw - 1)
    ya, yb = np.clip(y0, 0, gh - 1), np.clip(y0 + 1, 0, gh - 1)
    one = np.float32(1.0)
    c = [grid[ya, xa], grid[ya, xb], grid[yb, xa], grid[yb, xb]]
    w = [(one - ax) * (one - ay), ax * (one - ay), (one - ax) * ay, ax * ay]
    out = (w[0] * c[0] + w[1] * c[1] + w[2] * c[2] + w[3] * c[3]).astype(np.float32)
    out[..., COVER] = c[0][..., COVER] + c[1][..., COVER] + c[2][..., COVER] + c[3][..., COVER]
    return out


def _positions(centres: np.ndarray, factor: int, corner: float) -> np.ndarray:
    """Grid positions of frame positions ``centres`` (pixel-centre coordinates) for a field of
    ``factor`` pixels per cell cornered at ``corner``."""
    return ((np.asarray(centres, np.float64) + 0.5 - corner) / factor - 0.5).astype(np.float32)


def _ramp(v: np.ndarray, knee: np.ndarray) -> np.ndarray:
    from .compositor import KNEE_RAMP

    return np.clip((knee - v) * np.float32(1.0 / np.float32(KNEE_RAMP)) + np.float32(0.5), 0.0, 1.0).astype(np.float32)


def _code8(v: np.ndarray) -> np.ndarray:
    return np.where(v < 0, 0.0, np.where(v > 255, 255.0, v + np.float32(0.5))).astype(np.uint8)


def _map(m: np.ndarray, row: int, v0, v1, v2) -> np.ndarray:
    """Row ``row`` (0-5: the tangent's three, then the chord's) of the sampled maps at v."""
    return m[..., 4 * row] * v0 + m[..., 4 * row + 1] * v1 + m[..., 4 * row + 2] * v2 + m[..., 4 * row + 3]


def field_rgb_numpy(img: np.ndarray, box, grid: np.ndarray, factor: int, corner) -> np.ndarray:
    """Twin of ``field_rgb``: a new (H, W, 3) uint8 frame."""
    out = np.array(img, dtype=np.uint8)
    h, w = out.shape[:2]
    x0, y0, x1, y1 = max(int(box[0]), 0), max(int(box[1]), 0), min(int(box[2]), w), min(int(box[3]), h)
    if x1 <= x0 or y1 <= y0:
        return out
    shape = (y1 - y0, x1 - x0)
    m = sample_field_numpy(grid, np.broadcast_to(_positions(np.arange(x0, x1), factor, corner[0])[None, :], shape),
                           np.broadcast_to(_positions(np.arange(y0, y1), factor, corner[1])[:, None], shape))
    region = out[y0:y1, x0:x1]
    v = region.astype(np.float32)
    new = []
    for c in range(3):
        t = _map(m, c, v[..., 0], v[..., 1], v[..., 2])
        d = _map(m, 3 + c, v[..., 0], v[..., 1], v[..., 2])
        new.append(_code8(t + _ramp(v[..., c], m[..., 25 + c]) * (d - t)))
    new = np.stack(new, axis=-1)
    on = m[..., COVER] > 0
    region[on] = new[on]
    return out


def field_planes_numpy(y: np.ndarray, u: np.ndarray, v: np.ndarray, box, grid: np.ndarray, factor: int,
                       corner) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Twin of ``field_planes``: new planes."""
    yo, uo, vo = np.array(y), np.array(u), np.array(v)
    h, w = y.shape
    cy = h // u.shape[0]
    cx0, cy0, cx1, cy1 = chroma_box(box, (w, h), cy)
    if cx1 <= cx0 or cy1 <= cy0:
        return yo, uo, vo
    ci, cj = np.meshgrid(np.arange(cx0, cx1), np.arange(cy0, cy1))
    # each chroma sample's centre (frame px): its block of 2 x cy luma pixels'
    m = sample_field_numpy(grid, _positions(2.0 * ci + 0.5, factor, corner[0]),
                           _positions(cy * cj + 0.5 * (cy - 1), factor, corner[1]))
    on = m[..., COVER] > 0
    cb = u[cj, ci].astype(np.float32)
    cr = v[cj, ci].astype(np.float32)
    bt = m[..., 1] * cb + m[..., 2] * cr + m[..., 3]
    bd = m[..., 13] * cb + m[..., 14] * cr + m[..., 15]
    total = np.zeros(ci.shape, np.float32)
    for k in range(2 * cy):
        px, py = 2 * ci + (k & 1), cy * cj + (k >> 1)
        lum = y[py, px].astype(np.float32)
        total += lum
        t = m[..., 0] * lum + bt
        new = _code8(t + _ramp(lum, m[..., 25]) * (m[..., 12] * lum + bd - t))
        yo[py[on], px[on]] = new[on]
    lm = total / np.float32(2 * cy)
    a = _ramp(lm, m[..., 25])
    for plane, r in ((uo, 1), (vo, 2)):
        t = _map(m, r, lm, cb, cr)
        plane[cj[on], ci[on]] = _code8(t + a * (_map(m, 3 + r, lm, cb, cr) - t))[on]
    return yo, uo, vo
