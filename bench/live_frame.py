"""The live frame against its truth: ``relight filter`` of a synthetic live clip into PNG frames
(no second encode), measured against the same clip rendered with the person under the target
light (``relight synth --live --truth-env``: full shading at every frame's pose).

Figures of one clip (one head, one environment), over every frame:

* ``silhouette_psnr``: PSNR (dB, sRGB 0-1) of the output against the truth over the person's
  pixels (``truth/silhouette``), after one least-squares gain in linear light for the clip
  (:func:`relight.bench.realface.clip_psnr`); ``face_psnr`` the same over the bundle's face
  region only (the bundle's mask moved with the head's true pose); ``input_psnr`` the unchanged
  input's, and ``noise_floor_psnr`` the input against its own noise-free render (what the
  sensor noise alone costs: no filter can be judged closer than that);
* ``outside_mean_codes`` / ``outside_p999_codes``: the change of the output against the input
  off the person - beyond :data:`OUTSIDE_PAD_PX` of the silhouette (its anti-aliased edge is the
  person's) - mean and 99.9th percentile over the pixels of every frame, in 8-bit codes (the
  largest of the three channels);
* ``seam_ratio``: the mean error (``|gain * output - truth|`` on the person, ``|output - truth|``
  off it; codes) in a band
  :data:`SEAM_BAND_PX` wide on each side of the composite's boundary - where the filter's change
  ends: the output differs from the input by more than :data:`CHANGED_CODES` there, closed and
  filled - against the mean error inside the composite beyond that band;
* ``flicker_codes``: :func:`relight.bench.clips.flicker_step`'s mean (the output's change on the
  face minus the input's); ``error_flicker_codes``: the mean change of the error against the
  truth from one frame to the next over the person (what the truth does not do);
* ``relit_frames``: frames with a face (from the filter's report);
* ``live_source``: the silhouette and face PSNR, the change off the person and the flicker of the
  same clip through a live source's path (:func:`live_source_frames`: ``relight live``'s and the
  service's streams - the slow stages beside the frames, each taken once made; the filter makes
  them in the frame): what the live path costs a turning head.

Goals (issue 32): silhouette PSNR >= 30 dB and >= input + 8 dB, outside mean <= 0.5 code and
99.9th percentile <= 8, seam <= 1.5, flicker <= 1 code. :func:`sheet` draws the before/after
sheet with crops at the hairline, the ears, the jaw and the neck.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import NamedTuple

import cv2
import numpy as np

from relight.engine.composite import DEFAULT_REGION

#: Clip length (s) and frame rate of the truth clips: the truth costs about a second a frame
#: at 640x360 (every frame shaded under every truth light, with cast shadows).
CLIP_S = 4.0
CLIP_FPS = 30.0
#: Pixels within this distance of the silhouette are not "outside" (its anti-aliased edge).
OUTSIDE_PAD_PX = 2
#: The seam band's width on each side of the composite's boundary (px).
SEAM_BAND_PX = 6
#: The composite: where the output differs from the input by more than this (codes, any channel).
CHANGED_CODES = 2
#: Goals (issue 32).
GOALS = {"silhouette_psnr": 30.0, "over_input_db": 8.0, "outside_mean_codes": 0.5, "outside_p999_codes": 8.0,
         "seam_ratio": 1.5, "flicker_codes": 1.0}
#: Crops of the sheet, in head units (``head_scale`` px) from the head centre at the reference
#: pose (x right, y down), each CROP_UNITS wide.
CROPS = {"hairline": (0.0, -0.62), "ear L": (-0.52, 0.02), "ear R": (0.52, 0.02), "jaw": (0.3, 0.5),
         "neck": (0.0, 0.85)}
CROP_UNITS = 0.36


def synth_truth_clip(out: Path, size: tuple[int, int], envs: tuple[str, ...], *, seed: int = 0,
                     head_mesh: str | None = None, duration: float = CLIP_S, progress: bool = False,
                     fov: float | None = None, **mesh_maps) -> Path:
    """A live clip with its truth under ``envs`` (cached by its settings; ``fov``: through a
    pinhole of that field of view)."""
    from relight.pipeline.synth.live_clip import LiveConfig, synthesize_live

    from .clips import head_tag

    tag = f"truth-{size[0]}x{size[1]}-{duration:g}s-seed{seed}{head_tag(head_mesh)}-" + \
        "-".join(e.removeprefix("builtin:") for e in envs) + (f"-fov{fov:g}" if fov is not None else "")
    folder = out / "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in tag)
    if not (folder / "truth" / "meta.json").exists():
        if progress:
            print(f"synthesising {folder.name} (the live frame's truth: ~1 s a frame) ...", flush=True)
        synthesize_live(folder, LiveConfig(width=size[0], height=size[1], duration=duration, fps=CLIP_FPS, seed=seed,
                                           head_mesh=head_mesh, truth_envs=tuple(envs), fov=fov, **mesh_maps),
                        progress=progress)
    return folder


def filter_frames(bundle: Path, live: Path, env: str, out: Path, *, mode: str = "transfer",
                  region: str = DEFAULT_REGION, focal: str | None = "ortho") -> dict:
    """``relight filter`` of the clip into PNG frames, in a fresh process (``--focal focal``; None:
    found by the path): (its report, wall s)."""
    dst = out / "frames"
    report = out / "report"
    if dst.exists():
        import shutil

        shutil.rmtree(dst)
    from .clips import run_filter_process

    doc = run_filter_process(live / "live.mp4", dst, bundle, env, report, "--mode", mode, "--region", region,
                             focal=focal)
    doc["frames_dir"] = str(dst)
    return doc


def live_source_frames(bundle, live: Path, env: str, out: Path, *, mode: str = "transfer",
                       region: str = DEFAULT_REGION) -> Path:
    """The clip through a live source's path - ``relight live``'s and the service's streams': the
    slow stages beside the frames, each taken once made (``FrameSettings(live_source=True)``) - in
    the filter's two-thread pipeline, into PNG frames (in this process; its jobs overlap the next
    frames as they would at 30 fps, so the figures vary a little from run to run). ``bundle``: the
    loaded bundle. Returns the frames' folder."""
    import shutil

    import relight
    from relight.apps.filter import run_filter
    from relight.engine.frame_path import FramePath
    from relight.engine.frame_settings import FrameSettings

    dst = out / "live-source-frames"
    shutil.rmtree(dst, ignore_errors=True)
    e = relight.load_environment(env)
    fp = FramePath(bundle, e, FrameSettings(mode=mode, region=region, focal="ortho", live_source=True))
    run_filter(live / "live.mp4", dst, bundle, e, mode=mode, region=region, focal="ortho", frame_path=fp,
               progress=False)
    return dst


