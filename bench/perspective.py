"""Head pose and the live frame through a webcam's pinhole (issue 49): the studio's head captured
as always (its bundle: an orthographic capture), then filmed by pinholes of :data:`FOVS` degrees
across at a call's distance (``relight synth --live --fov``), each clip run with its focal
length known (``--focal`` the truth's) and unknown (no ``--focal``: the path finds it,
:mod:`relight.engine.focal`); the orthographic clip beside them (``--focal ortho`` against none).

Per clip and focal: the head pose's error against the truth (median and p95 over every frame
with a face, and over the frames after the focal search switched), the focal length used at the
end (px, and as a share of the true one), the per-frame path's median ms; and the live frame
against its truth (:mod:`.live_frame`: silhouette and face PSNR, off the person's p99.9) through
``relight filter`` of a :data:`~.live_frame.CLIP_S` s truth clip under :data:`ENV`.

And the capture's mirror sphere through 50-100 degree lenses (:func:`sphere_run`): each flash's
direction as ``relight capture --focal`` reads it, against the outline's circle alone; and the
whole capture through each lens (:func:`capture_run`): ``--focal ortho``, told and ``auto``.

The pose's p95 over one clip is its 15 worst frames, often one stretch of a strong turn, and it
moves by a degree with the focal length's last digits; so the pose is also run over
:data:`HEADS` heads (each its own capture and clips, ``relight synth --seed``), pooled over all
their frames (:func:`heads_run`).

Goals (issue 49): with the focal length unknown, head pose <= 2 deg median and <= 4 deg p95, and
the live frame within 1 dB of the same clip with the focal length known; ``--focal ortho`` on an
orthographic clip unchanged.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from relight.engine.composite import DEFAULT_REGION

#: Horizontal fields of view (degrees) of the clips; None: the orthographic camera.
FOVS = (None, 50.0, 65.0, 80.0)
SIZE = (640, 360)
#: Seconds of the pose clips, and the capture's.
POSE_S = 10.0
CAPTURE_S = 24.0
#: The live frame's truth light.
ENV = "builtin:sunset"
GOALS = {"median_deg": 2.0, "p95_deg": 4.0, "live_frame_db": 1.0}
#: The heads (``relight synth --seed``) the pose is pooled over (:func:`heads_run`).
HEADS = (0, 1, 2, 3)


def pose_run(bundle, clip: Path, focal) -> dict:
    """The per-frame path over ``clip`` with ``focal`` (px, "ortho" or None: found): the pose's
    errors against the truth, the frame the focal search switched at, the focal used at the end."""
    import relight
    from relight.engine.frame_path import FramePath
    from relight.engine.frame_settings import FrameSettings
    from relight.video_read import read_frames

    from .clips import rotation_errors

    meta = json.loads((clip / "truth" / "meta.json").read_text())
    fps = float(meta["fps"])
    fp = FramePath(bundle, relight.load_environment(ENV), FrameSettings(focal=focal))
    estimates, ms, switched = {}, [], None
    for i, frame in enumerate(read_frames(clip / "live.mp4")):
        t0 = time.perf_counter()
        _, info = fp.process(frame, i / fps)
        ms.append((time.perf_counter() - t0) * 1e3)
        if info.face:
            estimates[str(i)] = info.angles
        if switched is None and fp.focal_found:
            switched = i
    truth = meta["head_rotation"]
    err = rotation_errors(estimates, truth)
    after = rotation_errors({k: v for k, v in estimates.items() if int(k) > (switched or -1)}, truth)
    f_true = meta["camera"].get("focal_px")
    f_used = fp.frames_focal
    return {"frames": len(ms), "faces": len(estimates), "median_deg": _q(err, 50), "p95_deg": _q(err, 95),
            "after_median_deg": _q(after, 50), "after_p95_deg": _q(after, 95), "switched_at": switched,
            "focal_px": f_used, "focal_share": f_used / f_true if f_true and f_used else None,
            "path_ms": float(np.median(ms)) if ms else None, "errors_deg": [float(e) for e in err]}


def heads_poses(out: Path, size, fovs, pose_s: float, capture_s: float, heads=HEADS, progress: bool = True) -> dict:
    """:func:`pose_run` through each camera of ``fovs``, focal known and unknown, for every head of
    ``heads`` (each its own ``capture_s`` s capture and ``pose_s`` s clips at ``size``):
    {(fov, "known" | "unknown", head): its result}."""
    import relight

    from .clips import synth_bundle, synth_live

    runs = {}
    bundles = {seed: relight.load_bundle(synth_bundle(out, size, capture_s, progress, seed=seed)) for seed in heads}
    for fov in fovs:
        name = "orthographic" if fov is None else f"{fov:g} deg"
        for label in ("known", "unknown"):
            for seed in heads:
                if progress:
                    print(f"the pose of head {seed} through {name}, focal {label} ...", flush=True)
                clip = synth_live(out, size, pose_s, progress, seed=seed, fov=fov)
                f_true = json.loads((clip / "truth" / "meta.json").read_text())["camera"].get("focal_px")
                focal = None if label == "unknown" else ("ortho" if fov is None else float(f_true))
                runs[(fov, label, seed)] = pose_run(bundles[seed], clip, focal)
    return runs


def heads_rows(runs: dict, fovs, heads=HEADS) -> list:
    """:func:`heads_poses`' results per camera and focal: each head's median / p95 and focal used,
    and the pooled median / p95 over all the heads' frames."""
    rows = []
    for fov in fovs:
        name = "orthographic" if fov is None else f"{fov:g} deg"
        for label in ("known", "unknown"):
            got = [(seed, runs[(fov, label, seed)]) for seed in heads]
            per = [{"head": seed, **{k: r[k] for k in ("median_deg", "p95_deg", "faces", "frames", "focal_px",
                                                        "focal_share")}} for seed, r in got]
            err = np.asarray([e for _, r in got for e in r["errors_deg"]])
            rows.append({"camera": name, "fov": fov, "focal": label, "heads": per, "median_deg": _q(err, 50),
                         "p95_deg": _q(err, 95), "worst_p95_deg": max((h["p95_deg"] or 0.0) for h in per),
                         "heads_p95_met": sum(h["p95_deg"] is not None and h["p95_deg"] <= GOALS["p95_deg"]
                                              for h in per)})
    return rows


