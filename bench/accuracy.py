"""``relight bench accuracy``: every method on the same captures, against the synthetic truth
and real held-out photos, with run time beside the error - one report.

Methods ("variants"): the paper's pipeline with what we added (``full``), its ablations
(without visibility, without light adaptation, without both, without the shading-model lights
beyond the captured hull), the paper's step 1 alone
(``barycentric``) and the baselines people use for sparse-light relighting (``ptm``, ``hsh`` of
order 3, ``hsh2`` of order 2, ``rbf``). Each scene's video is prepared once (flash separation,
registration, light directions) and every variant builds its maps from the same samples and the
same geometry; each becomes a bundle rendered by the same engine (the exact path), so what is
compared is the representation only.

Metrics, per variant x scene x environment, inside the face mask (bundle mask and truth mask):

* environments (the truth renders of ``relight synth``): PSNR (peak = the truth's maximum) and
  SSIM (Wang et al. 2004, scikit-image, on both images divided by that peak and clipped to
  [0, 1], averaged over the mask) after one least-squares exposure gain. ``in hull``
  environments keep only light well inside a frontal capture's hull; ``whole sphere`` ones
  light the head from everywhere (the paper limits its error maps to the hull).
* one light at a time (the paper's Fig. 14): the truth rendered for each of the 32x16 lat-long
  light directions and the variant's prediction (``Relighter.relight_light``), one exposure
  gain per variant and scene over all of them. Reported: RMS error relative to the truth's RMS,
  over the whole sphere of directions and over the captured hull only, each direction weighted
  by its solid angle (sin of the polar angle); and per pixel as heat maps (PNG).
* real data nobody here made: ``../shared/data/rti-dome`` - bundles from Dome's 49 lights
  predict Test's 20 held-out photos through ``relight_light`` (what ``render --light`` runs);
  PSNR / SSIM in sRGB inside the mask, no gain fitted.
* run time: capture seconds (the shared preparation + the variant's own maps), bundle MB and
  relight ms (default compact path, median of calls with the head turning).
* numerical stability: :mod:`relight.bench.stability`.
"""

from __future__ import annotations

import copy
import json
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np

from .variants import BASELINES, VARIANTS

#: Synthetic scenes: they differ in seed, size, flash rate, sampling density, head motion and
#: camera drift.
SCENES = [
    {"name": "base 640x360", "width": 640, "height": 360, "duration": 30.0, "seed": 20},
    {"name": "sparse sides", "width": 640, "height": 360, "duration": 30.0, "seed": 21, "sparse_sides": True},
    {"name": "4 Hz, 2x motion", "width": 480, "height": 270, "duration": 30.0, "seed": 22, "flash_hz": 4.0,
     "head_motion": 2.0},
    {"name": "camera drift", "width": 640, "height": 360, "duration": 20.0, "seed": 23, "camera_drift": True},
    {"name": "12 s (sparse)", "width": 480, "height": 270, "duration": 12.0, "seed": 24},
    # The scanned head shipped with relight, under the base scene's settings (issue 31: both heads
    # side by side).
    {"name": "scan 640x360", "width": 640, "height": 360, "duration": 30.0, "seed": 20,
     "head_mesh": "builtin:lee-perry-smith"},
]
QUICK_SCENES = [
    {"name": "quick sparse sides", "width": 384, "height": 216, "duration": 8.0, "seed": 26, "sparse_sides": True},
]
#: Light directions of the one-light-at-a-time comparison (a lat-long grid) and truth batch size.
OLAT_GRID = (32, 16)
#: Relight calls timed per variant (median), after one warm-up.
TIMED_CALLS = 15
#: Real faces (``../shared/data/faces-yale``): every FACE_HOLDOUT-th light of a subject (0, 6, 12,
#: ... in dirs.lp order) is held out and predicted from the rest. The Extended Yale B photos are
#: camera-linear (the data's README): decoded as such, compared sRGB-encoded.
FACE_HOLDOUT = 6
FACES_TRANSFER = "linear"
QUICK_FACES = ("yaleB01",)
#: Goals on the real faces: ``full`` over the best other method (baselines and the nearest photo),
#: mean over the subjects and on every subject (dB).
FACE_GOAL_MEAN_DB = 2.0
FACE_GOAL_EACH_DB = 1.0
#: ``--quick`` builds these variants for its one subject (the others cost ~20 s each).
#: The default bundle (recipe, compact transport) against its exact maps: goals of issue 14.
DEFAULT_BUNDLE_DB = 0.1
DEFAULT_BUNDLE_KB = 1.0
QUICK_FACE_VARIANTS = ("full", "barycentric", "ptm", "hsh")


def _environments(out: Path) -> dict[str, tuple[str, str]]:
    """name -> (source, "in hull" | "whole sphere"); the frontal ones written to ``out``."""
    from relight.bench.relight import frontal_environment
    from relight.envmap import load_environment
    from relight.imageio import write_image

    out.mkdir(parents=True, exist_ok=True)
    envs = {}
    for name, src in (("front studio", "builtin:studio"), ("front sky", "builtin:sunset")):
        path = out / f"{name.replace(' ', '_')}.exr"
        if not path.exists():
            write_image(path, frontal_environment(load_environment(src)))
        envs[name] = (str(path), "in hull")
    envs["studio"] = ("builtin:studio", "whole sphere")
    envs["sunset"] = ("builtin:sunset", "whole sphere")
    return envs


def _synth(out: Path, scene: dict, envs: dict, progress: bool):
    from relight.pipeline.synth.studio import SynthConfig, cached_synthesis

    cfg = SynthConfig(**{k: v for k, v in scene.items() if k != "name"},
                      truth_envs=tuple(src for src, _ in envs.values()))
    return cfg, cached_synthesis(out, cfg, label=scene["name"], progress=progress)


