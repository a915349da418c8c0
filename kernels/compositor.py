"""Host wrapper of ``composite.cl`` and the thresholds of its rules (its NumPy twins:
:mod:`relight.kernels.composite_twin`; which work-groups it runs:
:mod:`relight.kernels.work_groups`): the relit face warped into a frame and composited (mode
``ambient``, ``paste`` or ``live``), sRGB in and out, in one pass over the face's box.

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

from .runtime import build_program, get_runtime
from .work_groups import GROUP, OUTSIDE_HALF, face_cells, work_groups

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
#: Work-group size of ``build_layer`` (one work item per face pixel).
LAYER_GROUP = 64
#: ``person_gain``: the gain a changed pixel of the small copy gives is (res + GAIN_EPS) / (f +
#: GAIN_EPS) per channel (linear; GAIN_EPS ~ a third of the darkest 8-bit code's step: a black
#: pixel's gain stays defined, and nothing black is multiplied into noise).
GAIN_EPS = 1e-4
#: ``field_cells``: the code maps' slope is bounded by this (a cell's colour near black under a
#: large gain: its codes' noise would be multiplied without end).
SLOPE_MAX = 16.0
#: ``field_cells``' chord: a pixel more than KNEE_GAP codes darker than its cell's colour takes
#: the line through black and the tangent there, not the tangent - what is much darker than its
#: cell (glasses' rims, pupils) keeps its darkness in proportion instead of being lifted with the
#: cell, while a shadowed cell's own noise and texture (within the gap of its colour) stay on the
#: tangent, where the change fills the shadow; a cell darker than the gap has no chord.
KNEE_GAP = 24.0
#: ... blended from the tangent to the chord over this many codes about the knee (a hard switch
#: flips pixel by pixel with the sensor's noise: a rim drawn in dots).
KNEE_RAMP = 8.0
#: Steps of the float encode table (linear 0-1 -> sRGB code, 0-255, unrounded) the code maps are
#: read from: interpolated, within 0.003 code of the curve (its steepest bend, at 0.004 linear).
ENCODE_STEPS = 4096


def decode_slope_table() -> np.ndarray:
    """(256,) float32: the sRGB decode curve's slope at each 8-bit code (linear light per code)."""
    x = np.arange(256, dtype=np.float64) / 255.0
    slope = np.where(x <= 0.04045, 1.0 / 12.92, (2.4 / 1.055) * ((x + 0.055) / 1.055) ** 1.4) / 255.0
    return slope.astype(np.float32)


def encode_table() -> np.ndarray:
    """(ENCODE_STEPS + 1,) float32: the sRGB code (0-255, unrounded) of linear i / ENCODE_STEPS."""
    from relight.colour import linear_to_srgb

    return (255.0 * linear_to_srgb(np.arange(ENCODE_STEPS + 1, dtype=np.float64) / ENCODE_STEPS)).astype(np.float32)


def ramp(v, lo_hi) -> np.ndarray:
    """(float32) 0 at ``lo_hi[0]`` and below, 1 at ``lo_hi[1]`` and above, linear between: the
    kernel's ramps (composite.cl's ``ramp``)."""
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
    return ramp(z, FACING)


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
              "GATE_HI": GATE_HI, "OUTSIDE_HALF": OUTSIDE_HALF, "GAIN_EPS": GAIN_EPS, "SLOPE_MAX": SLOPE_MAX,
              "KNEE_GAP": KNEE_GAP}
    floats = tuple(f"-D{k}={float(np.float32(v)):.9e}f" for k, v in values.items())  # (always a C float literal)
    return floats + tuple(f"-DMODE_{name.upper()}={code:d}" for name, code in LAYER_MODES.items())


def program_options() -> tuple[str, ...]:
    """The options ``composite.cl`` is built with: denormals flushed (a feathered mask's Gaussian
    tails reach them: each costs a microcode assist) and :func:`kernel_defines`."""
    return ("-cl-denorms-are-zero", *kernel_defines())


