"""The ``relight`` command line.

Subcommands: ``synth`` (the synthetic capture studio), ``demo`` (what ``make demo`` runs).
Every error a user can cause ends in one line saying what to change, exit status 2.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from .errors import RelightError


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: write the size as WIDTHxHEIGHT, e.g. 960x540") from None
    return w, h


def _add_synth(sub) -> None:
    from .pipeline.synth.studio import DEFAULT_TRUTH_ENVS, SynthConfig

    d = SynthConfig()
    p = sub.add_parser(
        "synth", help="simulate a two-phone capture of a synthetic head, with its ground truth",
        description="Simulate the paper's acquisition on a procedural head whose truth is known: a phone "
                    "films the face while a second phone's flash blinks and is waved over the front "
                    "hemisphere, a mirror sphere beside the head shows the flash. Writes OUT/capture.mp4 "
                    "(H.264) and OUT/truth/ (meta.json, mask.png, normals/depth/albedo EXR, head.ply, "
                    "relit_<env>.exr per truth environment, olat_<name>.exr one-light images, ambient.exr).",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("out", type=Path, help="output folder (created if missing)")
    p.add_argument("--seed", type=int, default=d.seed,
                   help="random seed: flash timing, hand path, head motion, noise, skin texture")
    p.add_argument("--fps", type=float, default=d.fps, help="camera frame rate (frames per second)")
    p.add_argument("--flash-hz", type=float, default=d.flash_hz,
                   help="flash blink rate (Hz); not synchronised with the camera")
    p.add_argument("--duration", type=float, default=d.duration, help="capture length in seconds")
    p.add_argument("--size", type=_size, default=(d.width, d.height), metavar="WxH",
                   help="frame size in pixels (even numbers)")
    p.add_argument("--truth-env", action="append", default=None, metavar="FILE|builtin:NAME",
                   help="environment to render the truth under (repeatable; default: "
                        + ", ".join(DEFAULT_TRUTH_ENVS) + ")")
    p.add_argument("--head-motion", type=float, default=d.head_motion,
                   help="head motion, times the paper's limits (3 px at 540 rows, 0.35 deg); 0 = still")
    p.add_argument("--ambient", type=float, default=d.ambient, help="room light strength, times the default")
    p.add_argument("--noise", type=float, default=d.noise, help="sensor noise, times the default; 0 = none")
    p.add_argument("--camera-drift", action="store_true",
                   help="simulate a phone's auto-exposure and white-balance drift")
    p.add_argument("--crf", type=int, default=d.crf, help="H.264 quality (lower = better, bigger)")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=_run_synth)


def _run_synth(args) -> int:
    from .pipeline.synth.studio import DEFAULT_TRUTH_ENVS, SynthConfig, synthesize

    cfg = SynthConfig(width=args.size[0], height=args.size[1], fps=args.fps, flash_hz=args.flash_hz,
                      duration=args.duration, seed=args.seed, head_motion=args.head_motion,
                      ambient=args.ambient, noise=args.noise, camera_drift=args.camera_drift,
                      truth_envs=tuple(args.truth_env or DEFAULT_TRUTH_ENVS), crf=args.crf)
    res = synthesize(args.out, cfg, progress=not args.quiet)
    print(f"wrote {res.video} ({res.frame_count} frames, {res.flash_frames} flash frames) and {res.truth}/")
    print("timings: " + ", ".join(f"{k} {v:.1f}s" for k, v in res.timings.items()))
    return 0


def _add_demo(sub) -> None:
    p = sub.add_parser("demo", help="synthesise a short capture and write a contact sheet (what `make demo` runs)",
                       description="Synthesise a short capture with the built-in defaults (no download) and "
                                   "write a contact sheet PNG: flash frames, the mirror-sphere crops, the "
                                   "truth relit under the built-in environments.",
                       formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("--out", type=Path, default=Path("out/demo"), help="output folder")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=_run_demo)


def _run_demo(args) -> int:
    from .pipeline.synth.contact_sheet import contact_sheet
    from .pipeline.synth.studio import SynthConfig, synthesize

    t0 = time.perf_counter()
    cfg = SynthConfig(width=480, height=270, duration=8.0, seed=1)
    res = synthesize(args.out / "capture", cfg, progress=not args.quiet)
    sheet = contact_sheet(args.out / "capture", args.out / "contact_sheet.png")
    print(f"synthetic capture: {res.video} ({res.frame_count} frames, {res.flash_frames} flash frames)")
    print(f"truth: {res.truth}/")
    print(f"contact sheet: {sheet}")
    print(f"done in {time.perf_counter() - t0:.1f} s")
    return 0


def build_parser() -> argparse.ArgumentParser:
    from . import __version__

    parser = argparse.ArgumentParser(
        prog="relight", description="Real-time relighting of a human face in video, on a CPU.")
    parser.add_argument("--version", action="version", version=f"relight {__version__}")
    sub = parser.add_subparsers(title="commands", metavar="COMMAND", required=True)
    _add_synth(sub)
    _add_demo(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.func(args)
    except RelightError as exc:
        print(f"relight: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("relight: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
