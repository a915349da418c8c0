"""Host wrapper and NumPy twin of ``composite.cl``: the relit face warped into a frame and
composited (mode ``ambient``, ``paste`` or ``live``), sRGB in and out, in one pass over the face's box.

Three kernels: ``build_layer`` makes the crop's float8 layer (lighting ratio r, live trust s,
the bundle's prediction T, alpha), ``warp_composite`` samples it once per frame pixel and
composites ``face = (s (f + lift) + k f) r + (1 - s - k) T``, ``out = f + a (face - f)`` (see the
.cl file for each mode; ``lift`` is mode live's ratio regulariser and ``k`` its share kept as
something over the face - glasses' rims - both 0 in the others); ``composite_person``
does the same and adds the light's change over the rest of the person, ``f max(m, a) (1 - a)
(rho - 1)``, over the face's box and the person's - on the frame or on a smaller copy of it
(region person: :mod:`relight.engine.head_light`).
Arrays (reference crop of ch x cw pixels whose top-left is reference pixel ``origin``):
alpha (ch, cw) float32 feathered mask; fill (ch, cw) int32 index into the relit frame's pixels
(-1 = none); inv_amb (ch, cw, 3) float32 = 1 / (reference ambient + eps); relit, live: the
Relighter's (H_ref, W_ref, 3) float32 linear frames (the target light; the live light).
``coarse``: (gh, gw, 2) float32 from :func:`relight.engine.warp.coarse_map`. Frames: (H, W, 3)
uint8 sRGB.
"""

from __future__ import annotations

from typing import NamedTuple

import cv2
import numpy as np

from relight.colour import decode_lut8, encode_lut
from relight.errors import InputError
from relight.numerics import EPS

from .runtime import build_program, get_runtime

#: Reference positions below this mark grid points outside the warp (see warp.OUTSIDE).
OUTSIDE_HALF = -5.0e3
#: A turned normal's camera-facing component: the face fades out from the second value down
#: to the first (the kernel's FACING_HI, FACING_LO) - counted from where the reference saw the
#: surface (:func:`facing_weight`).
FACING = (0.15, 0.45)
#: Feathered-mask values below this are zero (no work, no denormals).
ALPHA_FLOOR = 1e-4
#: The kernel's modes (composite.cl MODE_*).
LAYER_MODES = {"ambient": 0, "paste": 1, "live": 2}
#: Mode live: the live pixel's trust falls from 1 to 0 as lum(live) / max(lum(live), lum(target))
#: goes from the second value down to the first (Q_HI, Q_LO), and as lum(live) over the face's
#: median goes from the second down to the first (D_HI, D_LO); and as the frame's pixel clips
#: (largest channel, linear, from the first value up to the second: CLIP_LO, CLIP_HI).
TRUST_RATIO = (0.25, 0.5)
TRUST_DARK = (0.02, 0.08)
CLIP_RAMP = (0.90, 0.99)
#: ... and as the frame's pixel is darker than the live light predicts (lum f / lum E from the
#: second value down to the first: AGREE_HI, AGREE_LO).
AGREE_RAMP = (0.30, 0.60)
#: ... unless the pixel is of another colour than the face the live light predicts there: the
#: spread of f / E over the three channels (the largest distance from their mean, relative to
#: it) from the first value up to the second keeps the pixel - taking the ratio as it is, f r -
#: as far as the darkness took its trust (FOREIGN_LO, FOREIGN_HI; then whatever the layer's own
#: trust was: not the face, so not the face's prediction). A shadow cast by a light of one colour
#: scales the three channels alike (spread 0); glasses' rims, a strand of hair or a dark object
#: over the face change the colour as well (black rims on skin: ~0.7). Only where the pixel is
#: darker than predicted: where the live light leaves the face black, black has no colour to
#: tell by, and a pixel's noise would be kept and multiplied (measured on the real faces when the
#: rule acted everywhere: 0.1-0.2 dB lost on four of ten). Each channel of E counts at least
#: CHROMA_FLOOR of lum E (a light with next to no blue leaves no blue to divide by).
FOREIGN_RAMP = (0.35, 0.60)
CHROMA_FLOOR = 0.05
#: ... the ratios taken with this added to f and E (linear: 3 codes of 8-bit sRGB above black,
#: about a camera's noise there): near black the colour is noise and nothing is kept for it.
FOREIGN_NOISE = 9.1e-4
#: composite_person with ``gate``: the person's share (the grid's 4th channel) at and above which
#: the face's composite is whole (the kernel's GATE_HI; it fades to nothing at the floor) - the
#: share of the solid matte (0.5): relight.engine.head_light.person_share(0.5).
GATE_HI = 0.8
#: The composite kernels' work-group (x, y): what nothing changes in is skipped per group (:func:`work_groups`).
GROUP = (16, 4)
#: Work-group size of ``build_layer`` (one work item per face pixel).
LAYER_GROUP = 64