def build_variants(source, out_dir: Path, *, images: bool = False, variants=None, progress: bool = False,
                   transfer: str = "srgb") -> dict:
    """Prepare ``source`` once (a capture video, or an RTI folder with ``images``, its files encoded
    with ``transfer``) and write one bundle per variant to ``out_dir``: name -> {"bundle",
    "capture_s", "prepare_s", "bundle_mb"}."""
    from relight.kernels.bundle import write_bundle
    from relight.pipeline.capture import CaptureOptions, Progress, finish, prepare_images, prepare_video

    variants = VARIANTS if variants is None else variants
    out_dir.mkdir(parents=True, exist_ok=True)
    bar = Progress(progress)
    timings: dict = {}
    t0 = time.perf_counter()
    prepare = prepare_images if images else prepare_video
    prep = prepare(source, CaptureOptions(transfer=transfer).validate(), bar, timings)
    prepare_s = time.perf_counter() - t0
    rows = {}
    try:
        for name, kw in variants.items():
            # The maps kept (the exact path starts at once); the default bundle, its recipe, is
            # measured from the same file (Bundle.default).
            opts = CaptureOptions(**(kw | {"keep_maps": True})).validate()
            mine = copy.copy(prep)
            mine.images = prep.images.copy()  # finish() releases the images it was given
            t1 = time.perf_counter()
            arrays, meta, _, _ = finish(mine, opts, bar, {})
            meta["rejected"] = prep.report.get("rejected", {})
            path = write_bundle(out_dir / f"{name.replace(' ', '_')}.bundle", meta, arrays)
            own = time.perf_counter() - t1
            rows[name] = {"bundle": str(path), "prepare_s": prepare_s, "capture_s": prepare_s + own,
                          "maps_s": own, "bundle_mb": path.stat().st_size / 1e6}
    finally:
        bar.close()
    return rows


def masked_ssim(pred: np.ndarray, truth: np.ndarray, mask: np.ndarray) -> float:
    """Mean SSIM inside ``mask`` of two (H, W, 3) images in [0, 1] (scikit-image, Gaussian window)."""
    from skimage.metrics import structural_similarity

    _, smap = structural_similarity(truth, pred, channel_axis=2, data_range=1.0, gaussian_weights=True,
                                    sigma=1.5, use_sample_covariance=False, full=True)
    return float(smap[mask].mean())


def env_metrics(pred: np.ndarray, truth: np.ndarray, mask: np.ndarray) -> dict:
    """PSNR (peak = the truth's maximum in the mask) and SSIM after one least-squares gain."""
    a = pred[mask].astype(np.float64)
    b = truth[mask].astype(np.float64)
    g = float((a * b).sum() / max(float((a * a).sum()), 1e-30))
    peak = max(float(b.max()), 1e-30)
    mse = float(((g * a - b) ** 2).mean())
    psnr = 10.0 * np.log10(peak * peak / max(mse, 1e-30))
    ssim = masked_ssim(np.clip(g * pred / peak, 0, 1), np.clip(truth / peak, 0, 1), mask)
    return {"psnr": float(psnr), "ssim": ssim, "gain": g}


def _olat_directions():
    from relight.directions import equirect_directions

    w, h = OLAT_GRID
    d = equirect_directions(w, h).reshape(-1, 3).astype(np.float64)
    weight = np.sqrt(np.clip(1.0 - d[:, 1] ** 2, 0.0, 1.0))  # solid angle of a lat-long texel ~ sin(polar)
    return d, weight


