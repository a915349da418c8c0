"""The face rig: everything the per-frame path (:class:`relight.engine.frame_path.FramePath`)
needs of a bundle, prepared once (:meth:`FaceRig.build`) and never changed - the reference's
geometry (crop, masks, feathered alpha), the control points and their 3D model, the warp's grid
and mesh, the tracking copies, the reference light and the lighting ratio's arrays, the
compositor's fill and normals, and the live light's sample pixels.

Coordinates: reference frame pixels (x right, y down) unless a name says crop.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from relight.colour import LUMINANCE
from relight.errors import InputError
from relight.video_yuv import downscale_area

from . import composite
from .live_light import SAMPLES
from .pose import ORTHOGRAPHIC_FOCAL, camera_matrix, lift_landmarks, lift_straight
from .refind import REFIND_STEP
from .tracking import MAX_TRACKED, thin_points
from .tracking_image import TRACK_ROWS, aligned_box
from .warp import GRID_STEP, face_ring, reference_triangles

#: The composited region reaches this share of the landmarks' extent beyond their hull.
HULL_MARGIN = 0.2
#: Feather of the face mask: erosion and Gaussian sigma, as shares of the face's size.
FEATHER_ERODE = 0.015
FEATHER_SIGMA = 0.02
#: The warp's rigid grid: one reference point every this share of the landmarks' extent.
WARP_GRID_SHARE = 1.0 / 16.0


def _remap_at(img: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """(N,) float32: the (H, W) ``img`` read bilinearly at points ``xy`` (N, 2) by ``cv2.remap``
    (edges replicated; positions quantised to 1/32 px, as OpenCV's bilinear does - not
    :func:`relight.sampling.bilinear`, whose exact weights would move every model point a little)."""
    m = cv2.remap(img.astype(np.float32), xy[:, 0:1].astype(np.float32), xy[:, 1:2].astype(np.float32),
                  cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return m.reshape(-1)


def largest_component(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(the mask's largest 8-connected component, the same with its holes filled): specks of
    a capture's mask on the wall would otherwise be composited as dots."""
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    if n <= 1:
        raise InputError("the bundle's face mask is empty: capture the bundle again")
    keep = (labels == 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))).astype(np.uint8)
    contours, _ = cv2.findContours(keep, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    filled = np.zeros_like(keep)
    cv2.drawContours(filled, contours, -1, 1, thickness=cv2.FILLED)
    return keep.astype(bool) & mask, filled.astype(bool)


def capture_focal(meta: dict) -> float | None:
    """The capture's camera as a bundle's meta records it (``camera_focal``, px of the reference
    frame), or None: orthographic (none recorded, or not a positive finite number)."""
    f = meta.get("camera_focal") if isinstance(meta, dict) else None
    if isinstance(f, int | float) and not isinstance(f, bool) and np.isfinite(f) and f > 0:
        return float(f)
    return None


def reference_focal(meta: dict, ref_size: tuple[int, int]) -> float:
    """The focal length (px) a bundle's reference frame is lifted with: the capture's camera
    (:func:`capture_focal`) or, without one, the long focal length that models an orthographic
    camera (:data:`.pose.ORTHOGRAPHIC_FOCAL`)."""
    f = capture_focal(meta)
    return ORTHOGRAPHIC_FOCAL * max(ref_size) if f is None else f


@dataclass(frozen=True)
class FaceRig:
    """What the per-frame path needs of a bundle, prepared once (:meth:`build`) and never changed:
    the reference's geometry (crop, masks, feathered alpha), the control points and their 3D
    model, the warp's grid and mesh, the tracking copies, the reference light and the lighting
    ratio's arrays, the compositor's fill and normals, and the live light's sample pixels.
    Coordinates: reference frame pixels (x right, y down) unless a name says crop."""

    ref_size: tuple[int, int]  # the reference frame's (w, h)
    origin: tuple[int, int]  # the face crop's corner (x0, y0) in the reference
    focal: object  # the focal length the frames are solved with (px; 'ortho' made a long one; None: per frame)
    mask_crop: np.ndarray  # (ch, cw) bool: the bundle's face, its largest component
    ref_grey: np.ndarray  # (H, W) uint8: the reference frame in grey
    control_ref: np.ndarray  # (N, 2) float32: the control points in the reference - landmarks, then a ring
    n_landmarks: int  # how many of control_ref are landmarks
    ring_index: np.ndarray  # indices of the ring's points in control_ref
    model: np.ndarray  # (N, 3) the control points lifted with the bundle's depth (the pose's model)
    #: (N, 3) the control points' shape as the capture's camera saw it - an orthographic capture's
    #: lifted straight (:func:`.pose.lift_straight`), a pinhole's as ``model`` - the focal search's model
    shape_model: np.ndarray
    refind_model: np.ndarray  # (3N, 3) model, then each point moved REFIND_STEP px right, then down
    model_normals: np.ndarray  # (N, 3) unit surface normals of ``model``'s points (toward the reference camera)
    depth_crop: np.ndarray  # (ch, cw) float32 depth (px toward the camera; off the face the nearest face px's)
    k_ref: np.ndarray  # (3, 3) the reference's camera (the one it is lifted with: reference_focal)
    ref_track_scale: float  # the tracking copy's scale of the reference
    track_reference: np.ndarray  # the reference grey at the tracking scale
    track_landmarks: np.ndarray  # (L, 2) the landmarks at the tracking scale
    track_mask: np.ndarray  # the face mask at the tracking scale
    track_face: np.ndarray  # the composited face at the tracking scale (the live-lit reference's pixels)
    lit_box: tuple  # the boxes the live-lit reference is remade in (.tracking_image.aligned_box)
    solid_full: np.ndarray  # (H, W) bool: the composited face in the reference frame
    alpha_crop: np.ndarray  # (ch, cw) float32: the feathered face mask
    grid_ref: np.ndarray  # (G, 2) the warp's rigid grid in the reference
    grid_model: np.ndarray  # (G, 3) the grid lifted with the bundle's depth
    grid_step: int  # the grid's spacing (reference px)
    mesh_ref: np.ndarray  # (M, 2) float32: the warp mesh's corners in the reference (landmarks first)
    mesh_model: np.ndarray  # (M, 3) the mesh's corners lifted
    mesh_triangles: np.ndarray  # (T, 3) int32: the mesh, triangulated once
    reference_light: str  # 'room' (the capture room's light) or 'uniform' (even light): the ambient ratio's
    ambient_crop: np.ndarray  # (ch, cw, 3) float32 linear: the face under the reference light
    ratio_eps: np.float32  # the lighting ratio's floor (linear)
    inv_ambient: np.ndarray  # (ch, cw, 3) float32: 1 / (ambient + eps)
    fill: np.ndarray  # (ch, cw) int32: crop pixel -> relit frame pixel (the fringe: the nearest face pixel; -1 none)
    fill_flat: np.ndarray  # fill, flat
    sample_crop: np.ndarray  # every 7th face pixel of the crop (flat indices)
    sample_full: np.ndarray  # their relit frame pixels
    normal_crop: np.ndarray  # (ch, cw, 3) float32: the crop's normals (the nearest face pixel's off the face)
    live_pixels: np.ndarray  # the bundle pixels the live light is fitted on
    live_ref: np.ndarray  # (S, 2) float32: their reference positions
    live_normal: np.ndarray  # (S, 3) their normals
    live_full: np.ndarray  # (S,) their relit frame pixels
    live_box: tuple  # (x0, y0, x1, y1) reference box around them

    def lift(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) model points (the pose's model space) of any reference pixels ``points`` (N, 2),
        lifted as the control points are (the depth read bilinearly, clamped to the crop)."""
        pts = np.asarray(points, np.float32).reshape(-1, 2)
        h, w = self.depth_crop.shape
        xy = np.clip(pts - np.array(self.origin, np.float32), 0, [w - 1, h - 1])
        return lift_landmarks(pts, _remap_at(self.depth_crop, xy), self.k_ref)

    @classmethod
    def build(cls, bundle, relighter, focal=None) -> FaceRig:
        """The rig of ``bundle`` (``relighter``: its Relighter - a bundle without a room-light
        frame takes its reference light from a uniform relight; ``focal``: px, "ortho" or None)."""
        ref_w, ref_h = bundle.frame_size
        r = {"ref_size": (ref_w, ref_h), "origin": tuple(int(v) for v in bundle.crop_origin)}
        origin = r["origin"]
        mask_crop, solid = largest_component(np.asarray(bundle.mask_crop, dtype=bool))
        # Reference grey (the no-flash reference frame) and the landmarks' 3D model.
        ref_grey = cv2.cvtColor(np.ascontiguousarray(np.asarray(bundle.background)), cv2.COLOR_RGB2GRAY)
        landmarks = thin_points(np.asarray(bundle.landmarks, dtype=np.float32).reshape(-1, 2), MAX_TRACKED)
        solid = solid & _composited_region(landmarks, origin, mask_crop.shape)
        if solid.sum() < 64:
            raise InputError("the bundle's landmarks do not cover its face: capture the bundle again")
        ring = face_ring(solid) + np.array(origin, np.float32)
        depth_filled, nearest = _filled_depth(bundle.depth, mask_crop)
        if focal == "ortho":
            # One long focal length for every frame (a crop or a resized copy of an orthographic
            # view must not get a different perspective than the reference).
            focal = ORTHOGRAPHIC_FOCAL * max(r["ref_size"])
        # The reference is lifted with the capture's own camera, not the frames': the one its
        # sphere's light directions assumed (``relight capture --focal``, in the bundle's meta),
        # else orthographic as the capture modelled it. (Lifted with the frames' focal length, an
        # orthographic capture's head off the frame's centre is modelled seen from its side: its
        # pose through a webcam was off by the view's angle, 5-9 deg on the perspective studio.)
        k_ref = camera_matrix(r["ref_size"], reference_focal(bundle.meta, r["ref_size"]))
        r.update(_control_model(landmarks, ring, depth_filled, origin, k_ref,
                                straight=capture_focal(bundle.meta) is None))
        r.update(focal=focal, mask_crop=mask_crop, ref_grey=ref_grey, depth_crop=depth_filled, k_ref=k_ref)
        r.update(_tracking_copies(ref_grey, mask_crop, solid, origin, r["ref_size"], landmarks))
        alpha_crop = _feathered_alpha(solid)
        r.update(_warp_grid(alpha_crop, landmarks, depth_filled, origin, k_ref))
        r.update(_warp_mesh(landmarks, r["model"], r["grid_ref"], r["grid_model"], r["grid_step"]))
        r.update(_reference_light(bundle, relighter, origin, mask_crop.shape))
        r.update(_lighting_ratio(r["ambient_crop"], mask_crop))
        fill, ref_index = _fill_map(mask_crop, alpha_crop, origin, ref_w, nearest)
        fill_flat = fill.ravel()
        # Every 7th face pixel: enough for the median of the lighting ratio.
        sample_crop = np.flatnonzero(mask_crop.ravel())[::7]
        r.update(alpha_crop=alpha_crop, fill=fill, fill_flat=fill_flat, sample_crop=sample_crop,
                 sample_full=fill_flat[sample_crop])
        r["normal_crop"] = _crop_normals(bundle, fill, ref_index, nearest, r["ref_size"])
        r.update(_live_samples(bundle, alpha_crop, origin))
        return cls(**{k: r[k] for k in cls.__dataclass_fields__})


def _composited_region(landmarks: np.ndarray, origin: tuple[int, int], shape: tuple[int, int]) -> np.ndarray:
    """(ch, cw) bool: the crop within a margin (HULL_MARGIN of their extent) of the landmarks' hull.
    Beyond the tracked points (neck, a turned head's far side) the warp would only extrapolate."""
    x0, y0 = origin
    h, w = shape
    hull = cv2.convexHull((landmarks - np.array([x0, y0], np.float32)).astype(np.int32))
    region = np.zeros((h, w), np.uint8)
    cv2.fillConvexPoly(region, hull, 1)
    grow = max(int(round(HULL_MARGIN * max(np.ptp(landmarks[:, 0]), np.ptp(landmarks[:, 1])))), 1)
    return cv2.dilate(region, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * grow + 1,) * 2)) > 0


def _filled_depth(depth, mask_crop: np.ndarray) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray]]:
    """((ch, cw) float32 depth with every pixel off the mask given its nearest mask pixel's (the
    ring, landmarks on the edge), (iy, ix): that nearest mask pixel of every crop pixel)."""
    depth = np.asarray(depth, dtype=np.float32)
    from scipy.ndimage import distance_transform_edt

    _, (iy, ix) = distance_transform_edt(~mask_crop, return_indices=True)
    return depth[iy, ix], (iy, ix)