def person_sampling(person: np.ndarray, frame_size, offset, origin, scale):
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
        self._k_gain = cl.Kernel(prg, "person_gain")
        self._k_cells = cl.Kernel(prg, "field_cells")
        self._gain, self._gain_cap = None, 0
        self._maps, self._maps_cap = None, 0
        self._dslope = cl.Buffer(rt.context, cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR,
                                 hostbuf=decode_slope_table())
        self._encf = cl.Buffer(rt.context, cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR,
                               hostbuf=encode_table())
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
        img = np.ascontiguousarray(img, dtype=np.uint8)
        bx0, by0, bx1, by1 = (int(v) for v in box)
        bw, bh = bx1 - bx0, by1 - by0
        if bw <= 0 or bh <= 0:
            return img.copy()
        args, groups, size = self._person_args(img, (bx0, by0, bx1, by1), face_box, coarse, step, scale, person,
                                               frame_size, floor, offset, person_origin, person_scale, gate)

        def launch(buf):
            self._k_person(self.rt.queue, size, GROUP, buf, *args, groups, self._dec, self._enc,
                           np.int32(self.lut_n), np.int32(LAYER_MODES[mode]), np.float32(tau),
                           np.float32(self._lift))

        return self._rows_through(img, (bx0, by0, bx1, by1), launch)

    def person_gain(self, img: np.ndarray, box, face_box, coarse: np.ndarray, step: int, *, mode: str,
                    tau: float = 0.0, scale: float = 1.0, person: np.ndarray | None = None, frame_size=None,
                    floor: float = 0.0, offset=(0.0, 0.0), person_origin=(0, 0), person_scale=None,
                    gate: bool = False, gain_max: float = 6.0, affine: bool = False,
                    code_maps=None) -> np.ndarray:
        """(bh, bw, 8) float32 over ``box`` of ``img``: :meth:`composite_person`'s change of each
        pixel (the ``person_gain`` kernel) - ``affine``: (G, 1, B, 0) with its value G f + B (linear,
        per channel), else ((res + GAIN_EPS) / (f + GAIN_EPS) clamped to ``gain_max``, 1, 0, 0, 0, 0);
        (1, 1, 1, 0, 0, 0, 0, 0) where it does not change. ``code_maps`` ((3, 4) to_rgb, (3, 4)
        to_ycc: a decoded frame's code maps; (None, None): an RGB frame's): instead (bh, bw, 32), the
        affine split as maps of the frame's codes (the ``field_cells`` kernel; its twin
        :func:`relight.engine.field.code_grid`). Other arguments as :meth:`composite_person`'s."""
        import pyopencl as cl

        img = np.ascontiguousarray(img, dtype=np.uint8)
        bx0, by0, bx1, by1 = (int(v) for v in box)
        bw, bh = bx1 - bx0, by1 - by0
        out = np.empty((max(bh, 0), max(bw, 0), 8 if code_maps is None else 32), np.float32)
        if bw <= 0 or bh <= 0:
            return out
        affine = affine or code_maps is not None
        args, groups, size = self._person_args(img, (bx0, by0, bx1, by1), face_box, coarse, step, scale, person,
                                               frame_size, floor, offset, person_origin, person_scale, gate)
        q = self.rt.queue
        buf = self._image_buf(img.shape)
        row = img.shape[1] * img.shape[2]
        cl.enqueue_copy(q, buf, img[by0:by1], dst_offset=by0 * row, is_blocking=False)
        gbuf = self._gain_buf(out.nbytes)
        self._k_gain(q, size, GROUP, buf, *args, groups, self._dec, np.int32(LAYER_MODES[mode]), np.float32(tau),
                     np.float32(self._lift), np.float32(gain_max), np.int32(bool(affine)), gbuf)
        if code_maps is not None:
            to_rgb, to_ycc = (np.hstack([np.eye(3), np.zeros((3, 1))]) if m is None else np.asarray(m)
                              for m in code_maps)
            mbuf = self._maps_buf(out.nbytes)
            m_rgb, m_ycc = np.zeros(16, np.float32), np.zeros(16, np.float32)
            m_rgb[:12], m_ycc[:12] = np.asarray(to_rgb, np.float32).ravel(), np.asarray(to_ycc, np.float32).ravel()
            self._k_cells(q, size, GROUP, buf, np.int32(img.shape[1]), np.int32(bx0), np.int32(by0), np.int32(bw),
                          np.int32(bh), gbuf, self._dec, self._dslope, self._encf, np.int32(ENCODE_STEPS),
                          m_rgb.view(cl.cltypes.float16)[0], m_ycc.view(cl.cltypes.float16)[0], mbuf)
            gbuf = mbuf
        cl.enqueue_copy(q, out, gbuf, is_blocking=True)
        return out

    def _maps_buf(self, nbytes: int):
        import pyopencl as cl

        if nbytes > self._maps_cap:
            self._maps_cap = max(nbytes, 2 * self._maps_cap)
            self._maps = cl.Buffer(self.rt.context, cl.mem_flags.READ_WRITE, self._maps_cap)
        return self._maps

    def _gain_buf(self, nbytes: int):
        import pyopencl as cl

        if nbytes > self._gain_cap:
            self._gain_cap = max(nbytes, 2 * self._gain_cap)
            self._gain = cl.Buffer(self.rt.context, cl.mem_flags.READ_WRITE, self._gain_cap)
        return self._gain

    def _person_args(self, img, box, face_box, coarse, step, scale, person, frame_size, floor, offset,
                     person_origin, person_scale, gate):
        """The arguments composite_person and person_gain share (image width to the gate), their
        work-groups' buffer and the launch size."""
        import pyopencl as cl

        coarse = self._coarse(coarse)
        bx0, by0, bx1, by1 = box
        bw, bh = bx1 - bx0, by1 - by0
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
            (sx, sy), (gox, goy) = person_sampling(person, frame_size, offset, person_origin, person_scale)
        groups = self._groups(box, (scx, scy), (fx0, fy0, fx1, fy1), coarse, step, person,
                              ((sx, sy), (gox, goy)), floor, bool(gate) and gw > 0)
        gx, gy = GROUP
        args = (np.int32(img.shape[1]), np.int32(bx0), np.int32(by0), np.int32(bw), np.int32(bh), np.float32(scx),
                np.float32(scy), np.int32(fx0), np.int32(fy0), np.int32(fx1 - fx0), np.int32(fy1 - fy0),
                self._coarse_buf, np.int32(coarse.shape[1]), np.int32(step), np.float32(self.origin[0]),
                np.float32(self.origin[1]), self._layer, np.int32(self.cw), np.int32(self.ch), self._expect,
                self._expect_rgb, grid_buf, np.int32(gw), np.int32(gh), np.float32(sx), np.float32(sy),
                np.float32(gox), np.float32(goy), np.float32(floor), np.int32(bool(gate) and gw > 0))
        return args, groups, (-(-bw // gx) * gx, -(-bh // gy) * gy)
