"""NumPy twins of ``composite.cl``'s kernels (:mod:`relight.kernels.compositor` runs them):
``build_layer`` -> :func:`build_layer_numpy`, ``warp_composite`` -> :func:`warp_composite_numpy`,
``composite_person`` -> :func:`composite_person_numpy`. The references the kernels are tested
against (tests/test_composite.py): the same arithmetic in NumPy, pixel by pixel, from the same
arguments, with the thresholds :mod:`relight.kernels.compositor` names.

Arrays as in :mod:`relight.kernels.compositor`: the reference crop's alpha (ch, cw) float32,
fill (ch, cw) int32 (-1 = none), inv_amb (ch, cw, 3) float32; frames (H, W, 3) uint8 sRGB.
"""

from __future__ import annotations

import numpy as np

from relight.colour import decode_lut8, encode_lut
from relight.numerics import EPS
from relight.sampling import bilinear

from .compositor import (
    AGREE_RAMP,
    ALPHA_FLOOR,
    CHROMA_FLOOR,
    CLIP_RAMP,
    FOREIGN_NOISE,
    FOREIGN_RAMP,
    GATE_HI,
    TRUST_DARK,
    TRUST_RATIO,
    LayerPair,
    facing_weight,
    layer_lift,
    person_sampling,
    ramp,
)
from .work_groups import OUTSIDE_HALF


def _bilinear_filled(img: np.ndarray, x: np.ndarray, y: np.ndarray, fill: np.ndarray | None = None) -> np.ndarray:
    """Bilinear samples (N, C) of img (ch, cw, C) - or of img's pixels (M, C) through ``fill`` -
    at crop positions x, y; zero outside the crop or where fill is -1 (the composite kernel's own
    read of the relit crop: float32 weights; images with replicated edges are read by
    :func:`relight.sampling.bilinear`)."""
    ch, cw = (fill.shape if fill is not None else img.shape[:2])
    flat = img.reshape(-1, img.shape[-1])
    x0 = np.floor(x)
    y0 = np.floor(y)
    ax = (x - x0).astype(np.float32)
    ay = (y - y0).astype(np.float32)
    x0 = x0.astype(np.int64)
    y0 = y0.astype(np.int64)
    acc = np.zeros((x.size, flat.shape[1]), dtype=np.float32)
    for k in range(4):
        xi, yi = x0 + (k & 1), y0 + (k >> 1)
        w = ((ax if k & 1 else 1.0 - ax) * (ay if k >> 1 else 1.0 - ay)).astype(np.float32)
        ok = (xi >= 0) & (yi >= 0) & (xi < cw) & (yi < ch)
        src = np.where(ok, yi * cw + xi, 0)
        if fill is not None:
            src = fill.ravel()[src]
            ok &= src >= 0
            src = np.where(ok, src, 0)
        acc += np.where(ok, w, 0.0)[:, None] * flat[src]
    return acc