def surface_normals(refind_model: np.ndarray, n: int) -> np.ndarray:
    """(n, 3) float64 unit normals of the model's points from their neighbours a step right and a
    step down (``refind_model``: the n points, then those, lifted alike), turned toward the
    reference camera (OpenCV's space: -Z); (0, 0, -1) where the neighbours give no plane."""
    p, right, down = refind_model[:n], refind_model[n:2 * n], refind_model[2 * n:3 * n]
    nrm = np.cross(right - p, down - p)
    length = np.linalg.norm(nrm, axis=1, keepdims=True)
    ok = (length[:, 0] > 1e-9) & np.isfinite(length[:, 0])
    out = np.tile(np.array([0.0, 0.0, -1.0]), (n, 1))
    out[ok] = nrm[ok] / length[ok]
    out[out[:, 2] > 0] *= -1.0  # the reference saw every point: its surface faces that camera
    return out


def _control_model(landmarks: np.ndarray, ring: np.ndarray, depth_filled: np.ndarray, origin: tuple[int, int],
                   k_ref: np.ndarray, straight: bool) -> dict:
    """The rig's control points (landmarks, then the ring; reference px) and their 3D models, lifted
    with the crop's depth and ``k_ref`` (``straight``: the focal search's shape lifted straight, as an
    orthographic capture saw it): ``control_ref``, ``n_landmarks``, ``ring_index``, ``model``,
    ``refind_model``, ``shape_model``."""
    x0, y0 = origin
    h, w = depth_filled.shape
    pts = np.concatenate([landmarks, ring])
    crop_xy = np.clip(pts - np.array([x0, y0], np.float32), 0, [w - 1, h - 1])
    depth_at = _remap_at(depth_filled, crop_xy)
    model = lift_landmarks(pts, depth_at, k_ref)
    # Each control point and its neighbours REFIND_STEP px right and down, lifted the same way:
    # the pose's local affine at a landmark (:func:`.refind.refind_landmarks`) by finite differences.
    steps = np.concatenate([pts + [REFIND_STEP, 0.0], pts + [0.0, REFIND_STEP]])
    steps_xy = np.clip(steps - np.array([x0, y0], np.float32), 0, [w - 1, h - 1]).astype(np.float32)
    refind_model = np.concatenate([model, lift_landmarks(steps, _remap_at(depth_filled, steps_xy), k_ref)])
    return {"control_ref": pts, "n_landmarks": len(landmarks), "ring_index": np.arange(len(landmarks), len(pts)),
            "model": model, "refind_model": refind_model, "model_normals": surface_normals(refind_model, len(pts)),
            "shape_model": lift_straight(pts, depth_at, k_ref) if straight else model}


