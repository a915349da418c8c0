"""The whole person relit: the light's change carried from the bundle's face to the hair, ears,
neck and shoulders, so no boundary shows and nothing off the person changes.

The bundle knows the face; beyond it the live frame has only the person's matte
(:mod:`.person`). There the change of light is the ratio of the target's diffuse irradiance to
the live light's at a proxy normal, in linear light::

    rho(x) = c(x) * (E_target(n(x)) + e) / (E_live(n(x)) + e)

* ``n(x)``: the matte inflated into a round body (:func:`inflate_normals`): a surface of circular
  cross-section of radius ``R`` rising from the matte's edge - facing sideways at the outline,
  the camera inside it (a silhouette's own shape: hair, ears and shoulders turn away at their
  edges, as they do);
* ``E``: order-2 spherical harmonics irradiance (:mod:`relight.spherical_harmonics`) of the
  target environment and of the live light the frame path fitted on the face, both in the
  camera's frame; ``e`` regularises where the live light leaves a part dark;
* ``c(x)``: the correction that makes the ratio the bundle's own on the face - the face's ratio
  (composited output over input) divided by the proxy's there, in log, extrapolated over the
  person by normalised convolution (a Gaussian of the head's size), so the ratio is continuous
  across the face's feathered edge and its level is the bundle's.

The output is ``out = c + P (1 - A) (f rho - f)`` (linear): ``c`` the frame with the face
composited, ``A`` the face's alpha, ``P`` the person's share (:func:`person_share`: its matte
ramped to reach the outline) joined with the face's alpha, ``f``
the frame. ``n(x)`` is the bundle's own normal wherever the bundle has one (turned with the head):
the inflation only guesses the geometry the bundle knows.
All maps are computed at the work scale (a few hundred rows: the ratio is smooth) over the box of
it the person reaches (:func:`person_crop`) and applied at full resolution in the person's box.
"""

from __future__ import annotations

import cv2
import numpy as np

from relight.colour import LUMINANCE
from relight.spherical_harmonics import sh9_irradiance

#: The inflated body's radius, as a share of the face's size (sqrt of its area): heads,
#: necks and shoulders are a few face sizes across.
INFLATE_RADIUS = 0.6
#: Regulariser of the irradiance ratio, as a share of the live light's median irradiance over
#: the person.
RATIO_EPS = 0.05
#: Bounds of the ratio applied beyond the face.
RATIO_MAX = 6.0
#: Face pixels whose alpha is above this, and whose luminance (linear) is above DARK_LUM, give the
#: correction.
FACE_CORE = 0.9
DARK_LUM = 0.01
#: Spread of the correction's extrapolation, as a share of the face's size.
SPREAD = 0.5
#: Matte values - and the person's share (:func:`person_share`) - below this are off the person
#: (no work).
MATTE_FLOOR = 0.02
#: The share of the person's change a pixel takes ramps from 0 to 1 across this range of the
#: matte (:func:`person_share`). The matte is a probability: the segmentation model's 256x144
#: estimate brought up by a guided filter, whose ramp across the outline is the model's own
#: footprint (measured on the truth clips at 640x360: 0.42 / 0.61 / 0.76 / 0.91 on the first,
#: second, third and sixth pixel inside the true outline, 0.09 on the first outside), not the
#: person's edge - so the person's change faded out over the outer 6-8 px of the person, where the
#: truth takes it whole. Relit whole from 0.6 and not at all below 0.1, the ramp spans the
#: outline's 2-3 px.
PERSON_SHARE = (0.1, 0.6)
#: Beyond the bundle's cover its normals fade into the inflated body's over this share of the
#: face's size (:func:`joined_normals`).
NORMAL_REACH = 0.25
#: The bundle's normals carried past its cover are smoothed over this share of that reach.
CARRY_SMOOTH = 0.5


#: The matte is trusted around a face when it covers (> 0.5) at least this share of the face's
#: core (alpha > FACE_CORE): then the face's composite is held to it as the rest of the person's
#: change is - a face's warp reaching past the jaw or the cheek onto the wall leaves the wall as
#: it was. A matte that misses the face (a model that does not see this person) is not; nor one
#: that holds it only now and then (measured on a real face photo on a plain canvas: the model's
#: cover of the face's core jumped between 0 and 0.98 from one frame to the next): the frame path
#: gates only after MATTE_TRUST_RUN trusted mattes in a row.
MATTE_TRUST = 0.9
MATTE_TRUST_RUN = 3