def _nearest(img: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """(N, C) samples of img (ch, cw, C) at its nearest pixel to crop positions x, y (halves
    rounded up, as the kernel's nearest3); zero outside the crop."""
    ch, cw = img.shape[:2]
    xi = np.floor(x + np.float32(0.5)).astype(np.int64)
    yi = np.floor(y + np.float32(0.5)).astype(np.int64)
    ok = (xi >= 0) & (yi >= 0) & (xi < cw) & (yi < ch)
    return np.where(ok[:, None], img.reshape(-1, img.shape[-1])[np.where(ok, yi * cw + xi, 0)], 0.0).astype(np.float32)



def build_layer_numpy(relit: np.ndarray, fill: np.ndarray, inv_amb: np.ndarray, alpha: np.ndarray,
                      normal: np.ndarray, rotation: np.ndarray, *, mode: str, gain: float, strength: float,
                      eps: float, ratio_max: float, live: np.ndarray | None = None,
                      live_median: float = 0.0) -> LayerPair:
    """NumPy twin of ``build_layer``: the :class:`LayerPair`."""
    from relight.colour import LUMINANCE

    f = fill.ravel()
    ok = f >= 0

    def read(img):
        out = np.zeros((f.size, 3), dtype=np.float32)
        out[ok] = img.reshape(-1, 3)[f[ok]]
        return out

    rel = read(relit)
    normals = normal.reshape(-1, 3)
    facing = facing_weight(normals @ np.asarray(rotation, dtype=np.float32)[2], normals[:, 2])
    a = np.where(alpha >= ALPHA_FLOOR, alpha, 0.0).astype(np.float32).ravel() * np.float32(strength) * facing
    r = np.zeros_like(rel)
    t = np.zeros_like(rel)
    s = np.zeros(f.size, np.float32)
    expect = np.zeros((f.size, 4), np.float32)
    g, e32, rmax = np.float32(gain), np.float32(eps), np.float32(ratio_max)
    if mode == "ambient":
        r = np.clip(g * (rel + e32) * inv_amb.reshape(-1, 3), 0.0, rmax)
        s[:] = 1.0
        a = np.where(ok, a, 0.0)
    elif mode == "paste":
        t = g * rel
    else:
        e = read(live)
        t = g * rel
        r = np.clip(t / (e + e32), 0.0, rmax)
        le, lt = e @ LUMINANCE, t @ LUMINANCE
        share = le / np.maximum(np.maximum(le, lt), np.float32(EPS))
        s = ramp(share, TRUST_RATIO) * ramp(le / np.float32(max(live_median, EPS)), TRUST_DARK)
        # (every crop pixel the layer supports, as the kernel writes it: facing and strength aside)
        support = np.where(alpha >= ALPHA_FLOOR, alpha, 0.0).ravel() > 0
        expect = np.where(support[:, None], np.concatenate([e, le[:, None]], axis=1), 0.0).astype(np.float32)
        a = np.where(ok, a, 0.0)
    layer = np.concatenate([r, s[:, None], t, a[:, None]], axis=1).astype(np.float32).reshape(*fill.shape, 8)
    return LayerPair(layer, expect.reshape(*fill.shape, 4), layer_lift(mode, eps))



def warp_composite_numpy(frame: np.ndarray, box, coarse: np.ndarray, step: int, origin, layer: LayerPair, *,
                         mode: str, tau: float = 0.0) -> np.ndarray:
    """NumPy twin of ``warp_composite``: a new frame (``layer``: :func:`build_layer_numpy`'s)."""
    return composite_person_numpy(frame, box, box, coarse, step, origin, layer, mode=mode, tau=tau)



def composite_person_numpy(img: np.ndarray, box, face_box, coarse: np.ndarray, step: int, origin, layer: LayerPair,
                           *, mode: str, tau: float = 0.0, scale: float = 1.0, person: np.ndarray | None = None,
                           frame_size=None, floor: float = 0.0, offset=(0.0, 0.0), person_origin=(0, 0),
                           person_scale=None, gate: bool = False) -> np.ndarray:
    """NumPy twin of ``composite_person``: a new image. ``img`` (h, w, 3) uint8 sRGB whose pixel
    (i, j) sits at frame position ((i + 0.5) sx - 0.5, (j + 0.5) sy - 0.5), ``scale`` = sx or
    (sx, sy); ``box`` (x0, y0, x1, y1) the image's pixels worked on; ``face_box`` the face's box in
    the frame (the one ``coarse`` covers); ``person`` (gh, gw, 4) float32 (rho - 1, the person's
    share: 0-1) on a grid over the frame (None: the face alone) of ``frame_size`` (W, H), read at
    the image's positions plus ``offset`` (an image of a box of the frame: the box's corner) - or
    a box of such a grid: ``person_scale`` (sx, sy) its cells per frame px and ``person_origin``
    (x, y) its first cell in the whole grid;
    ``floor``: the person's share below which nothing is added; ``gate``: the face's composite
    held to the person's share too (its share and change scaled by the person's from ``floor`` up
    to :data:`GATE_HI`; the frame path's choice where the matte is trusted)."""
    out = np.array(img)
    bx0, by0, bx1, by1 = box
    region = out[by0:by1, bx0:bx1].reshape(-1, 3)
    _, res_all, _, _, changed = _person_terms(
        img, box, face_box, coarse, step, origin, layer, mode=mode, tau=tau, scale=scale, person=person,
        frame_size=frame_size, floor=floor, offset=offset, person_origin=person_origin, person_scale=person_scale,
        gate=gate)
    lut, n = encode_lut()
    idx = np.clip(res_all[changed] * np.float32(n) + np.float32(0.5), 0, n).astype(np.int32)
    region[changed] = lut[idx]
    out[by0:by1, bx0:bx1] = region.reshape(by1 - by0, bx1 - bx0, 3)
    return out


def person_gain_numpy(img: np.ndarray, box, face_box, coarse: np.ndarray, step: int, origin, layer: LayerPair,
                      *, mode: str, tau: float = 0.0, scale: float = 1.0, person: np.ndarray | None = None,
                      frame_size=None, floor: float = 0.0, offset=(0.0, 0.0), person_origin=(0, 0),
                      person_scale=None, gate: bool = False, gain_max: float = 6.0,
                      affine: bool = False) -> np.ndarray:
    """NumPy twin of ``person_gain``: (bh, bw, 8) float32 over ``box`` - where a pixel changes,
    ``affine``: (G, 1, B, 0) with composite_person's value = G f + B, else ((res + GAIN_EPS) /
    (f + GAIN_EPS) clamped to ``gain_max``, 1, 0, 0, 0, 0); (1, 1, 1, 0, 0, 0, 0, 0) elsewhere.
    Arguments as :func:`composite_person_numpy`'s."""
    from .compositor import GAIN_EPS

    bx0, by0, bx1, by1 = box
    f_all, res_all, gain, off, changed = _person_terms(
        img, box, face_box, coarse, step, origin, layer, mode=mode, tau=tau, scale=scale, person=person,
        frame_size=frame_size, floor=floor, offset=offset, person_origin=person_origin, person_scale=person_scale,
        gate=gate)
    out = np.zeros((f_all.shape[0], 8), np.float32)
    out[:, :3] = 1.0
    if affine:
        out[changed, :3], out[changed, 4:7] = gain[changed], off[changed]
    else:
        e = np.float32(GAIN_EPS)
        out[changed, :3] = np.clip((res_all[changed] + e) / (f_all[changed] + e), 0.0, np.float32(gain_max))
    out[changed, 3] = 1.0
    return out.reshape(by1 - by0, bx1 - bx0, 8)


def _person_terms(img, box, face_box, coarse, step, origin, layer, *, mode, tau, scale, person, frame_size, floor,
                  offset, person_origin, person_scale, gate):
    """composite_person's arithmetic over ``box``: (f, res, G, B, changed) per pixel - the pixels
    (N, 3) linear, their composited value, res = G f + B, and where it changes (N,) bool."""
    from relight.colour import LUMINANCE

    layer, expect, lift = layer
    bx0, by0, bx1, by1 = box
    fx0, fy0, fx1, fy1 = face_box
    scx, scy = (np.float32(v) for v in np.broadcast_to(np.asarray(scale, np.float64), (2,)))
    ys, xs = np.mgrid[by0:by1, bx0:bx1]
    fx = ((xs.astype(np.float32) + np.float32(0.5)) * scx - np.float32(0.5)).ravel()
    fy = ((ys.astype(np.float32) + np.float32(0.5)) * scy - np.float32(0.5)).ravel()
    region = np.asarray(img)[by0:by1, bx0:bx1].reshape(-1, 3)
    f_all = decode_lut8()[region]
    res_all = f_all.copy()
    gain_all = np.ones_like(f_all)
    off_all = np.zeros_like(f_all)
    a_all = np.zeros(region.shape[0], np.float32)
    rx, ry = fx - np.float32(fx0), fy - np.float32(fy0)
    in_box = (rx >= 0) & (ry >= 0) & (rx <= np.float32(fx1 - fx0 - 1)) & (ry <= np.float32(fy1 - fy0 - 1))
    changed = np.zeros(region.shape[0], bool)
    k = np.flatnonzero(in_box)
    if k.size:
        cx = (rx[k] + np.float32(step) + np.float32(0.5)) / np.float32(step) - np.float32(0.5)
        cy = (ry[k] + np.float32(step) + np.float32(0.5)) / np.float32(step) - np.float32(0.5)
        i0, j0 = cx.astype(np.int64), cy.astype(np.int64)  # cx, cy > 0: truncation is the floor
        ax, ay = (cx - i0).astype(np.float32), (cy - j0).astype(np.float32)
        c = [coarse[j0 + dj, i0 + di] for dj, di in ((0, 0), (0, 1), (1, 0), (1, 1))]
        inside = np.all([ci[:, 0] >= OUTSIDE_HALF for ci in c], axis=0)
        m = ((c[0] * (1 - ax)[:, None] + c[1] * ax[:, None]) * (1 - ay)[:, None]
             + (c[2] * (1 - ax)[:, None] + c[3] * ax[:, None]) * ay[:, None])
        lay = _bilinear_filled(layer, m[:, 0] - np.float32(origin[0]), m[:, 1] - np.float32(origin[1]))
        sel = inside & (lay[:, 7] > 0)
        k, lay = k[sel], lay[sel]
        mx, my = m[sel, 0] - np.float32(origin[0]), m[sel, 1] - np.float32(origin[1])
        a = lay[:, 7:8]
        f = f_all[k]
        s = lay[:, 3:4]
        kf = np.zeros_like(s)  # the share kept as something over the face (mode live)
        if mode == "live":
            e = _bilinear_filled(expect[..., 3:4], mx, my)
            ec = _nearest(expect[..., :3], mx, my)  # (E's colour is smooth: the nearest texel's)
            agree = (f @ LUMINANCE)[:, None] / np.maximum(e, np.float32(EPS))
            dark = ramp(agree, AGREE_RAMP)
            dev = np.abs(agree - 1.0)
            shrink = np.where(dev > tau, (dev - np.float32(tau)) / np.maximum(dev, np.float32(EPS)), 0.0)
            s = np.where(s > 0, s * (1.0 - ramp(f.max(axis=1, keepdims=True), CLIP_RAMP)) * dark * shrink, s)
            noise = np.float32(FOREIGN_NOISE)
            q = (f + noise) / (np.maximum(np.maximum(ec, np.float32(CHROMA_FLOOR) * e), 0.0) + noise)
            qm = q.sum(axis=1, keepdims=True) * np.float32(1.0 / 3.0)
            spread = np.abs(q - qm).max(axis=1, keepdims=True) / np.maximum(qm, np.float32(EPS))
            kf = np.maximum(ramp(spread, FOREIGN_RAMP) * (1.0 - dark) - s, 0.0)
        face = (s * (f + np.float32(lift)) + kf * f) * lay[:, 0:3] + (1.0 - s - kf) * lay[:, 4:7]
        res_all[k] = f + a * (face - f)
        gain_all[k] = 1.0 - a + a * (s + kf) * lay[:, 0:3]
        off_all[k] = a * (s * np.float32(lift) * lay[:, 0:3] + (1.0 - s - kf) * lay[:, 4:7])
        a_all[k] = a[:, 0]
        changed[k] = True
    if person is not None:
        (sx, sy), (gox, goy) = person_sampling(person, frame_size, offset, person_origin, person_scale)
        g = bilinear(person, (fx + gox + np.float32(0.5)) * sx - np.float32(0.5),
                     (fy + goy + np.float32(0.5)) * sy - np.float32(0.5)).astype(np.float32)
        if gate:
            fl = np.float32(floor)
            kk = np.clip((g[:, 3] - fl) / (np.float32(GATE_HI) - fl), 0.0, 1.0).astype(np.float32)
            kk = np.where(a_all > 0, kk, np.float32(1.0))
            res_all = f_all + kk[:, None] * (res_all - f_all)
            gain_all = 1.0 + kk[:, None] * (gain_all - 1.0)
            off_all = off_all * kk[:, None]
            a_all = a_all * kk
        wgt = np.maximum(g[:, 3], a_all) * (1.0 - a_all)
        on = wgt > np.float32(floor)
        res_all[on] += f_all[on] * wgt[on, None] * g[on, :3]
        gain_all[on] += wgt[on, None] * g[on, :3]
        changed |= on
    return f_all, res_all, gain_all.astype(np.float32), off_all.astype(np.float32), changed