def _tracking_copies(ref_grey: np.ndarray, mask_crop: np.ndarray, solid: np.ndarray, origin: tuple[int, int],
                     ref_size: tuple[int, int], landmarks: np.ndarray) -> dict:
    """The reference, its landmarks, face mask and composited face at the tracking scale
    (``ref_track_scale``, ``track_*``), the boxes the live-lit reference is remade in (``lit_box``)
    and the composited face in the reference frame (``solid_full``)."""
    ref_w, ref_h = ref_size
    x0, y0 = origin
    h, w = mask_crop.shape
    full_mask = np.zeros((ref_h, ref_w), dtype=bool)
    full_mask[y0:y0 + h, x0:x0 + w] = mask_crop
    # Tracking runs on frames scaled to at most TRACK_ROWS rows (LK's cost is its pyramids
    # and windows; a third of a pixel at 1080 rows is still far below the pose's noise).
    rs = min(1.0, TRACK_ROWS / ref_h)
    small_ref = downscale_area(ref_grey, (round(ref_w * rs), round(ref_h * rs))) if rs < 1 else ref_grey
    small_mask = cv2.resize(full_mask.astype(np.uint8), small_ref.shape[::-1], interpolation=cv2.INTER_NEAREST) > 0
    # The bundle's own face in its illumination subspace finds the face where a generic
    # detector does not (one-sided light, tight crops).
    solid_full = np.zeros((ref_h, ref_w), dtype=bool)
    solid_full[y0:y0 + h, x0:x0 + w] = solid
    track_face = cv2.resize(solid_full.astype(np.uint8), small_ref.shape[::-1], interpolation=cv2.INTER_NEAREST) > 0
    return {"ref_track_scale": rs, "track_reference": small_ref, "track_landmarks": landmarks * np.float32(rs),
            "track_mask": small_mask, "track_face": track_face, "lit_box": aligned_box(track_face, (ref_h, ref_w)),
            "solid_full": solid_full}


