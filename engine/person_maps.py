"""The person's maps (region person): the light's change carried from the face over the rest of
the person - hair, ears, neck, shoulders - as a grid at the work scale (:class:`PersonMaps`), made
by :func:`build_person_maps` from what one frame gives (:class:`PersonInputs`,
:func:`person_inputs`; the face's own maps over the work scale: :func:`face_alpha_work`). The
ratio itself is :mod:`.head_light`'s, the person's matte :mod:`.person`'s; when the maps are made
and reused is :class:`relight.engine.frame_path.FramePath`'s.

Frames are (H, W, 3) uint8 sRGB (or a :class:`relight.video_yuv.YuvFrame`); boxes are
(x0, y0, x1, y1); the work scale is :data:`.person.WORK_ROWS` rows.
"""
from __future__ import annotations

from typing import NamedTuple

import cv2
import numpy as np

from relight.kernels.work_groups import OUTSIDE
from relight.video_yuv import downscale_area

from . import head_light
from .warp import GRID_STEP

#: Work pixels beyond the person's share the ratio is made over: the kernel's bilinear reach and a
#: few cells of the ratio's coarser grid, so its smoothing sees past the person's edge as over the
#: whole frame (measured on the truth clip against the whole frame's maps: 4 px cost 0.04 dB and
#: the seam 0.02; 12 px gave the same figures).
RATIO_REACH = 12


def union_box(a, b) -> tuple[int, int, int, int]:
    """The smallest box (x0, y0, x1, y1) holding boxes ``a`` and ``b``."""
    return min(a[0], b[0]), min(a[1], b[1]), max(a[2], b[2]), max(a[3], b[3])


class PersonMaps(NamedTuple):
    """The person's maps of a frame (region person), at the work scale (:data:`.person.WORK_ROWS`
    rows) over the box of it the person reaches: ``grid`` (h, w, 4) float32 read-only, rho - 1
    and the person's share (:func:`.head_light.person_share` of the matte); ``origin`` (x, y)
    its corner in work px; ``scale`` (sx, sy) work px per frame px; ``box`` the frame's box
    (x0, y0, x1, y1) the person reaches, None when nowhere; ``gate``: the matte is trusted around
    the face (:func:`.head_light.matte_trusted`) - the face's composite is held to it too;
    ``anchor`` (x, y) the head's place in the frame (px) when they were made (:meth:`moved`
    carries them with the head)."""

    grid: np.ndarray
    origin: tuple[float, float]
    scale: tuple[float, float]
    box: tuple[int, int, int, int] | None
    anchor: tuple[float, float]
    gate: bool = False

    def moved(self, anchor) -> PersonMaps:
        """The maps carried to the head at ``anchor`` (frame px): the grid's origin and the box
        shifted by the head's move since they were made (the hair and ears move with the head;
        the maps are remade when the scheduler says, :mod:`.schedule`; the face's own alpha is
        every frame's)."""
        dx, dy = float(anchor[0]) - self.anchor[0], float(anchor[1]) - self.anchor[1]
        if dx == 0.0 and dy == 0.0:
            return self
        box = self.box
        if box is not None:  # over both places (a box at the frame's edge keeps reaching it; the
            ix, iy = int(np.floor(dx)), int(np.floor(dy))  # grid's edges are replicated there)
            box = (min(box[0], box[0] + ix), min(box[1], box[1] + iy), max(box[2], box[2] + ix + 1),
                   max(box[3], box[3] + iy + 1))
        return self._replace(origin=(self.origin[0] + dx * self.scale[0], self.origin[1] + dy * self.scale[1]),
                             box=box, anchor=(float(anchor[0]), float(anchor[1])))


class PersonInputs(NamedTuple):
    """What :func:`build_person_maps` makes the person's maps of (see :func:`person_inputs`):
    ``small`` the frame at the work scale ((h, w, 3) uint8 sRGB) and ``composited`` the same with
    the face composited; ``face_box`` the face's box in it; ``alpha``, ``normals``, ``cover`` the
    face's alpha, turned normals and the bundle's cover over that box; ``size`` the frame's (w, h);
    ``target_sh``, ``live_sh`` (9, 3) the target's and the live light's SH9 in the camera's frame;
    ``anchor`` (x, y) the head's place in the frame (px: :attr:`PersonMaps.anchor`)."""

    small: np.ndarray
    composited: np.ndarray
    face_box: tuple[int, int, int, int]
    alpha: np.ndarray
    normals: np.ndarray
    cover: np.ndarray
    size: tuple[int, int]
    target_sh: np.ndarray
    live_sh: np.ndarray
    anchor: tuple[float, float]