def olat_truth(cfg, dirs: np.ndarray, progress: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Truth (D, P, 3) of the synthetic head under each direction at the flash's power, at the
    reference pose, and the shaded pixels' flat frame indices (P,)."""
    from relight.kernels.shading import MAX_OUT
    from relight.pipeline.synth.studio import FLASH_STRENGTH, Studio

    studio = Studio(cfg)
    pix = studio.surface.pix
    out = np.zeros((dirs.shape[0], pix.size, 3), dtype=np.float32)
    for a in range(0, dirs.shape[0], MAX_OUT):
        d = dirs[a:a + MAX_OUT]
        power = np.zeros((d.shape[0], d.shape[0], 3), dtype=np.float32)
        power[np.arange(d.shape[0]), np.arange(d.shape[0])] = np.pi * FLASH_STRENGTH
        out[a:a + d.shape[0]] = studio.shader.shade(d, power)
    return out, pix


def olat_errors(relighter, truth: np.ndarray, pix: np.ndarray, keep: np.ndarray, dirs: np.ndarray,
                weight: np.ndarray, inside: np.ndarray) -> dict:
    """One gain over all directions; relative RMS error over the whole sphere and the hull, and
    per-pixel RMS error maps (P_keep,) for both."""
    flat_keep = np.flatnonzero(keep.ravel())
    sel = np.searchsorted(pix, flat_keep)
    t = truth[:, sel].astype(np.float64)  # (D, P', 3)
    p = np.empty_like(t)
    for j, d in enumerate(dirs):
        p[j] = np.asarray(relighter.relight_light(d)).reshape(-1, 3)[flat_keep]
    g = float((p * t).sum() / max(float((p * p).sum()), 1e-30))
    e = ((g * p - t) ** 2).sum(axis=2)  # (D, P')
    energy = (t ** 2).sum(axis=2)
    out = {"gain": g}
    for name, m in (("whole", np.ones_like(inside)), ("hull", inside)):
        w = weight * m
        wsum = max(float(w.sum()), 1e-30)
        num = float((w[:, None] * e).sum())
        den = max(float((w[:, None] * energy).sum()), 1e-30)
        out[f"rel_rmse_{name}"] = float(np.sqrt(num / den))
        out[f"pixel_rmse_{name}"] = np.sqrt((w[:, None] * e).sum(axis=0) / wsum).astype(np.float32)
    out["direction_rel_err"] = (np.sqrt(e.mean(axis=1)) / np.sqrt(max(float(energy.mean()), 1e-30))).astype(np.float32)
    return out


def relight_ms(relighter, env: np.ndarray) -> float:
    """Median ms of a default-path relight call, the head turning a little every call."""
    from relight.directions import rotation_matrix
    from relight.kernels.relighter import frozen

    env, out = frozen(env), np.zeros_like(relighter.frame)  # the hot path: no hashing, no new array
    relighter.relight(env, rotation_matrix(1.0, 0.0, 0.0), out=out)
    ts = []
    for i in range(TIMED_CALLS):
        r = rotation_matrix(4 * np.sin(i / 3), 2 * np.sin(i / 5), 0.0)
        t0 = time.perf_counter()
        relighter.relight(env, r, out=out)
        ts.append((time.perf_counter() - t0) * 1e3)
    return float(np.median(ts))


def evaluate_scene(cfg, cap: Path, bundles: dict, envs: dict, out: Path, name: str, progress: bool, *,
                   keep_bundles: bool = False) -> dict:
    import relight
    from relight.imageio import read_image
    from relight.kernels.triangulation import inside_hull

    meta = json.loads((cap / "truth" / "meta.json").read_text())
    truth_mask = read_image(cap / "truth" / "mask.png")[..., 0] > 0.5
    truths = {}
    for env_name, (src, _) in envs.items():
        stem = relight.envmap.environment_stem(src)
        truths[env_name] = read_image(cap / meta["files"]["relit"][stem])
    env_arrays = {k: relight.load_environment(src) for k, (src, _) in envs.items()}
    dirs, weight = _olat_directions()
    if progress:
        print(f"  truth under {dirs.shape[0]} single lights ...", flush=True)
    o_truth, o_pix = olat_truth(cfg, dirs)
    rows, heat = {}, {}
    for variant, info in bundles.items():
        b = relight.load_bundle(info["bundle"])
        mask = np.asarray(b.mask) & truth_mask
        exact = relight.Relighter(b, exact=True)
        per_env = {}
        for env_name, env in env_arrays.items():
            pred = exact.relight(env)
            per_env[env_name] = env_metrics(pred, truths[env_name], mask) | {"kind": envs[env_name][1]}
        keep = mask.copy()
        keep.ravel()[np.setdiff1d(np.flatnonzero(keep.ravel()), o_pix)] = False
        inside = inside_hull(np.asarray(b.light_dirs, dtype=np.float64), dirs)
        ol = olat_errors(exact, o_truth, o_pix, keep, dirs, weight, inside)
        heat[variant] = (keep, ol.pop("pixel_rmse_whole"), ol.pop("pixel_rmse_hull"))
        ol["direction_rel_err"] = ol["direction_rel_err"].tolist()
        compact = relight.Relighter(b.default() if b.recipe_stored else b)
        default_envs = {}
        if b.recipe_stored:  # the default bundle's relight (its recipe's texels, the 8-bit basis)
            for env_name, env in env_arrays.items():
                default_envs[env_name] = env_metrics(compact.relight(env), truths[env_name], mask)["psnr"]
        rows[variant] = {"envs": per_env, "olat": ol, "relight_ms": relight_ms(compact, env_arrays["studio"]),
                         "default_psnr": default_envs, "default_kb_per_px": _kb_per_px(b),
                         "rank": int(compact.rank) if getattr(compact, "rank", None) is not None else None,
                         "samples": int(b.light_dirs.shape[0]), "pixels": int(b.pixels.size),
                         "hull_share": float((weight * inside).sum() / weight.sum())} | \
            {k: info[k] for k in ("capture_s", "prepare_s", "maps_s", "bundle_mb")}
        del exact, compact, b
        if not keep_bundles:
            Path(info["bundle"]).unlink()  # the size is recorded; 45 bundles would fill the disk
    heat_png = out / f"heat_{_slug(name)}.png"
    _heat_maps(heat, heat_png, name)
    return {"name": name, "config": asdict(cfg), "variants": rows, "heat_map": heat_png.name}


def _slug(s: str) -> str:
    return "".join(c if c.isalnum() else "_" for c in s).strip("_").lower()


def _heat_maps(heat: dict, path: Path, title: str) -> None:
    """One column per variant, two rows: per-pixel RMS error over the whole sphere of light
    directions and over the captured hull; each row on one colour scale shared by all variants
    (so they compare), black = 0, white = that row's 99th percentile over all variants."""
    import cv2

    from relight.imageio import write_image

    names = list(heat)
    keep0 = heat[names[0]][0]
    ys, xs = np.nonzero(keep0)
    y0, y1, x0, x1 = ys.min(), ys.max() + 1, xs.min(), xs.max() + 1
    scale = [max(float(np.percentile(heat[n][c], 99)) for n in names) or 1.0 for c in (1, 2)]
    tile_h = 220
    tw = int(round(tile_h * (x1 - x0) / max(y1 - y0, 1)))
    label_h, side_w = 22, 96
    cols = []
    for n in names:
        keep, *maps = heat[n]
        label = np.full((label_h, tw, 3), 255, np.uint8)
        cv2.putText(label, n[:22], (3, 15), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
        tiles = [label]
        for c, m in enumerate(maps):
            img = np.zeros(keep.shape, np.float32)
            img[keep] = m / scale[c]
            col = cv2.applyColorMap(np.clip(img * 255, 0, 255).astype(np.uint8), cv2.COLORMAP_INFERNO)
            col[~keep] = 255
            tiles.append(cv2.resize(col[y0:y1, x0:x1], (tw, tile_h), interpolation=cv2.INTER_AREA)[..., ::-1])
        cols.append(np.concatenate(tiles, axis=0))
    side = np.full((label_h + 2 * tile_h, side_w, 3), 255, np.uint8)
    for r, text in enumerate(("whole", "hull")):
        cv2.putText(side, text, (4, label_h + r * tile_h + tile_h // 2), cv2.FONT_HERSHEY_SIMPLEX, 0.5,
                    (0, 0, 0), 1, cv2.LINE_AA)
    body = np.concatenate([side, *cols], axis=1)
    head = np.full((26, body.shape[1], 3), 255, np.uint8)
    cv2.putText(head, f"{title}: per-pixel RMS error, single lights (top: whole sphere, bottom: captured hull)",
                (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    write_image(path, np.concatenate([head, body], axis=0))


def scaled_rti(folder: Path, out: Path, factor: int) -> Path:
    """A copy of an RTI image set (images, dirs.lp, mask.png, ambient) shrunk by ``factor`` (area
    average)."""
    import cv2

    from relight.pipeline.capture import AMBIENT_NAMES, read_lp

    out.mkdir(parents=True, exist_ok=True)
    names = [n for n, _ in read_lp(folder / "dirs.lp")]
    for name in [*names, "mask.png", *AMBIENT_NAMES]:
        src = folder / name
        if not src.exists():
            continue
        img = cv2.imread(str(src), cv2.IMREAD_UNCHANGED)
        if img is None:
            raise ValueError(f"{src}: not an image OpenCV reads")
        h, w = img.shape[:2]
        small = cv2.resize(img, (w // factor, h // factor), interpolation=cv2.INTER_AREA)
        jpeg = src.suffix.lower() in (".jpg", ".jpeg")
        cv2.imwrite(str(out / name), small, [cv2.IMWRITE_JPEG_QUALITY, 98] if jpeg else [])
    (out / "dirs.lp").write_text((folder / "dirs.lp").read_text())
    return out


def evaluate_dome(dome: Path, test: Path, out: Path, progress: bool, *, scale: int = 1) -> dict:
    """Bundles from Dome's lights predict Test's held-out photos (sRGB, no gain). ``scale`` > 1
    shrinks both sets first (``--quick``: the full set makes 1.1 GB bundles)."""
    import relight
    from relight.colour import linear_to_srgb
    from relight.imageio import read_image
    from relight.pipeline.capture import read_lp

    if scale > 1:
        dome = scaled_rti(dome, out / "dome-small" / "Dome", scale)
        test = scaled_rti(test, out / "dome-small" / "Test", scale)
    bundles = build_variants(dome, out / "bundles" / "dome", images=True, progress=progress)
    lights_in = len(read_lp(dome / "dirs.lp"))
    held = [(d, read_image(test / name, linearize=False)[..., :3].astype(np.float32))
            for name, d in read_lp(test / "dirs.lp")]
    rows = {}
    for variant, info in bundles.items():
        b = relight.load_bundle(info["bundle"])
        rl = relight.Relighter(b, exact=True)
        dflt = relight.Relighter(b.default()) if b.recipe_stored else None
        mask = np.asarray(b.mask)
        ps, ss, pd = [], [], []
        for d, photo in held:
            pred = np.clip(linear_to_srgb(np.clip(np.array(rl.relight_light(d)), 0, None)), 0, 1)
            ps.append(_psnr(pred[mask], photo[mask]))
            ss.append(masked_ssim(pred, photo, mask))
            if dflt is not None:
                pred = np.clip(linear_to_srgb(np.clip(np.array(dflt.relight_light(d)), 0, None)), 0, 1)
                pd.append(_psnr(pred[mask], photo[mask]))
        rows[variant] = {"psnr": float(np.mean(ps)), "ssim": float(np.mean(ss)), "psnr_per_light": ps,
                         "default_psnr": float(np.mean(pd)) if pd else None, "default_kb_per_px": _kb_per_px(b)} | \
            {k: info[k] for k in ("capture_s", "maps_s", "bundle_mb")}
        del rl, dflt, b
        Path(info["bundle"]).unlink()  # ~1 GB each at full size; the size is recorded
    h, w = held[0][1].shape[:2]  # both sets share one size (a bundle renders the Dome frame)
    return {"lights_in": lights_in, "held_out": len(held), "variants": rows, "image_size": [w, h], "scale": scale}


def split_rti(folder: Path, out: Path, every: int = FACE_HOLDOUT) -> list[tuple[str, np.ndarray]]:
    """Write ``out``: an RTI set of ``folder``'s images without every ``every``-th light (0, every,
    2 every, ... in ``dirs.lp`` order; links to the files, its ``ambient.*`` and ``mask.png`` too).
    Returns the held-out (name, direction) pairs."""
    import os

    from relight.pipeline.capture import AMBIENT_NAMES, read_lp

    entries = read_lp(folder / "dirs.lp")
    held = [e for i, e in enumerate(entries) if i % every == 0]
    train = [e for i, e in enumerate(entries) if i % every != 0]
    out.mkdir(parents=True, exist_ok=True)
    for name in [n for n, _ in train] + ["mask.png", *AMBIENT_NAMES]:
        src, dst = folder / name, out / name
        if src.exists() and not dst.exists():
            os.symlink(src.resolve(), dst)
    (out / "dirs.lp").write_text(f"{len(train)}\n" + "".join(f"{n} {d[0]:.6f} {d[1]:.6f} {d[2]:.6f}\n"
                                                              for n, d in train))
    return held


def _kb_per_px(b) -> float | None:
    """KB per face pixel of the bundle as written by default (its recipe, no maps), or None."""
    return b.default_nbytes / 1e3 / max(b.n_pixels, 1) if b.recipe_stored else None


def _psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(((a.astype(np.float64) - b) ** 2).mean())
    return float(10.0 * np.log10(1.0 / max(mse, 1e-30)))


def evaluate_face(folder: Path, out: Path, progress: bool, *, variants=None, transfer: str = FACES_TRANSFER) -> dict:
    """A real face's held-out photos predicted by every variant and by the nearest captured photo.

    Every ``FACE_HOLDOUT``-th light of ``folder`` (an RTI set) is held out, the rest build the
    bundles; each held-out photo is predicted by ``relight_light`` (what ``render --light`` runs)
    plus the set's room-light frame (``render --ambient``), and both are compared sRGB-encoded
    (0-1, no gain) over the face (``mask.png``, else the whole crop): PSNR and SSIM."""
    import relight
    from relight.colour import linear_to_srgb
    from relight.pipeline.capture import read_lp, read_set_image

    train = out / "train" / folder.name
    held = split_rti(folder, train)
    bundles = build_variants(train, out / "bundles" / folder.name, images=True, variants=variants,
                             progress=progress, transfer=transfer)
    photos = [(d, linear_to_srgb(read_set_image(folder / name, transfer)[0])) for name, d in held]
    shots = [(d, read_set_image(folder / name, transfer)[0]) for name, d in read_lp(train / "dirs.lp")]
    rows: dict = {}
    mask = None
    for variant, info in bundles.items():
        b = relight.load_bundle(info["bundle"])
        rl = relight.Relighter(b, exact=True)
        dflt = relight.Relighter(b.default()) if b.recipe_stored else None
        mask = np.asarray(b.mask)
        room = b.ambient_frame()
        ps, ss, pd = [], [], []
        for d, photo in photos:
            pred = np.clip(linear_to_srgb(np.clip(np.array(rl.relight_light(d)) + room, 0, None)), 0, 1)
            ps.append(_psnr(pred[mask], photo[mask]))
            ss.append(masked_ssim(pred, photo, mask))
            if dflt is not None:
                pred = np.clip(linear_to_srgb(np.clip(np.array(dflt.relight_light(d)) + room, 0, None)), 0, 1)
                pd.append(_psnr(pred[mask], photo[mask]))
        rows[variant] = {"psnr": float(np.mean(ps)), "ssim": float(np.mean(ss)), "psnr_per_light": ps,
                         "default_psnr": float(np.mean(pd)) if pd else None, "default_kb_per_px": _kb_per_px(b)} | \
            {k: info[k] for k in ("capture_s", "maps_s", "bundle_mb")}
        del rl, dflt, b
        Path(info["bundle"]).unlink()
    ps, ss = [], []
    for d, photo in photos:  # the nearest captured photo, as it is
        near = linear_to_srgb(shots[int(np.argmax([float(np.dot(d, t)) for t, _ in shots]))][1])
        ps.append(_psnr(near[mask], photo[mask]))
        ss.append(masked_ssim(near, photo, mask))
    rows["nearest"] = {"psnr": float(np.mean(ps)), "ssim": float(np.mean(ss)), "psnr_per_light": ps,
                       "capture_s": 0.0, "maps_s": 0.0, "bundle_mb": 0.0}
    others = [n for n in (*BASELINES, "nearest") if n in rows]
    best = max(others, key=lambda n: rows[n]["psnr"])
    return {"subject": folder.name, "lights_in": len(shots), "held_out": [n for n, _ in held],
            "held_out_dirs": [[round(float(x), 6) for x in d] for _, d in held], "transfer": transfer,
            "image_size": [int(mask.shape[1]), int(mask.shape[0])], "variants": rows, "best_other": best,
            "margin_db": rows["full"]["psnr"] - rows[best]["psnr"] if "full" in rows else None}


def _mean(xs) -> float | None:
    xs = [x for x in xs if x is not None and np.isfinite(x)]
    return float(np.mean(xs)) if xs else None


def summarise(doc: dict) -> dict:
    """Per variant: mean PSNR / SSIM over scenes x environments (in hull, whole sphere), OLAT
    relative errors, Dome PSNR / SSIM, and run time; plus the goal check (full vs each baseline)."""
    names = list(VARIANTS)
    out = {}
    for v in names:
        rows = [s["variants"][v] for s in doc["scenes"] if v in s["variants"]]
        r = {}
        for kind in ("in hull", "whole sphere"):
            envs = [e for row in rows for e in row["envs"].values() if e["kind"] == kind]
            r[f"psnr {kind}"] = _mean(e["psnr"] for e in envs)
            r[f"ssim {kind}"] = _mean(e["ssim"] for e in envs)
        r["psnr all"] = _mean(e["psnr"] for row in rows for e in row["envs"].values())
        r["olat whole"] = _mean(row["olat"]["rel_rmse_whole"] for row in rows)
        r["olat hull"] = _mean(row["olat"]["rel_rmse_hull"] for row in rows)
        r["capture s"] = _mean(row["capture_s"] for row in rows)
        r["maps s"] = _mean(row["maps_s"] for row in rows)
        r["bundle MB"] = _mean(row["bundle_mb"] for row in rows)
        r["relight ms"] = _mean(row["relight_ms"] for row in rows)
        dome = (doc.get("dome") or {}).get("variants", {}).get(v)
        r["dome psnr"] = dome["psnr"] if dome else None
        r["dome ssim"] = dome["ssim"] if dome else None
        out[v] = r
    goal = {}
    for key in ("psnr all", "dome psnr"):
        full = out["full"][key]
        best = max(((out[b][key], b) for b in BASELINES if out[b][key] is not None), default=(None, None))
        goal[key] = {"full": full, "best_baseline": best[1], "best_baseline_value": best[0],
                     "margin_db": None if full is None or best[0] is None else full - best[0]}
    return {"variants": out, "goal": goal, "default_bundle": default_bundle(doc)}


def default_bundle(doc: dict) -> dict:
    """The ``full`` variant as ``relight capture`` writes it by default (its maps' recipe, the
    8/4-bit compact transport) against its exact maps: mean PSNR of both per source (synthetic
    scenes x environments, Dome, each real face), the difference (goal: within
    ``DEFAULT_BUNDLE_DB``) and its size per face pixel (goal: <= ``DEFAULT_BUNDLE_KB``)."""
    rows = []
    for sc in doc.get("scenes", []):
        v = sc["variants"].get("full")
        if v and v.get("default_psnr"):
            exact = _mean(v["envs"][k]["psnr"] for k in v["default_psnr"])
            rows.append({"source": f"synthetic {sc['name']}", "exact": exact,
                         "default": _mean(v["default_psnr"].values()), "kb_per_px": v.get("default_kb_per_px")})
    dome = (doc.get("dome") or {}).get("variants", {}).get("full")
    if dome and dome.get("default_psnr") is not None:
        rows.append({"source": "rti-dome", "exact": dome["psnr"], "default": dome["default_psnr"],
                     "kb_per_px": dome.get("default_kb_per_px")})
    for f in doc.get("faces") or []:
        v = f["variants"].get("full")
        if v and v.get("default_psnr") is not None:
            rows.append({"source": f"face {f['subject']}", "exact": v["psnr"], "default": v["default_psnr"],
                         "kb_per_px": v.get("default_kb_per_px")})
    for r in rows:
        r["difference_db"] = None if r["exact"] is None or r["default"] is None else r["default"] - r["exact"]
    diffs = [abs(r["difference_db"]) for r in rows if r["difference_db"] is not None]
    kbs = [r["kb_per_px"] for r in rows if r["kb_per_px"] is not None]
    return {"rows": rows, "worst_difference_db": max(diffs) if diffs else None,
            "largest_kb_per_px": max(kbs) if kbs else None,
            "goal_met": bool(diffs) and max(diffs) <= DEFAULT_BUNDLE_DB and bool(kbs) and max(kbs) <= DEFAULT_BUNDLE_KB}


def face_subjects(faces: Path | None) -> list[Path]:
    """The subject folders (each an RTI set with ``dirs.lp``) of a faces folder, sorted."""
    if faces is None or not Path(faces).is_dir():
        return []
    return sorted(p for p in Path(faces).iterdir() if (p / "dirs.lp").exists())


def summarise_faces(faces: list[dict]) -> dict | None:
    """Per variant the mean PSNR / SSIM over the subjects; the goal check (full against the best
    other method, mean and per subject)."""
    if not faces:
        return None
    names = list(faces[0]["variants"])
    mean = {n: {"psnr": _mean(f["variants"][n]["psnr"] for f in faces),
                "ssim": _mean(f["variants"][n]["ssim"] for f in faces)} for n in names}
    margins = {f["subject"]: f["margin_db"] for f in faces}
    m = _mean(margins.values())
    return {"variants": mean, "margins_db": margins, "mean_margin_db": m,
            "goal_met": m is not None and m >= FACE_GOAL_MEAN_DB and
            all(v is not None and v >= FACE_GOAL_EACH_DB for v in margins.values())}


def run(out: Path, quick: bool = False, progress: bool = True, rti: Path | None = None,
        faces: Path | None = None) -> dict:
    """The whole benchmark; writes ``out/bench.json``, ``out/report.md`` and PNG plots.

    rti : a folder with ``Dome/`` (the lights a bundle is built from) and ``Test/`` (held-out
    photos), each an RTI image set with ``dirs.lp``; None or missing skips the real-data part.
    faces : a folder of real faces, one RTI set per subject (``../shared/data/faces-yale``);
    ``quick`` takes ``QUICK_FACES`` of them with ``QUICK_FACE_VARIANTS``.
    """
    from relight.bench.stability import run_stability

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    t_all = time.perf_counter()
    envs = _environments(out / "envs")
    scenes = []
    for scene in QUICK_SCENES if quick else SCENES:
        cfg, cap = _synth(out / "cache", scene, envs, progress)
        if progress:
            print(f"capturing {scene['name']} with {len(VARIANTS)} variants ...", flush=True)
        bundles = build_variants(cap / "capture.mp4", out / "bundles" / _slug(scene["name"]), progress=progress)
        if progress:
            print(f"evaluating {scene['name']} ...", flush=True)
        scenes.append(evaluate_scene(cfg, cap, bundles, envs, out, scene["name"], progress))
    dome = None
    if rti is not None and (rti / "Dome" / "dirs.lp").exists() and (rti / "Test" / "dirs.lp").exists():
        if progress:
            print(f"real held-out photos ({rti}) ...", flush=True)
        dome = evaluate_dome(rti / "Dome", rti / "Test", out, progress, scale=2 if quick else 1)
    face_rows = []
    subjects = face_subjects(faces)
    if quick:
        subjects = [p for p in subjects if p.name in QUICK_FACES]
    for subject in subjects:
        if progress:
            print(f"real face {subject.name} ...", flush=True)
        face_rows.append(evaluate_face(subject, out / "faces", progress,
                                       variants={k: VARIANTS[k] for k in QUICK_FACE_VARIANTS} if quick else None))
    if progress:
        print("numerical stability suite ...", flush=True)
    stability = run_stability()
    doc = {"quick": quick, "envs": {k: {"source": s, "kind": kind} for k, (s, kind) in envs.items()},
           "scenes": scenes, "dome": dome,
           "dome_skipped": None if dome else f"no RTI set with Dome/ and Test/ at {rti}",
           "faces": face_rows, "faces_summary": summarise_faces(face_rows),
           "faces_skipped": None if face_rows else f"no subject folders with dirs.lp at {faces}",
           "stability": stability, "olat_grid": list(OLAT_GRID)}
    doc["summary"] = summarise(doc)
    doc["seconds"] = time.perf_counter() - t_all
    _write_json(out / "bench.json", doc)
    _pareto_plot(doc, out / "error_vs_time.png")
    (out / "report.md").write_text(report_markdown(doc))
    return doc


def _write_json(path: Path, doc: dict) -> None:
    from relight.imageio import atomic_path

    with atomic_path(path) as tmp:
        Path(tmp).write_text(json.dumps(doc, indent=1))


def _pareto_plot(doc: dict, path: Path) -> None:
    """Mean PSNR against capture time and relight time, one point per variant, the Pareto
    front (no variant both faster and more accurate) joined."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    s = doc["summary"]["variants"]
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.6))
    panels = [("capture s", "psnr all", "capture time (s, mean over scenes)", "mean PSNR, synth (dB)"),
              ("relight ms", "psnr all", "relight call (ms, default compact path)", "mean PSNR, synth (dB)"),
              ("capture s", "dome psnr", "capture time (s, Dome set)", "PSNR on held-out photos (dB)")]
    for ax, (xk, yk, xl, yl) in zip(axes, panels, strict=True):
        pts = [(v[xk], v[yk], n) for n, v in s.items() if v[xk] is not None and v[yk] is not None]
        if yk == "dome psnr" and doc.get("dome"):
            pts = [(doc["dome"]["variants"][n]["capture_s"], y, n) for _, y, n in pts]
        for x, y, n in pts:
            ax.scatter(x, y, color="C3" if n.startswith("full") else "C0", zorder=3)
            ax.annotate(n, (x, y), textcoords="offset points", xytext=(4, 3), fontsize=8)
        front = sorted([p for p in pts if not any(q[0] <= p[0] and q[1] > p[1] or q[0] < p[0] and q[1] >= p[1]
                                                   for q in pts)])
        if front:
            ax.plot([p[0] for p in front], [p[1] for p in front], "--", color="grey", lw=1)
        ax.set_xlabel(xl)
        ax.set_ylabel(yl)
        ax.grid(alpha=0.3)
    fig.suptitle("error against run time (up and left is better; dashed: Pareto front)")
    fig.tight_layout()
    from relight.imageio import atomic_path

    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)


def _f(v, fmt="{:.2f}") -> str:
    return "-" if v is None else fmt.format(v)


def report_markdown(doc: dict) -> str:
    s = doc["summary"]
    names = list(VARIANTS)
    lines = ["# Accuracy report (`relight bench accuracy`" + (" --quick" if doc["quick"] else "") + ")", ""]
    g = s["goal"]
    lines += ["## Goal: `full` >= 1 dB over every baseline", ""]
    for key, label in (("psnr all", "synthetic scenes, mean PSNR over scenes x environments"),
                       ("dome psnr", "real held-out photos (rti-dome Test), mean PSNR")):
        r = g[key]
        if r["full"] is None:
            lines.append(f"* {label}: not measured ({doc.get('dome_skipped')})")
        else:
            ok = r["margin_db"] is not None and r["margin_db"] >= 1.0
            lines.append(f"* {label}: full {r['full']:.2f} dB, best baseline {r['best_baseline']} "
                         f"{r['best_baseline_value']:.2f} dB, margin {r['margin_db']:+.2f} dB - "
                         + ("met" if ok else "**not met**"))
    lines += ["", "## Headline", "",
              "PSNR / SSIM after one exposure gain inside the face mask, mean over scenes; OLAT: RMS error of "
              "single-light renders relative to the truth's RMS (solid-angle weighted), whole sphere / captured "
              "hull; Dome: 20 real held-out photos, sRGB, no gain; time: capture (shared preparation + the "
              "variant's maps), relight call (default compact path).", "",
              "| variant | PSNR in hull | PSNR whole sphere | SSIM in hull | SSIM whole | OLAT err whole | "
              "OLAT err hull | Dome PSNR | Dome SSIM | capture s | maps s | bundle MB | relight ms |",
              "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for n in names:
        v = s["variants"][n]
        lines.append(f"| {n} | {_f(v['psnr in hull'])} | {_f(v['psnr whole sphere'])} | "
                     f"{_f(v['ssim in hull'], '{:.4f}')} | {_f(v['ssim whole sphere'], '{:.4f}')} | "
                     f"{_f(v['olat whole'], '{:.3f}')} | {_f(v['olat hull'], '{:.3f}')} | {_f(v['dome psnr'])} | "
                     f"{_f(v['dome ssim'], '{:.4f}')} | {_f(v['capture s'], '{:.1f}')} | {_f(v['maps s'], '{:.2f}')} | "
                     f"{_f(v['bundle MB'], '{:.1f}')} | {_f(v['relight ms'])} |")
    db = s.get("default_bundle") or {}
    if db.get("rows"):
        lines += ["", f"## The default bundle: recipe + 8/4-bit compact transport against the exact maps (goal: "
                  f"within {DEFAULT_BUNDLE_DB} dB, <= {DEFAULT_BUNDLE_KB:g} KB per face pixel)", "",
                  "`full` relit from the bundle `relight capture` writes by default (the maps' recipe: texels "
                  "made on demand, the compact transport at the default tolerance) and from its exact maps "
                  "(`--keep-maps`, `--exact`); mean PSNR as in the tables below.", "",
                  "| source | exact maps dB | default bundle dB | difference dB | KB per face pixel |",
                  "|---|---|---|---|---|"]
        for r in db["rows"]:
            lines.append(f"| {r['source']} | {_f(r['exact'])} | {_f(r['default'])} | "
                         f"{_f(r['difference_db'], '{:+.3f}')} | {_f(r['kb_per_px'], '{:.3f}')} |")
        lines.append("")
        lines.append(f"Worst difference {_f(db['worst_difference_db'], '{:.3f}')} dB, largest bundle "
                     f"{_f(db['largest_kb_per_px'], '{:.3f}')} KB per face pixel: goal "
                     + ("met" if db["goal_met"] else "**not met**") + ".")
    lines += ["", "![error against run time](error_vs_time.png)", "",
              "## Method x scene (PSNR dB: in hull / whole sphere)", ""]
    lines.append("| variant | " + " | ".join(sc["name"] for sc in doc["scenes"]) + " |")
    lines.append("|---|" + "---|" * len(doc["scenes"]))
    for n in names:
        cells = []
        for sc in doc["scenes"]:
            e = sc["variants"][n]["envs"]
            ih = _mean(x["psnr"] for x in e.values() if x["kind"] == "in hull")
            ws = _mean(x["psnr"] for x in e.values() if x["kind"] == "whole sphere")
            cells.append(f"{_f(ih)} / {_f(ws)}")
        lines.append(f"| {n} | " + " | ".join(cells) + " |")
    lines += ["", "Scenes:", ""]
    for sc in doc["scenes"]:
        c = sc["config"]
        v = sc["variants"]["full"]
        lines.append(f"* {sc['name']}: {c['width']}x{c['height']}, {c['duration']:g} s, seed {c['seed']}, flash "
                     f"{c['flash_hz']:g} Hz, head motion x{c['head_motion']:g}, camera drift {c['camera_drift']}, "
                     f"sparse sides {c.get('sparse_sides', False)}; {v['samples']} light samples, {v['pixels']} face "
                     f"pixels, hull {100 * v['hull_share']:.0f} % of the sphere")
    lines += ["", "Environments: " + ", ".join(f"{k} ({e['kind']})" for k, e in doc["envs"].items()), ""]
    lines += ["## Per-environment PSNR / SSIM (mean over scenes)", "",
              "| variant | " + " | ".join(doc["envs"]) + " |", "|---|" + "---|" * len(doc["envs"])]
    for n in names:
        cells = []
        for k in doc["envs"]:
            ps = _mean(sc["variants"][n]["envs"][k]["psnr"] for sc in doc["scenes"])
            ss = _mean(sc["variants"][n]["envs"][k]["ssim"] for sc in doc["scenes"])
            cells.append(f"{_f(ps)} / {_f(ss, '{:.3f}')}")
        lines.append(f"| {n} | " + " | ".join(cells) + " |")
    if doc.get("dome"):
        d = doc["dome"]
        lines += ["", f"## Real held-out photos: rti-dome ({d['lights_in']} lights in, {d['held_out']} held out, "
                  f"{d['image_size'][0]}x{d['image_size'][1]} px"
                  + (" - shrunk for --quick)" if d["scale"] > 1 else ")"),
                  "", "| variant | PSNR (dB) | SSIM | worst light PSNR | capture s | bundle MB |",
                  "|---|---|---|---|---|---|"]
        for n in names:
            r = d["variants"][n]
            lines.append(f"| {n} | {r['psnr']:.2f} | {r['ssim']:.4f} | {min(r['psnr_per_light']):.2f} | "
                         f"{r['capture_s']:.1f} | {r['bundle_mb']:.1f} |")
    if doc.get("faces"):
        fs = doc["faces_summary"]
        f0 = doc["faces"][0]
        names_f = list(f0["variants"])
        lines += ["", f"## Real faces: {len(doc['faces'])} subject(s), every {FACE_HOLDOUT}th light held out", "",
                  f"Each subject's photos ({f0['image_size'][0]}x{f0['image_size'][1]}, decoded as "
                  f"{f0['transfer']}) minus the held-out lights build the bundles; each held-out photo is "
                  "predicted by `render --light` plus the set's room-light frame; PSNR / SSIM sRGB-encoded over "
                  "the face, no gain. `nearest`: the captured photo whose light is closest.", "",
                  "| variant | " + " | ".join(f["subject"] for f in doc["faces"]) + " | mean PSNR | mean SSIM |",
                  "|---|" + "---|" * (len(doc["faces"]) + 2)]
        for n in names_f:
            cells = [f"{f['variants'][n]['psnr']:.2f}" for f in doc["faces"]]
            v = fs["variants"][n]
            lines.append(f"| {n} | " + " | ".join(cells) + f" | {_f(v['psnr'])} | {_f(v['ssim'], '{:.4f}')} |")
        lines += ["", "Goal: `full` >= the best other method (baselines, nearest photo) + "
                  f"{FACE_GOAL_MEAN_DB:g} dB mean, + {FACE_GOAL_EACH_DB:g} dB on every subject: margins "
                  + ", ".join(f"{f['subject']} {f['margin_db']:+.2f} dB (over {f['best_other']})" for f in doc["faces"])
                  + f"; mean {fs['mean_margin_db']:+.2f} dB - " + ("met" if fs["goal_met"] else "**not met**"), "",
                  "Per held-out light (PSNR dB, full / best other):", ""]
        for f in doc["faces"]:
            pf, po = f["variants"]["full"]["psnr_per_light"], f["variants"][f["best_other"]]["psnr_per_light"]
            lines.append(f"* {f['subject']}: " + ", ".join(f"{n.split('.')[0]} {a:.1f}/{b:.1f}"
                                                         for n, a, b in zip(f["held_out"], pf, po, strict=True)))
    lines += ["", "## Error heat maps (the paper's Fig. 14)", "",
              "Per pixel: RMS error of single-light renders over all 32x16 light directions (top) and over the "
              "captured hull only (bottom), solid-angle weighted; one colour scale per row and scene.", ""]
    for sc in doc["scenes"]:
        lines.append(f"![{sc['name']}]({sc['heat_map']})")
    lines += ["", "## Numerical stability", "",
              "Each case through every variant; max error relative to a float64 reference; finite = every output "
              "finite. A clear error for invalid input counts as handled.", "",
              "| case | variant | max rel. error | finite | note |", "|---|---|---|---|---|"]
    for r in doc["stability"]:
        note = (r.get("error") or "").replace("|", "/")[:90]
        lines.append(f"| {r['case']} | {r['variant']} | {_f(r.get('max_rel_error'), '{:.2e}')} | "
                     f"{'yes' if r['finite'] else '**no**'} | {note} |")
    lines += ["", f"Run time of this report: {doc['seconds']:.0f} s.", ""]
    return "\n".join(lines)


def table(doc: dict) -> str:
    s = doc["summary"]
    lines = [f"{'variant':18s} {'PSNR hull':>9s} {'PSNR whole':>10s} {'OLAT whole':>10s} {'OLAT hull':>9s} "
             f"{'Dome PSNR':>9s} {'capture s':>9s} {'relight ms':>10s}"]
    for n, v in s["variants"].items():
        lines.append(f"{n:18s} {_f(v['psnr in hull']):>9s} {_f(v['psnr whole sphere']):>10s} "
                     f"{_f(v['olat whole'], '{:.3f}'):>10s} {_f(v['olat hull'], '{:.3f}'):>9s} "
                     f"{_f(v['dome psnr']):>9s} {_f(v['capture s'], '{:.1f}'):>9s} {_f(v['relight ms']):>10s}")
    for key, r in s["goal"].items():
        if r["margin_db"] is not None:
            lines.append(f"goal ({key}): full {r['full']:.2f} dB vs best baseline {r['best_baseline']} "
                         f"{r['best_baseline_value']:.2f} dB: margin {r['margin_db']:+.2f} dB (need >= +1)")
    fs = doc.get("faces_summary")
    if fs:
        for f in doc["faces"]:
            lines.append(f"real face {f['subject']}: full {f['variants']['full']['psnr']:.2f} dB, best other "
                         f"{f['best_other']} {f['variants'][f['best_other']]['psnr']:.2f} dB: "
                         f"margin {f['margin_db']:+.2f} dB (need >= +{FACE_GOAL_EACH_DB:g})")
        lines.append(f"real faces: mean margin {fs['mean_margin_db']:+.2f} dB (need >= +{FACE_GOAL_MEAN_DB:g}): "
                     + ("met" if fs["goal_met"] else "not met"))
    db = s.get("default_bundle") or {}
    for r in db.get("rows", []):
        lines.append(f"default bundle, {r['source']}: {_f(r['default'])} dB vs exact maps {_f(r['exact'])} dB "
                     f"({_f(r['difference_db'], '{:+.3f}')}), {_f(r['kb_per_px'], '{:.3f}')} KB per face pixel")
    if db.get("rows"):
        lines.append(f"default bundle: worst {_f(db['worst_difference_db'], '{:.3f}')} dB "
                     f"(need <= {DEFAULT_BUNDLE_DB}), largest {_f(db['largest_kb_per_px'], '{:.3f}')} KB/px "
                     f"(need <= {DEFAULT_BUNDLE_KB:g}): "
                     + ("met" if db["goal_met"] else "not met"))
    bad = [r for r in doc["stability"] if not r["finite"]]
    lines.append(f"stability: {len(doc['stability'])} case x variant runs, non-finite: {len(bad)}")
    return "\n".join(lines)