def heads_run(out: Path, size, fovs, pose_s: float, capture_s: float, heads=HEADS, progress: bool = True) -> list:
    """The pose through each camera of ``fovs``, focal known and unknown, over every head of
    ``heads`` (:func:`heads_poses`), as :func:`heads_rows`."""
    return heads_rows(heads_poses(out, size, fovs, pose_s, capture_s, heads, progress), fovs, heads)


def _q(err: np.ndarray, q: float) -> float | None:
    return float(np.percentile(err, q)) if len(err) else None


def run(out: Path, *, quick: bool = False, progress: bool = True, mode: str = "transfer",
        region: str = DEFAULT_REGION) -> dict:
    """Every clip of :data:`FOVS` (quick: the 65-degree one at 480x270, shorter): pose and live
    frame, focal known and unknown. Returns the document (also ``out/perspective.json``)."""
    import relight
    from relight.envmap import environment_stem
    from relight.imageio import atomic_path

    from .clips import synth_bundle, synth_live
    from .live_frame import CLIP_S, evaluate, filter_frames, synth_truth_clip

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    fovs, size, pose_s, clip_s, capture_s = (FOVS, SIZE, POSE_S, CLIP_S, CAPTURE_S) if not quick else \
        ((65.0,), (480, 270), 4.0, 2.0, 12.0)
    bundle_path = synth_bundle(out, size, capture_s, progress)
    bundle = relight.load_bundle(bundle_path)
    mask = np.asarray(bundle.mask)
    stem = environment_stem(ENV)
    # (head 0's runs are this document's rows too: run once)
    heads = (0,) if quick else HEADS
    poses = heads_poses(out, size, fovs, pose_s, capture_s, heads, progress)
    rows = []
    for fov in fovs:
        name = "orthographic" if fov is None else f"{fov:g} deg"
        if progress:
            print(f"a webcam's camera: {name} ...", flush=True)
        clip = synth_live(out, size, pose_s, progress, fov=fov)
        f_true = json.loads((clip / "truth" / "meta.json").read_text())["camera"].get("focal_px")
        known = "ortho" if fov is None else float(f_true)
        row = {"camera": name, "fov": fov, "focal_true_px": f_true, "size": list(size)}
        for label in ("known", "unknown"):
            row[f"pose_{label}"] = {k: v for k, v in poses[(fov, label, 0)].items() if k != "errors_deg"}
        truth = synth_truth_clip(out, size, (ENV,), fov=fov, duration=clip_s, progress=progress)
        for label, focal in (("known", known if fov is None else f"{known:.4f}"), ("unknown", None)):
            work = out / "runs" / f"{truth.name}-{label}"
            rep = filter_frames(bundle_path, truth, ENV, work, mode=mode, region=region, focal=focal)
            fig = evaluate(bundle_path, truth, stem, Path(rep["frames_dir"]), bundle_mask=mask)
            row[f"live_frame_{label}"] = {"silhouette_psnr": fig["silhouette_psnr"], "face_psnr": fig["face_psnr"],
                                          "outside_p999_codes": fig["outside_p999_codes"],
                                          "relit_frames": rep["faces"], "frames": rep["frames"],
                                          "focal_px": rep.get("focal_px")}
        rows.append(row)
    doc = {"rows": rows, "goals": GOALS, "env": ENV, "mode": mode, "region": region,
           "heads": heads_rows(poses, fovs, heads),
           "sphere": sphere_run(size, (65.0,) if quick else (50.0, 65.0, 80.0, 100.0)),
           "captures": capture_run(out, size, capture_s, fovs, progress)}
    with atomic_path(out / "perspective.json") as tmp:
        Path(tmp).write_text(json.dumps(doc, indent=1))
    return doc