def build_person_maps(matte_model, inputs: PersonInputs, prob=None) -> tuple[PersonMaps, bool]:
    """The person's :class:`PersonMaps` (``gate`` unset) and whether the matte is trusted around
    the face (:func:`.head_light.matte_trusted`), made from ``inputs`` with ``matte_model``
    (a :class:`.person.PersonMatte`) over the box of the work scale the person and a margin reach
    (:func:`.head_light.person_crop`: their cost is the person's size, not the frame's). ``prob``:
    the model's probability over ``inputs.small`` when already made (a Future of it or the
    array; None: made here). Touches nothing but its arguments and the model: it may run on a
    worker."""
    from relight.colour import decode_lut8

    from .person import GUIDE_RADIUS

    small, c_small, face_small = inputs.small, inputs.composited, inputs.face_box
    wh, ww = small.shape[:2]
    w, h = inputs.size
    fa = inputs.alpha
    face_px = float(np.sqrt(max(float(np.count_nonzero(fa > 0.5)), 1.0)))
    if prob is None:
        prob = matte_model.probability(small)
    elif hasattr(prob, "result"):
        prob = prob.result()
    margin = max(int(round(head_light.BACKGROUND_RING * face_px)), 2) + 2 * GUIDE_RADIUS + 2
    cx0, cy0, cx1, cy1 = crop = head_light.person_crop(prob, face_small, (ww, wh), margin)
    cw, ch = cx1 - cx0, cy1 - cy0
    # the face's maps placed in the crop (none beyond the face's box, as in the kernel)
    fsl = np.s_[face_small[1] - cy0:face_small[3] - cy0, face_small[0] - cx0:face_small[2] - cx0]
    alpha = np.zeros((ch, cw), np.float32)
    alpha[fsl] = fa
    cover = np.zeros((ch, cw), np.float32)
    cover[fsl] = inputs.cover
    face_normals = np.zeros((ch, cw, 3), np.float32)
    face_normals[..., 2] = 1.0
    face_normals[fsl] = inputs.normals
    sl = np.s_[cy0:cy1, cx0:cx1]
    small_c = np.ascontiguousarray(small[sl])
    matte = head_light.colour_check(small_c, matte_model.refine(small, prob, crop), alpha, face_px)
    matte = head_light.attached_to_face(matte, alpha)
    lut = decode_lut8()
    trusted = head_light.matte_trusted(matte, alpha)
    # The ratio over the box the person and the face reach (the ring beyond served the colour check)
    covered = np.maximum(matte, alpha)
    tx0, ty0, tx1, ty1 = head_light.share_box(covered, RATIO_REACH)
    tsl = np.s_[ty0:ty1, tx0:tx1]
    rho = head_light.ratio_field(lut[small_c[tsl]], lut[c_small[sl][tsl]], alpha[tsl], matte[tsl],
                                 inputs.target_sh, inputs.live_sh, face_px, face_normals=face_normals[tsl],
                                 face_cover=cover[tsl])
    grid = np.empty((ty1 - ty0, tx1 - tx0, 4), np.float32)
    grid[..., :3] = rho - np.float32(1.0)
    grid[..., 3] = head_light.person_share(matte[tsl])  # the person's share of its change: to its outline
    grid.flags.writeable = False  # reused as it is (the compositor keeps its device copy)
    return PersonMaps(grid, (cx0 + tx0, cy0 + ty0), (ww / w, wh / h),
                      head_light.person_box(covered, (w, h), (ww, wh), (cx0, cy0)), inputs.anchor), trusted


