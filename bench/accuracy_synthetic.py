"""The synthetic-capture half of ``relight bench accuracy``: scenes synthesised with their truth
(:mod:`relight.pipeline.synth`), every variant's bundle of a scene measured against the truth
renders (PSNR / SSIM per environment, one light at a time over a lat-long grid of directions,
relight time) and the per-pixel error heat maps (the paper's Fig. 14)."""

from __future__ import annotations

import json
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np

from .accuracy_bundles import kb_per_px
from .accuracy_metrics import env_metrics

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


def environments(out: Path) -> dict[str, tuple[str, str]]:
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


def synthesize_scene(out: Path, scene: dict, envs: dict, progress: bool):
    from relight.pipeline.synth.config import SynthConfig
    from relight.pipeline.synth.studio import cached_synthesis

    cfg = SynthConfig(**{k: v for k, v in scene.items() if k != "name"},
                      truth_envs=tuple(src for src, _ in envs.values()))
    return cfg, cached_synthesis(out, cfg, label=scene["name"], progress=progress)


def olat_directions():
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
    from relight.kernels.relight_inputs import frozen

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
    from relight.pipeline.triangulate import inside_hull

    meta = json.loads((cap / "truth" / "meta.json").read_text())
    truth_mask = read_image(cap / "truth" / "mask.png")[..., 0] > 0.5
    truths = {}
    for env_name, (src, _) in envs.items():
        stem = relight.envmap.environment_stem(src)
        truths[env_name] = read_image(cap / meta["files"]["relit"][stem])
    env_arrays = {k: relight.load_environment(src) for k, (src, _) in envs.items()}
    dirs, weight = olat_directions()
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
                         "default_psnr": default_envs, "default_kb_per_px": kb_per_px(b),
                         "rank": int(compact.rank) if getattr(compact, "rank", None) is not None else None,
                         "samples": int(b.light_dirs.shape[0]), "pixels": int(b.pixels.size),
                         "hull_share": float((weight * inside).sum() / weight.sum())} | \
            {k: info[k] for k in ("capture_s", "prepare_s", "maps_s", "bundle_mb")}
        del exact, compact, b
        if not keep_bundles:
            Path(info["bundle"]).unlink()  # the size is recorded; 45 bundles would fill the disk
    heat_png = out / f"heat_{slug(name)}.png"
    _heat_maps(heat, heat_png, name)
    return {"name": name, "config": asdict(cfg), "variants": rows, "heat_map": heat_png.name}


def slug(s: str) -> str:
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