def _bilinear(img: np.ndarray, x: np.ndarray, y: np.ndarray, fill: np.ndarray | None = None) -> np.ndarray:
    """Bilinear samples (N, C) of img (ch, cw, C) - or of img's pixels (M, C) through ``fill`` -
    at crop positions x, y; zero outside the crop or where fill is -1."""
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


def _ramp(v, lo_hi) -> np.ndarray:
    lo, hi = (np.float32(x) for x in lo_hi)
    return np.clip((v - lo) / (hi - lo), 0.0, 1.0).astype(np.float32)


def facing_weight(turned_z, reference_z) -> np.ndarray:
    """The share of the face composited where the head's rotation turns the surface away (0-1,
    float32): a turned normal's camera-facing component ``turned_z`` fades it out over
    :data:`FACING`, lifted by how far below the ramp's top the reference's own ``reference_z``
    was - a surface the capture saw at a grazing angle is placed as well as the reference holds
    it (weight 1 unturned) and fades only as the rotation turns it further. (A ramp on the
    turned normal alone dimmed the sides of every face at rest: a real face's cheeks and jaw
    sit at 0.2-0.45 in the photos' own view, 10-25 % of the face, and there the output was the
    live frame blended in, not the relit face.)"""
    z = np.asarray(turned_z, np.float32) + np.maximum(np.float32(FACING[1]) - np.asarray(reference_z, np.float32),
                                                        np.float32(0.0))
    return _ramp(z, FACING)


class LayerPair(NamedTuple):
    """What :func:`build_layer_numpy` makes (the device's layer and expect buffers - lum E and E
    apart there, the one read bilinearly, the other at the nearest texel - and the lift
    :class:`Compositor` keeps with them): ``layer`` (ch, cw, 8) float32 (r rgb, s, T rgb, alpha),
    ``expect`` (ch, cw, 4) float32 (E, lum E), the live light's prediction (zero but in mode live), and
    ``lift`` (:func:`layer_lift`) the composite adds to the live pixel."""

    layer: np.ndarray
    expect: np.ndarray
    lift: float


def layer_lift(mode: str, eps: float) -> float:
    """The composite's ``lift`` for a layer built in ``mode`` with regulariser ``eps``: mode live's
    ratio (T / (E + eps)) multiplies f + eps (exactly T where the frame is what the live light
    predicts), the other modes' nothing."""
    return float(eps) if mode == "live" else 0.0


def kernel_defines() -> tuple[str, ...]:
    """The build options that give ``composite.cl`` the rules' thresholds named here (each once),
    the outside-the-warp mark (``OUTSIDE_HALF``) and the layer modes' codes (``MODE_LIVE``, ...)."""
    values = {"FACING_LO": FACING[0], "FACING_HI": FACING[1], "Q_LO": TRUST_RATIO[0], "Q_HI": TRUST_RATIO[1],
              "D_LO": TRUST_DARK[0], "D_HI": TRUST_DARK[1], "CLIP_LO": CLIP_RAMP[0], "CLIP_HI": CLIP_RAMP[1],
              "AGREE_LO": AGREE_RAMP[0], "AGREE_HI": AGREE_RAMP[1], "FOREIGN_LO": FOREIGN_RAMP[0],
              "FOREIGN_HI": FOREIGN_RAMP[1], "CHROMA_FLOOR": CHROMA_FLOOR, "FOREIGN_NOISE": FOREIGN_NOISE,
              "GATE_HI": GATE_HI, "OUTSIDE_HALF": OUTSIDE_HALF}
    floats = tuple(f"-D{k}={float(np.float32(v)):.9e}f" for k, v in values.items())  # (always a C float literal)
    return floats + tuple(f"-DMODE_{name.upper()}={code:d}" for name, code in LAYER_MODES.items())


