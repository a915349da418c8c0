"""The capture's back half: from :class:`~relight.pipeline.capture_types.Prepared` samples (video
or image set) to geometry (photometric stereo, or a given mesh), the maps
(:mod:`reflectance_maps`), the compact light transport and the tracking landmarks - the bundle's
arrays and meta, ready to write."""

from __future__ import annotations

import time
from pathlib import Path

import cv2
import numpy as np

from relight import __version__
from relight.colour import encode_srgb8
from relight.errors import InputError, NumericalError
from relight.kernels.bundle_format import Field
from relight.numerics import EPS_VALUE, flush_subnormal_halves

from . import geometry
from .capture_progress import Progress
from .capture_types import CaptureOptions, Prepared
from .reflectance_maps import horizon_rows, reflectance_maps, texel_major
from .triangulate import triangulate

#: The most landmarks stored.
MAX_LANDMARKS = 300


def finish(prep: Prepared, opts: CaptureOptions, progress: Progress, timings: dict):
    """Geometry, maps and bundle arrays from prepared samples: (arrays, meta, geometry, triangulation)."""
    t0 = time.perf_counter()
    k, h, w = prep.images.shape[:3]
    geo = _geometry(prep, opts, progress, (h, w))
    if opts.export_mesh:
        _export_mesh(geo, prep.origin, opts.export_mesh)
    timings["geometry"] = time.perf_counter() - t0

    # The large arrays (samples, maps) are rebound here as each step replaces them, so that the
    # one they replace is freed: a helper's caller would keep it alive.
    t0 = time.perf_counter()
    pix = np.flatnonzero(geo.mask)
    samples = np.ascontiguousarray(prep.images.reshape(k, -1, 3)[:, pix], dtype=np.float32)
    prep.images = None  # the full sample images are the largest thing held: the head's pixels suffice now
    from .shading_fit import stored_precision

    # The normals as the bundle stores them (float16): its recipe makes the maps from those.
    normals = stored_precision(geo.normal.reshape(-1, 3)[pix].astype(np.float32))
    tri = triangulate(prep.dirs, opts.map_size)
    horizon = None
    if opts.visibility and opts.method == "full":
        horizon = horizon_rows(geo.depth, geo.mask)
        timings["horizon"] = time.perf_counter() - t0
    t1 = time.perf_counter()
    cb = _PixelProgress(progress, pix.size)
    made: dict = {}
    maps, texels, scale, samples = reflectance_maps(samples, normals, tri, opts, horizon, progress=cb, grid=geo.mask,
                                                    recipe_out=made, recipe_only=not opts.keep_maps)
    recipe = made.get("recipe")
    from relight.kernels import transport

    rows = None
    if maps is None:
        # The default bundle stores the maps' recipe: the maps are made chunk by chunk for the
        # compact transport and dropped (no array of every pixel's maps is ever held).
        timings["maps"] = time.perf_counter() - t1  # the fits; making the maps counts as transport
        t1 = time.perf_counter()
        cb.done = 0
        compact = _transport_from_recipe(recipe, pix.size, texels, opts, cb)
    else:
        timings["maps"] = time.perf_counter() - t1
        maps = _half_maps(maps)
        t1 = time.perf_counter()
        # The maps texel-major (what the bundle stores); the pixel-major copy only when kept: the
        # two together were the capture's peak memory.
        rows = texel_major(maps, texels.size)
        if not opts.keep_maps:
            maps = None
        compact = transport.factorize(rows, opts.map_size, texels, texel_major=True,
                                      store_tolerance=opts.store_tolerance)
    timings["transport"] = time.perf_counter() - t1
    t1 = time.perf_counter()
    arrays, rec_meta = _bundle_arrays(prep, geo, pix=pix, normals=normals, tri=tri, texels=texels, compact=compact,
                                      recipe=recipe, rows=rows, samples=samples, maps=maps, opts=opts)
    meta = _bundle_meta(prep, opts, (k, h, w), pix.size, tri, scale, compact)
    if recipe is not None:
        meta["recipe"] = rec_meta
    timings["landmarks"] = time.perf_counter() - t1
    return arrays, meta, geo, tri