def _feathered_alpha(solid: np.ndarray) -> np.ndarray:
    """(ch, cw) float32: the composited face ``solid`` eroded and blurred (FEATHER_ERODE, FEATHER_SIGMA)."""
    h, w = solid.shape
    size = max(h, w)
    er = max(int(round(FEATHER_ERODE * size)), 1)
    m = cv2.erode(solid.astype(np.uint8), cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * er + 1,) * 2))
    return cv2.GaussianBlur(m.astype(np.float32), (0, 0), FEATHER_SIGMA * size)


def _warp_grid(alpha_crop: np.ndarray, landmarks: np.ndarray, depth_filled: np.ndarray, origin: tuple[int, int],
               k_ref: np.ndarray) -> dict:
    """The warp's rigid grid: ``grid_ref`` (G, 2) float32 reference px, ``grid_model`` (G, 3) lifted
    with the crop's depth, ``grid_step`` (reference px)."""
    x0, y0 = origin
    h, w = alpha_crop.shape
    # Reference points every WARP_GRID_SHARE of the face's size, lifted
    # with the bundle's depth - a frame moves them with its head pose (the landmarks add what
    # the pose does not explain: an expression). It reaches a GRID_STEP and a cell past the
    # face's alpha (the inverse map is defined inside the grid's hull and evaluated on cells of
    # GRID_STEP frame pixels), past the crop too: a mask that fills its crop - a tight photo -
    # is covered to its edge (depths there are the nearest mask pixel's).
    step = max(int(round(WARP_GRID_SHARE * max(np.ptp(landmarks[:, 0]), np.ptp(landmarks[:, 1])))), 3)
    cells = int(np.ceil(GRID_STEP / step)) + 1
    reach = cells * step
    pad = reach + step
    from relight.kernels.compositor import ALPHA_FLOOR

    cover = cv2.dilate(np.pad((alpha_crop > ALPHA_FLOOR).astype(np.uint8), pad),
                       cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * reach + 1,) * 2))
    gy, gx = np.mgrid[-reach:h + reach + 1:step, -reach:w + reach + 1:step]
    on = cover[gy + pad, gx + pad] > 0
    gx, gy = gx[on], gy[on]
    grid_ref = np.stack([gx, gy], axis=1).astype(np.float32) + np.array([x0, y0], np.float32)
    grid_model = lift_landmarks(grid_ref, depth_filled[np.clip(gy, 0, h - 1), np.clip(gx, 0, w - 1)], k_ref)
    return {"grid_ref": grid_ref, "grid_model": grid_model, "grid_step": step}


