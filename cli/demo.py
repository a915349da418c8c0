"""``relight demo``: what ``make demo`` runs - a synthetic capture, its bundle, a live clip relit."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from .common import COMMANDS


def add_parser(sub) -> None:
    p = sub.add_parser("demo", help=COMMANDS["demo"],
                       description="Synthesise a short capture with the built-in defaults (no download), run "
                                   "the capture pipeline on it, measure it against the truth and write a "
                                   "contact sheet PNG: flash frames, the mirror-sphere crops, the truth relit "
                                   "under the built-in environments, and the bundle beside the truth; then relight "
                                   "a short live clip of the same head under three environments (relight filter) "
                                   "and write the relit clips and a before/after contact sheet.",
                       formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("--out", type=Path, default=Path("out/demo"), help="output folder")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=_run_demo)


#: The environments ``relight demo`` relights its live clip under, and that clip's length (s).
DEMO_ENVS = ("sunset", "window", "studio")
DEMO_CLIP_S = 3.0


def _run_demo(args) -> int:
    from .. import load_bundle, load_environment
    from ..apps.filter import run_filter
    from ..engine.frame_path import FramePath
    from ..engine.frame_settings import FrameSettings
    from ..pipeline.capture import capture
    from ..pipeline.evaluate import evaluate_capture
    from ..pipeline.synth.config import SynthConfig
    from ..pipeline.synth.contact_sheet import before_after_sheet, contact_sheet
    from ..pipeline.synth.live_clip import LiveConfig, synthesize_live
    from ..pipeline.synth.studio import synthesize

    t0 = time.perf_counter()
    # Progress bars on a terminal only: a log file gets one line per stage.
    bars = not args.quiet and sys.stderr.isatty()

    def stage(text: str) -> None:
        print(f"[{time.perf_counter() - t0:5.1f} s] {text}", flush=True)

    from ..pipeline.synth.mesh_head import DEMO_HEAD, head_credit

    # The face people see first: the scanned head shipped with relight (credited on every sheet).
    cfg = SynthConfig(width=480, height=270, duration=12.0, seed=1, head_mesh=DEMO_HEAD)
    res = synthesize(args.out / "capture", cfg, progress=bars)
    stage(f"synthetic capture: {res.video} ({res.frame_count} frames, {res.flash_frames} flash frames); "
          f"truth: {res.truth}/")
    cap = capture(res.video, args.out / "face.bundle", report_dir=args.out / "report", progress=bars)
    bundle = load_bundle(cap.bundle)
    m = evaluate_capture(cap.report, bundle, res.truth)
    stage(f"bundle: {cap.bundle} ({bundle.light_dirs.shape[0]} light samples, {bundle.pixels.size} pixels); "
          f"report: {args.out / 'report'}/")
    print(f"accuracy against the truth: flash frames precision {m['flash_precision']:.3f} recall "
          f"{m['flash_recall']:.3f}, registration {m['registration_rms_px']:.3f} px RMS, light directions "
          f"{m['light_dir_mean_deg']:.2f} deg mean, normals {m['normal_median_deg']:.1f} deg median")
    sheet = contact_sheet(args.out / "capture", args.out / "contact_sheet.png", bundle=bundle)
    stage(f"capture contact sheet: {sheet}")
    # The product: a live clip of the same head (turning, under the room's light) relit by
    # `relight filter` under each environment.
    live = synthesize_live(args.out / "live", LiveConfig(width=cfg.width, height=cfg.height,
                                                          duration=DEMO_CLIP_S, seed=cfg.seed, audio="none",
                                                          head_mesh=cfg.head_mesh),
                           progress=bars)
    stage(f"live clip: {live.video}")
    fp = None
    relit = {}
    for name in DEMO_ENVS:
        env = load_environment(f"builtin:{name}")
        if fp is None:
            fp = FramePath(bundle, env, FrameSettings(focal="ortho"))
        else:
            fp.set_environment(env)
            fp.reset()
        r = run_filter(live.video, args.out / f"relit-{name}.mp4", bundle, env, frame_path=fp, progress=bars)
        relit[name] = r.out
        stage(f"relit under {name}: {r.out} ({r.faces} of {r.frames} frames with the face found)")
    ba = before_after_sheet(live.video, relit, args.out / "before_after.png", credit=head_credit(cfg.head_mesh))
    stage(f"before/after contact sheet: {ba}")
    print(f"done in {time.perf_counter() - t0:.1f} s - look at {ba} and {relit[DEMO_ENVS[0]]}")
    serve = "make serve" if args.out == Path("out/demo") else f"relight serve {args.out / 'face.bundle'}"
    print(f"relight this face live in a browser: {serve}; or a webcam: relight live --bundle "
          f"{args.out / 'face.bundle'} --env builtin:sunset --preview")
    return 0


