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


def pose_run(bundle, clip: Path, focal) -> dict:
    """The per-frame path over ``clip`` with ``focal`` (px, "ortho" or None: found): the pose's
    errors against the truth, the frame the focal search switched at, the focal used at the end."""
    import relight
    from relight.engine.frame_path import FramePath
    from relight.video import read_frames

    from .clips import rotation_errors

    meta = json.loads((clip / "truth" / "meta.json").read_text())
    fps = float(meta["fps"])
    fp = FramePath(bundle, relight.load_environment(ENV), focal=focal)
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
            "path_ms": float(np.median(ms)) if ms else None}


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
    rows = []
    for fov in fovs:
        name = "orthographic" if fov is None else f"{fov:g} deg"
        if progress:
            print(f"a webcam's camera: {name} ...", flush=True)
        clip = synth_live(out, size, pose_s, progress, fov=fov)
        f_true = json.loads((clip / "truth" / "meta.json").read_text())["camera"].get("focal_px")
        known = "ortho" if fov is None else float(f_true)
        row = {"camera": name, "fov": fov, "focal_true_px": f_true, "size": list(size),
               "pose_known": pose_run(bundle, clip, known), "pose_unknown": pose_run(bundle, clip, None)}
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
    doc = {"rows": rows, "goals": GOALS, "env": ENV, "mode": mode, "region": region}
    with atomic_path(out / "perspective.json") as tmp:
        Path(tmp).write_text(json.dumps(doc, indent=1))
    return doc


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
    return "\n".join(lines)