def person_share(matte: np.ndarray) -> np.ndarray:
    """(h, w) float32 in 0-1: the share of the person's change of light each pixel of ``matte``
    (h, w) takes - the matte's probability ramped across :data:`PERSON_SHARE`."""
    lo, hi = PERSON_SHARE
    out = (np.asarray(matte, np.float32) - np.float32(lo)) * np.float32(1.0 / (hi - lo))
    return np.clip(out, 0.0, 1.0, out=out)


def matte_trusted(matte: np.ndarray, face_alpha: np.ndarray) -> bool:
    """Whether ``matte`` (h, w) covers at least :data:`MATTE_TRUST` of the face's core in
    ``face_alpha`` (h, w): False without a core."""
    core = face_alpha > FACE_CORE
    n = np.count_nonzero(core)
    return n > 0 and np.count_nonzero(matte[core] > 0.5) >= MATTE_TRUST * n


def attached_to_face(matte: np.ndarray, face_alpha: np.ndarray) -> np.ndarray:
    """The matte (h, w) kept only on its parts connected to the face (alpha > 0.5): the person
    is one body with the face; anything else the segmentation took for a person (another
    person, a lamp, a shadow on the wall) stays untouched. Soft edges kept (the kept parts are
    grown by a pixel before the matte is cut)."""
    solid = (matte > 0.5).astype(np.uint8)
    n, labels = cv2.connectedComponents(solid, connectivity=8)
    if n <= 1:
        return np.zeros_like(matte)
    hit = np.unique(labels[(face_alpha > 0.5) & (solid > 0)])
    hit = hit[hit > 0]
    keep = np.isin(labels, hit).astype(np.uint8)
    keep = cv2.dilate(keep, np.ones((3, 3), np.uint8))
    return (matte * keep).astype(np.float32)


#: Colour check of the matte: the ring around the person the background is sampled in (a share
#: of the face's size), and the colour difference (CIE Lab, Delta E) below which a pixel the
#: model calls the person is the background continuing behind it (a wall's noise and texture
#: are a few units; skin, hair and clothes against it many).
BACKGROUND_RING = 0.5
BACKGROUND_DELTA_E = 8.0
#: Inside the matte - beyond STRICT_EDGE_PX of its half-way contour, where the model's edge and
#: the camera's blur tint the wall - a pixel is the wall only within WALL_SPREAD_K standard
#: deviations of the wall's own colours about their local mean (and at least WALL_JND, a just
#: noticeable difference): a plain wall is called the wall only where it looks like that wall,
#: so skin lit at a grazing angle a few Delta E from it stays the person. (STRICT_EDGE_PX, work
#: pixels: at 2 a pale rim followed the outline of `make demo`'s head at frame 67, at 3 and 4 none;
#: 3 kept more of the skull on the eight truth clips.)
WALL_SPREAD_K = 3.0
WALL_JND = 2.3
STRICT_EDGE_PX = 3.0