def program_options() -> tuple[str, ...]:
    """The options ``composite.cl`` is built with: denormals flushed (a feathered mask's Gaussian
    tails reach them: each costs a microcode assist) and :func:`kernel_defines`."""
    return ("-cl-denorms-are-zero", *kernel_defines())


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
        s = _ramp(share, TRUST_RATIO) * _ramp(le / np.float32(max(live_median, EPS)), TRUST_DARK)
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
    from relight.colour import LUMINANCE

    layer, expect, lift = layer
    out = np.array(img)
    bx0, by0, bx1, by1 = box
    bw, bh = bx1 - bx0, by1 - by0
    fx0, fy0, fx1, fy1 = face_box
    scx, scy = (np.float32(v) for v in np.broadcast_to(np.asarray(scale, np.float64), (2,)))
    ys, xs = np.mgrid[by0:by1, bx0:bx1]
    fx = ((xs.astype(np.float32) + np.float32(0.5)) * scx - np.float32(0.5)).ravel()
    fy = ((ys.astype(np.float32) + np.float32(0.5)) * scy - np.float32(0.5)).ravel()
    region = out[by0:by1, bx0:bx1].reshape(-1, 3)
    f_all = decode_lut8()[region]
    res_all = f_all.copy()
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
        lay = _bilinear(layer, m[:, 0] - np.float32(origin[0]), m[:, 1] - np.float32(origin[1]))
        sel = inside & (lay[:, 7] > 0)
        k, lay = k[sel], lay[sel]
        mx, my = m[sel, 0] - np.float32(origin[0]), m[sel, 1] - np.float32(origin[1])
        a = lay[:, 7:8]
        f = f_all[k]
        s = lay[:, 3:4]
        kf = np.zeros_like(s)  # the share kept as something over the face (mode live)
        if mode == "live":
            e = _bilinear(expect[..., 3:4], mx, my)
            ec = _nearest(expect[..., :3], mx, my)  # (E's colour is smooth: the nearest texel's)
            agree = (f @ LUMINANCE)[:, None] / np.maximum(e, np.float32(EPS))
            dark = _ramp(agree, AGREE_RAMP)
            dev = np.abs(agree - 1.0)
            shrink = np.where(dev > tau, (dev - np.float32(tau)) / np.maximum(dev, np.float32(EPS)), 0.0)
            s = np.where(s > 0, s * (1.0 - _ramp(f.max(axis=1, keepdims=True), CLIP_RAMP)) * dark * shrink, s)
            noise = np.float32(FOREIGN_NOISE)
            q = (f + noise) / (np.maximum(np.maximum(ec, np.float32(CHROMA_FLOOR) * e), 0.0) + noise)
            qm = q.sum(axis=1, keepdims=True) * np.float32(1.0 / 3.0)
            spread = np.abs(q - qm).max(axis=1, keepdims=True) / np.maximum(qm, np.float32(EPS))
            kf = np.maximum(_ramp(spread, FOREIGN_RAMP) * (1.0 - dark) - s, 0.0)
        face = (s * (f + np.float32(lift)) + kf * f) * lay[:, 0:3] + (1.0 - s - kf) * lay[:, 4:7]
        res_all[k] = f + a * (face - f)
        a_all[k] = a[:, 0]
        changed[k] = True
    if person is not None:
        (sx, sy), (gox, goy) = _person_sampling(person, frame_size, offset, person_origin, person_scale)
        g = _bilinear_replicate(person, (fx + gox + np.float32(0.5)) * sx - np.float32(0.5),
                                (fy + goy + np.float32(0.5)) * sy - np.float32(0.5))
        if gate:
            fl = np.float32(floor)
            k = np.clip((g[:, 3] - fl) / (np.float32(GATE_HI) - fl), 0.0, 1.0).astype(np.float32)
            k = np.where(a_all > 0, k, np.float32(1.0))
            res_all = f_all + k[:, None] * (res_all - f_all)
            a_all = a_all * k
        wgt = np.maximum(g[:, 3], a_all) * (1.0 - a_all)
        on = wgt > np.float32(floor)
        res_all[on] += f_all[on] * wgt[on, None] * g[on, :3]
        changed |= on
    lut, n = encode_lut()
    idx = np.clip(res_all[changed] * np.float32(n) + np.float32(0.5), 0, n).astype(np.int32)
    region[changed] = lut[idx]
    out[by0:by1, bx0:bx1] = region.reshape(bh, bw, 3)
    return out