def _geometry(prep: Prepared, opts: CaptureOptions, progress: Progress, shape: tuple[int, int]) -> geometry.Geometry:
    """The head's geometry on the (h, w) reference grid: from the given mesh, from photometric
    stereo inside the given mask, or estimated (photometric stereo and the head's mask)."""
    if opts.mesh is not None:
        return _mesh_geometry(prep, opts.mesh, shape)
    if prep.mask is not None:
        normal, albedo, resid = geometry.photometric_stereo(prep.images, prep.dirs, prep.mask, prep.clipped)
        return geometry.Geometry(normal=normal, albedo=albedo, depth=geometry.integrate_normals(normal, prep.mask),
                                 mask=prep.mask, fit_residual=resid)
    return geometry.estimate_geometry(prep.images, prep.dirs, prep.ambient, prep.clipped, prep.face_local,
                                      progress=progress)


def _mesh_geometry(prep: Prepared, mesh_path, shape: tuple[int, int]) -> geometry.Geometry:
    """Depth and normals from the mesh file at ``mesh_path`` rasterized on the (h, w) grid, albedo
    from photometric stereo. Raises :class:`InputError` on an unreadable or misaligned mesh."""
    import trimesh

    h, w = shape
    try:
        mesh = trimesh.load(mesh_path, force="mesh", process=False)
    except Exception as exc:  # trimesh raises many kinds for a bad file
        raise InputError(f"{mesh_path}: not a mesh trimesh can read ({exc})") from None
    depth, normal, cover = geometry.rasterize_mesh(mesh, (h, w), prep.origin)
    mask = cover if prep.mask is None else (cover & prep.mask)
    if mask.sum() < 16:
        raise InputError(f"{mesh_path}: the mesh covers {int(mask.sum())} pixels of the reference frame; "
                         "it must be aligned to the reference camera (vertices: column, -row, height)")
    _, albedo, resid = geometry.photometric_stereo(prep.images, prep.dirs, mask, prep.clipped)
    return geometry.Geometry(normal=normal, albedo=albedo, depth=np.where(mask, depth, 0).astype(np.float32),
                             mask=mask, fit_residual=resid)


def _export_mesh(geo: geometry.Geometry, origin, path) -> None:
    """Write the depth as a height-field mesh to ``path`` (its suffix names the format; ply without one)."""
    from relight.imageio import atomic_path

    out = Path(path)
    with atomic_path(out) as tmp:
        geometry.height_field_mesh(geo.depth, geo.mask, origin).export(str(tmp), file_type=out.suffix[1:] or "ply")


class _PixelProgress:
    """A progress callback for work done in chunks of pixels: reports the running count of ``total``."""

    def __init__(self, progress: Progress, total: int):
        self.progress = progress
        self.total = total
        self.done = 0

    def __call__(self, n: int) -> None:
        """Count ``n`` more pixels done and report."""
        self.done += n
        self.progress("maps", self.done, self.total)


def _half_maps(maps: np.ndarray) -> np.ndarray:
    """The maps as float16 with subnormals flushed; raises :class:`NumericalError` on a non-finite value."""
    if not np.isfinite(maps).all():
        raise NumericalError("reflectance maps hold non-finite values; this is a bug, please report it")
    return flush_subnormal_halves(maps.astype(np.float16, copy=False))


def _transport_from_recipe(recipe, n_pixels: int, texels, opts: CaptureOptions, cb: _PixelProgress):
    """The compact transport of the maps the recipe makes, chunk by chunk (no full maps array held)."""
    from relight.kernels.recipe import recipe_maps

    from .transport_stream import factorize_stream

    def make(index):  # texel-major float32 maps (the NumPy backend's transposed)
        if opts.backend == "opencl":
            return recipe_maps(recipe.subset(index), texel_major=True)
        return recipe_maps(recipe.subset(index), backend=opts.backend, half=False).transpose(2, 1, 0)

    return factorize_stream(make, n_pixels, opts.map_size, texels, store_tolerance=opts.store_tolerance,
                            progress=cb)