def _warp_mesh(landmarks: np.ndarray, model: np.ndarray, grid_ref: np.ndarray, grid_model: np.ndarray,
               step: int) -> dict:
    """The warp's mesh: every landmark and the grid points farther than a cell from them,
    triangulated once in the reference (a frame moves its corners: the tracked landmarks
    where they were seen, the rest where the head pose puts them) - ``mesh_*``."""
    from scipy.spatial import cKDTree

    near, _ = cKDTree(landmarks).query(grid_ref, k=1)
    free = near > step
    mesh_ref = np.concatenate([landmarks, grid_ref[free]]).astype(np.float32)
    return {"mesh_ref": mesh_ref, "mesh_model": np.concatenate([model[:len(landmarks)], grid_model[free]]),
            "mesh_triangles": reference_triangles(mesh_ref)}


def _reference_light(bundle, relighter, origin: tuple[int, int], shape: tuple[int, int]) -> dict:
    """The light the lighting ratio is taken against: ``reference_light`` ('room' or 'uniform') and
    ``ambient_crop`` (ch, cw, 3) float32 linear, the face under it."""
    x0, y0 = origin
    h, w = shape
    room = bundle.room_light
    if room is not None:
        return {"reference_light": "room", "ambient_crop": np.asarray(room, dtype=np.float32)}
    # An RTI-set bundle (or a capture in a dark room) has no usable room-light reference:
    # the lighting ratio is taken against the face under even light (a uniform
    # environment) instead.
    from relight.envmap import load_environment

    even = relighter.relight(load_environment("builtin:uniform", width=64))
    return {"reference_light": "uniform", "ambient_crop": np.ascontiguousarray(even[y0:y0 + h, x0:x0 + w])}