#: The figures kept of a live source's run (:func:`live_source_frames`), beside the filter's.
LIVE_SOURCE_KEYS = ("silhouette_psnr", "face_psnr", "outside_mean_codes", "outside_p999_codes", "flicker_codes")


def _rgb(path: Path) -> np.ndarray:
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise RuntimeError(f"{path}: missing or unreadable")
    return np.ascontiguousarray(img[..., ::-1])


def _codes(linear: np.ndarray) -> np.ndarray:
    from relight.colour import linear_to_srgb

    return 255.0 * linear_to_srgb(np.clip(linear, 0.0, 1.0))


def composite_region(inp: np.ndarray, out: np.ndarray) -> np.ndarray:
    """(H, W) bool: where the filter changed the frame (more than CHANGED_CODES in a channel),
    closed over small gaps and with its holes filled."""
    from scipy.ndimage import binary_fill_holes

    changed = (np.abs(out.astype(np.int16) - inp.astype(np.int16)).max(axis=2) > CHANGED_CODES).astype(np.uint8)
    closed = cv2.morphologyEx(changed, cv2.MORPH_CLOSE, np.ones((5, 5), np.uint8))
    return binary_fill_holes(closed > 0)


def _band(region: np.ndarray, width: int) -> tuple[np.ndarray, np.ndarray]:
    """(band, interior): pixels within ``width`` of the region's boundary on either side, and
    the region's pixels beyond it."""
    from scipy.ndimage import distance_transform_edt

    d_in = distance_transform_edt(region)
    d_out = distance_transform_edt(~region)
    band = (region & (d_in <= width)) | (~region & (d_out <= width))
    return band, region & (d_in > width)


def live_scene(live: Path):
    """The :class:`LiveScene` a clip was made from (its truth's config)."""
    from relight.pipeline.synth.live_clip import LiveConfig, LiveScene

    meta = json.loads((live / "truth" / "meta.json").read_text())
    return LiveScene(LiveConfig(**{k: (tuple(v) if isinstance(v, list) else v) for k, v in meta["config"].items()}))