def colour_check(rgb: np.ndarray, matte: np.ndarray, face_alpha: np.ndarray, face_px: float) -> np.ndarray:
    """The matte (h, w) with what looks like the background taken out: a segmentation model
    trained on selfies sees shoulders where a person usually has them; a pixel it calls the
    person (off the face) whose colour is within BACKGROUND_DELTA_E of the background there -
    the colours of a ring just outside the matte spread inward (normalised convolution), so a
    graded or textured wall is matched where it is - is the wall. Inside the matte (beyond
    STRICT_EDGE_PX of its half-way contour) the wall must also look like itself: within
    WALL_SPREAD_K of its own local spread (at least WALL_JND) - skin lit at a grazing angle, a few
    Delta E from a plain wall, stays the person (the back of a turned head's skull was cut as a pale
    crescent); the rim where the model's edge and the camera's blur pass the outline keeps the
    BACKGROUND_DELTA_E test alone. ``rgb`` (h, w, 3) uint8 at the matte's scale."""
    lab = cv2.cvtColor(rgb, cv2.COLOR_RGB2LAB).astype(np.float32)
    lab[..., 0] *= 100.0 / 255.0  # OpenCV's 8-bit Lab: L in 0-255, a and b offset by 128
    grow = max(int(round(BACKGROUND_RING * face_px)), 2)
    # within ``grow`` px of the matte (a distance transform: a dilation by a disc this wide costs
    # ~13 ms at the work scale)
    off = (matte <= 0.05).astype(np.uint8)
    ring = (cv2.distanceTransform(off, cv2.DIST_L2, 3) <= grow) & (off > 0)
    doubt = (matte > 0.05) & (face_alpha <= 0.5)
    if np.count_nonzero(ring) < 16 or not doubt.any():
        return matte
    ring_w = ring.astype(np.float32)
    den, inv = smoothed = smoothed_weight(ring_w, float(grow))
    local = normalised_convolution(lab, ring_w, float(grow), smoothed)
    d2 = _square_norm3(lab - local)
    # the wall's own spread about its local colour, spread inward as its colour is
    spread2 = gaussian_smooth(d2 * ring_w, float(grow)) * inv
    loose2 = np.maximum(np.float32(WALL_SPREAD_K ** 2) * spread2, np.float32(WALL_JND ** 2))
    inside = (matte >= 0.5).astype(np.uint8)
    deep = cv2.distanceTransform(inside, cv2.DIST_L2, 3) > STRICT_EDGE_PX
    reach = den > 1e-3
    strict2 = np.float32(BACKGROUND_DELTA_E ** 2)
    limit2 = np.where(deep, np.minimum(loose2, strict2), strict2)
    wall = doubt & reach & (d2 < limit2)
    out = np.where(wall, 0.0, matte).astype(np.float32)
    # soft again at the cut: a 3x3 mean of the kept matte, never above the model's own value
    return np.minimum(cv2.blur(out, (3, 3)), matte).astype(np.float32)


def _square_norm3(v: np.ndarray) -> np.ndarray:
    """(...) squared Euclidean norms of vectors (..., 3): ``(v ** 2).sum(axis=-1)`` to the bit (the
    same sums in the same order), without NumPy's slow reduction over a last axis of three (5x at
    the work scale)."""
    sq = v * v
    return sq[..., 0] + sq[..., 1] + sq[..., 2]


def _norm3(v: np.ndarray) -> np.ndarray:
    """(..., 1) Euclidean norms of vectors (..., 3): ``np.linalg.norm(v, axis=-1, keepdims=True)``
    to the bit (:func:`_square_norm3`)."""
    return np.sqrt(_square_norm3(v))[..., None]


def inflate_normals(matte: np.ndarray, radius_px: float) -> np.ndarray:
    """(h, w, 3) float32 unit normals (camera frame: +X right, +Y up, +Z toward the camera) of
    the matte (h, w) in 0-1 inflated into a body of circular cross-section: height
    ``sqrt(d (2 R - d))`` at distance ``d`` (px) inside the edge, ``R`` beyond - facing sideways
    at the outline, the camera inside."""
    inside = (matte > 0.5).astype(np.uint8)
    d = cv2.distanceTransform(inside, cv2.DIST_L2, 5).astype(np.float32)
    r = np.float32(max(radius_px, 1.0))
    dc = np.minimum(d, r)
    z = np.sqrt(np.maximum(dc * (2.0 * r - dc), 0.0))
    sigma = max(0.15 * float(r), 0.8)
    z = cv2.GaussianBlur(z, (0, 0), sigma)
    gy, gx = np.gradient(z)
    n = np.stack([-gx, gy, np.ones_like(z)], axis=-1)  # image rows run down, camera +Y up
    n /= _norm3(n)
    return n.astype(np.float32)


#: Wide Gaussians (sigma above this, px) are taken on a grid scaled down to SMOOTH_SIGMA px per
#: sigma and brought back bilinearly: the fields they smooth (ratios, reaches, colours a face's
#: size away) have no detail at that scale, and a direct blur of sigma 40 at 270 rows costs ~20 ms.
SMOOTH_SIGMA = 3.0


