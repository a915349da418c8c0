"""``relight bench NAME``: every benchmark's parser and how it is run (the measuring is
:mod:`relight.bench`'s)."""

from __future__ import annotations

import argparse
from pathlib import Path

from .common import COMMANDS, name_table, parse_size


def add_parser(sub) -> None:
    p = sub.add_parser("bench", help=COMMANDS["bench"],
                       description="Benchmarks: speed, memory and accuracy, measured here and printed.")
    bsub = p.add_subparsers(title="benchmarks", metavar="NAME")
    p.set_defaults(func=lambda args: _list_benchmarks(bsub))  # `relight bench` alone: the list
    # One parser per benchmark, in the order --help lists them; each takes its defaults from its module.
    _add_capture(bsub)
    _add_relight(bsub)
    _add_video(bsub)
    _add_serve(bsub)
    _add_live(bsub)
    _add_fuzz(bsub)
    _add_crash(bsub)
    _add_soak(bsub)
    _add_accuracy(bsub)


def _list_benchmarks(bsub) -> int:
    """What ``relight bench`` alone prints: the benchmarks, one line each (exit status 0)."""
    rows = name_table({a.dest: a.help for a in bsub._choices_actions})
    print(f"usage: relight bench NAME ...\n\nbenchmarks:\n{rows}\n'relight bench NAME --help' lists a "
          "benchmark's flags.")
    return 0