def face_regions(scene, bundle_mask: np.ndarray) -> list[np.ndarray]:
    """The bundle's face region (its reference mask) in every frame of the clip, moved with the
    head's true pose (the live scene's own rasteriser)."""
    mesh = scene.mesh
    h, w = scene.wall.shape[:2]
    if bundle_mask.shape != (h, w):
        raise ValueError(f"the bundle's mask is {bundle_mask.shape[1]}x{bundle_mask.shape[0]}, the clip {w}x{h}: "
                         "capture the bundle at the clip's size")
    values = mesh.vertex_values(bundle_mask.astype(np.float64))
    out = []
    for i in range(scene.n):
        (x0, y0, x1, y1), v, _ = mesh.render(*scene.pose(i), values)
        region = np.zeros((h, w), dtype=bool)
        region[y0:y1, x0:x1] = v[..., 0] > 0.5
        out.append(region)
    return out


class TruthClip(NamedTuple):
    """What a clip's figures are measured against, loaded once (:func:`load_truth`): its input
    frames, truth frames (sRGB and linear) and the person's silhouette in each, the bundle's face
    region in each (or None), and the figures of the input itself."""

    inputs: list
    truths: list
    truth_lin: np.ndarray
    sils: list
    faces: list | None
    base: dict


def load_truth(live: Path, env_stem: str, *, bundle_mask: np.ndarray | None = None) -> TruthClip:
    """The :class:`TruthClip` of ``live`` under the truth light ``env_stem``."""
    from relight.bench.realface import clip_psnr
    from relight.colour import decode_srgb8
    from relight.video_read import read_frames

    meta = json.loads((live / "truth" / "meta.json").read_text())
    pattern = meta["files"]["live_truth"][env_stem]
    inputs = list(read_frames(live / "live.mp4"))
    n = len(inputs)
    truths = [_rgb(live / (pattern % i)) for i in range(n)]
    sils = [cv2.imread(str(live / (meta["files"]["silhouette"] % i)), cv2.IMREAD_GRAYSCALE) > 0 for i in range(n)]
    truth_lin = np.stack([decode_srgb8(t) for t in truths])
    base: dict = {"frames": n, "input_psnr": clip_psnr(inputs, truth_lin, sils)}
    scene = live_scene(live)
    clean = np.stack([decode_srgb8(scene.camera_frame(i, noisy=False)) for i in range(n)])
    base["noise_floor_psnr"] = clip_psnr(inputs, clean, sils)
    faces = None
    if bundle_mask is not None:
        faces = face_regions(scene, bundle_mask)
        base["face_input_psnr"] = clip_psnr(inputs, truth_lin, faces)
    return TruthClip(inputs, truths, truth_lin, sils, faces, base)


def evaluate(bundle: Path, live: Path, env_stem: str, frames_dir: Path, *, bundle_mask: np.ndarray | None = None
             ) -> dict:
    """The figures of the module docstring for one filtered clip (``frames_dir``: its PNGs)."""
    truth = load_truth(live, env_stem, bundle_mask=bundle_mask)
    outputs = [_rgb(frames_dir / f"{i:06d}.png") for i in range(len(truth.inputs))]
    return figures(truth, outputs)


