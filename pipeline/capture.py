"""``relight capture``: a phone video (or an RTI image set) -> reflectance bundle.

Video: :mod:`ingest` (one decoding pass) -> :mod:`samples` (flash separation, registration,
light directions, ambient-free samples) -> :mod:`geometry` -> :mod:`reflectance` (or a fitted
baseline from :mod:`methods`) -> :mod:`bundle`. An RTI image set (``dirs.lp``) enters at the
samples. Every stage is timed; what was dropped and why is counted.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from relight import __version__
from relight.colour import encode_srgb8, srgb_to_linear
from relight.errors import InputError, NumericalError
from relight.imageio import read_image
from relight.kernels import interpolation, reflectance, triangulation
from relight.kernels.bundle import BUNDLE_MODE, storage_scale, write_bundle
from relight.kernels.heightfield import HORIZON_DIRS
from relight.kernels.transport import STORE_TOLERANCE
from relight.numerics import EPS_VALUE, flush_subnormal_halves

from . import geometry, methods
from .ingest import DEFAULT_FACE_PIXELS, ingest
from .samples import SampleOptions, collect_samples

#: The head size (pixels) above which the horizon table (relight.kernels.heightfield.HORIZON_DIRS
#: directions) is computed at half resolution.
HALF_RES_PIXELS = 30000
#: Largest image set accepted (files) and the most landmarks stored.
MAX_IMAGES = 2000
MAX_LANDMARKS = 300

#: Transfer curves an image set's 8/16-bit files may be encoded with (``relight capture
#: --transfer``): sRGB (phones, cameras' JPEGs, most RTI sets) or linear (a camera's raw response,
#: e.g. the Extended Yale B faces). EXR/HDR files are always linear.
TRANSFERS = ("srgb", "linear")
#: An image set's room-light frame (no light of the set on): subtracted from every image and kept
#: as the bundle's ambient, as a video capture's no-flash frames are.
AMBIENT_NAMES = ("ambient.png", "ambient.exr", "ambient.tif", "ambient.tiff", "ambient.jpg")


@dataclass
class CaptureOptions:
    """Everything ``relight capture`` can be told (each stage switchable)."""

    method: str = "full"
    visibility: bool = True
    adaptation: bool = True
    extrapolation: bool = True
    paper_adaptation: bool = False
    spline: bool = True
    model_reach: float = reflectance.MODEL_REACH_DEG
    map_size: tuple[int, int] = triangulation.DEFAULT_MAP_SIZE
    samples: SampleOptions = field(default_factory=SampleOptions)
    face: tuple[int, int, int, int] | None = None
    mesh: str | None = None
    export_mesh: str | None = None
    backend: str = "opencl"
    transfer: str = "srgb"
    # --keep-maps: also the pixel-major copy of the maps (the texel-major ``maps_rows`` hold the
    # same values; the exact path gathers from them) and the flash samples (for re-fitting).
    keep_maps: bool = False
    face_pixels: int | None = DEFAULT_FACE_PIXELS
    # --store-tolerance: the finest relight tolerance the compact transport is stored for.
    store_tolerance: float = STORE_TOLERANCE

    def validate(self) -> CaptureOptions:
        methods.validate_method(self.method)
        if self.transfer not in TRANSFERS:
            raise InputError(f"--transfer {self.transfer}: use one of {', '.join(TRANSFERS)}")
        w, h = self.map_size
        if w != 2 * h or not (8 <= h <= 256):
            raise InputError(f"--map-size {w}x{h}: use a 2:1 size between 16x8 and 512x256, e.g. 64x32")
        if not (np.isfinite(self.model_reach) and 0.0 < self.model_reach <= 180.0):
            raise InputError(f"--model-reach {self.model_reach}: use degrees in (0, 180], e.g. 60")
        return self


@dataclass
class Prepared:
    """What the back half of the pipeline starts from (video and image sets alike)."""

    images: np.ndarray          # (K, h, w, 3) linear flash-only samples
    dirs: np.ndarray            # (K, 3)
    clipped: np.ndarray         # (K, h, w) bool
    ambient: np.ndarray         # (h, w, 3) linear
    background: np.ndarray      # (H, W, 3) uint8 sRGB full frame
    origin: tuple[int, int]
    frame_size: tuple[int, int]
    face_local: tuple[int, int, int, int] | None
    mask: np.ndarray | None     # given mask (crop coordinates) or None to estimate
    meta: dict = field(default_factory=dict)
    report: dict = field(default_factory=dict)


@dataclass
class CaptureResult:
    """What ``capture`` produced: the bundle path, report content, per-stage timings (s)."""

    bundle: Path
    report: dict
    timings: dict
    arrays: dict = field(repr=False, default_factory=dict)
    prepared: Prepared | None = field(repr=False, default=None)
    meta: dict = field(repr=False, default_factory=dict)


class Progress:
    """Progress of a capture: one tqdm bar per stage (or none when not ``enabled``)."""

    def __init__(self, enabled: bool):
        self.enabled = enabled
        self.bar = None
        self.name = None

    def __call__(self, name: str, done: int, total: int):
        if not self.enabled:
            return
        if self.name != name:
            self.close()
            self.bar = tqdm(total=total, desc=name, leave=False)
            self.name = name
        self.bar.n = done
        self.bar.refresh()

    def close(self):
        if self.bar is not None:
            self.bar.close()
            self.bar = None
            self.name = None


def prepare_video(path, opts: CaptureOptions, progress: Progress, timings: dict) -> Prepared:
    """Stages 1-3 on a capture video."""
    from relight.video import probe_video

    t0 = time.perf_counter()
    expected = probe_video(path).frame_count
    total = [0]

    def frame_cb(n):
        total[0] += n
        progress("decode", total[0], max(expected, total[0]))

    ing = ingest(path, face=opts.face, sphere_hint=opts.samples.sphere, progress=frame_cb,
                 face_pixels=opts.face_pixels)
    timings["ingest"] = time.perf_counter() - t0
    smp = collect_samples(ing, opts.samples, progress=progress)
    timings.update({f"samples_{k}": v for k, v in smp.timings.items()})
    x0, y0 = smp.origin
    face_local = None
    if ing.face_box is not None:
        fx, fy, fw, fh = ing.face_box
        face_local = (fx - x0, fy - y0, fw, fh)
    scale = {"capture_scale": ing.scale, "source_size": list(ing.source_size or ing.size)}
    report = {
        "flash_frames": [int(f) for f in smp.flash.flash_frames],
        "flash_peaks": [int(f) for f in smp.flash.peaks],
        "dark_frames": [int(f) for f in smp.flash.dark],
        "flash_hz": smp.flash.flash_hz,
        "flash_hz_estimated": smp.flash.estimated,
        "light_dirs": {str(f): [round(float(x), 6) for x in d] for f, d in smp.light_dirs.items()},
        "transforms": {str(f): [round(float(x), 5) for x in m] for f, m in smp.motions.items()},
        "transform_center": list(smp.motion_center),
        "reference_frame": smp.reference_frame,
        "rejected": dict(smp.rejected),
        "sphere": list(smp.circle) if smp.circle else None,
        "sphere_source": ing.sphere_source,
        "face_box": list(ing.face_box) if ing.face_box else None,
        "face_source": ing.face_source,
        "notes": list(ing.notes),
        "pulse_frames": smp.pulse_frames,
        "_trace": ing.face_trace().tolist(),
        "_level": smp.flash.level.tolist(),
        "_track_quality": {str(k): list(v) for k, v in smp.track_quality.items()},
        "fps": ing.fps,
        **scale,
    }
    background = ing.still
    return Prepared(images=smp.images, dirs=smp.dirs, clipped=smp.clipped, ambient=smp.ambient,
                    background=background, origin=smp.origin, frame_size=ing.size, face_local=face_local,
                    mask=None, meta={"source": str(path), "kind": "video", "fps": ing.fps, **scale}, report=report)


def read_lp(path: Path) -> list[tuple[str, np.ndarray]]:
    """Parse an RTI ``.lp`` file: first line N, then ``filename x y z`` per line."""
    try:
        text = path.read_text(encoding="utf-8", errors="strict")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read the light-position file ({exc})") from None
    if len(text) > 1 << 20:
        raise InputError(f"{path}: {len(text)} bytes is far too long for a light-position file")
    lines = [ln.strip() for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    if not lines:
        raise InputError(f"{path}: empty light-position file")
    try:
        n = int(lines[0].split()[0])
    except ValueError:
        raise InputError(f"{path}: the first line must be the number of images") from None
    if not (1 <= n <= MAX_IMAGES) or len(lines) - 1 < n:
        raise InputError(f"{path}: says {n} images but lists {len(lines) - 1}; fix the count (at most {MAX_IMAGES})")
    out = []
    for i, ln in enumerate(lines[1:n + 1], start=2):
        parts = ln.split()
        if len(parts) < 4:
            raise InputError(f"{path}:{i}: expected 'filename x y z', got {ln!r}")
        name = parts[0]
        if "/" in name or "\\" in name or name.startswith(".."):
            raise InputError(f"{path}:{i}: image names must be plain file names in the same folder, got {name!r}")
        try:
            d = np.array([float(v) for v in parts[1:4]])
        except ValueError:
            raise InputError(f"{path}:{i}: x y z must be numbers, got {parts[1:4]}") from None
        peak = float(np.max(np.abs(d))) if np.isfinite(d).all() else 0.0
        if peak == 0.0:
            raise InputError(f"{path}:{i}: light direction {parts[1:4]} is not a finite non-zero vector")
        d = d / peak  # first to about 1: the norm of 1e308-sized or subnormal entries stays finite
        out.append((name, d / np.linalg.norm(d)))
    return out


def read_set_image(f: Path, transfer: str) -> tuple[np.ndarray, np.ndarray]:
    """(linear (h, w, 3) float32, clipped (h, w) bool) of one image of an RTI set, its 8/16-bit
    code values decoded with ``transfer`` (:data:`TRANSFERS`; EXR/HDR are linear as stored)."""
    if f.suffix.lower() in (".exr", ".hdr"):
        img = read_image(f)
        return img, np.zeros(img.shape[:2], dtype=bool)
    raw = read_image(f, linearize=False)  # 0-1 code values, 8 or 16 bits
    clip = raw.max(axis=2) >= 250 / 255.0
    if transfer == "linear":
        return raw, clip
    return srgb_to_linear(raw), clip


def prepare_images(folder, opts: CaptureOptions, progress: Progress, timings: dict) -> Prepared:
    """An RTI image set: images + ``dirs.lp`` (+ optional ``mask.png``, ``ambient.png``) skip
    stages 1-3. Files are decoded with ``opts.transfer`` (EXR/HDR: linear); an ambient frame is
    subtracted from every image and becomes the bundle's ambient."""
    t0 = time.perf_counter()
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(f"{folder}: not a folder; --images takes a folder with images and dirs.lp")
    lps = sorted(folder.glob("*.lp"))
    if not lps:
        raise InputError(f"{folder}: no .lp light-position file (e.g. dirs.lp) found")
    entries = read_lp(lps[0])
    images, clipped, size = [], [], None
    for i, (name, _) in enumerate(entries):
        f = folder / name
        img, clip = read_set_image(f, opts.transfer)
        if size is None:
            size = img.shape[:2]
        elif img.shape[:2] != size:
            raise InputError(f"{f}: {img.shape[1]}x{img.shape[0]}, the others are {size[1]}x{size[0]}; "
                             "all images of a set must have one size")
        images.append(img.astype(np.float32))
        clipped.append(clip)
        progress("images", i + 1, len(entries))
    h, w = size
    mask = None
    mpath = folder / "mask.png"
    if mpath.exists():
        m = cv2.imread(str(mpath), cv2.IMREAD_UNCHANGED)
        if m is None or m.shape[:2] != (h, w):
            raise InputError(f"{mpath}: must be a {w}x{h} image (white = object)")
        if m.ndim == 3:
            m = m[..., 3] if m.shape[2] == 4 and m[..., 3].min() < 255 else m[..., :3].max(axis=2)
        mask = m > 127
    else:
        mask = np.ones((h, w), dtype=bool)
    notes = []
    ambient = np.zeros((h, w, 3), dtype=np.float32)
    listed = {name for name, _ in entries}
    amb_path = next((folder / n for n in AMBIENT_NAMES if (folder / n).exists() and n not in listed), None)
    if amb_path is not None:
        ambient, _ = read_set_image(amb_path, opts.transfer)
        if ambient.shape[:2] != (h, w):
            raise InputError(f"{amb_path}: {ambient.shape[1]}x{ambient.shape[0]}, the images are {w}x{h}; "
                             "the room-light frame must have their size (or remove it)")
        notes.append(f"{amb_path.name}: the room light, subtracted from every image")
    timings["read_images"] = time.perf_counter() - t0
    dirs = np.array([d for _, d in entries])
    stack = np.stack(images)
    if amb_path is not None:
        np.maximum(stack - ambient[None], 0.0, out=stack)
    background = encode_srgb8(np.clip(np.median(stack, axis=0) + ambient, 0.0, 1.0))
    report = {"light_dirs": {name: [round(float(x), 6) for x in d] for name, d in entries},
              "rejected": {}, "notes": notes, "images": len(entries), "transfer": opts.transfer}
    return Prepared(images=stack, dirs=dirs, clipped=np.stack(clipped), ambient=ambient.astype(np.float32),
                    background=background, origin=(0, 0), frame_size=(w, h), face_local=None, mask=mask,
                    meta={"source": str(folder), "kind": "images", "lp": lps[0].name, "transfer": opts.transfer},
                    report=report)


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
    from relight.kernels.bundle import encode_background

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