def _add_capture(bsub) -> None:
    """The parser of ``relight bench capture``: the capture pipeline's time, memory and accuracy."""
    c = bsub.add_parser("capture", help="capture pipeline: time per stage, peak memory, accuracy vs truth",
                        description="Synthesise captures (cached) and run `relight capture` on each in a fresh "
                                    "process: total and per-stage time, peak memory, and accuracy against the "
                                    "truth (flash frames, registration, light directions, normals), bundle size; "
                                    "goals: real time up to 960x540, twice real time at 1080p/4K, <= 3 GB. Writes "
                                    "bench.json, capture_timings.png and (several scenarios) capture_growth.png.",
                        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    c.add_argument("-o", "--out", type=Path, default=Path("out/bench-capture"), help="output and cache folder")
    c.add_argument("--quick", action="store_true", help="one short capture (10 s at 480x270) instead of the set")
    c.add_argument("--growth", action="store_true",
                   help="the growth series (640x360 at 6/12/24 s, 12 s at 480x270/640x360/960x540) and its plot, "
                        "capture_growth.png")
    c.add_argument("--only", nargs="+", metavar="NAME",
                   help="run only the scenarios whose name contains one of these (e.g. 640x360 1920x1080)")
    c.add_argument("--quiet", action="store_true", help="no progress output")
    c.set_defaults(func=_run_bench_capture)


def _add_relight(bsub) -> None:
    """The parser of ``relight bench relight``: the relighting engine's error against run time."""
    r = bsub.add_parser("relight", help="relighting: error against run time, exact vs compact vs NumPy",
                        description="Capture a synthetic 960x540 face (cached) and time the relighting engine on "
                                    "it: exact and compact paths at several tolerances, their NumPy twins and the "
                                    "same product with NumPy/BLAS, head turning every call; error against the "
                                    "exact path and the synthetic truth; bytes moved against this machine's "
                                    "measured memory bandwidth. Writes bench.json and "
                                    "relight_error_vs_time.png.",
                        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    r.add_argument("-o", "--out", type=Path, default=Path("out/bench-relight"), help="output and cache folder")
    r.add_argument("--quick", action="store_true", help="a 10 s 480x270 capture instead (for CI)")
    r.add_argument("--quiet", action="store_true", help="no progress output")
    r.set_defaults(func=_run_bench_relight)


def _add_video(bsub) -> None:
    """The parser of ``relight bench video``: head pose and speed of the per-frame path."""
    from ..bench import video
    from ..engine.composite import DEFAULT_MODE, DEFAULT_REGION, MODES, REGIONS

    v = bsub.add_parser("video", help="per-frame video path: head-pose error and speed on synthetic live video",
                        description="Synthesise live videos of the head turning (cached) and a bundle of the same "
                                    "head (a 24 s capture at a 4 Hz flash), then measure the head rotation error "
                                    "against the truth (at 640x360 also on two other synthetic heads, each with "
                                    "its own capture), the per-frame path's time per stage (decode/encode "
                                    "excluded), flicker, and a whole `relight filter` run in a fresh process "
                                    "against the clip's duration; the live frame against its truth (the clip "
                                    "rendered under the target light at every pose: PSNR over the person and the "
                                    "face, the background's change, the seam, flicker; live-frame/sheet_*.png); "
                                    "and real faces: a clip of each subject's photo "
                                    "under a side light, moving, relit toward a held-out light in every mode, "
                                    "against the photo under that light. Writes bench.json, video_pose.png and "
                                    "video_frames.png.",
                        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    v.add_argument("-o", "--out", type=Path, default=Path("out/bench-video"), help="output and cache folder")
    v.add_argument("--env", default=video.ENV, metavar="FILE|builtin:NAME", help="environment to relight with")
    v.add_argument("--mode", choices=MODES, default=DEFAULT_MODE,
                   help="compositing mode of the synthetic clips (the real faces run every mode)")
    v.add_argument("--region", choices=REGIONS, default=DEFAULT_REGION,
                   help="what mode transfer relights in the live-frame and real-face runs: the whole person or "
                        "the face alone (relight filter --region)")
    v.add_argument("--faces", type=Path, default=None,
                   help="real faces: a folder with one RTI image set per subject (default: "
                        "../shared/data/faces-yale when present); each becomes a moving clip relit toward a "
                        "held-out light")
    v.add_argument("--quick", action="store_true", help="480x270 clips of 4 s and one real face instead (for CI)")
    v.add_argument("--quiet", action="store_true", help="no progress output")
    v.set_defaults(func=_run_bench_video)


def _add_serve(bsub) -> None:
    """The parser of ``relight bench serve``: the frame service under websocket load."""
    from ..bench import serve

    sv = bsub.add_parser("serve", help="the frame service under load: websocket clients on loopback",
                         description="Start relight serve in a fresh process and drive it with websocket clients "
                                     "sending 640x360 JPEG frames of a synthetic live video at a fixed rate: "
                                     "errors, dropped frames, relit frames per second, round-trip p50/p95/p99 and "
                                     "the hypervisor's steal, server memory before and after; then one client "
                                     "alone sending 1280x720 frames (--single-size); and the start-up time "
                                     "(launch -> ready) of a first and a second start; and single POST /v1/relight "
                                     "requests (a face, noise, a session) beside the JPEG decode + encode floor. "
                                     "Writes bench.json.",
                         formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    sv.add_argument("-o", "--out", type=Path, default=Path("out/bench-serve"), help="output and cache folder")
    sv.add_argument("--bundle", type=Path, default=None, help="bundle to serve (default: a synthetic 640x360 one)")
    sv.add_argument("--clients", type=int, default=serve.CLIENTS, help="websocket clients at once")
    sv.add_argument("--fps", type=float, default=serve.FPS, help="frames per second each client sends")
    sv.add_argument("--duration", type=float, default=serve.DURATION_S, help="seconds of load")
    sv.add_argument("--start-bundle", type=Path, default=None,
                    help="bundle whose start-up (launch -> ready) is timed, twice (default: the served one)")
    sv.add_argument("--single-size", type=parse_size, default=serve.SINGLE_SIZE, metavar="WxH",
                    help="frame size the single client sends")
    sv.add_argument("--quick", action="store_true", help="8 s of load and 640x360 for the single client (for CI)")
    sv.add_argument("--quiet", action="store_true", help="no progress output")
    sv.set_defaults(func=_run_bench_serve)


def _add_live(bsub) -> None:
    """The parser of ``relight bench live``: relight live and the browser page."""
    from ..bench import live

    lv = bsub.add_parser("live", help="relight live and the browser page (WebRTC vs websocket) on one clip",
                         description="relight live with a synthetic clip played as the camera (640x360 and "
                                     "1280x720, into the preview page with no viewer; --record: recorded too): fps "
                                     "in/relit/out, dropped, latency, CPU; then the browser "
                                     "page in headless Chromium over WebRTC and over the websocket on the same "
                                     "640x360 clip: fps, round trip from the frames' bar codes, bandwidth. Writes "
                                     "bench.json.",
                         formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    lv.add_argument("-o", "--out", type=Path, default=Path("out/bench-live"), help="output and cache folder")
    lv.add_argument("--seconds", type=float, default=live.SECONDS, help="seconds measured per case")
    lv.add_argument("--no-browser", action="store_true", help="leave out the browser page")
    lv.add_argument("--record", action="store_true",
                    help="measure each size recorded as well (H.264 ultrafast at the output rate)")
    lv.add_argument("--quick", action="store_true", help=f"640x360 only, {live.QUICK_SECONDS:g} s per case (for CI)")
    lv.add_argument("--quiet", action="store_true", help="no progress output")
    lv.set_defaults(func=_run_bench_live)


def _add_fuzz(bsub) -> None:
    """The parser of ``relight bench fuzz``: the readers of hostile input, fuzzed."""
    from ..bench import fuzz

    fz = bsub.add_parser("fuzz", help="every reader of hostile input fed mutated real files (Hypothesis)",
                         description="Fuzz the bundle loader (and the relighter on what it accepts), the .lp parser, "
                                     "the environment upload's loader, POST /v1/relight's image decoder, the "
                                     "websocket's control messages and the video prober with mutations of real "
                                     "files (../shared/data and files made from them), each target in its own "
                                     "process: inputs tried, accepted, refused with our error, crashes (shrunk "
                                     "and kept), the largest allocation one input made. Writes bench.json.",
                         formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    fz.add_argument("-o", "--out", type=Path, default=Path("out/bench-fuzz"), help="output and seed folder")
    fz.add_argument("--examples", type=int, default=None,
                    help=f"inputs per target (default {fuzz.DEFAULT_EXAMPLES}; {fuzz.QUICK_EXAMPLES} with --quick)")
    fz.add_argument("--target", action="append", default=None, metavar="NAME",
                    help="fuzz only this target (repeatable): " + ", ".join(fuzz.TARGETS))
    fz.add_argument("--seed", type=int, default=0, help="random seed (another seed tries other inputs)")
    fz.add_argument("--quick", action="store_true", help=f"{fuzz.QUICK_EXAMPLES} inputs per target (for CI)")
    fz.add_argument("--quiet", action="store_true", help="no progress output")
    fz.set_defaults(func=_run_bench_fuzz)


def _add_crash(bsub) -> None:
    """The parser of ``relight bench crash``: the writers killed at random moments."""
    from ..bench import crash

    cr = bsub.add_parser("crash", help="writers killed with SIGKILL at random moments: no damaged file",
                         description="Kill relight capture (bundle), relight filter (video) and relight-serve taking "
                                     "an environment upload with SIGKILL at random moments (half in the last fifth "
                                     "of a run) while a previous result is in place; check the target is the "
                                     "previous file or a whole new one, and that temporaries left are removed by "
                                     "the next run. Needs ../shared/data (real faces). Writes bench.json.",
                         formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    cr.add_argument("-o", "--out", type=Path, default=Path("out/bench-crash"), help="output and work folder")
    cr.add_argument("--kills", type=int, default=None,
                    help=f"kills per writer (default {crash.DEFAULT_KILLS}; {crash.QUICK_KILLS} with --quick)")
    cr.add_argument("--seed", type=int, default=0, help="random seed of the kill times")
    cr.add_argument("--quick", action="store_true", help=f"{crash.QUICK_KILLS} kills per writer (for CI)")
    cr.add_argument("--quiet", action="store_true", help="no progress output")
    cr.set_defaults(func=_run_bench_crash)


def _add_soak(bsub) -> None:
    """The parser of ``relight bench soak``: relight-serve for minutes under mixed clients."""
    from ..bench import soak

    so = bsub.add_parser("soak", help="relight-serve for minutes with good and misbehaving clients",
                         description=f"A real relight-serve with {soak.CLIENTS} websocket clients at {soak.FPS:g} "
                                     "fps for --minutes, beside clients that vanish, send garbage, never read, or "
                                     "post broken frames: errors seen by the good clients, round trip p50/p95/p99 "
                                     "per minute, the server's RSS, open file descriptors and threads with their "
                                     "slopes. Writes bench.json and soak.png.",
                         formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    so.add_argument("-o", "--out", type=Path, default=Path("out/bench-soak"), help="output and cache folder")
    so.add_argument("--minutes", type=float, default=soak.MINUTES, help="length of the soak")
    so.add_argument("--bundle", type=Path, default=None, help="bundle to serve (default: a synthetic 640x360 one)")
    so.add_argument("--quick", action="store_true", help=f"{soak.QUICK_MINUTES:g} minutes (for CI)")
    so.add_argument("--quiet", action="store_true", help="no progress output")
    so.set_defaults(func=_run_bench_soak)


def _add_accuracy(bsub) -> None:
    """The parser of ``relight bench accuracy``: every method against the truth."""
    a = bsub.add_parser("accuracy", help="every method against the truth and real held-out photos: one report",
                        description="Synthesise several captures (cached), build a bundle per method (full, its "
                                    "ablations, barycentric, PTM, HSH orders 3 and 2, RBF) from the same samples, "
                                    "and measure each against the truth (PSNR/SSIM under in-hull and whole-sphere "
                                    "environments, single-light error heat maps) and on a real RTI set's held-out "
                                    "photos; run time beside the error; the numerical stability suite. Writes "
                                    "bench.json, report.md and PNG plots.",
                        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    a.add_argument("-o", "--out", type=Path, default=Path("out/bench-accuracy"), help="output and cache folder")
    a.add_argument("--rti", type=Path, default=None,
                   help="real RTI data: a folder with Dome/ and Test/ image sets (default: ../shared/data/rti-dome "
                        "when present)")
    a.add_argument("--faces", type=Path, default=None,
                   help="real faces: a folder with one RTI image set per subject (default: "
                        "../shared/data/faces-yale when present)")
    a.add_argument("--quick", action="store_true",
                   help="one short 384x216 scene instead of five, the real set at half size and one face (for CI)")
    a.add_argument("--quiet", action="store_true", help="no progress output")
    a.set_defaults(func=_run_bench_accuracy)

def _run_bench_accuracy(args) -> int:
    from ..bench import accuracy, accuracy_report
    from ..bench.real_data import shared_data
    from ..errors import InputError

    rti = args.rti if args.rti is not None else shared_data("rti-dome", "Dome/dirs.lp")
    if args.rti is not None and not (args.rti / "Dome" / "dirs.lp").exists():
        raise InputError(f"--rti {args.rti}: expected Dome/dirs.lp and Test/dirs.lp inside")
    faces = args.faces if args.faces is not None else shared_data("faces-yale", "*/dirs.lp")
    if args.faces is not None and not accuracy.face_subjects(args.faces):
        raise InputError(f"--faces {args.faces}: expected one folder per subject, each with dirs.lp")
    doc = accuracy.run(args.out, quick=args.quick, progress=not args.quiet, rti=rti, faces=faces)
    print(accuracy_report.table(doc))
    print(f"wrote {args.out / 'bench.json'}, {args.out / 'report.md'} and its PNG plots")
    return 0


def _run_bench_capture(args) -> int:
    from ..bench import capture as benchmark

    doc = benchmark.run(args.out, quick=args.quick, progress=not args.quiet, growth=args.growth, only=args.only)
    print(benchmark.table(doc))
    print(f"wrote {args.out / ('bench-growth.json' if args.growth else 'bench.json')} and "
          f"{args.out / 'capture_timings.png'}")
    return 0


def _run_bench_relight(args) -> int:
    from ..bench import relight as benchmark

    doc = benchmark.run(args.out, quick=args.quick, progress=not args.quiet)
    print(benchmark.table(doc))
    print(f"wrote {args.out / 'bench.json'} and {args.out / 'relight_error_vs_time.png'}")
    return 0


def _run_bench_video(args) -> int:
    from ..bench import video as benchmark
    from ..bench.accuracy import face_subjects
    from ..bench.real_data import shared_data
    from ..errors import InputError

    faces = args.faces if args.faces is not None else shared_data("faces-yale", "*/dirs.lp")
    if args.faces is not None and not face_subjects(args.faces):
        raise InputError(f"--faces {args.faces}: expected one folder per subject, each with dirs.lp")
    doc = benchmark.run(args.out, quick=args.quick, progress=not args.quiet, env=args.env, mode=args.mode,
                        faces=faces, region=args.region)
    print(benchmark.table(doc))
    print(f"wrote {args.out / 'bench.json'}, {args.out / 'video_pose.png'}, {args.out / 'video_frames.png'} and a "
          "before/after sheet per real face (faces/*/sheet.png)")
    return 0


def _run_bench_live(args) -> int:
    from ..bench import live
    from ..errors import InputError

    if not (1 <= args.seconds <= 600):
        raise InputError(f"--seconds {args.seconds}: use 1 to 600")
    doc = live.run(args.out, quick=args.quick, progress=not args.quiet, seconds=args.seconds,
                   browser=not args.no_browser, record=args.record)
    print(live.table(doc))
    print(f"wrote {args.out / 'bench.json'}")
    return 0


def _run_bench_fuzz(args) -> int:
    from ..bench import fuzz
    from ..errors import InputError

    examples = args.examples or (fuzz.QUICK_EXAMPLES if args.quick else fuzz.DEFAULT_EXAMPLES)
    if not (1 <= examples <= 10_000_000):
        raise InputError(f"--examples {examples}: use 1 to 10000000")
    unknown = sorted(set(args.target or ()) - set(fuzz.TARGETS))
    if unknown:
        raise InputError(f"--target {', '.join(unknown)}: choose from {', '.join(fuzz.TARGETS)}")
    doc = fuzz.run(args.out, targets=args.target, examples=examples, seed=args.seed, progress=not args.quiet)
    print(fuzz.table(doc))
    print(f"wrote {args.out / 'bench.json'}")
    return 1 if any(r.get("crashes") for r in doc["targets"]) else 0


def _run_bench_crash(args) -> int:
    from ..bench import crash
    from ..errors import InputError

    kills = args.kills or (crash.QUICK_KILLS if args.quick else crash.DEFAULT_KILLS)
    if not (1 <= kills <= 10_000):
        raise InputError(f"--kills {kills}: use 1 to 10000")
    doc = crash.run(args.out, kills=kills, seed=args.seed, progress=not args.quiet)
    print(crash.table(doc))
    print(f"wrote {args.out / 'bench.json'}")
    return 1 if any(r["damaged_total"] for r in doc["writers"]) else 0


def _run_bench_soak(args) -> int:
    from ..bench import soak
    from ..errors import InputError

    minutes = soak.QUICK_MINUTES if args.quick else args.minutes
    if not (0.5 <= minutes <= 24 * 60):
        raise InputError(f"--minutes {minutes}: use 0.5 to 1440")
    doc = soak.run(args.out, minutes=minutes, bundle=args.bundle, progress=not args.quiet)
    print(soak.table(doc))
    print(f"wrote {args.out / 'bench.json'} and {args.out / 'soak.png'}")
    return 0 if doc["good"]["errors"] == 0 and doc["ready_after"] else 1


def _run_bench_serve(args) -> int:
    from ..bench import serve as loadtest
    from ..errors import InputError

    if not (1 <= args.clients <= 64) or not (1 <= args.fps <= 120) or not (1 <= args.duration <= 3600):
        raise InputError("--clients 1..64, --fps 1..120, --duration 1..3600 seconds")
    doc = loadtest.run(args.out, bundle=args.bundle, clients=args.clients, fps=args.fps, duration=args.duration,
                       quick=args.quick, progress=not args.quiet, single_size=tuple(args.single_size),
                       start_bundle=args.start_bundle)
    print(loadtest.table(doc))
    print(f"wrote {args.out / 'bench.json'}")
    return 0