def figures(truth: TruthClip, outputs: list) -> dict:
    """The figures of the module docstring of ``outputs`` ((H, W, 3) uint8 sRGB, one per frame)
    against ``truth``."""
    from relight.bench.realface import clip_psnr, clip_psnr_gain
    from relight.colour import decode_srgb8

    from .clips import flicker_step

    inputs, truths, truth_lin, sils = truth.inputs, truth.truths, truth.truth_lin, truth.sils
    n = len(inputs)
    doc: dict = dict(truth.base)
    doc["silhouette_psnr"], gain = clip_psnr_gain(outputs, truth_lin, sils)
    if truth.faces is not None:
        doc["face_psnr"] = clip_psnr(outputs, truth_lin, truth.faces)
    # off the person: the change against the input
    kernel = np.ones((2 * OUTSIDE_PAD_PX + 1, 2 * OUTSIDE_PAD_PX + 1), np.uint8)
    moved = []
    for inp, out, sil in zip(inputs, outputs, sils, strict=True):
        off = cv2.dilate(sil.astype(np.uint8), kernel) == 0
        moved.append(np.abs(out.astype(np.int16) - inp.astype(np.int16)).max(axis=2)[off])
    moved_all = np.concatenate(moved).astype(np.float64)
    doc["outside_mean_codes"] = float(moved_all.mean()) if moved_all.size else 0.0
    doc["outside_p999_codes"] = float(np.percentile(moved_all, 99.9)) if moved_all.size else 0.0
    # the seam: error in a band each side of the composite's boundary against inside it
    doc["gain"] = gain
    band_err, inner_err = [], []
    for inp, out, tr, sil in zip(inputs, outputs, truths, sils, strict=True):
        region = composite_region(inp, out)
        if region.sum() < 100:
            continue
        band, inner = _band(region, SEAM_BAND_PX)
        # the clip's gain on the person; off it the output is compared as it is (it must not move)
        gained = np.where(sil[..., None], _codes(gain * decode_srgb8(out)), out.astype(np.float64))
        err = np.abs(gained - tr.astype(np.float64)).mean(axis=2)
        band_err.append(err[band])
        inner_err.append(err[inner])
    if band_err:
        b, c = np.concatenate(band_err), np.concatenate(inner_err)
        doc["seam_band_codes"] = float(b.mean())
        doc["seam_inside_codes"] = float(c.mean()) if c.size else None
        doc["seam_ratio"] = float(b.mean() / max(float(c.mean()), 1e-6)) if c.size else None
    else:
        doc["seam_band_codes"] = doc["seam_inside_codes"] = doc["seam_ratio"] = None
    flick = [flicker_step(inputs[i - 1], outputs[i - 1], inputs[i], outputs[i]) for i in range(1, n)]
    flick = [f for f in flick if f is not None]
    doc["flicker_codes"] = float(np.mean(flick)) if flick else None
    # the same against the truth: the frame-to-frame change of the error on the person (a target
    # light that changes as the head turns makes the output change more than the input - the
    # flicker above counts that too; this counts only what the truth does not do)
    steps = []
    for i in range(1, n):
        both = sils[i] & sils[i - 1]
        if both.sum() < 100:
            continue
        e1 = outputs[i].astype(np.int16) - truths[i].astype(np.int16)
        e0 = outputs[i - 1].astype(np.int16) - truths[i - 1].astype(np.int16)
        steps.append(float(np.abs(e1 - e0).mean(axis=2)[both].mean()))
    doc["error_flicker_codes"] = float(np.mean(steps)) if steps else None
    doc["goals_met"] = goals_met(doc)
    return doc


def goals_met(doc: dict) -> dict:
    """Each goal of the module docstring: True / False (None where not measured)."""
    def at_most(key, goal):
        return None if doc.get(key) is None else bool(doc[key] <= goal)

    return {"silhouette_psnr": bool(doc["silhouette_psnr"] >= GOALS["silhouette_psnr"]),
            "over_input": bool(doc["silhouette_psnr"] - doc["input_psnr"] >= GOALS["over_input_db"]),
            "outside_mean": at_most("outside_mean_codes", GOALS["outside_mean_codes"]),
            "outside_p999": at_most("outside_p999_codes", GOALS["outside_p999_codes"]),
            "seam": at_most("seam_ratio", GOALS["seam_ratio"]),
            "flicker": at_most("flicker_codes", GOALS["flicker_codes"])}


def _crop_boxes(live: Path, frame: int) -> dict:
    """Crop boxes (x0, y0, x1, y1) of :data:`CROPS` in ``frame``, moved with the head's pose."""
    from relight.directions import rotation_matrix

    meta = json.loads((live / "truth" / "meta.json").read_text())
    (cx, cy), s = meta["head_center"], float(meta["head_scale"])
    px, py, pz = meta["pivot"]
    r = rotation_matrix(*meta["head_rotation"][frame])
    tx, ty = meta["head_translation"][frame]
    w, h = meta["size"]
    half = CROP_UNITS * s / 2
    boxes = {}
    for name, (ux, uy) in CROPS.items():
        p = np.array([cx + ux * s, -(cy + uy * s), pz + 0.35 * s])  # on the head's front half
        q = r @ (p - np.array([px, -py, pz])) + np.array([px, -py, pz]) + np.array([tx, -ty, 0.0])
        x, y = q[0], -q[1]
        x0, y0 = int(np.clip(x - half, 0, w - 2 * half)), int(np.clip(y - half, 0, h - 2 * half))
        boxes[name] = (x0, y0, x0 + int(2 * half), y0 + int(2 * half))
    return boxes