def _lighting_ratio(ambient_crop: np.ndarray, mask_crop: np.ndarray) -> dict:
    """The lighting ratio's floor ``ratio_eps`` (linear, from the face's median luminance) and
    ``inv_ambient`` (ch, cw, 3) float32: 1 / (ambient + eps)."""
    amb_lum = (ambient_crop[mask_crop] @ LUMINANCE) if mask_crop.any() else np.zeros(1, np.float32)
    ratio_eps = np.float32(composite.RATIO_EPS * max(float(np.median(amb_lum)), composite.TINY))
    return {"ratio_eps": ratio_eps, "inv_ambient": (1.0 / (ambient_crop + ratio_eps)).astype(np.float32)}


def _fill_map(mask_crop: np.ndarray, alpha_crop: np.ndarray, origin: tuple[int, int], ref_w: int,
              nearest: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """(fill (ch, cw) int32: crop pixel -> relit frame pixel, ref_index (ch, cw) int64: each crop
    pixel's flat index in the reference frame); ``nearest``: (iy, ix) of :func:`_filled_depth`."""
    x0, y0 = origin
    h, w = mask_crop.shape
    iy, ix = nearest
    # The face's own, the nearest face pixel in the feathered
    # fringe (no dark or bright halo from the background the maps never saw), else none.
    ref_index = ((np.arange(h)[:, None] + y0) * ref_w + (np.arange(w)[None, :] + x0)).astype(np.int64)
    fill = np.full((h, w), -1, dtype=np.int32)
    fill[mask_crop] = ref_index[mask_crop]
    from relight.kernels.compositor import ALPHA_FLOOR

    fringe = (alpha_crop > ALPHA_FLOOR) & ~mask_crop
    fill[fringe] = ref_index[iy[fringe], ix[fringe]]
    return fill, ref_index


def _crop_normals(bundle, fill: np.ndarray, ref_index: np.ndarray, nearest: tuple[np.ndarray, np.ndarray],
                  ref_size: tuple[int, int]) -> np.ndarray:
    """(ch, cw, 3) float32: the crop's normals (the nearest face pixel's off the face), for fading
    out turned-away surface."""
    ref_w, ref_h = ref_size
    h, w = fill.shape
    iy, ix = nearest
    normal_full = np.zeros((ref_h * ref_w, 3), np.float32)
    normal_full[bundle.frame_index] = np.asarray(bundle.normal, np.float32)
    nfill = np.where(fill >= 0, fill, ref_index[iy, ix].astype(np.int32))
    normal_crop = normal_full[nfill.ravel()].reshape(h, w, 3)
    return np.ascontiguousarray(normal_crop, dtype=np.float32)


def _live_samples(bundle, alpha_crop: np.ndarray, origin: tuple[int, int]) -> dict:
    """The live light's (mode transfer) sample pixels: face pixels well inside the composited
    region that face the camera, at most SAMPLES of them, spread evenly - ``live_*``."""
    x0, y0 = origin
    w = alpha_crop.shape[1]
    pix = np.asarray(bundle.pixels, dtype=np.int64)
    px, py = pix % w, pix // w
    normals = np.asarray(bundle.normal, dtype=np.float32)
    good = np.flatnonzero((alpha_crop[py, px] > 0.5) & (normals[:, 2] > 0.3))
    if good.size > SAMPLES:
        good = good[np.linspace(0, good.size - 1, SAMPLES).round().astype(np.int64)]
    live_ref = np.stack([px[good] + x0, py[good] + y0], axis=1).astype(np.float32)
    live_box = (int(live_ref[:, 0].min(initial=0)) - 2, int(live_ref[:, 1].min(initial=0)) - 2,
                int(live_ref[:, 0].max(initial=0)) + 3, int(live_ref[:, 1].max(initial=0)) + 3)
    return {"live_pixels": good, "live_ref": live_ref, "live_normal": normals[good],
            "live_full": bundle.frame_index[good], "live_box": live_box}