def gaussian_smooth(img: np.ndarray, sigma: float) -> np.ndarray:
    """A Gaussian blur of ``img`` (h, w) or (h, w, C) float32 with ``sigma`` px: direct up to
    :data:`SMOOTH_SIGMA`, else on a grid halved (2x2 means) while ``sigma`` spans at least
    SMOOTH_SIGMA of its pixels, blurred there by what the halvings have not yet blurred (their
    variances add), brought back bilinearly; the result's shape is the input's. (An area
    resize straight to the coarse grid costs 3 ms for three channels at 270 rows, this 0.3.)"""
    sigma = float(sigma)
    if sigma <= SMOOTH_SIGMA:
        return cv2.GaussianBlur(img, (0, 0), max(sigma, 1e-3))
    h, w = img.shape[:2]
    small, scale, var = img, 1, 0.0
    while sigma / (2 * scale) >= SMOOTH_SIGMA and small.shape[0] >= 4 and small.shape[1] >= 4:
        small = cv2.resize(small, (small.shape[1] // 2, small.shape[0] // 2), interpolation=cv2.INTER_AREA)
        var += 0.25 * scale * scale  # a 2x2 mean at this level: variance 1/4 of its input's pixel
        scale *= 2
    rest = np.sqrt(max(sigma * sigma - var, 0.25)) / scale
    small = cv2.GaussianBlur(small, (0, 0), rest)
    return cv2.resize(small, (w, h), interpolation=cv2.INTER_LINEAR)


def smoothed_weight(weight: np.ndarray, sigma: float) -> tuple[np.ndarray, np.ndarray]:
    """(den, inv) of a normalised convolution with ``weight`` (h, w) >= 0: its Gaussian
    smoothing and the inverse of that where it exceeds 1e-6 (0 beyond)."""
    den = gaussian_smooth(weight.astype(np.float32), sigma)
    inv = np.zeros_like(den)
    np.divide(np.float32(1.0), den, out=inv, where=den > 1e-6)
    return den, inv


def normalised_convolution(values: np.ndarray, weight: np.ndarray, sigma: float, smoothed=None) -> np.ndarray:
    """Normalised convolution: the weighted Gaussian average of ``values`` (h, w, C) with
    ``weight`` (h, w) >= 0, defined everywhere the Gaussian reaches a weighted pixel (0 beyond).
    ``smoothed``: the weight's :func:`smoothed_weight` when already made."""
    w = weight.astype(np.float32)
    num = gaussian_smooth(values * w[..., None], sigma)
    _, inv = smoothed_weight(w, sigma) if smoothed is None else smoothed
    return num * inv[..., None]


#: The ratio is computed on a grid this many times coarser than the work scale and brought up
#: bilinearly: it is smooth (a Gaussian of half the face's size and a body's low-frequency
#: irradiance); only the matte's edge needs the work scale, and it is applied there.
RATIO_SHRINK = 2


def ratio_field(frame_lin: np.ndarray, composite_lin: np.ndarray, face_alpha: np.ndarray, matte: np.ndarray,
                target_sh: np.ndarray, live_sh: np.ndarray, face_px: float, *,
                face_normals: np.ndarray | None = None, face_cover: np.ndarray | None = None) -> np.ndarray:
    """(h, w, 3) float32 linear ratio rho over the person at the work scale (module docstring),
    computed :data:`RATIO_SHRINK` times coarser (each map area-averaged) and brought up bilinearly.

    frame_lin, composite_lin : (h, w, 3) the frame and the face-composited frame, linear;
    face_alpha, matte : (h, w) in 0-1; target_sh, live_sh : (9, 3) camera-frame SH radiance;
    face_px : the face's size (sqrt of its area) at the work scale; face_normals (h, w, 3), face_cover
    (h, w) in 0-1: the bundle's own normals (camera frame) and where it has them - they replace the
    inflated body's there (the face's geometry is known; a silhouette's inflation only guesses it)."""
    h, w = matte.shape
    sw, sh = max(1, w // RATIO_SHRINK), max(1, h // RATIO_SHRINK)
    if RATIO_SHRINK > 1 and min(sw, sh) >= 16:

        def down(a):
            return None if a is None else cv2.resize(a, (sw, sh), interpolation=cv2.INTER_AREA)

        rho = _ratio_field(down(frame_lin), down(composite_lin), down(face_alpha), down(matte), target_sh, live_sh,
                           face_px * sw / w, down(face_normals), down(face_cover))
        return cv2.resize(rho, (w, h), interpolation=cv2.INTER_LINEAR)
    return _ratio_field(frame_lin, composite_lin, face_alpha, matte, target_sh, live_sh, face_px, face_normals,
                        face_cover)


def joined_normals(inflated: np.ndarray, face_normals: np.ndarray, face_cover: np.ndarray,
                   face_px: float) -> np.ndarray:
    """(h, w, 3) unit normals: the bundle's ``face_normals`` where ``face_cover`` (h, w, 0-1) has
    them, the ``inflated`` body's beyond - joined without a step: the bundle's normals carried
    past the cover's edge (each pixel takes the cover's nearest normal: a cheek's turned edge
    stays turned at the outline) and faded into the inflated body's over :data:`NORMAL_REACH` x
    ``face_px`` px. (Switched at the edge, the two surfaces' irradiance differs by a step: where a
    capture's face region ends on the neck, or the face's box cuts it, the ratio showed the
    cover's outline as a block.)"""
    cov = np.clip(face_cover, 0.0, 1.0).astype(np.float32)
    solid = cov > 0.5
    if not solid.any():
        return inflated
    reach = max(NORMAL_REACH * float(face_px), 1.0)
    # each pixel's distance to the cover and the cover's nearest pixel (labels number the
    # cover's pixels in scan order)
    near, labels = cv2.distanceTransformWithLabels((~solid).astype(np.uint8), cv2.DIST_L2, 5,
                                                   labelType=cv2.DIST_LABEL_PIXEL)
    fade = np.clip(1.0 - near / np.float32(reach), 0.0, 1.0).astype(np.float32)
    idx = np.flatnonzero(solid.ravel())
    nearest = idx[np.clip(labels.ravel() - 1, 0, idx.size - 1)]
    carried = face_normals.reshape(-1, 3)[nearest].reshape(face_normals.shape)
    # smoothed along the edge: the nearest pixel's normal alone is a patchwork (each pixel beyond
    # takes one of the edge's normals - a capture's edge is ragged - and a hard light shows every
    # patch, as the demo's turned head under sunset did behind its far ear)
    carried = gaussian_smooth(np.ascontiguousarray(carried, np.float32), CARRY_SMOOTH * reach)
    bundle = cov[..., None] * face_normals + (1.0 - cov[..., None]) * carried
    wb = np.maximum(cov, fade)[..., None]
    out = wb * bundle + (1.0 - wb) * inflated
    return (out / np.maximum(_norm3(out), 1e-6)).astype(np.float32)


def _ratio_field(frame_lin, composite_lin, face_alpha, matte, target_sh, live_sh, face_px, face_normals,
                 face_cover) -> np.ndarray:
    """:func:`ratio_field` at the grid of its arguments."""
    normals = inflate_normals(matte, INFLATE_RADIUS * face_px)
    if face_normals is not None and face_cover is not None:
        normals = joined_normals(normals, face_normals, face_cover, face_px)
    e_t = np.maximum(sh9_irradiance(target_sh, normals), 0.0)
    e_l = np.maximum(sh9_irradiance(live_sh, normals), 0.0)
    person = matte > 0.5
    e_p = e_l[person]
    eps = RATIO_EPS * max(float(np.median((e_p[:, 0] + e_p[:, 1] + e_p[:, 2]) / 3.0)) if e_p.size else 0.0, 1e-12)
    proxy = ((e_t + eps) / (e_l + eps)).astype(np.float32)
    lum_f = frame_lin @ LUMINANCE
    core = (face_alpha > FACE_CORE) & (lum_f > DARK_LUM)
    face_ratio = (composite_lin + 1e-4) / (frame_lin + 1e-4)
    log_c = np.log(np.clip(face_ratio, 1.0 / RATIO_MAX, RATIO_MAX) / np.maximum(proxy, 1e-6))
    if np.count_nonzero(core) >= 16:
        corr = normalised_convolution(log_c, core.astype(np.float32), SPREAD * face_px)
        # where the Gaussian does not reach: the core's median correction
        far = gaussian_smooth(core.astype(np.float32), SPREAD * face_px) <= 1e-6
        corr[far] = np.median(log_c[core], axis=0)
    else:
        corr = np.zeros_like(proxy)
    return np.clip(proxy * np.exp(corr), 1.0 / RATIO_MAX, RATIO_MAX).astype(np.float32)


def person_box(share: np.ndarray, frame_size: tuple[int, int], work_size: tuple[int, int] | None = None,
               origin: tuple[int, int] = (0, 0)):
    """The frame's box (x0, y0, x1, y1) where the person's ``share`` (h, w) at the work scale is
    above :data:`MATTE_FLOOR` - a work pixel of margin: the bilinear sample's reach - or None when
    nowhere. ``frame_size``: (W, H) of the frame; ``share`` covers the box of the work scale
    ``work_size`` (its (w, h); None: ``share`` is all of it) from ``origin`` (x, y)."""
    w, h = frame_size
    sw, sh = (share.shape[1], share.shape[0]) if work_size is None else work_size
    ys, xs = np.nonzero(share > MATTE_FLOOR)
    if ys.size == 0:
        return None
    xs_min, xs_max = int(xs.min()) + origin[0], int(xs.max()) + origin[0]
    ys_min, ys_max = int(ys.min()) + origin[1], int(ys.max()) + origin[1]
    x0, x1 = max(0, int((xs_min - 1) * w / sw)), min(w, int(np.ceil((xs_max + 2) * w / sw)))
    y0, y1 = max(0, int((ys_min - 1) * h / sh)), min(h, int(np.ceil((ys_max + 2) * h / sh)))
    return x0, y0, x1, y1


def share_box(share: np.ndarray, reach: int) -> tuple[int, int, int, int]:
    """The box (x0, y0, x1, y1) of ``share`` (h, w) where it is above :data:`MATTE_FLOOR`, grown by
    ``reach`` px and clipped, its corner even (the ratio's coarser grid keeps its alignment); a
    2x2 box at the centre when nowhere (an empty grid is no grid)."""
    h, w = share.shape
    ys, xs = np.nonzero(share > MATTE_FLOOR)
    if ys.size == 0:
        return w // 2 & ~1, h // 2 & ~1, min(w, (w // 2 & ~1) + 2), min(h, (h // 2 & ~1) + 2)
    return _grown_box((int(xs.min()), int(ys.min()), int(xs.max()) + 1, int(ys.max()) + 1), reach, (w, h))


def _grown_box(box, margin: int, size: tuple[int, int]) -> tuple[int, int, int, int]:
    """``box`` (x0, y0, x1, y1) grown by ``margin`` px, clipped to ``size`` (w, h), its corner
    moved down to even coordinates (the ratio's coarser grid keeps its alignment)."""
    x0, y0 = max(0, box[0] - margin), max(0, box[1] - margin)
    return x0 - x0 % 2, y0 - y0 % 2, min(size[0], box[2] + margin), min(size[1], box[3] + margin)


#: The model's probability that places a pixel in the person's box (:func:`person_crop`): half
#: the solid matte's 0.5.
CROP_PROB = 0.25


def person_crop(prob: np.ndarray, face_box, work_size: tuple[int, int], margin: int) -> tuple[int, int, int, int]:
    """The box (x0, y0, x1, y1) of the work scale ``work_size`` (w, h) the person's maps need:
    where the segmentation's ``prob`` (at its own scale, the frame's aspect) is above
    :data:`CROP_PROB`, joined with ``face_box`` (work px), grown by ``margin`` px (the guided
    filter's reach, the colour check's ring) and clipped; its corner even (the ratio's coarser
    grid keeps its alignment). Beyond it the matte is taken as 0: only the solid matte (> 0.5)
    and the pixel around it survive :func:`attached_to_face`, and the guided filter lifts no
    pixel above 0.5 beyond its reach of one the model gives at least CROP_PROB."""
    ww, wh = work_size
    x0, y0, x1, y1 = face_box
    ys, xs = np.nonzero(prob > CROP_PROB)
    if ys.size:
        ph, pw = prob.shape
        x0, x1 = min(x0, int(xs.min() * ww / pw)), max(x1, int(np.ceil((xs.max() + 1) * ww / pw)))
        y0, y1 = min(y0, int(ys.min() * wh / ph)), max(y1, int(np.ceil((ys.max() + 1) * wh / ph)))
    return _grown_box((x0, y0, x1, y1), margin, work_size)
