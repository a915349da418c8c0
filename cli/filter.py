"""``relight filter``: the face in a video (or an image sequence) relit, frame by frame."""

from __future__ import annotations

import time
from pathlib import Path

from .common import (
    COMMANDS,
    ENV_KINDS,
    ENV_SPIN_HELP,
    ENV_TURN_HELP,
    REGION_HELP,
    DefaultsUnlessNone,
    focal_default,
    parse_focal,
    parse_strength,
)


def add_parser(sub) -> None:
    from ..engine.composite import DEFAULT_MODE, DEFAULT_REGION, MODES, REGIONS
    from ..video_write import DEFAULT_CRF, DEFAULT_PRESET, X264_PRESETS

    p = sub.add_parser(
        "filter", help=COMMANDS["filter"],
        description="Relight the face of every frame of a video (any container FFmpeg reads) or a folder of "
                    "images with a reflectance bundle: the head is tracked, its rotation turns the environment "
                    "the other way, and the relit light is warped onto the face. Audio and timestamps are "
                    "kept; OUT appears only when complete. Frames without a face pass through unchanged.",
        formatter_class=DefaultsUnlessNone)
    p.add_argument("input", type=Path, metavar="IN", help="video file, or a folder of images (a sequence)")
    p.add_argument("output", type=Path, metavar="OUT",
                   help="video to write (.mp4/.mov/.mkv/.avi: H.264, .webm: VP9), or a folder for PNG frames")
    p.add_argument("--bundle", type=Path, required=True, help="reflectance bundle of this face (relight capture)")
    p.add_argument("--env", required=True, metavar="FILE|builtin:NAME",
                   help="environment to light the face with: " + ENV_KINDS)
    p.add_argument("--mode", choices=MODES, default=DEFAULT_MODE,
                   help="transfer: the live face relit for real - its own light measured from it and swapped for "
                        "the target (eyes, mouth, expression kept where lit; the bundle's prediction where the live "
                        "light left the face dark); ambient: the ratio to the capture room's light (the live "
                        "room's light stays); paste: the relit reference face warped in (the paper)")
    p.add_argument("--region", choices=REGIONS, default=DEFAULT_REGION,
                   help=REGION_HELP)
    p.add_argument("--fixed-env", action="store_true",
                   help="do not turn the environment against the head's rotation (the light follows the face)")
    p.add_argument("--strength", type=parse_strength, default=1.0, help="blend with the original frame, 0 to 1")
    p.add_argument("--exposure", type=float, default=0.0,
                   help="stops (EV) on top of the automatic exposure matching")
    p.add_argument("--env-turn", type=float, default=0.0, metavar="DEG", help=ENV_TURN_HELP)
    p.add_argument("--env-spin", type=float, default=0.0, metavar="DEG_PER_S", help=ENV_SPIN_HELP)
    p.add_argument("--focal", type=parse_focal, default=None, metavar="PIXELS|ortho",
                   help=f"the video's focal length in pixels (default: {focal_default()}, a phone or "
                        "webcam); 'ortho' for an orthographic camera such as relight synth's")
    p.add_argument("--fps", type=float, default=30.0, help="frame rate of an image-sequence input")
    p.add_argument("--crf", type=int, default=DEFAULT_CRF, help="output quality (lower = better, bigger)")
    p.add_argument("--preset", choices=X264_PRESETS, default=DEFAULT_PRESET,
                   help="the H.264 encoder's settings: realtime (x264's ultrafast with CABAC, B-frames and "
                        "deblocking: a 720p frame in about half of superfast's CPU, files within a fifth of its "
                        "size) or one of x264's presets (slower ones make smaller files more slowly); .webm's "
                        "VP9 keeps its real-time settings")
    p.add_argument("--report", type=Path, metavar="DIR",
                   help="write DIR/report.json: head_rotation per frame, timings, counts")
    p.add_argument("--virtual-camera", action="store_true",
                   help="also send the frames to a virtual camera (needs the pyvirtualcam extra)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=_filter_command)


def _filter_command(args) -> int:
    t0 = time.perf_counter()
    import numpy as np

    import relight

    from ..apps.filter import run_filter
    from ..engine.frame_settings import EXPOSURE_RANGE_EV
    from ..errors import InputError

    lo, hi = EXPOSURE_RANGE_EV
    if not (np.isfinite(args.exposure) and lo <= args.exposure <= hi):
        raise InputError(f"--exposure {args.exposure}: use stops between {lo:g} and {hi:g}")
    if not (1.0 <= args.fps <= 240.0):
        raise InputError(f"--fps {args.fps}: use 1 to 240")
    if not (0 <= args.crf <= 51):
        raise InputError(f"--crf {args.crf}: use 0 to 51")
    if not args.input.exists():
        raise InputError(f"{args.input}: no such file or folder")
    bundle = relight.load_bundle(args.bundle)
    env = relight.load_environment(args.env)
    res = run_filter(args.input, args.output, bundle, env, mode=args.mode, region=args.region,
                     fixed_env=args.fixed_env, env_turn=args.env_turn, env_spin=args.env_spin,
                     strength=args.strength, exposure=args.exposure, focal=args.focal, fps=args.fps, crf=args.crf,
                     preset=args.preset,
                     report_dir=args.report, virtual_camera=args.virtual_camera, progress=not args.quiet,
                     start_time=t0)
    print(f"wrote {res.out}: {res.summary()}")
    for note in res.notes:
        print(f"note: {note}")
    if args.report:
        print(f"report: {args.report / 'report.json'}")
    return 0


