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
from relight.kernels import triangulation
from relight.numerics import EPS_VALUE, flush_subnormal_halves

from . import geometry
from .capture_progress import Progress
from .capture_types import CaptureOptions, Prepared
from .reflectance_maps import horizon_rows, reflectance_maps, texel_major

#: The most landmarks stored.
MAX_LANDMARKS = 300


def finish(prep: Prepared, opts: CaptureOptions, progress: Progress, timings: dict):
    """Geometry, maps and bundle arrays from prepared samples: (arrays, meta, geometry, triangulation)."""
    t0 = time.perf_counter()
    k, h, w = prep.images.shape[:3]
    if opts.mesh is not None:
        import trimesh

        try:
            mesh = trimesh.load(opts.mesh, force="mesh", process=False)
        except Exception as exc:  # trimesh raises many kinds for a bad file
            raise InputError(f"{opts.mesh}: not a mesh trimesh can read ({exc})") from None
        depth, normal, cover = geometry.rasterize_mesh(mesh, (h, w), prep.origin)
        mask = cover if prep.mask is None else (cover & prep.mask)
        if mask.sum() < 16:
            raise InputError(f"{opts.mesh}: the mesh covers {int(mask.sum())} pixels of the reference frame; "
                             "it must be aligned to the reference camera (vertices: column, -row, height)")
        _, albedo, resid = geometry.photometric_stereo(prep.images, prep.dirs, mask, prep.clipped)
        geo = geometry.Geometry(normal=normal, albedo=albedo, depth=np.where(mask, depth, 0).astype(np.float32),
                                mask=mask, fit_residual=resid)
    elif prep.mask is not None:
        normal, albedo, resid = geometry.photometric_stereo(prep.images, prep.dirs, prep.mask, prep.clipped)
        geo = geometry.Geometry(normal=normal, albedo=albedo, depth=geometry.integrate_normals(normal, prep.mask),
                                mask=prep.mask, fit_residual=resid)
    else:
        geo = geometry.estimate_geometry(prep.images, prep.dirs, prep.ambient, prep.clipped, prep.face_local,
                                         progress=progress)
    if opts.export_mesh:
        from relight.imageio import atomic_path

        out = Path(opts.export_mesh)
        with atomic_path(out) as tmp:
            geometry.height_field_mesh(geo.depth, geo.mask, prep.origin).export(str(tmp), file_type=out.suffix[1:]
                                                                               or "ply")
    timings["geometry"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    pix = np.flatnonzero(geo.mask)
    samples = np.ascontiguousarray(prep.images.reshape(k, -1, 3)[:, pix], dtype=np.float32)
    prep.images = None  # the full sample images are the largest thing held: the head's pixels suffice now
    from relight.kernels.reflectance import stored_precision

    # The normals as the bundle stores them (float16): its recipe makes the maps from those.
    normals = stored_precision(geo.normal.reshape(-1, 3)[pix].astype(np.float32))
    tri = triangulation.triangulate(prep.dirs, opts.map_size)
    horizon = None
    if opts.visibility and opts.method == "full":
        horizon = horizon_rows(geo.depth, geo.mask)
        timings["horizon"] = time.perf_counter() - t0
    t1 = time.perf_counter()
    done = [0]

    def cb(n):
        done[0] += n
        progress("maps", done[0], pix.size)

    made: dict = {}
    maps, texels, scale, samples = reflectance_maps(samples, normals, tri, opts, horizon, progress=cb, grid=geo.mask,
                                                    recipe_out=made, recipe_only=not opts.keep_maps)
    recipe = made.get("recipe")
    from relight.kernels import transport
    from relight.kernels.bundle_format import encode_background

    rows = None
    if maps is None:
        # The default bundle stores the maps' recipe: the maps are made chunk by chunk for the
        # compact transport and dropped (no array of every pixel's maps is ever held).
        from relight.kernels.recipe import recipe_maps

        timings["maps"] = time.perf_counter() - t1  # the fits; making the maps counts as transport
        t1 = time.perf_counter()
        done[0] = 0

        def make(index):  # texel-major float32 maps (the NumPy backend's transposed)
            if opts.backend == "opencl":
                return recipe_maps(recipe.subset(index), texel_major=True)
            return recipe_maps(recipe.subset(index), backend=opts.backend, half=False).transpose(2, 1, 0)

        compact = transport.factorize_stream(make, pix.size, opts.map_size, texels,
                                             store_tolerance=opts.store_tolerance, progress=cb)
    else:
        timings["maps"] = time.perf_counter() - t1
        if not np.isfinite(maps).all():
            raise NumericalError("reflectance maps hold non-finite values; this is a bug, please report it")
        maps = flush_subnormal_halves(maps.astype(np.float16, copy=False))
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
    landmarks = _landmarks(prep, geo.mask)
    arrays = {
        "pixels": pix.astype(np.int32), "mask_crop": geo.mask,
        "ambient": stored_precision(prep.ambient.astype(np.float32)).astype(np.float16),
        "background_jpeg": encode_background(prep.background), "normal": normals.astype(np.float16),
        "albedo": stored_precision(geo.albedo.reshape(-1, 3)[pix].astype(np.float32)).astype(np.float16),
        "depth": stored_precision(geo.depth.astype(np.float32)).astype(np.float16),
        "landmarks": landmarks, "light_dirs": prep.dirs.astype(np.float32),
        "map_texels": texels.astype(np.int32), "tri_vertices": tri.vertices.astype(np.float64),
        "tri_faces": tri.faces.astype(np.int32),
        "transport_u": compact.u, "transport_v": compact.q, "transport_v_scale": compact.q_scale,
        "transport_errors": compact.rank_errors,
        "transport_sigma": compact.sigma,
    }
    if compact.q4 is not None:
        arrays.update({"transport_v4": compact.q4, "transport_v4_scale": compact.q4_scale})
    if recipe is not None:  # what the maps are made of (~K + 100 bytes per pixel), not the maps
        from relight.kernels.recipe import recipe_arrays

        rec_arrays, rec_meta = recipe_arrays(recipe)
        arrays.update(rec_arrays)
    if recipe is None or opts.keep_maps:
        arrays["maps_rows"] = rows
    if opts.keep_maps:
        arrays.update({"samples": samples.astype(np.float16), "maps": maps})
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
        "n_pixels": int(pix.size),
        "n_black_lights": int(len(tri.vertices) - tri.n_samples), "units": "linear Rec.709, flash units",
        "conventions": "camera space +X right, +Y up, +Z toward the camera; maps are lat-long (OpenEXR)",
        "geometry": "mesh" if opts.mesh else "photometric stereo",
        "sample_scale": scale,
        "transport_direct": compact.direct,
        "transport_rank_1pct": compact.rank_for(0.01),
    })
    if recipe is not None:
        meta["recipe"] = rec_meta
    timings["landmarks"] = time.perf_counter() - t1
    return arrays, meta, geo, tri


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