#: The sphere's directions (:func:`sphere_run`): the flashes' directions, toward the light.
SPHERE_LIGHTS = ((0.1, 0.2, 1.0), (0.7, -0.3, 0.6), (-0.5, 0.6, 0.62), (0.9, 0.1, 0.3), (-0.8, -0.2, 0.5),
                 (0.3, 0.8, 0.5), (-0.2, -0.7, 0.7))


def pinhole_ball(size, fov: float):
    """The capture's mirror sphere where the studio puts it, seen through a pinhole of ``fov``
    degrees at a call's distance: (the :class:`~relight.pipeline.synth.scene.MirrorSphere`, its
    coverage and its no-flash image over its box - the ball at 0.35 over a wall at 0.05 -, its
    outline's refined circle and the principal point, both in the box's pixels)."""
    from relight.pipeline.sphere import refine_circle
    from relight.pipeline.synth.pinhole import Pinhole
    from relight.pipeline.synth.scene import MirrorSphere, sphere_placement

    w, h = size
    cam = Pinhole.from_fov((w, h), fov, 60.0, head_scale=0.3 * h, pivot_z=0.0)
    cx, cy, r = sphere_placement(w, h)
    ball = MirrorSphere(cx, cy, r, glare_sigma=1.0, camera=cam)
    x0, y0, _, _ = ball.bbox
    _, cover = ball.ambient_layer(np.full((32, 64, 3), 0.5, np.float32))
    dark = (0.05 + 0.3 * cover).astype(np.float32)
    return ball, cover, dark, refine_circle(dark, (cx - x0, cy - y0, r)), (w / 2 - x0, h / 2 - y0)


