"""``relight live``: a live camera relit into a virtual camera, a preview page or a recording."""

from __future__ import annotations

import sys
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
    parse_size,
    parse_strength,
)


def add_parser(sub) -> None:
    from ..engine.composite import DEFAULT_MODE, DEFAULT_REGION, MODES, REGIONS
    from ..video_write import DEFAULT_CRF

    p = sub.add_parser(
        "live", help=COMMANDS["live"],
        description="Relight a live camera: frames from a webcam (v4l2 on Linux, avfoundation on macOS, dshow on "
                    "Windows) or a video file played at its own rate and looped, relit with a bundle and sent to "
                    "a virtual camera (pyvirtualcam: v4l2loopback, OBS Virtual Camera) that Zoom, Meet or OBS "
                    "pick as a webcam, to a preview page and/or to a recording. The latest frame always wins: "
                    "a slow frame drops the next, never builds a queue. Keys on a terminal: e next environment, "
                    "[ ] strength -/+0.1, m next mode, q quit; signals: SIGUSR1 next environment, SIGUSR2 "
                    "strength 1 -> 0.5 -> 0, SIGINT/SIGTERM stop cleanly.",
        formatter_class=DefaultsUnlessNone)
    p.add_argument("--bundle", type=Path, required=True, help="reflectance bundle of this face (relight capture)")
    p.add_argument("--env", required=True, action="append", metavar="FILE|builtin:NAME",
                   help="environment to light the face with; give it again for more (the e key and SIGUSR1 "
                        "switch between them): " + ENV_KINDS)
    p.add_argument("--camera", default=None, metavar="DEVICE|FILE",
                   help="camera index or device name (0, /dev/video2, 'FaceTime HD Camera'), or a video file "
                        "(played at its own rate, looped); default: the first camera")
    p.add_argument("--size", type=parse_size, default=None, metavar="WxH",
                   help="frame size asked of the camera (a file's frames are scaled to it); default: the camera's")
    p.add_argument("--fps", type=float, default=None,
                   help="frame rate asked of the camera and of the output; default: the camera's (a file's own)")
    p.add_argument("--duration", type=float, default=None, metavar="SECONDS",
                   help="stop after this many seconds (default: run until q or Ctrl-C)")
    p.add_argument("--mode", choices=MODES, default=DEFAULT_MODE,
                   help="transfer: the live light measured from the face and swapped for the target; ambient: the "
                        "ratio to the capture room's light; paste: the relit reference face (the paper)")
    p.add_argument("--region", choices=REGIONS, default=DEFAULT_REGION,
                   help=REGION_HELP)
    p.add_argument("--strength", type=parse_strength, default=1.0, help="blend with the camera's frame, 0 to 1")
    p.add_argument("--exposure", type=float, default=0.0,
                   help="stops (EV) on top of the automatic exposure matching")
    p.add_argument("--env-turn", type=float, default=0.0, metavar="DEG", help=ENV_TURN_HELP)
    p.add_argument("--env-spin", type=float, default=0.0, metavar="DEG_PER_S", help=ENV_SPIN_HELP)
    p.add_argument("--focal", type=parse_focal, default=None, metavar="PIXELS|ortho",
                   help=f"the camera's focal length in pixels, or 'ortho' (default: {focal_default()})")
    p.add_argument("--virtual-camera", action="store_true",
                   help="send the relit frames to a virtual camera (needs the pyvirtualcam extra and a driver; "
                        "without one the command says what to install and exits 2)")
    p.add_argument("--preview", action="store_true",
                   help="a page on loopback (its URL is printed): the relit frames with a before/after split, "
                        "and the light's controls - drag the key light on a lit ball, environments, uploads and "
                        "photos, strength, mode, exposure, turn, spin, a snapshot, lights saved by name")
    p.add_argument("--preview-port", type=int, default=0, help="the preview page's port (0: a free one)")
    p.add_argument("--lights-dir", type=Path, default=None, metavar="DIR",
                   help="where the page keeps uploads and saves lights by name (NAME.json, given back with "
                        "--env NAME.json); default: $XDG_CONFIG_HOME/relight/lights (~/.config/relight/lights)")
    p.add_argument("--record", type=Path, default=None, metavar="OUT.mp4",
                   help="record the relit frames (H.264, at the output rate; appears only when complete)")
    p.add_argument("--crf", type=int, default=DEFAULT_CRF, help="the recording's quality (lower = better, bigger)")
    p.add_argument("--stats-json", type=Path, default=None, metavar="FILE",
                   help="write the run's figures (frames in/out, dropped, latency, CPU) as JSON")
    p.set_defaults(func=_live_command)


def _live_command(args) -> int:
    import json

    import numpy as np

    import relight

    from ..apps.live import run_live
    from ..apps.virtual_camera import VirtualCameraMissing, check_virtual_camera_backend
    from ..errors import InputError
    from ..imageio import atomic_path

    if not (args.virtual_camera or args.preview or args.record):
        raise InputError("nothing to send the frames to: add --virtual-camera, --preview and/or --record OUT.mp4")
    if args.fps is not None and not (1.0 <= args.fps <= 240.0):
        raise InputError(f"--fps {args.fps}: use 1 to 240")
    if args.duration is not None and not (np.isfinite(args.duration) and args.duration > 0):
        raise InputError(f"--duration {args.duration}: use a positive number of seconds")
    if not (0 <= args.crf <= 51):
        raise InputError(f"--crf {args.crf}: use 0 to 51")
    if not (0 <= args.preview_port <= 65535):
        raise InputError(f"--preview-port {args.preview_port}: use 0 to 65535")
    if args.record is not None and args.record.suffix.lower() not in (".mp4", ".mov", ".mkv"):
        raise InputError(f"--record {args.record}: name an .mp4, .mov or .mkv file")
    if args.virtual_camera:
        try:
            check_virtual_camera_backend()
        except VirtualCameraMissing as exc:
            print(f"relight: {exc}", file=sys.stderr)
            return 2
    bundle = relight.load_bundle(args.bundle)

    def ready(res):
        where = [f"camera {res.camera}"]
        if res.preview:
            where.append(f"preview {res.preview}")
        if args.record:
            where.append(f"recording {args.record}")
        print("relight live: " + ", ".join(where) + "; keys e [ ] m q, Ctrl-C stops", file=sys.stderr, flush=True)

    try:
        res = run_live(bundle, args.env, camera=args.camera, size=args.size, fps=args.fps, duration=args.duration,
                       mode=args.mode, region=args.region, strength=args.strength, focal=args.focal,
                       exposure=args.exposure, env_turn=args.env_turn, env_spin=args.env_spin,
                       lights_dir=args.lights_dir,
                       virtual_camera=args.virtual_camera,
                       preview=args.preview, preview_port=args.preview_port, record=args.record, crf=args.crf,
                       on_ready=ready)
    except VirtualCameraMissing as exc:
        print(f"relight: {exc}", file=sys.stderr)
        return 2
    lat = res.latency_ms
    print(f"relight live: {res.frames_in} frames in ({res.fps_in:.1f} fps), {res.frames_relit} relit "
          f"({res.fps_relit:.1f} fps, {res.faces} with a face), {res.frames_out} out, {res.dropped} dropped; "
          f"latency median {lat.get('median', 0):.1f} ms, p95 {lat.get('p95', 0):.1f} ms; CPU {res.cpu_percent:.0f}%; "
          f"stopped by {res.stopped_by or 'end'}")
    if args.stats_json:
        with atomic_path(args.stats_json) as tmp:
            Path(tmp).write_text(json.dumps(res.as_json(), indent=1))
    return 0