def _person_sampling(person: np.ndarray, frame_size, offset, origin, scale):
    """((sx, sy), (gox, goy)) float32 of the kernel's person grid: its cells per frame px and the
    shift of the image's positions (``offset`` less the grid box's ``origin`` in frame px)."""
    if scale is None:
        gh, gw = person.shape[:2]
        scale = (gw / float(frame_size[0]), gh / float(frame_size[1]))
    sx, sy = (float(v) for v in scale)
    if not (sx > 0 and sy > 0):
        raise InputError(f"person grid scale {scale}: two positive numbers (cells per frame px)")
    return ((np.float32(sx), np.float32(sy)),
            (np.float32(float(offset[0]) - origin[0] / sx), np.float32(float(offset[1]) - origin[1] / sy)))


def _bilinear_replicate(grid: np.ndarray, gx: np.ndarray, gy: np.ndarray) -> np.ndarray:
    """(N, C) bilinear samples of ``grid`` (gh, gw, C) at grid positions gx, gy, edges replicated."""
    gh, gw = grid.shape[:2]
    ix, iy = np.floor(gx).astype(np.int64), np.floor(gy).astype(np.int64)
    ax, ay = (gx - ix).astype(np.float32)[:, None], (gy - iy).astype(np.float32)[:, None]
    xa, xb = np.clip(ix, 0, gw - 1), np.clip(ix + 1, 0, gw - 1)
    ya, yb = np.clip(iy, 0, gh - 1), np.clip(iy + 1, 0, gh - 1)
    return ((grid[ya, xa] * (1 - ax) + grid[ya, xb] * ax) * (1 - ay)
            + (grid[yb, xa] * (1 - ax) + grid[yb, xb] * ax) * ay).astype(np.float32)


def face_cells(coarse: np.ndarray, origin, reach_sat: np.ndarray) -> np.ndarray:
    """(gh - 1, gw - 1) bool: the cells of the coarse map (``coarse`` (gh, gw, 2) reference
    positions, ``OUTSIDE_HALF`` marking points outside the warp) where the face's layer may be
    non-zero - a cell's pixels take their reference position inside the box of its four corners
    (bilinear weights are convex), and the layer's bilinear sample reads the texels around it:
    the cell is kept where that box, grown by two texels (float32 rounding), holds a crop pixel
    the layer reaches. ``reach_sat``: (ch + 1, cw + 1) summed-area table of those pixels
    (``cv2.integral``); ``origin``: the crop's corner in the reference."""
    ch, cw = reach_sat.shape[0] - 1, reach_sat.shape[1] - 1
    x = coarse[..., 0].astype(np.float64) - origin[0]
    y = coarse[..., 1].astype(np.float64) - origin[1]
    inside = coarse[..., 0] >= OUTSIDE_HALF
    quad = np.s_[:-1, :-1], np.s_[:-1, 1:], np.s_[1:, :-1], np.s_[1:, 1:]
    ok = inside[quad[0]] & inside[quad[1]] & inside[quad[2]] & inside[quad[3]]
    x0 = np.floor(np.minimum.reduce([x[q] for q in quad])) - 2
    x1 = np.floor(np.maximum.reduce([x[q] for q in quad])) + 3
    y0 = np.floor(np.minimum.reduce([y[q] for q in quad])) - 2
    y1 = np.floor(np.maximum.reduce([y[q] for q in quad])) + 3
    ok &= (x1 >= 0) & (y1 >= 0) & (x0 < cw) & (y0 < ch)
    x0, x1 = (np.clip(np.where(ok, v, 0), 0, cw - 1).astype(np.int64) for v in (x0, x1))
    y0, y1 = (np.clip(np.where(ok, v, 0), 0, ch - 1).astype(np.int64) for v in (y0, y1))
    return ok & (_box_sums(reach_sat, y0, y1, x0, x1) > 0)


