"""``relight bench capture``: speed, memory and accuracy of the capture pipeline on synthetic captures.

For each scenario a synthetic capture is made (cached in the output folder by its settings),
then ``relight capture`` runs in a fresh process that reports its own peak memory; the result
is measured against the truth. Figures are printed as a table and written to ``bench.json``
with a stage-timing plot. The default scenarios include the issue's target, a 60 s 960x540
capture (goal: <= 60 s, <= 4 GB); ``--quick`` runs one short capture.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

SCENARIOS = [
    {"name": "960x540 60 s", "width": 960, "height": 540, "duration": 60.0, "seed": 0},
    {"name": "960x540 30 s drift", "width": 960, "height": 540, "duration": 30.0, "seed": 1, "camera_drift": True},
    {"name": "480x270 20 s", "width": 480, "height": 270, "duration": 20.0, "seed": 2},
    {"name": "640x360 20 s 4 Hz", "width": 640, "height": 360, "duration": 20.0, "seed": 3, "flash_hz": 4.0},
]
QUICK = [{"name": "480x270 10 s", "width": 480, "height": 270, "duration": 10.0, "seed": 5}]


def _child(video: str, bundle: str, truth: str) -> None:
    """Run one capture in this (fresh) process and print its figures as JSON."""
    import resource

    from relight import load_bundle
    from relight.pipeline.capture import capture
    from relight.pipeline.evaluate import evaluate_capture

    res = capture(video, bundle, progress=False)
    peak_kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    metrics = evaluate_capture(res.report, load_bundle(bundle), truth)
    print(json.dumps({"timings": res.timings, "peak_mb": peak_kb / 1024.0, "metrics": metrics,
                      "samples": int(res.arrays["light_dirs"].shape[0]), "pixels": int(res.arrays["pixels"].size),
                      "bundle_mb": Path(bundle).stat().st_size / 1e6}))


def run(out: Path, quick: bool = False, progress: bool = True) -> dict:
    from .synth.studio import SynthConfig, cached_synthesis

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for sc in QUICK if quick else SCENARIOS:
        cfg = SynthConfig(**{k: v for k, v in sc.items() if k != "name"}, truth_envs=("builtin:studio",))
        cap = cached_synthesis(out, cfg, label=sc["name"], progress=progress)
        key = cap.name.removeprefix("synth-")
        if progress:
            print(f"capturing {sc['name']} ...", flush=True)
        code = (f"from relight.pipeline.benchmark import _child; _child({str(cap / 'capture.mp4')!r}, "
                f"{str(out / (key + '.bundle'))!r}, {str(cap / 'truth')!r})")
        proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
        if proc.returncode != 0:
            raise RuntimeError(f"capture of {sc['name']} failed:\n{proc.stderr[-2000:]}")
        fig = json.loads(proc.stdout.strip().splitlines()[-1])
        fig["scenario"] = sc
        rows.append(fig)
        (out / (key + ".bundle")).unlink(missing_ok=True)
    doc = {"scenarios": rows}
    (out / "bench.json").write_text(json.dumps(doc, indent=1))
    _plot(rows, out / "capture_timings.png")
    return doc


def table(doc: dict) -> str:
    head = (f"{'scenario':22s} {'total s':>8s} {'peak MB':>8s} {'flash P/R':>11s} {'reg px':>7s} "
            f"{'dir mean/p95 deg':>17s} {'normal med':>10s} {'samples':>7s}")
    lines = [head, "-" * len(head)]
    for r in doc["scenarios"]:
        m = r["metrics"]
        lines.append(f"{r['scenario']['name']:22s} {r['timings']['total']:8.1f} {r['peak_mb']:8.0f} "
                     f"{m['flash_precision']:5.3f}/{m['flash_recall']:5.3f} {m['registration_rms_px']:7.3f} "
                     f"{m['light_dir_mean_deg']:8.2f}/{m['light_dir_p95_deg']:6.2f} {m['normal_median_deg']:10.2f} "
                     f"{r['samples']:7d}")
    return "\n".join(lines)


def _plot(rows, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    stages = [k for k in rows[0]["timings"] if k not in ("total", "assemble")]
    fig, ax = plt.subplots(figsize=(10, 0.8 + 0.5 * len(rows)))
    for i, r in enumerate(rows):
        left = 0.0
        for s in stages:
            v = r["timings"].get(s, 0.0)
            ax.barh(i, v, left=left, label=s if i == 0 else None)
            left += v
    ax.set_yticks(range(len(rows)), [r["scenario"]["name"] for r in rows])
    ax.set_xlabel("seconds (2-core machine)")
    ax.set_title("relight capture: time per stage")
    ax.legend(fontsize=7, ncols=4, loc="lower right")
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)