def sphere_run(size=SIZE, fovs=(50.0, 65.0, 80.0, 100.0)) -> list:
    """The capture's mirror sphere (where the studio puts it) through pinholes of ``fovs``: each
    flash's direction as ``relight capture --focal`` reads it - the ball's cone fitted to its
    outline (:func:`relight.pipeline.sphere.refine_cone`) -, as the outline's circle alone
    gives it (before issue 49) and as ``--focal auto`` reads it (the focal length found from the
    outline, :func:`relight.pipeline.sphere.find_focal`, and its cone), against the truth: mean
    and max error (deg) of :data:`SPHERE_LIGHTS`; whether a cone was fitted (a lens too wide for
    the edge search keeps the circle) and the focal length found (px; None: orthographic)."""
    from relight.directions import angle_between_deg
    from relight.pipeline.sphere import find_focal, find_highlight, light_direction, refine_cone

    w, h = size
    rows = []
    for fov in fovs:
        ball, _, dark, local, principal = pinhole_ball(size, fov)
        cam = ball.camera
        x0, y0, _, _ = ball.bbox
        cone = refine_cone(dark, local, focal=cam.focal, principal=principal)
        circle = (local[0] + x0, local[1] + y0, local[2])
        found = find_focal(dark, local, principal=principal, size=size)
        f_auto = None if found is None else found.focal
        cone_auto = None if f_auto is None else refine_cone(dark, local, focal=f_auto, principal=principal)
        errs = {"cone": [], "circle": [], "auto": []}
        for d in SPHERE_LIGHTS:
            d = np.asarray(d, np.float64) / np.linalg.norm(d)
            hl = find_highlight(np.clip(dark + ball.flash_layer(d)[..., 0], 0, 1), dark, local)
            if hl.xy is None:
                continue
            xy = (hl.xy[0] + x0, hl.xy[1] + y0)
            for key, c in (("cone", cone), ("circle", None)):
                got = light_direction(xy, circle, focal=cam.focal, image_size=(w, h), cone=c)
                errs[key].append(float(angle_between_deg(got, d)))
            got = light_direction(xy, circle, focal=f_auto, image_size=(w, h), cone=cone_auto)
            errs["auto"].append(float(angle_between_deg(got, d)))
        rows.append({"fov": fov, "focal_px": cam.focal, "cone_fitted": cone is not None, "focal_found_px": f_auto,
                     "highlights": len(errs["cone"]), "lights": len(SPHERE_LIGHTS),
                     **{f"{k}_mean_deg": float(np.mean(v)) if v else None for k, v in errs.items()},
                     **{f"{k}_max_deg": float(np.max(v)) if v else None for k, v in errs.items()}})
    return rows


def sphere_table(rows: list) -> str:
    lines = ["| lens | cone fitted | highlights found | directions with the cone: mean / max (deg) "
             "| with the outline's circle (before) | focal found / true | `--focal auto`: mean / max |",
             "|---|---|---|---|---|---|---|"]
    def f(r, k):
        return "-" if r.get(k) is None else f"{r[k]:.2f}"

    for r in rows:
        found = "orthographic" if r.get("focal_found_px") is None else f"{r['focal_found_px'] / r['focal_px']:.3f}"
        lines.append(f"| {r['fov']:g} deg | {'yes' if r['cone_fitted'] else 'no'} | {r['highlights']} of "
                     f"{r['lights']} | {f(r, 'cone_mean_deg')} / {f(r, 'cone_max_deg')} | "
                     f"{f(r, 'circle_mean_deg')} / {f(r, 'circle_max_deg')} | {found} | "
                     f"{f(r, 'auto_mean_deg')} / {f(r, 'auto_max_deg')} |")
    return "\n".join(lines)


#: The capture's camera readings compared (:func:`capture_run`): relight capture's --focal.
CAPTURE_FOCALS = ("ortho", "told", "auto")


def capture_run(out: Path, size=SIZE, duration: float = CAPTURE_S, fovs=FOVS, progress: bool = True) -> list:
    """The capture itself through a pinhole (``relight synth --fov`` without ``--live``): each
    studio capture of ``fovs`` (None: orthographic; ``duration`` s at ``size``, 4 Hz flash)
    captured with ``--focal ortho`` (every capture before issue 49), told the true focal length
    and ``--focal auto`` (the default: found from the ball), against the studio's truth
    (:func:`relight.pipeline.evaluate.evaluate_capture`: light directions, normals, relit PSNR)."""
    from relight import load_bundle
    from relight.pipeline.capture import capture
    from relight.pipeline.capture_types import CaptureOptions
    from relight.pipeline.evaluate import evaluate_capture
    from relight.pipeline.samples import SampleOptions
    from relight.pipeline.synth.config import SynthConfig
    from relight.pipeline.synth.studio import cached_synthesis

    rows = []
    for fov in fovs:
        name = "orthographic" if fov is None else f"{fov:g} deg"
        cap = cached_synthesis(out, SynthConfig(width=size[0], height=size[1], duration=duration, flash_hz=4.0,
                                                fov=fov), label=f"a {name} capture", progress=progress)
        f_true = json.loads((cap / "truth" / "meta.json").read_text())["camera"].get("focal_px")
        for label in CAPTURE_FOCALS:
            if label == "told" and f_true is None:
                continue
            focal = {"ortho": None, "told": f_true, "auto": "auto"}[label]
            if progress:
                print(f"capturing the {name} capture, --focal {label} ...", flush=True)
            res = capture(cap / "capture.mp4", cap / f"focal-{label}.bundle",
                          CaptureOptions(samples=SampleOptions(focal=focal)), progress=False)
            m = evaluate_capture(res.report, load_bundle(res.bundle), cap / "truth")
            used = res.report["camera"]["focal_px"]
            rows.append({"camera": name, "fov": fov, "focal": label, "focal_true_px": f_true, "focal_px": used,
                         "focal_share": None if used is None or f_true is None else used / f_true,
                         **{k: m[k] for k in ("light_dir_mean_deg", "light_dir_p95_deg", "normal_median_deg",
                                              "relit_psnr_window", "relit_psnr_sunset", "registration_rms_px")}})
    return rows