def _bundle_arrays(prep: Prepared, geo: geometry.Geometry, *, pix, normals, tri, texels, compact, recipe, rows,
                   samples, maps, opts: CaptureOptions) -> tuple[dict, dict | None]:
    """The bundle's arrays (name -> array, the landmarks found here) and the recipe's meta (None
    without a recipe). ``pix``: (P,) flat indices of the head's pixels in the crop."""
    from .bundle_write import encode_background
    from .shading_fit import stored_precision

    landmarks = _landmarks(prep, geo.mask)
    arrays = {
        Field.PIXELS: pix.astype(np.int32), Field.MASK_CROP: geo.mask,
        Field.AMBIENT: stored_precision(prep.ambient.astype(np.float32)).astype(np.float16),
        Field.BACKGROUND_JPEG: encode_background(prep.background), Field.NORMAL: normals.astype(np.float16),
        Field.ALBEDO: stored_precision(geo.albedo.reshape(-1, 3)[pix].astype(np.float32)).astype(np.float16),
        Field.DEPTH: stored_precision(geo.depth.astype(np.float32)).astype(np.float16),
        Field.LANDMARKS: landmarks, Field.LIGHT_DIRS: prep.dirs.astype(np.float32),
        Field.MAP_TEXELS: texels.astype(np.int32), Field.TRI_VERTICES: tri.vertices.astype(np.float64),
        Field.TRI_FACES: tri.faces.astype(np.int32),
        Field.TRANSPORT_U: compact.u, Field.TRANSPORT_V: compact.q, Field.TRANSPORT_V_SCALE: compact.q_scale,
        Field.TRANSPORT_ERRORS: compact.rank_errors,
        Field.TRANSPORT_SIGMA: compact.sigma,
    }
    if compact.q4 is not None:
        arrays.update({Field.TRANSPORT_V4: compact.q4, Field.TRANSPORT_V4_SCALE: compact.q4_scale})
    rec_meta = None
    if recipe is not None:  # what the maps are made of (~K + 100 bytes per pixel), not the maps
        from .recipe_write import recipe_arrays

        rec_arrays, rec_meta = recipe_arrays(recipe)
        arrays.update(rec_arrays)
    if recipe is None or opts.keep_maps:
        arrays[Field.MAPS_ROWS] = rows
    if opts.keep_maps:
        arrays.update({Field.SAMPLES: samples.astype(np.float16), Field.MAPS: maps})
    return arrays, rec_meta


def _bundle_meta(prep: Prepared, opts: CaptureOptions, khw: tuple[int, int, int], n_pixels: int, tri, scale,
                 compact) -> dict:
    """The bundle's meta: the prepared capture's, plus what the maps and transport were made with."""
    k, h, w = khw
    meta = dict(prep.meta)
    meta.update({
        "relight_version": __version__, "frame_size": list(prep.frame_size), "crop_origin": list(prep.origin),
        "crop_size": [w, h], "map_size": list(opts.map_size), "method": opts.method,
        "visibility": bool(opts.visibility and opts.method == "full"),
        "adaptation": bool(opts.adaptation and opts.method == "full"),
        "extrapolation": bool(opts.extrapolation and opts.method == "full"),
        "spline": bool(opts.spline and opts.method == "full"),
        "model_reach_deg": float(opts.model_reach) if opts.method == "full" and opts.extrapolation else 0.0,
        "light_adaptation": ("none" if not (opts.adaptation and opts.method == "full") else
                             "paper" if opts.paper_adaptation else "shading model"), "n_samples": int(k),
        "n_pixels": int(n_pixels),
        "n_black_lights": int(len(tri.vertices) - tri.n_samples), "units": "linear Rec.709, flash units",
        "conventions": "camera space +X right, +Y up, +Z toward the camera; maps are lat-long (OpenEXR)",
        "geometry": "mesh" if opts.mesh else "photometric stereo",
        "sample_scale": scale,
        "transport_direct": compact.direct,
        "transport_rank_1pct": compact.rank_for(0.01),
    })
    return meta


def _landmarks(prep: Prepared, mask: np.ndarray) -> np.ndarray:
    """Shi-Tomasi corners of the reference inside the head (frame pixels), for tracking later:
    on the room-light frame when it shows the face (a video's no-flash frames), else on the
    reference frame (an image set's typical lit face)."""
    from relight.colour import decode_srgb8, luminance
    from relight.kernels.bundle import ROOM_LIGHT_MIN_SHARE

    x0, y0 = prep.origin
    ref = prep.background[y0:y0 + mask.shape[0], x0:x0 + mask.shape[1]]
    if mask.any():
        amb = float(np.median(luminance(prep.ambient[mask])))
        if amb > 0.0 and amb >= ROOM_LIGHT_MIN_SHARE * float(np.median(luminance(decode_srgb8(ref)[mask]))):
            ref = encode_srgb8(prep.ambient / max(float(prep.ambient.max()), EPS_VALUE))
    grey = cv2.cvtColor(np.ascontiguousarray(ref), cv2.COLOR_RGB2GRAY)
    pts = cv2.goodFeaturesToTrack(grey, maxCorners=MAX_LANDMARKS, qualityLevel=0.01, minDistance=5,
                                  mask=mask.astype(np.uint8) * 255)
    if pts is None:
        return np.zeros((0, 2), dtype=np.float32)
    return (pts.reshape(-1, 2) + np.asarray(prep.origin, dtype=np.float32)).astype(np.float32)