def sheet(live: Path, env_stem: str, frames_dir: Path, path: Path, title: str, frames=None) -> Path:
    """A before/after sheet: for each chosen frame, input | output | truth | error x4, then crops
    (input / output / truth) at the hairline, ears, jaw and neck."""
    from relight.video_read import read_frames

    meta = json.loads((live / "truth" / "meta.json").read_text())
    n = int(meta["frame_count"])
    frames = frames or [n // 3, (2 * n) // 3]
    inputs = list(read_frames(live / "live.mp4"))
    rows = []
    for i in frames:
        inp = inputs[i]
        out = _rgb(frames_dir / f"{i:06d}.png")
        truth = _rgb(live / (meta["files"]["live_truth"][env_stem] % i))
        err = np.clip(4.0 * np.abs(out.astype(np.float64) - truth).mean(axis=2), 0, 255).astype(np.uint8)
        heat = cv2.applyColorMap(err, cv2.COLORMAP_INFERNO)[..., ::-1]
        top = np.concatenate([inp, out, truth, heat], axis=1)
        for k, label in enumerate(("input", "relight filter", f"truth ({env_stem})", "|error| x4")):
            cv2.putText(top, label, (k * inp.shape[1] + 6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1,
                        cv2.LINE_AA)
        crops = []
        for name, (x0, y0, x1, y1) in _crop_boxes(live, i).items():
            tiles = [cv2.resize(img[y0:y1, x0:x1], None, fx=2, fy=2, interpolation=cv2.INTER_NEAREST)
                     for img in (inp, out, truth)]
            tile = np.concatenate(tiles, axis=0)
            cv2.putText(tile, name, (4, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1, cv2.LINE_AA)
            crops.append(tile)
        strip = np.concatenate(crops, axis=1)
        pad = top.shape[1] - strip.shape[1]
        if pad > 0:
            strip = np.concatenate([strip, np.zeros((strip.shape[0], pad, 3), np.uint8)], axis=1)
        else:
            strip = cv2.resize(strip, (top.shape[1], int(strip.shape[0] * top.shape[1] / strip.shape[1])))
        rows.append(np.concatenate([top, strip], axis=0))
    img = np.concatenate(rows, axis=0)
    banner = np.zeros((28, img.shape[1], 3), np.uint8)
    cv2.putText(banner, title, (6, 19), cv2.FONT_HERSHEY_SIMPLEX, 0.55, (255, 255, 255), 1, cv2.LINE_AA)
    credit = meta.get("head", {}).get("credit")
    parts = [banner, img]
    if credit:
        foot = np.zeros((22, img.shape[1], 3), np.uint8)
        cv2.putText(foot, credit[:170], (6, 15), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (200, 200, 200), 1, cv2.LINE_AA)
        parts.append(foot)
    full = np.concatenate(parts, axis=0)
    scale = min(1.0, 2400 / full.shape[1])
    if scale < 1.0:
        full = cv2.resize(full, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    from relight.imageio import write_image

    write_image(path, full)
    return path


#: The heads of the live frame's benchmark: (label, seed, head mesh). The procedural head of seed
#: 0 and the scan are the ones developed on; seed 11's head and the scan under another motion
#: seed are not.
HEADS = (("procedural", 0, None), ("scan", 0, "builtin:lee-perry-smith"),
         ("procedural seed 11 (unseen)", 11, None), ("scan seed 11 (unseen)", 11, "builtin:lee-perry-smith"))
ENVS = ("builtin:window", "builtin:sunset")


def run(out: Path, *, quick: bool = False, progress: bool = True, mode: str = "transfer",
        region: str = DEFAULT_REGION, heads=HEADS,
        envs=ENVS, size=(640, 360), capture_s: float = 24.0) -> dict:
    """Every head of ``heads`` under every environment of ``envs``: its capture's bundle, its
    truth clip, the filter into PNG frames, the figures and a sheet. Returns the document."""
    import relight
    from relight.envmap import environment_stem

    from .clips import synth_bundle

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    if quick:
        heads, envs, size, capture_s = heads[:1], envs[-1:], (480, 270), 12.0
    duration = 2.0 if quick else CLIP_S
    rows = []
    for label, seed, mesh in heads:
        bundle = synth_bundle(out, size, capture_s, progress, seed=seed, head_mesh=mesh)
        live = synth_truth_clip(out, size, tuple(envs), seed=seed, head_mesh=mesh, duration=duration,
                                progress=progress)
        loaded = relight.load_bundle(bundle)
        mask = np.asarray(loaded.mask)
        for env in envs:
            stem = environment_stem(env)
            work = out / "runs" / f"{live.name}-{stem}-{mode}-{region}"
            if progress:
                print(f"the live frame: {label}, {stem} ...", flush=True)
            rep = filter_frames(bundle, live, env, work, mode=mode, region=region)
            fig = evaluate(bundle, live, stem, Path(rep["frames_dir"]), bundle_mask=mask)
            src = evaluate(bundle, live, stem, live_source_frames(loaded, live, env, work, mode=mode, region=region),
                           bundle_mask=mask)
            fig["live_source"] = {k: src[k] for k in LIVE_SOURCE_KEYS}
            fig.update({"head": label, "seed": seed, "mesh": mesh, "env": stem, "size": list(size),
                        "relit_frames": rep["faces"], "filter_wall_s": rep["wall_s"]})
            fig["sheet"] = str(sheet(live, stem, Path(rep["frames_dir"]), out / f"sheet_{_slug(label)}_{stem}.png",
                                     f"{label}, {size[0]}x{size[1]}, {stem}, mode {mode}, {region}: silhouette "
                                     f"{fig['silhouette_psnr']:.2f} dB (input {fig['input_psnr']:.2f})").name)
            rows.append(fig)
    doc = {"mode": mode, "region": region, "rows": rows, "goals": GOALS}
    from relight.imageio import atomic_path

    with atomic_path(out / "live_frame.json") as tmp:
        Path(tmp).write_text(json.dumps(doc, indent=1))
    return doc


def _slug(s: str) -> str:
    return "".join(ch if ch.isalnum() else "_" for ch in s).strip("_").lower()


def table(doc: dict) -> str:
    def f(v, fmt="{:.2f}"):
        return "-" if v is None else fmt.format(v)

    lines = [f"the live frame against its truth (relight filter --mode {doc['mode']} into PNG frames; PSNR dB over "
             "the person / the bundle's face, one gain per clip; codes 8-bit):",
             f"{'head':30s} {'env':7s} {'silh':>6s} {'input':>6s} {'floor':>6s} {'face':>6s} {'out mean':>8s} "
             f"{'out p99.9':>9s} {'seam':>5s} {'flick':>6s} {'e-flk':>6s} {'relit':>7s}"]
    for r in doc["rows"]:
        lines.append(f"{r['head']:30s} {r['env']:7s} {r['silhouette_psnr']:6.2f} {r['input_psnr']:6.2f} "
                     f"{r['noise_floor_psnr']:6.2f} {f(r.get('face_psnr')):>6s} {r['outside_mean_codes']:8.3f} "
                     f"{r['outside_p999_codes']:9.1f} {f(r['seam_ratio']):>5s} {f(r['flicker_codes']):>6s} "
                     f"{f(r.get('error_flicker_codes')):>6s} "
                     f"{r['relit_frames']:3d}/{r['frames']:<3d}")
    if any("live_source" in r for r in doc["rows"]):
        lines.append("the same through a live source's path (relight live, the service's streams: the slow stages "
                     "beside the frames, taken once made):")
        lines.append(f"{'head':30s} {'env':7s} {'silh':>6s} {'(filter)':>8s} {'face':>6s} {'out mean':>8s} "
                     f"{'out p99.9':>9s} {'flick':>6s}")
        for r in doc["rows"]:
            q = r.get("live_source")
            if q is not None:
                lines.append(f"{r['head']:30s} {r['env']:7s} {q['silhouette_psnr']:6.2f} {r['silhouette_psnr']:8.2f} "
                             f"{f(q.get('face_psnr')):>6s} {q['outside_mean_codes']:8.3f} "
                             f"{q['outside_p999_codes']:9.1f} {f(q['flicker_codes']):>6s}")
    g = doc["goals"]
    lines.append(f"goals: silhouette >= {g['silhouette_psnr']:g} dB and >= input + {g['over_input_db']:g}; outside "
                 f"mean <= {g['outside_mean_codes']:g}, p99.9 <= {g['outside_p999_codes']:g} codes; seam <= "
                 f"{g['seam_ratio']:g}; flicker <= {g['flicker_codes']:g} code")
    return "\n".join(lines)