def reflectance_maps(samples: np.ndarray, normals: np.ndarray, tri, opts: CaptureOptions, horizon, *,
                     half: bool = True, progress=None, grid: np.ndarray | None = None, recipe_out: dict | None = None,
                     recipe_only: bool = False):
    """The maps stage of :func:`finish`: (maps (P, 3, T_pad) float16 (float32 unless ``half``),
    texels (T,) map texel ids, scale, stored samples (K, P, 3) float32).

    The samples are divided by ``scale``, a power of two (1 for ordinary captures; see
    :func:`relight.kernels.bundle.storage_scale`) so that maps and samples fit float16;
    the bundle records it as ``sample_scale`` and the renderer multiplies its light by it.
    ``horizon``: the pixels' horizon table for visibility (P, n_az), or (table, index) as
    :func:`horizon_rows` gives it, or None.

    Samples and horizons are quantised first, as the bundle stores them
    (:mod:`relight.kernels.recipe`), and everything is made from the stored values. With
    ``recipe_out`` (a dict) and the shading-model method, it receives the
    :class:`relight.kernels.recipe.Recipe` the maps can be made again from; with
    ``recipe_only`` too the maps are then not made here (None is returned for them: the caller
    makes them chunk by chunk, :func:`relight.kernels.recipe.recipe_maps`).
    """
    from relight.kernels import recipe as rcp

    if not np.isfinite(samples).all():
        raise InputError("light samples hold NaN or infinite values; check the input images")
    scale = storage_scale(samples)
    if scale != 1.0:
        samples = (samples / np.float32(scale)).astype(np.float32)
    codes, code_scale = rcp.encode_samples(samples)
    samples = rcp.decode_samples(codes, code_scale)
    horizon_index = None
    if isinstance(horizon, tuple):
        horizon, horizon_index = horizon
    horizon = rcp.quantise_horizon(horizon)
    horizon_table = horizon
    if horizon is not None and horizon_index is not None:
        horizon = horizon[horizon_index]  # a row per pixel for the fits and maps
    if opts.method in methods.FITTED:
        front = tri.texel_dirs[:, 2] > 0.0
        maps = methods.fit_and_evaluate(opts.method, tri.vertices[:tri.n_samples], samples, tri.texel_dirs[front])
        return maps, np.flatnonzero(front), scale, samples
    full = opts.method == "full"
    adapt = opts.adaptation and full
    trend = adapt and not opts.paper_adaptation
    if full and (trend or opts.extrapolation or opts.spline):
        sm, blend, active = reflectance.fit_model(samples, normals, tri, horizon, HORIZON_DIRS,
                                                  extrapolate=opts.extrapolation, spline=opts.spline, grid=grid,
                                                  reach_deg=opts.model_reach, backend=opts.backend)
        recipe = None
        if recipe_out is not None and not (adapt and not trend):  # the paper's adaptation: maps kept
            recipe = recipe_out["recipe"] = rcp.Recipe(
                codes=codes, scale=code_scale, normals=np.asarray(normals, np.float32), horizon=horizon_table,
                horizon_index=horizon_index,
                albedo=sm.albedo.astype(np.float32), spec=sm.spec.astype(np.float32),
                trust=sm.trust.astype(np.float32), blend=np.asarray(blend, np.float32), tri=tri,
                active=active, n_az=HORIZON_DIRS, trend=bool(trend), extrapolate=bool(opts.extrapolation),
                spline=bool(opts.spline))
        if recipe is not None and recipe_only:
            return None, np.flatnonzero(active), scale, samples
        maps, map_tri = reflectance.maps_from_fit(samples, normals, tri, horizon, HORIZON_DIRS, sm, blend, active,
                                                  trend=trend, extrapolate=opts.extrapolation,
                                                  paper_adaptation=adapt and not trend, spline=opts.spline,
                                                  backend=opts.backend, half=half, codes=(codes, code_scale),
                                                  progress=progress)
        return maps, np.flatnonzero(map_tri.active), scale, samples
    maps = interpolation.compute_maps(samples, normals, tri, horizon=horizon, n_az=HORIZON_DIRS, adaptation=adapt,
                                    backend=opts.backend, half=half, progress=progress)
    return maps, np.flatnonzero(tri.active), scale, samples