def _group_spans(lo: int, n: int, group: int, scale: float, clip, offset: float, step: float, cells: int):
    """Per work-group along one axis: (any pixel at a frame position in ``clip`` (lo, hi or None),
    first cell, last cell) - the group's pixels at frame positions X = (i + 0.5) scale - 0.5 read
    cell floor((X + offset) / step) and the next (a bilinear sample); one more each side
    (rounding), clipped to the ``cells``."""
    ng = -(-n // group)
    first = lo + np.arange(ng) * group
    last = np.minimum(first + group, lo + n) - 1
    a, b = (first + 0.5) * scale - 0.5, (last + 0.5) * scale - 0.5
    if clip is not None:
        a, b = np.maximum(a, clip[0]), np.minimum(b, clip[1])
    c0 = np.clip(np.floor((a + offset) / step) - 1, 0, max(cells - 1, 0)).astype(np.int64)
    c1 = np.clip(np.floor((b + offset) / step) + 2, 0, max(cells - 1, 0)).astype(np.int64)
    return a <= b, c0, c1


def _box_sums(sat: np.ndarray, y0, y1, x0, x1) -> np.ndarray:
    """Sums over the inclusive boxes rows y0..y1, columns x0..x1 (index arrays, broadcast) of the
    image whose summed-area table (``cv2.integral``: (h + 1, w + 1)) is ``sat``."""
    return sat[y1 + 1, x1 + 1] - sat[y0, x1 + 1] - sat[y1 + 1, x0] + sat[y0, x0]


def _any_in(flags: np.ndarray, ys, xs) -> np.ndarray:
    """(ny, nx) bool: any of ``flags`` (h, w) bool in the rectangles rows ys, columns xs (each
    (hit, first, last) per group from :func:`_group_spans`)."""
    (hy, y0, y1), (hx, x0, x1) = ys, xs
    if flags.size == 0:
        return np.zeros((hy.size, hx.size), bool)
    sat = cv2.integral(flags.astype(np.uint8))
    return (_box_sums(sat, y0[:, None], y1[:, None], x0[None, :], x1[None, :]) > 0) & hy[:, None] & hx[None, :]


def work_groups(box, scale, face_box, cells: np.ndarray | None, step: int, person: np.ndarray | None = None,
                person_sampling=None, floor: float = 0.0, gate: bool = False, group=GROUP) -> np.ndarray:
    """(ngy, ngx) uint8 flags of the composite kernels' work-groups over ``box`` (x0, y0, x1, y1
    of the image, its pixels at frame positions (i + 0.5) ``scale`` - 0.5): bit 0 - the face's
    composite may change a pixel of the group (its pixels inside ``face_box`` read the coarse
    map's ``cells``, from :func:`face_cells`); bit 1 - the person's change may (a grid cell it
    reads has a matte above ``floor``: ``person`` (gh, gw, 4), ``person_sampling`` ((sx, sy),
    (gox, goy)) as :func:`_person_sampling` gives); with ``gate`` the face's only where bit 1 is
    set (the face's composite is scaled by the matte there: nothing of it is left beyond). A group
    with neither keeps its bytes: the kernel skips it (exactly what the kernel would leave)."""
    bx0, by0, bx1, by1 = box
    flags = np.zeros((-(-(by1 - by0) // group[1]), -(-(bx1 - bx0) // group[0])), np.uint8)
    if cells is not None and face_box[2] > face_box[0] and face_box[3] > face_box[1]:
        # face_at: cell floor((fx + 0.5) / step + 0.5) of fx = X - fx0 in [0, fw - 1]
        xs = _group_spans(bx0, bx1 - bx0, group[0], scale[0], (face_box[0], face_box[2] - 1.0),
                          0.5 + 0.5 * step - face_box[0], step, cells.shape[1])
        ys = _group_spans(by0, by1 - by0, group[1], scale[1], (face_box[1], face_box[3] - 1.0),
                          0.5 + 0.5 * step - face_box[1], step, cells.shape[0])
        flags |= _any_in(cells, ys, xs).astype(np.uint8)
    if person is not None:
        (sx, sy), (gox, goy) = person_sampling
        # the grid at (X + go + 0.5) s - 0.5: cell floor(...) and the next, edges replicated
        gh, gw = person.shape[:2]
        xs = _group_spans(bx0, bx1 - bx0, group[0], scale[0], None, gox + 0.5 - 0.5 / sx, 1.0 / sx, gw)
        ys = _group_spans(by0, by1 - by0, group[1], scale[1], None, goy + 0.5 - 0.5 / sy, 1.0 / sy, gh)
        on = _any_in(person[..., 3] > floor, ys, xs)
        if gate:
            flags &= on
        flags |= on.astype(np.uint8) << 1
    return flags


class Compositor:
    """The ``warp_composite`` kernel bound to one reference crop and the Relighter's frame."""

    def __init__(self, alpha: np.ndarray, fill: np.ndarray, inv_amb: np.ndarray, normal: np.ndarray, origin,
                 relighter):
        import pyopencl as cl

        rt = get_runtime()
        self.rt = rt
        ctx = rt.context
        mf = cl.mem_flags
        prg = build_program("composite", program_options())
        self._kernel = cl.Kernel(prg, "warp_composite")
        self._k_person = cl.Kernel(prg, "composite_person")
        self._person = None  # (the person grid last sent, its buffer)
        self._k_layer = cl.Kernel(prg, "build_layer")
        self.alpha = np.ascontiguousarray(alpha, dtype=np.float32)
        # alpha below ALPHA_FLOOR counts as zero
        self.alpha = np.where(self.alpha >= ALPHA_FLOOR, self.alpha, 0.0).astype(np.float32)
        self.fill = np.ascontiguousarray(fill, dtype=np.int32)
        self.inv_amb = np.ascontiguousarray(inv_amb, dtype=np.float32)
        if not (np.isfinite(self.alpha).all() and np.isfinite(self.inv_amb).all()):
            raise InputError("compositor inputs must be finite: the bundle's alpha, fill and ambient arrays")
        self.ch, self.cw = self.alpha.shape
        self.origin = (float(origin[0]), float(origin[1]))
        self.relighter = relighter
        self._alpha = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=self.alpha)
        self._fill = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=self.fill)
        self._inv = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=self.inv_amb)
        self.normal = np.ascontiguousarray(normal, dtype=np.float32)
        if self.normal.shape != (*self.alpha.shape, 3) or not np.isfinite(self.normal).all():
            raise InputError("compositor normals must be finite, (ch, cw, 3): the bundle's normal field")
        self._normal = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=self.normal)
        self._dec = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=decode_lut8().astype(np.float32))
        lut, self.lut_n = encode_lut()
        self._enc = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=np.ascontiguousarray(lut))
        # The layer is zero except at the crop pixels with alpha > 0, the only ones rebuilt per frame.
        self.support = np.flatnonzero(self.alpha.ravel() > 0).astype(np.int32)
        self._reach = cv2.integral((self.alpha > 0).astype(np.uint8))  # face_cells' table
        self._groups_buf, self._groups_cap = None, 0
        self._support = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR,
                                  hostbuf=self.support if self.support.size else np.zeros(1, np.int32))
        self._layer = cl.Buffer(ctx, mf.READ_WRITE | mf.COPY_HOST_PTR,
                                hostbuf=np.zeros((self.alpha.size, 8), dtype=np.float32))
        self._expect = cl.Buffer(ctx, mf.READ_WRITE | mf.COPY_HOST_PTR,
                                 hostbuf=np.zeros(self.alpha.size, dtype=np.float32))
        self._expect_rgb = cl.Buffer(ctx, mf.READ_WRITE | mf.COPY_HOST_PTR,
                                     hostbuf=np.zeros((self.alpha.size, 4), dtype=np.float32))
        self._lift = 0.0  # the last layer's (mode live: its eps)
        self._bufs: dict = {}  # image shape -> device buffer
        self._coarse_buf = None
        self._coarse_cap = 0

    def _image_buf(self, shape):
        """The device buffer of images of ``shape`` (the frame's and its work-scale copy's, kept)."""
        import pyopencl as cl

        buf = self._bufs.get(shape)
        if buf is None:
            if len(self._bufs) >= 4:  # frames of another size now: the old buffers go
                self._bufs.clear()
            buf = self._bufs[shape] = cl.Buffer(self.rt.context, cl.mem_flags.READ_WRITE,
                                                int(np.prod(shape)))
        return buf

    def layer(self, *, relit, live=None, mode: str, gain: float, strength: float, eps: float, ratio_max: float,
              rotation: np.ndarray | None = None, live_median: float = 0.0) -> None:
        """Queue ``build_layer``: the face's layer for :meth:`composite` and :meth:`composite_person`
        (arguments as :meth:`run`'s)."""
        if mode not in LAYER_MODES:
            raise InputError(f"layer mode {mode!r}: use one of {', '.join(LAYER_MODES)}")
        if mode == "live" and live is None:
            raise InputError("mode live composites the face under the live light: pass its buffer as live=")
        n = self.support.size
        rz = np.eye(3)[2] if rotation is None else np.asarray(rotation, dtype=np.float64)[2]
        # the layer's ratio regulariser, which the composites add to the live pixel (mode live)
        self._lift = layer_lift(mode, eps)
        size = (max(-(-n // LAYER_GROUP), 1) * LAYER_GROUP,)
        self._k_layer(self.rt.queue, size, (LAYER_GROUP,), relit, live if mode == "live" else relit,
                      self._fill, self._inv, self._alpha, self._normal, np.float32(rz[0]), np.float32(rz[1]),
                      np.float32(rz[2]), self._support, np.int32(n), np.int32(LAYER_MODES[mode]), np.float32(gain),
                      np.float32(strength), np.float32(eps), np.float32(ratio_max), np.float32(live_median),
                      self._layer, self._expect, self._expect_rgb)

    def _coarse(self, coarse: np.ndarray):
        import pyopencl as cl

        coarse = np.ascontiguousarray(coarse, dtype=np.float32)
        if coarse.nbytes > self._coarse_cap:
            self._coarse_cap = max(coarse.nbytes, 2 * self._coarse_cap)
            self._coarse_buf = cl.Buffer(self.rt.context, cl.mem_flags.READ_ONLY, self._coarse_cap)
        cl.enqueue_copy(self.rt.queue, self._coarse_buf, coarse, is_blocking=False)
        return coarse

    def _groups(self, box, scale, face_box, coarse: np.ndarray, step: int, person=None, person_sampling=None,
                floor: float = 0.0, gate: bool = False) -> object:
        """The device buffer of :func:`work_groups` for a launch over ``box``."""
        import pyopencl as cl

        groups = work_groups(box, scale, face_box, face_cells(coarse, self.origin, self._reach), step, person,
                             person_sampling, floor, gate)
        if groups.nbytes > self._groups_cap:
            self._groups_cap = max(groups.nbytes, 2 * self._groups_cap)
            self._groups_buf = cl.Buffer(self.rt.context, cl.mem_flags.READ_ONLY, self._groups_cap)
        cl.enqueue_copy(self.rt.queue, self._groups_buf, groups, is_blocking=False)
        return self._groups_buf

    def _rows_through(self, img: np.ndarray, box, launch) -> np.ndarray:
        """``img`` (a new array) after ``launch(buf)`` ran on the device copy of its rows of ``box``:
        only those rows go in and come out, through explicit copies (a host-pointer buffer written
        by the host between kernels is not guaranteed to be seen by the device); the kernels change
        nothing outside the box."""
        import pyopencl as cl

        q = self.rt.queue
        buf = self._image_buf(img.shape)
        row = img.shape[1] * img.shape[2]
        lo, hi = min(max(int(box[1]), 0), img.shape[0]), min(max(int(box[3]), 0), img.shape[0])
        if hi > lo:
            cl.enqueue_copy(q, buf, img[lo:hi], dst_offset=lo * row, is_blocking=False)
        launch(buf)
        out = img.copy()
        if hi > lo:
            cl.enqueue_copy(q, out[lo:hi], buf, src_offset=lo * row, is_blocking=True)
        else:
            q.finish()
        return out

    def run(self, rgb: np.ndarray, box, coarse: np.ndarray, step: int, *, relit, live=None, mode: str, gain: float,
            strength: float, eps: float, ratio_max: float, rotation: np.ndarray | None = None,
            live_median: float = 0.0, tau: float = 0.0) -> np.ndarray:
        """``rgb`` with the face composited (a new array). ``relit``: the OpenCL buffer of the
        relit reference frame (:meth:`relight.kernels.relighter.Relighter.buffer`); ``live``: the
        buffer of the face under the live light (mode ``live``); mode : one of :data:`LAYER_MODES`."""
        self.layer(relit=relit, live=live, mode=mode, gain=gain, strength=strength, eps=eps, ratio_max=ratio_max,
                   rotation=rotation, live_median=live_median)
        return self.composite(rgb, box, coarse, step, mode=mode, tau=tau)

    def composite(self, rgb: np.ndarray, box, coarse: np.ndarray, step: int, *, mode: str,
                  tau: float = 0.0) -> np.ndarray:
        """``rgb`` with the face of the last :meth:`layer` composited over ``box`` (a new array)."""
        rgb = np.ascontiguousarray(rgb, dtype=np.uint8)
        coarse = self._coarse(coarse)
        bx0, by0, bx1, by1 = box
        bw, bh = bx1 - bx0, by1 - by0

        groups = self._groups(box, (1.0, 1.0), box, coarse, step)
        gx, gy = GROUP

        def launch(buf):
            self._kernel(self.rt.queue, (-(-bw // gx) * gx, -(-bh // gy) * gy), GROUP, buf, np.int32(rgb.shape[1]),
                         np.int32(bx0), np.int32(by0), np.int32(bw), np.int32(bh), self._coarse_buf,
                         np.int32(coarse.shape[1]), np.int32(step), np.float32(self.origin[0]),
                         np.float32(self.origin[1]), self._layer, np.int32(self.cw), np.int32(self.ch), self._expect,
                         self._expect_rgb, groups, self._dec, self._enc, np.int32(self.lut_n),
                         np.int32(LAYER_MODES[mode]), np.float32(tau), np.float32(self._lift))

        return self._rows_through(rgb, box, launch)

    def composite_person(self, img: np.ndarray, box, face_box, coarse: np.ndarray, step: int, *, mode: str,
                         tau: float = 0.0, scale: float = 1.0, person: np.ndarray | None = None,
                         frame_size=None, floor: float = 0.0, offset=(0.0, 0.0), person_origin=(0, 0),
                         person_scale=None, gate: bool = False) -> np.ndarray:
        """``img`` with the face of the last :meth:`layer` and the person's change of light
        composited over ``box`` (a new array): the ``composite_person`` kernel (its twin and the
        arguments: :func:`composite_person_numpy`). A read-only ``person`` grid handed again (the
        same array) is not sent to the device again."""
        import pyopencl as cl

        img = np.ascontiguousarray(img, dtype=np.uint8)
        coarse = self._coarse(coarse)
        bx0, by0, bx1, by1 = (int(v) for v in box)
        bw, bh = bx1 - bx0, by1 - by0
        if bw <= 0 or bh <= 0:
            return img.copy()
        fx0, fy0, fx1, fy1 = (int(v) for v in face_box)
        scx, scy = (float(v) for v in np.broadcast_to(np.asarray(scale, np.float64), (2,)))
        gw = gh = 0
        grid_buf = self._layer  # any buffer: gw = 0 never reads it
        sx = sy = gox = goy = 0.0
        if person is not None:
            if self._person is None or self._person[0] is not person or person.flags.writeable:
                grid = np.ascontiguousarray(person, dtype=np.float32)
                if grid.ndim != 3 or grid.shape[2] != 4 or not np.isfinite(grid).all():
                    raise InputError("composite_person: the person grid must be (gh, gw, 4) finite float32")
                buf = cl.Buffer(self.rt.context, cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR, hostbuf=grid)
                self._person = (person, buf)
            gh, gw = person.shape[:2]
            grid_buf = self._person[1]
            (sx, sy), (gox, goy) = _person_sampling(person, frame_size, offset, person_origin, person_scale)
        groups = self._groups((bx0, by0, bx1, by1), (scx, scy), (fx0, fy0, fx1, fy1), coarse, step, person,
                              ((sx, sy), (gox, goy)), floor, bool(gate) and gw > 0)
        gx, gy = GROUP

        def launch(buf):
            self._k_person(self.rt.queue, (-(-bw // gx) * gx, -(-bh // gy) * gy), GROUP, buf, np.int32(img.shape[1]),
                           np.int32(bx0), np.int32(by0), np.int32(bw), np.int32(bh), np.float32(scx), np.float32(scy),
                           np.int32(fx0), np.int32(fy0), np.int32(fx1 - fx0), np.int32(fy1 - fy0), self._coarse_buf,
                           np.int32(coarse.shape[1]), np.int32(step), np.float32(self.origin[0]),
                           np.float32(self.origin[1]), self._layer, np.int32(self.cw), np.int32(self.ch),
                           self._expect, self._expect_rgb, grid_buf, np.int32(gw), np.int32(gh), np.float32(sx),
                           np.float32(sy), np.float32(gox), np.float32(goy), np.float32(floor),
                           np.int32(bool(gate) and gw > 0), groups, self._dec, self._enc,
                           np.int32(self.lut_n), np.int32(LAYER_MODES[mode]), np.float32(tau),
                           np.float32(self._lift))

        return self._rows_through(img, (bx0, by0, bx1, by1), launch)