def capture_table(rows: list) -> str:
    lines = ["| camera | `--focal` | focal used (share of true) | light directions: mean / p95 (deg) "
             "| normals: median (deg) | relit window / sunset (dB) |", "|---|---|---|---|---|---|"]
    for r in rows:
        used = "orthographic" if r["focal_px"] is None else \
            f"{r['focal_px']:.0f} px" + ("" if r["focal_share"] is None else f" ({r['focal_share']:.3f})")
        lines.append(f"| {r['camera']} | {r['focal']} | {used} | {r['light_dir_mean_deg']:.2f} / "
                     f"{r['light_dir_p95_deg']:.2f} | {r['normal_median_deg']:.2f} | {r['relit_psnr_window']:.2f} / "
                     f"{r['relit_psnr_sunset']:.2f} |")
    return "\n".join(lines)


def heads_table(rows: list) -> str:
    """:func:`heads_run`'s rows as a Markdown table."""
    lines = ["| camera | focal | pooled median / p95 (deg) | each head's p95 (focal used) | heads with p95 <= 4 |",
             "|---|---|---|---|---|"]
    for r in rows:
        each = ", ".join(("-" if h["p95_deg"] is None else f"{h['p95_deg']:.2f}")
                         + ("" if h["focal_px"] is None else f" ({h['focal_px']:.0f} px)") for h in r["heads"])
        med = "-" if r["median_deg"] is None else f"{r['median_deg']:.2f}"
        p95 = "-" if r["p95_deg"] is None else f"{r['p95_deg']:.2f}"
        lines.append(f"| {r['camera']} | {r['focal']} | {med} / {p95} | {each} | {r['heads_p95_met']} of "
                     f"{len(r['heads'])} |")
    return "\n".join(lines)


def table(doc: dict) -> str:
    """The document as a Markdown table."""
    def f(v, fmt="{:.2f}"):
        return "-" if v is None else fmt.format(v)

    lines = ["| camera | focal | faces | pose median / p95 (deg) | after the search | focal used (share of true) "
             "| live frame silhouette / face (dB) | off the person p99.9 |",
             "|---|---|---|---|---|---|---|---|"]
    for r in doc["rows"]:
        for label in ("known", "unknown"):
            p, lf = r[f"pose_{label}"], r[f"live_frame_{label}"]
            share = "" if p["focal_share"] is None else f" ({p['focal_share']:.2f})"
            lines.append(f"| {r['camera']} | {label} | {p['faces']}/{p['frames']} | {f(p['median_deg'])} / "
                         f"{f(p['p95_deg'])} | {f(p['after_median_deg'])} / {f(p['after_p95_deg'])} | "
                         f"{f(p['focal_px'], '{:.0f}')} px{share} | {f(lf['silhouette_psnr'])} / "
                         f"{f(lf['face_psnr'])} | {f(lf['outside_p999_codes'], '{:.0f}')} |")
    if doc.get("heads"):
        lines += ["", "The pose over several heads (each its own capture and clips), pooled over their frames:", "",
                  heads_table(doc["heads"])]
    if doc.get("sphere"):
        lines += ["", "The capture's mirror sphere through each lens (`relight capture --focal`):", "",
                  sphere_table(doc["sphere"])]
    if doc.get("captures"):
        lines += ["", "The capture through each lens (`relight synth --fov`, `relight capture --focal`):", "",
                  capture_table(doc["captures"])]
    return "\n".join(lines)