def texel_major(maps: np.ndarray, n_texels: int, chunk: int = 64) -> np.ndarray:
    """(T, 3, P) float16 copy of pixel-major maps (P, 3, T_pad), transposed in texel blocks."""
    p = maps.shape[0]
    out = np.empty((n_texels, 3, p), dtype=np.float16)
    for t0 in range(0, n_texels, chunk):
        t1 = min(t0 + chunk, n_texels)
        out[t0:t1] = np.asarray(maps[:, :, t0:t1], dtype=np.float16).transpose(2, 1, 0)
    return out


def horizon_for(depth: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """(P, HORIZON_DIRS) float32 horizon elevations (radians: the arctangent of the largest rise
    per pixel toward each direction) of the mask's pixels (row-major order).

    Large heads are done on a half-resolution height field (heights halved too, so slopes are
    unchanged): visibility varies slowly across a face and this is about 8x cheaper.
    """
    table, index = horizon_rows(depth, mask)
    return table if index is None else table[index]


def horizon_rows(depth: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """:func:`horizon_for` as (table (R, HORIZON_DIRS) float32, index (P,) int32 of each pixel's
    row, or None when there is a row per pixel): large heads share a row per 2x2 pixels (what a
    bundle stores: a quarter of the bytes)."""
    from relight.kernels.heightfield import NO_SURFACE, horizon_table

    pix = np.flatnonzero(mask)
    if pix.size <= HALF_RES_PIXELS:
        hgt = np.where(mask, depth, NO_SURFACE).astype(np.float32)
        return np.arctan(horizon_table(hgt, pix.astype(np.int32), HORIZON_DIRS)), None
    h, w = mask.shape
    h2, w2 = (h + 1) // 2, (w + 1) // 2
    m = np.zeros((h2 * 2, w2 * 2), dtype=np.float32)
    z = np.zeros_like(m)
    m[:h, :w] = mask
    z[:h, :w] = np.where(mask, depth, 0.0)
    cover = m.reshape(h2, 2, w2, 2).sum(axis=(1, 3))
    low = np.where(cover > 0, z.reshape(h2, 2, w2, 2).sum(axis=(1, 3)) / np.maximum(cover, 1) / 2.0, NO_SURFACE)
    low_pix = np.flatnonzero(cover > 0)
    table = horizon_table(low.astype(np.float32), low_pix.astype(np.int32), HORIZON_DIRS)
    row_of = -np.ones(h2 * w2, dtype=np.int64)
    row_of[low_pix] = np.arange(low_pix.size)
    ys, xs = pix // w, pix % w
    return np.arctan(table), row_of[(ys // 2) * w2 + xs // 2].astype(np.int32)


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


class StageTimings(dict):
    """Stage name -> seconds; each entry also notes the process's peak memory (RSS high-water
    mark, MB) when the stage ended, in :attr:`peak_mb` (which stage made the peak)."""

    def __init__(self):
        super().__init__()
        self.peak_mb: dict[str, float] = {}

    def __setitem__(self, key, value):
        super().__setitem__(key, value)
        _trim_heap()  # a stage's freed arrays back to the system before the next one allocates
        self.peak_mb[key] = _peak_rss_mb()

    def update(self, other=(), **kw):
        for k, v in dict(other, **kw).items():
            self[k] = v


def _trim_heap() -> None:
    """Return freed heap memory to the system (glibc's malloc_trim; elsewhere nothing). glibc
    raises its mmap threshold as large arrays are freed, so later mid-size arrays (a frame's
    crop, a chunk's temporaries) come from the heap, which it keeps resident after they are
    freed: on a 1080p capture that held ~0.5 GB nobody used into the next stages."""
    global _MALLOC_TRIM
    if _MALLOC_TRIM is None:
        try:
            import ctypes

            _MALLOC_TRIM = ctypes.CDLL(None).malloc_trim
        except (OSError, AttributeError):
            _MALLOC_TRIM = False
    if _MALLOC_TRIM:
        _MALLOC_TRIM(0)


_MALLOC_TRIM = None


def _peak_rss_mb() -> float:
    try:
        import resource
    except ImportError:  # not on Windows
        return float("nan")
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # kB on Linux


def expected_bundle_bytes(n_samples: int, n_pixels: int, opts: CaptureOptions) -> int:
    """A generous estimate of the bundle's size before it is made (the free-space check):
    per face pixel its sample codes (3 K bytes), horizon, fits and compact transport (~400
    bytes), with --keep-maps the maps twice in float16 (half the map's texels lit), a quarter
    more for what varies, and 1 MB of header and background."""
    per_pixel = 3 * n_samples + 400
    if opts.keep_maps:
        per_pixel += 2 * 3 * 2 * (opts.map_size[0] * opts.map_size[1] // 2) + 6 * n_samples
    return int(1.25 * per_pixel * n_pixels) + (1 << 20)


def capture(source, out, opts: CaptureOptions | None = None, *, images: bool = False, report_dir=None,
            progress: bool = True, file_mode: int = BUNDLE_MODE) -> CaptureResult:
    """Run the whole capture; write the bundle to ``out`` (and a report to ``report_dir``).

    ``file_mode``: the bundle's permission bits (default owner-only: it holds a face). The
    output's folder must have room for the bundle: checked once the samples are known, before
    the long part (maps, transport), and again with the bundle's exact size before writing."""
    from relight.imageio import check_free_space, check_writable

    opts = (opts or CaptureOptions()).validate()
    check_writable(out)
    timings = StageTimings()
    bar = Progress(progress)
    t_all = time.perf_counter()
    # BLAS and OpenCV with as many threads as the machine has, whatever the process set before (a
    # frame path limits them to one): BLAS's sums' order follows the thread count, and the same
    # input must give the same bundle bytes; OpenCV's pools make the capture's images faster.
    from threadpoolctl import threadpool_limits

    blas = threadpool_limits(limits=os.cpu_count() or 1, user_api="blas")
    cv_threads = cv2.getNumThreads()
    cv2.setNumThreads(-1)
    try:
        prep = prepare_images(source, opts, bar, timings) if images else prepare_video(source, opts, bar, timings)
        n_pix = int(prep.mask.sum()) if prep.mask is not None else int(np.prod(prep.images.shape[1:3]))
        check_free_space(out, expected_bundle_bytes(prep.images.shape[0], n_pix, opts), "the bundle")
        arrays, meta, geo, tri = finish(prep, opts, bar, timings)
        t0 = time.perf_counter()
        # (run facts - timings, peak memory - go to the report: the same input gives the same bundle)
        meta["rejected"] = prep.report.get("rejected", {})
        meta["stored"] = sorted(arrays)
        check_free_space(out, sum(np.asarray(a).nbytes for a in arrays.values()) + (1 << 20), "the bundle")
        path = write_bundle(out, meta, arrays, mode=file_mode)
        timings["write"] = time.perf_counter() - t0
    finally:
        bar.close()
        blas.restore_original_limits()
        cv2.setNumThreads(cv_threads)
    timings["total"] = time.perf_counter() - t_all
    report = {k: v for k, v in prep.report.items()}
    report["timings"] = {k: round(v, 3) for k, v in timings.items()}
    report["peak_rss_mb"] = {k: round(v, 1) for k, v in timings.peak_mb.items()}
    result = CaptureResult(bundle=path, report=report, timings=timings, arrays=arrays, prepared=prep, meta=meta)
    if report_dir is not None:
        from .report import write_report

        write_report(report_dir, result, geo, tri)
    return result