def face_alpha_work(rig, box, coarse: np.ndarray, rotation: np.ndarray, size, work, wbox, strength: float):
    """Over the box ``wbox`` (x0, y0, x1, y1) of the work scale ``work`` (ww, wh): the
    compositor's face alpha (feathered mask x facing x strength), (h, w) float32; the bundle's
    normals turned with the head (camera frame, (h, w, 3)); and where the bundle has them (its
    mask, bilinear: (h, w) in 0-1). ``rig``: the path's :class:`relight.engine.rig.FaceRig`;
    ``box``: the face's box in the frame (``coarse``'s: the warp's coarse map over it)."""
    from relight.kernels.compositor import facing_weight

    w, h = size
    ww, wh = work
    x0, y0 = box[0], box[1]
    gx = (((np.arange(wbox[0], wbox[2]) + 0.5) * w / ww - 0.5) - x0 + 0.5) / GRID_STEP + 0.5
    gy = (((np.arange(wbox[1], wbox[3]) + 0.5) * h / wh - 0.5) - y0 + 0.5) / GRID_STEP + 0.5
    mx, my = np.meshgrid(gx.astype(np.float32), gy.astype(np.float32))
    pos = cv2.remap(coarse, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=(OUTSIDE, OUTSIDE))
    px = (pos[..., 0] - rig.origin[0]).astype(np.float32)
    py = (pos[..., 1] - rig.origin[1]).astype(np.float32)
    alpha = cv2.remap(rig.alpha_crop, px, py, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    normal = cv2.remap(rig.normal_crop, px, py, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                       borderValue=(0, 0, 1))
    turned = normal @ np.asarray(rotation, np.float32).T
    cover = cv2.remap(rig.mask_crop.astype(np.float32), px, py, cv2.INTER_LINEAR,
                      borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    facing = facing_weight(turned[..., 2], normal[..., 2])
    # the bundle's normals are trusted where it has them and the head's turn has not taken them
    # past the capture's view (there the face fades out too: an ear or a jaw seen edge-on holds the
    # capture's noisiest normals, and a hard light showed each of them as a patch)
    return (alpha * facing * strength).astype(np.float32), turned, (cover * facing).astype(np.float32)


def environment_texels(env: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The environment ``env`` ((H, 2H, 3) float32 linear) at 64x32 texels: ((2048, 3) float64
    directions, (2048, 3) float64 power - radiance x solid angle), for its irradiance's low
    frequencies (:func:`person_inputs`)."""
    from relight.directions import equirect_directions, equirect_solid_angles
    from relight.light_preview import shrunk

    texels = shrunk(env, 64)
    omega = np.repeat(equirect_solid_angles(64, 32), 64)[:, None]
    return (equirect_directions(64, 32).reshape(-1, 3).astype(np.float64),
            (texels.reshape(-1, 3) * omega).astype(np.float64))


def work_copy(frame, work) -> np.ndarray:
    """The frame ((H, W, 3) uint8 sRGB or a YuvFrame) at the work scale ``work`` (ww, wh):
    (wh, ww, 3) uint8 sRGB, area-averaged."""
    return downscale_area(frame, work) if isinstance(frame, np.ndarray) else frame.small_rgb(work)


def person_inputs(rig, compositor, frame, box, coarse, rotation, tau: float, work, anchor, *, strength: float,
                  env_texels, fixed_env: bool, texel_dirs, texel_light, small=None) -> PersonInputs:
    """What the person's maps are made of (:class:`PersonInputs`), from this frame: one copy of
    the frame at the work scale ``work`` (ww, wh), its face composited by the same kernel as the
    frame's (the face's ratio at that scale; ``compositor``: the path's
    :class:`relight.kernels.compositor.Compositor`, ``tau`` its detail threshold), the face's maps
    over its box (:func:`face_alpha_work`), and the target's and the live light's irradiance in
    the camera's frame. ``box``, ``coarse``: the face's box in the frame and the warp's coarse map
    over it; ``rotation``: the head's (3x3); ``anchor``: the head's place (frame px);
    ``env_texels``: the environment's (:func:`environment_texels`), turned with the head when
    ``fixed_env``; ``texel_dirs``, ``texel_light``: (T, 3) the bundle's texel directions and the
    live light in them; ``small``: the frame's :func:`work_copy` when already made."""
    from relight.spherical_harmonics import lights_sh9

    h, w = frame.shape[:2]
    ww, wh = work
    if small is None:
        small = work_copy(frame, work)
    sx, sy = w / ww, h / wh
    face_small = (max(int(box[0] / sx) - 1, 0), max(int(box[1] / sy) - 1, 0),
                  min(int(np.ceil(box[2] / sx)) + 1, ww), min(int(np.ceil(box[3] / sy)) + 1, wh))
    fa, fn, fc = face_alpha_work(rig, box, coarse, rotation, (w, h), work, face_small, strength)
    c_small = compositor.composite_person(small, face_small, box, coarse, GRID_STEP, mode="live", tau=tau,
                                          scale=(sx, sy))
    r = np.asarray(rotation, dtype=np.float64)
    env_dirs, env_power = env_texels
    target_sh = lights_sh9(env_dirs @ r.T if fixed_env else env_dirs, env_power)
    live_sh = lights_sh9(np.asarray(texel_dirs, np.float64) @ r.T, texel_light)
    return PersonInputs(small, c_small, face_small, fa, fn, fc, (w, h), target_sh, live_sh,
                        (float(anchor[0]), float(anchor[1])))
