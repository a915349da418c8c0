"""The ``relight`` command line.

Subcommands: ``synth`` (the synthetic capture studio), ``demo`` (what ``make demo`` runs).
Every error a user can cause ends in one line saying what to change, exit status 2.
"""

from __future__ import annotations

import argparse
import math
import os
import re
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


#: A value that starts with '-' yet is a number or a list of numbers ("-0.5,0.2,0.8", "-1e-3",
#: "-20,0"): argparse takes it for an option ("expected one argument"), so it is joined to the
#: long flag before it (``--light -0.5,0.2,0.8`` -> ``--light=-0.5,0.2,0.8``).
_NEGATIVE_VALUE = re.compile(r"^-(?:\d|\.\d)[0-9eE.+\-,]*$")


def negative_values_joined(argv: list[str]) -> list[str]:
    """``argv`` with every negative number (or number list) joined to the long flag before it,
    so flags taking numbers accept negative values as users type them."""
    out: list[str] = []
    for tok in argv:
        prev = out[-1] if out else ""
        if (_NEGATIVE_VALUE.match(tok) and prev.startswith("--") and "=" not in prev and prev != "--"
                and "--" not in out):
            out[-1] = f"{prev}={tok}"
        else:
            out.append(tok)
    return out


def parse_args(parser: argparse.ArgumentParser, argv: list[str] | None = None) -> argparse.Namespace:
    """``parser.parse_args`` of ``argv`` (default: the command line) with negative values joined
    to their flags (:func:`negative_values_joined`): what every relight entry point parses with."""
    return parser.parse_args(negative_values_joined(sys.argv[1:] if argv is None else list(argv)))


class _DefaultsUnlessNone(argparse.ArgumentDefaultsHelpFormatter):
    """Shows defaults, except None (those flags say in their help what they default to)."""

    def _get_help_string(self, action):
        if action.default is None:
            return action.help
        return super()._get_help_string(action)


#: The commands in the order --help lists them, and each one's line there. Only the command being
#: run has its full parser built (importing what its defaults come from); the others are a line each,
#: so `relight filter ...` does not import the capture pipeline or the web app to parse its arguments.
COMMANDS = {
    "synth": "simulate a two-phone capture of a synthetic head, with its ground truth",
    "capture": "turn a capture video (or an RTI image set) into a reflectance bundle",
    "render": "relight a bundle's face under an environment or one light, to an image",
    "bench": "benchmarks that print measured figures",
    "demo": "synthesise a capture, turn it into a bundle, show both (what `make demo` runs)",
    "filter": "relight the face in a video (a virtual-camera-style batch filter)",
    "live": "relight a live camera into a virtual camera, a preview page or a recording",
    "serve": "serve relighting of video frames over HTTP (also: relight-serve)",
}


def _add_synth(sub) -> None:
    from .pipeline.synth.live import AUDIO_KINDS, LiveConfig
    from .pipeline.synth.studio import DEFAULT_TRUTH_ENVS, SynthConfig

    d = SynthConfig()
    live = LiveConfig()
    p = sub.add_parser(
        "synth", help=COMMANDS["synth"],
        description="Simulate the paper's acquisition on a procedural head whose truth is known: a phone "
                    "films the face while a second phone's flash blinks and is waved over the front "
                    "hemisphere, a mirror sphere beside the head shows the flash. Writes OUT/capture.mp4 "
                    "(H.264) and OUT/truth/ (meta.json, mask.png, normals/depth/albedo EXR, head.ply, "
                    "relit_<env>.exr per truth environment, olat_<name>.exr one-light images, ambient.exr). "
                    "With --live: OUT/live.mp4 (H.264 + AAC) of the same head (same --seed and --size) turning "
                    "and moving under the room light, and OUT/truth/ (meta.json with the head rotation and "
                    "translation of every frame, reference.png, mask_reference.png; with --truth-env, every frame "
                    "under each environment, truth/live_<stem>/NNNN.png, and truth/silhouette/NNNN.png).",
        formatter_class=_DefaultsUnlessNone)
    p.add_argument("out", type=Path, help="output folder (created if missing)")
    p.add_argument("--seed", type=int, default=d.seed,
                   help="random seed: flash timing, hand path, head motion, noise, skin texture")
    p.add_argument("--fps", type=float, default=d.fps, help="camera frame rate (frames per second)")
    p.add_argument("--flash-hz", type=float, default=d.flash_hz,
                   help="flash blink rate (Hz); not synchronised with the camera")
    p.add_argument("--duration", type=float, default=None,
                   help=f"capture length in seconds (default {d.duration:g}; with --live {live.duration:g})")
    p.add_argument("--size", type=_size, default=(d.width, d.height), metavar="WxH",
                   help="frame size in pixels (even numbers)")
    p.add_argument("--truth-env", action="append", default=None, metavar="FILE|builtin:NAME",
                   help="environment to render the truth under (repeatable; default: "
                        + ", ".join(DEFAULT_TRUTH_ENVS) + "); with --live none by default, and each "
                        "writes every frame with the person under it (truth/live_<stem>/NNNN.png, 8-bit sRGB) "
                        "and the person's pixels (truth/silhouette/NNNN.png)")
    p.add_argument("--head-motion", "--head", dest="head_motion", type=float, default=d.head_motion,
                   help="head motion, times the paper's limits (3 px at 540 rows, 0.35 deg); 0 = still")
    p.add_argument("--head-mesh", metavar="FILE",
                   help="a textured head mesh (.glb/.gltf/.obj/.ply, +Y up, facing +Z) instead of the procedural "
                        "head; its face is placed and sized as the procedural face")
    p.add_argument("--head-texture", metavar="FILE",
                   help="with --head-mesh: its colour map (used as albedo), when the mesh does not embed one")
    p.add_argument("--head-normal-map", metavar="FILE",
                   help="with --head-mesh: a tangent-space normal map (OpenGL convention: green toward +v)")
    p.add_argument("--head-specular-map", metavar="FILE",
                   help="with --head-mesh: a grey specular map (white: the oiliest skin)")
    p.add_argument("--head-texture-flip", action="store_true",
                   help="with --head-mesh: its images are stored the other way up from its texture coordinates "
                        "(texture coordinates count v up from the bottom row, as OBJ and trimesh do)")
    p.add_argument("--ambient", type=float, default=d.ambient, help="room light strength, times the default")
    p.add_argument("--noise", type=float, default=d.noise, help="sensor noise, times the default; 0 = none")
    p.add_argument("--camera-drift", action="store_true",
                   help="simulate a phone's auto-exposure and white-balance drift")
    p.add_argument("--sparse-sides", action="store_true",
                   help="wave the flash quickly through the sides: sparse samples there (the paper's Fig. 14)")
    p.add_argument("--crf", type=int, default=None,
                   help=f"H.264 quality, lower = better and bigger (default {d.crf}; with --live {live.crf})")
    p.add_argument("--live", action="store_true",
                   help="a video of the head turning and moving under room light, with an audio track, and "
                        "per-frame head rotation truth, instead of a capture (uses --size, --seed, --fps, "
                        "--duration, --noise, --ambient, --crf, --audio, --quiet)")
    p.add_argument("--audio", choices=AUDIO_KINDS, default=live.audio,
                   help="--live only: the audio track, a 440 Hz tone, white noise, or none (no audio stream)")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=_run_synth)


def _head_mesh_args(args) -> dict:
    """The --head-mesh flags as SynthConfig / LiveConfig fields."""
    return {"head_mesh": args.head_mesh, "head_texture": args.head_texture, "head_normal_map": args.head_normal_map,
            "head_specular_map": args.head_specular_map, "head_texture_flip": args.head_texture_flip}


def _run_synth(args) -> int:
    from .errors import InputError

    if args.live:
        return _run_synth_live(args)
    if args.audio != "tone":
        raise InputError("--audio applies to --live videos only; add --live or leave --audio out")
    from .pipeline.synth.studio import DEFAULT_TRUTH_ENVS, SynthConfig, synthesize

    d = SynthConfig()
    cfg = SynthConfig(width=args.size[0], height=args.size[1], fps=args.fps, flash_hz=args.flash_hz,
                      duration=d.duration if args.duration is None else args.duration, seed=args.seed,
                      head_motion=args.head_motion, ambient=args.ambient, noise=args.noise,
                      camera_drift=args.camera_drift, sparse_sides=args.sparse_sides,
                      truth_envs=tuple(args.truth_env or DEFAULT_TRUTH_ENVS),
                      crf=d.crf if args.crf is None else args.crf, **_head_mesh_args(args))
    res = synthesize(args.out, cfg, progress=not args.quiet)
    print(f"wrote {res.video} ({res.frame_count} frames, {res.flash_frames} flash frames) and {res.truth}/")
    print("timings: " + ", ".join(f"{k} {v:.1f}s" for k, v in res.timings.items()))
    return 0


def _run_synth_live(args) -> int:
    from .envmap import environment_stem
    from .errors import InputError
    from .pipeline.synth.live import LiveConfig, synthesize_live
    from .pipeline.synth.studio import SynthConfig

    d, s = LiveConfig(), SynthConfig()
    capture_only = [flag for flag, used in (("--flash-hz", args.flash_hz != s.flash_hz),
                                            ("--head-motion", args.head_motion != s.head_motion),
                                            ("--camera-drift", args.camera_drift),
                                            ("--sparse-sides", args.sparse_sides)) if used]
    if capture_only:
        raise InputError(f"{', '.join(capture_only)} apply to captures, not --live videos; leave them out "
                         f"(a live video's light is the room's alone)")
    cfg = LiveConfig(width=args.size[0], height=args.size[1], fps=args.fps,
                     duration=d.duration if args.duration is None else args.duration, seed=args.seed,
                     ambient=args.ambient, noise=args.noise, crf=d.crf if args.crf is None else args.crf,
                     audio=args.audio, truth_envs=tuple(args.truth_env or ()), **_head_mesh_args(args))
    res = synthesize_live(args.out, cfg, progress=not args.quiet)
    audio = "no audio" if cfg.audio == "none" else f"{cfg.audio} audio"
    print(f"wrote {res.video} ({res.frame_count} frames, {cfg.width}x{cfg.height} at {cfg.fps:g} fps, {audio}), "
          f"{res.meta} (per-frame head rotation and translation), {res.reference} and {res.mask}")
    if cfg.truth_envs:
        stems = ", ".join(f"live_{environment_stem(e)}/" for e in cfg.truth_envs)
        print(f"wrote the live truth: {res.truth}/{{{stems}}} (every frame under each environment) and "
              f"{res.truth}/silhouette/")
    print("timings: " + ", ".join(f"{k} {v:.1f}s" for k, v in res.timings.items()))
    return 0


def _box(text: str) -> tuple[int, int, int, int]:
    try:
        vals = tuple(int(round(float(v))) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: write the box as x,y,w,h in pixels") from None
    if len(vals) != 4 or vals[2] <= 0 or vals[3] <= 0:
        raise argparse.ArgumentTypeError(f"{text!r}: write the box as x,y,w,h with positive w and h")
    return vals


def _circle(text: str) -> tuple[float, float, float]:
    try:
        vals = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: write the sphere as cx,cy,r in pixels") from None
    if len(vals) != 3 or vals[2] <= 0:
        raise argparse.ArgumentTypeError(f"{text!r}: write the sphere as cx,cy,r with r > 0")
    return vals


def _add_capture(sub) -> None:
    from .kernels.bundle import BUNDLE_MODE
    from .kernels.transport import STORE_TOLERANCE
    from .pipeline.capture import TRANSFERS
    from .pipeline.ingest import DEFAULT_FACE_PIXELS
    from .pipeline.methods import METHODS

    p = sub.add_parser(
        "capture", help=COMMANDS["capture"],
        description="Build a reflectance bundle from a phone video of a face lit by a blinking, hand-waved "
                    "flash with a mirror sphere beside it (or from an RTI image set with --images): flash "
                    "separation, registration, light directions, photometric-stereo geometry, per-pixel "
                    "reflectance maps.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("video", nargs="?", type=Path, help="capture video (any container FFmpeg reads)")
    p.add_argument("--images", type=Path, metavar="DIR",
                   help="an RTI image set instead of a video: images plus dirs.lp (and optional mask.png, and "
                        "ambient.png: the room light alone, subtracted and kept as the bundle's ambient)")
    p.add_argument("-o", "--out", type=Path, required=True, help="bundle file to write")
    p.add_argument("--method", default="full", choices=METHODS,
                   help="how samples become maps: the paper's triangulation (full = with visibility and light "
                        "adaptation, barycentric = without) or a fitted baseline")
    p.add_argument("--no-visibility", action="store_true", help="leave out visibility-aware interpolation")
    p.add_argument("--no-adaptation", action="store_true",
                   help="leave out light adaptation (the shading model's cosine, or the paper's cosine factors)")
    p.add_argument("--paper-adaptation", action="store_true",
                   help="the paper's light adaptation (divide by the vertices' cosines) instead of interpolating "
                        "what a shading model (albedo x cosine x visibility) leaves unexplained")
    p.add_argument("--no-extrapolation", action="store_true",
                   help="black light beyond the captured directions (the paper) instead of a shading model's")
    p.add_argument("--no-spline", action="store_true",
                   help="leave out the thin-plate spline over light directions that pixels the shading model does "
                        "not explain (shiny, badly modelled) are blended with; barycentric only, as the paper")
    p.add_argument("--model-reach", type=float, default=60.0, metavar="DEG",
                   help="how far (degrees) beyond the captured directions the shading model's light reaches; "
                        "less: smaller bundle and faster capture, darker under light from behind the head")
    p.add_argument("--map-size", type=_size, default=(64, 32), metavar="WxH", help="reflectance map size (2:1)")
    p.add_argument("--sphere", type=_circle, metavar="cx,cy,r", help="mirror sphere centre and radius (pixels) "
                   "instead of finding it")
    p.add_argument("--face", type=_box, metavar="x,y,w,h", help="face box (pixels) instead of detecting it")
    p.add_argument("--flash-hz", type=float, help="flash rate in Hz (estimated from the video when not given)")
    p.add_argument("--flash-threshold", type=float, default=0.002,
                   help="least brightness (linear, 0-1) a flash must add to the face over the dark frames")
    p.add_argument("--focal", type=float, help="camera focal length in pixels for a perspective sphere "
                   "(orthographic when not given)")
    p.add_argument("--highlight", default="blob", choices=("blob", "paper"),
                   help="highlight position: whole blob (default) or the paper's 0.85 threshold")
    p.add_argument("--no-registration", action="store_true", help="leave out head-motion registration")
    p.add_argument("--no-ambient-subtraction", action="store_true",
                   help="keep the room light in the flash samples (the paper's choice)")
    p.add_argument("--mesh", type=Path, help="a mesh (any format trimesh reads) aligned to the reference camera, "
                   "vertices (column, -row, height) in pixels, instead of photometric-stereo geometry")
    p.add_argument("--export-mesh", type=Path, metavar="FILE", help="write the estimated head as a mesh (.ply, .obj)")
    p.add_argument("--transfer", choices=TRANSFERS, default="srgb",
                   help="with --images: how the set's PNG/JPEG/TIFF files encode light - srgb (phones, most RTI "
                        "sets) or linear (a camera's raw response, e.g. Extended Yale B); EXR/HDR are always linear")
    p.add_argument("--face-pixels", type=int, default=DEFAULT_FACE_PIXELS, metavar="N",
                   help="work on the head at about N pixels: larger captures (1080p, 4K) are downscaled as they "
                        "are decoded, bounding time and memory; the bundle records the scale (0: never downscale)")
    p.add_argument("--keep-maps", action="store_true",
                   help="also store the maps themselves, texel- and pixel-major, and the flash samples in float16 "
                        "(~25 KB per face pixel: the exact path and the accuracy bench start at once); without it "
                        "the bundle holds what the maps are made of (~1 KB per face pixel) and makes any texel "
                        "on demand")
    p.add_argument("--store-tolerance", type=float, default=STORE_TOLERANCE, metavar="TOL",
                   help="finest relight tolerance (relative L2) the bundle serves from its compact transport: "
                        "ranks are stored until their validation error, 8-bit storage included, meets it (finer "
                        "tolerances build the exact maps on load)")
    p.add_argument("--report", type=Path, metavar="DIR", help="write report.json and PNG plots here")
    p.add_argument("--file-mode", type=_octal_mode, default=f"{BUNDLE_MODE:o}", metavar="OCTAL",
                   help="the bundle's permission bits, octal: owner-only by default - a bundle is a person's face "
                        "(biometric data); widen it deliberately, e.g. 640 for a group")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=_run_capture)


def _octal_mode(text: str) -> int:
    try:
        mode = int(text, 8)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: an octal mode such as 600 or 640") from None
    if not (0 <= mode <= 0o777 and mode & 0o600 == 0o600):
        raise argparse.ArgumentTypeError(f"{text!r}: a mode from 600 to 777 that lets the owner read and write")
    return mode


def _run_capture(args) -> int:
    from .errors import InputError
    from .pipeline.capture import CaptureOptions, capture
    from .pipeline.samples import SampleOptions

    if (args.video is None) == (args.images is None):
        raise InputError("give either a capture video or --images DIR (not both)")
    if args.images is None and args.transfer != "srgb":
        raise InputError("--transfer applies to --images sets; a video's transfer curve is read from its tags")
    if not (math.isfinite(args.store_tolerance) and 0 < args.store_tolerance < 1):
        raise InputError(f"--store-tolerance {args.store_tolerance}: use a relative error such as 0.01 (1 %)")
    opts = CaptureOptions(transfer=args.transfer, keep_maps=args.keep_maps, face_pixels=args.face_pixels or None,
        store_tolerance=args.store_tolerance,
        method=args.method, visibility=not args.no_visibility, adaptation=not args.no_adaptation,
        extrapolation=not args.no_extrapolation, paper_adaptation=args.paper_adaptation,
        spline=not args.no_spline, model_reach=args.model_reach,
        map_size=args.map_size, face=args.face, mesh=str(args.mesh) if args.mesh else None,
        export_mesh=str(args.export_mesh) if args.export_mesh else None,
        samples=SampleOptions(flash_hz=args.flash_hz, flash_threshold=args.flash_threshold, sphere=args.sphere,
                              focal=args.focal, highlight=args.highlight, register=not args.no_registration,
                              subtract_ambient=not args.no_ambient_subtraction))
    res = capture(args.images or args.video, args.out, opts, images=args.images is not None,
                  report_dir=args.report, progress=not args.quiet, file_mode=args.file_mode)
    rej = ", ".join(f"{k} {v}" for k, v in res.report.get("rejected", {}).items()) or "none"
    print(f"wrote {res.bundle} ({res.arrays['light_dirs'].shape[0]} light samples, "
          f"{res.arrays['pixels'].size} pixels, {res.bundle.stat().st_size / 1e6:.0f} MB)")
    print(f"dropped: {rej}")
    for note in res.report.get("notes", []):
        print(f"note: {note}")
    print("timings: " + ", ".join(f"{k} {v:.1f}s" for k, v in res.timings.items()))
    return 0


def _vec3(text: str) -> tuple[float, float, float]:
    try:
        vals = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: write three numbers x,y,z") from None
    if len(vals) != 3:
        raise argparse.ArgumentTypeError(f"{text!r}: write three numbers x,y,z")
    return vals


def _add_render(sub) -> None:
    p = sub.add_parser(
        "render", help=COMMANDS["render"],
        description="Relight the reference frame of a bundle (from `relight capture`) under an environment map "
                    "or a single directional light, and write it as an image: EXR is linear, PNG/JPEG are "
                    "sRGB-encoded (clipped to 0-1).",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("bundle", type=Path, help="reflectance bundle")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--env", metavar="FILE|builtin:NAME", help="environment map (lat-long .exr/.hdr/.png/.jpg) "
                     "or a built-in (builtin:studio, sunset, window, uniform, room, point:x,y,z)")
    src.add_argument("--light", type=_vec3, metavar="x,y,z",
                     help="one directional light toward x,y,z (camera space), as strong as the capture flash: "
                          "rendering a captured direction reproduces that capture")
    p.add_argument("-o", "--out", type=Path, required=True, help="image to write (.exr, .png, .jpg)")
    p.add_argument("--rotate", type=_vec3, metavar="yaw,pitch,roll",
                   help="head rotation in degrees (R = Ry(yaw) Rx(pitch) Rz(roll)); the environment turns the "
                        "other way")
    p.add_argument("--exposure", type=float, default=0.0, help="exposure in stops (EV): the light is scaled by 2^EV")
    acc = p.add_mutually_exclusive_group()
    acc.add_argument("--tolerance", type=float, default=0.01,
                     help="relative L2 error allowed against the exact sum (picks the compact rank)")
    acc.add_argument("--exact", action="store_true",
                     help="sum over the full reflectance maps (a bundle captured without --keep-maps makes "
                          "them from its recipe first: about as long as the capture's maps stage)")
    p.add_argument("--background", choices=("none", "reference"), default="none",
                   help="outside the face: black, or the bundle's no-flash reference frame")
    p.add_argument("--ambient", action="store_true",
                   help="add the capture room's light (the bundle's ambient frame) to the face: what a photo "
                        "taken under this light in the capture room shows")
    p.set_defaults(func=_run_render)


def _run_render(args) -> int:
    import numpy as np

    from . import load_bundle, load_environment
    from .colour import decode_srgb8
    from .directions import rotation_matrix
    from .errors import InputError
    from .imageio import write_image
    from .kernels.relighter import Relighter

    if not np.isfinite(args.exposure) or abs(args.exposure) > 40:
        raise InputError(f"--exposure {args.exposure}: use a number of stops between -40 and 40")
    if args.out.suffix.lower() not in (".exr", ".png", ".jpg", ".jpeg", ".hdr"):
        raise InputError(f"{args.out}: write .exr (linear), .png or .jpg (sRGB)")
    t0 = time.perf_counter()
    bundle = load_bundle(args.bundle)
    r = Relighter(bundle, tolerance=args.tolerance, exact=args.exact)
    scale = float(2.0 ** args.exposure)
    if args.light is not None:
        img = np.array(r.relight_light(args.light, exposure=scale))
        what = f"light {args.light}"
    else:
        env = load_environment(args.env)
        rot = rotation_matrix(*args.rotate) if args.rotate else None
        img = np.array(r.relight(env, rot, exposure=scale))
        what = args.env
    if args.ambient:
        img = img + np.where(bundle.mask[..., None], bundle.ambient_frame() * np.float32(scale), 0.0)
    if args.background == "reference":
        bg = decode_srgb8(np.asarray(bundle.background))
        img = np.where(bundle.mask[..., None], img, bg)
    write_image(args.out, img)
    path = "exact" if r.exact else f"compact, rank {r.rank}"
    print(f"wrote {args.out} ({what}; {path}; {time.perf_counter() - t0:.2f} s)")
    return 0


def _add_bench(sub) -> None:
    from .engine.composite import DEFAULT_MODE, DEFAULT_REGION, MODES, REGIONS

    p = sub.add_parser("bench", help=COMMANDS["bench"],
                       description="Benchmarks: speed, memory and accuracy, measured here and printed.")
    bsub = p.add_subparsers(title="benchmarks", metavar="NAME", required=True)
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
    v.add_argument("--env", default="builtin:sunset", metavar="FILE|builtin:NAME", help="environment to relight with")
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
    sv = bsub.add_parser("serve", help="the frame service under load: websocket clients on loopback",
                         description="Start relight serve in a fresh process and drive it with websocket clients "
                                     "sending 640x360 JPEG frames of a synthetic live video at a fixed rate: "
                                     "errors, dropped frames, relit frames per second, round-trip p50/p95/p99 and "
                                     "the hypervisor's steal, server memory before and after; then one client "
                                     "alone sending 1280x720 frames (--single-size); and the start-up time "
                                     "(launch -> ready) of a first and a second start. Writes bench.json.",
                         formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    sv.add_argument("-o", "--out", type=Path, default=Path("out/bench-serve"), help="output and cache folder")
    sv.add_argument("--bundle", type=Path, default=None, help="bundle to serve (default: a synthetic 640x360 one)")
    sv.add_argument("--clients", type=int, default=4, help="websocket clients at once")
    sv.add_argument("--fps", type=float, default=30.0, help="frames per second each client sends")
    sv.add_argument("--duration", type=float, default=60.0, help="seconds of load")
    sv.add_argument("--start-bundle", type=Path, default=None,
                    help="bundle whose start-up (launch -> ready) is timed, twice (default: the served one)")
    sv.add_argument("--single-size", type=_size, default=(1280, 720), metavar="WxH",
                    help="frame size the single client sends")
    sv.add_argument("--quick", action="store_true", help="8 s of load and 640x360 for the single client (for CI)")
    sv.add_argument("--quiet", action="store_true", help="no progress output")
    sv.set_defaults(func=_run_bench_serve)
    lv = bsub.add_parser("live", help="relight live and the browser page (WebRTC vs websocket) on one clip",
                         description="relight live with a synthetic clip played as the camera (640x360 and "
                                     "1280x720, into the preview page with no viewer; --record: recorded too): fps "
                                     "in/relit/out, dropped, latency, CPU; then the browser "
                                     "page in headless Chromium over WebRTC and over the websocket on the same "
                                     "640x360 clip: fps, round trip from the frames' bar codes, bandwidth. Writes "
                                     "bench.json.",
                         formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    lv.add_argument("-o", "--out", type=Path, default=Path("out/bench-live"), help="output and cache folder")
    lv.add_argument("--seconds", type=float, default=15.0, help="seconds measured per case")
    lv.add_argument("--no-browser", action="store_true", help="leave out the browser page")
    lv.add_argument("--record", action="store_true",
                    help="measure each size recorded as well (H.264 ultrafast at the output rate)")
    lv.add_argument("--quick", action="store_true", help="640x360 only, 6 s per case (for CI)")
    lv.add_argument("--quiet", action="store_true", help="no progress output")
    lv.set_defaults(func=_run_bench_live)
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
                    help="inputs per target (default 1500; 40 with --quick)")
    fz.add_argument("--target", action="append", default=None, metavar="NAME",
                    help="fuzz only this target (repeatable): bundle, lp, envmap, frame, control, video")
    fz.add_argument("--seed", type=int, default=0, help="random seed (another seed tries other inputs)")
    fz.add_argument("--quick", action="store_true", help="40 inputs per target (for CI)")
    fz.add_argument("--quiet", action="store_true", help="no progress output")
    fz.set_defaults(func=_run_bench_fuzz)
    cr = bsub.add_parser("crash", help="writers killed with SIGKILL at random moments: no damaged file",
                         description="Kill relight capture (bundle), relight filter (video) and relight-serve taking "
                                     "an environment upload with SIGKILL at random moments (half in the last fifth "
                                     "of a run) while a previous result is in place; check the target is the "
                                     "previous file or a whole new one, and that temporaries left are removed by "
                                     "the next run. Needs ../shared/data (real faces). Writes bench.json.",
                         formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    cr.add_argument("-o", "--out", type=Path, default=Path("out/bench-crash"), help="output and work folder")
    cr.add_argument("--kills", type=int, default=None, help="kills per writer (default 25; 4 with --quick)")
    cr.add_argument("--seed", type=int, default=0, help="random seed of the kill times")
    cr.add_argument("--quick", action="store_true", help="4 kills per writer (for CI)")
    cr.add_argument("--quiet", action="store_true", help="no progress output")
    cr.set_defaults(func=_run_bench_crash)
    so = bsub.add_parser("soak", help="relight-serve for minutes with good and misbehaving clients",
                         description="A real relight-serve with 4 websocket clients at 10 fps for --minutes, beside "
                                     "clients that vanish, send garbage, never read, or post broken frames: errors "
                                     "seen by the good clients, round trip p50/p95/p99 per minute, the server's "
                                     "RSS, open file descriptors and threads with their slopes. Writes bench.json "
                                     "and soak.png.",
                         formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    so.add_argument("-o", "--out", type=Path, default=Path("out/bench-soak"), help="output and cache folder")
    so.add_argument("--minutes", type=float, default=10.0, help="length of the soak")
    so.add_argument("--bundle", type=Path, default=None, help="bundle to serve (default: a synthetic 640x360 one)")
    so.add_argument("--quick", action="store_true", help="2 minutes (for CI)")
    so.add_argument("--quiet", action="store_true", help="no progress output")
    so.set_defaults(func=_run_bench_soak)
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


def _shared_data(name: str, probe: str) -> Path | None:
    """A real data set next to the project (../shared/data/NAME, holding PROBE), if present."""
    for base in (Path.cwd(), Path(__file__).resolve().parents[1]):
        cand = base.parent / "shared" / "data" / name
        if list(cand.glob(probe)):
            return cand
    return None


def _run_bench_accuracy(args) -> int:
    from .bench import accuracy
    from .errors import InputError

    rti = args.rti if args.rti is not None else _shared_data("rti-dome", "Dome/dirs.lp")
    if args.rti is not None and not (args.rti / "Dome" / "dirs.lp").exists():
        raise InputError(f"--rti {args.rti}: expected Dome/dirs.lp and Test/dirs.lp inside")
    faces = args.faces if args.faces is not None else _shared_data("faces-yale", "*/dirs.lp")
    if args.faces is not None and not accuracy.face_subjects(args.faces):
        raise InputError(f"--faces {args.faces}: expected one folder per subject, each with dirs.lp")
    doc = accuracy.run(args.out, quick=args.quick, progress=not args.quiet, rti=rti, faces=faces)
    print(accuracy.table(doc))
    print(f"wrote {args.out / 'bench.json'}, {args.out / 'report.md'} and its PNG plots")
    return 0


def _run_bench_capture(args) -> int:
    from .bench import capture as benchmark

    doc = benchmark.run(args.out, quick=args.quick, progress=not args.quiet, growth=args.growth, only=args.only)
    print(benchmark.table(doc))
    print(f"wrote {args.out / ('bench-growth.json' if args.growth else 'bench.json')} and "
          f"{args.out / 'capture_timings.png'}")
    return 0


def _run_bench_relight(args) -> int:
    from .bench import relight as benchmark

    doc = benchmark.run(args.out, quick=args.quick, progress=not args.quiet)
    print(benchmark.table(doc))
    print(f"wrote {args.out / 'bench.json'} and {args.out / 'relight_error_vs_time.png'}")
    return 0


def _run_bench_video(args) -> int:
    from .bench import video as benchmark
    from .bench.accuracy import face_subjects
    from .errors import InputError

    faces = args.faces if args.faces is not None else _shared_data("faces-yale", "*/dirs.lp")
    if args.faces is not None and not face_subjects(args.faces):
        raise InputError(f"--faces {args.faces}: expected one folder per subject, each with dirs.lp")
    doc = benchmark.run(args.out, quick=args.quick, progress=not args.quiet, env=args.env, mode=args.mode,
                        faces=faces, region=args.region)
    print(benchmark.table(doc))
    print(f"wrote {args.out / 'bench.json'}, {args.out / 'video_pose.png'}, {args.out / 'video_frames.png'} and a "
          "before/after sheet per real face (faces/*/sheet.png)")
    return 0


def _run_bench_live(args) -> int:
    from .bench import live
    from .errors import InputError

    if not (1 <= args.seconds <= 600):
        raise InputError(f"--seconds {args.seconds}: use 1 to 600")
    doc = live.run(args.out, quick=args.quick, progress=not args.quiet, seconds=args.seconds,
                   browser=not args.no_browser, record=args.record)
    print(live.table(doc))
    print(f"wrote {args.out / 'bench.json'}")
    return 0


def _run_bench_fuzz(args) -> int:
    from .bench import fuzz
    from .errors import InputError

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
    from .bench import crash
    from .errors import InputError

    kills = args.kills or (crash.QUICK_KILLS if args.quick else crash.DEFAULT_KILLS)
    if not (1 <= kills <= 10_000):
        raise InputError(f"--kills {kills}: use 1 to 10000")
    doc = crash.run(args.out, kills=kills, seed=args.seed, progress=not args.quiet)
    print(crash.table(doc))
    print(f"wrote {args.out / 'bench.json'}")
    return 1 if any(r["damaged_total"] for r in doc["writers"]) else 0


def _run_bench_soak(args) -> int:
    from .bench import soak
    from .errors import InputError

    minutes = 2.0 if args.quick else args.minutes
    if not (0.5 <= minutes <= 24 * 60):
        raise InputError(f"--minutes {minutes}: use 0.5 to 1440")
    doc = soak.run(args.out, minutes=minutes, bundle=args.bundle, progress=not args.quiet)
    print(soak.table(doc))
    print(f"wrote {args.out / 'bench.json'} and {args.out / 'soak.png'}")
    return 0 if doc["good"]["errors"] == 0 and doc["ready_after"] else 1


def _run_bench_serve(args) -> int:
    from .bench import serve as loadtest
    from .errors import InputError

    if not (1 <= args.clients <= 64) or not (1 <= args.fps <= 120) or not (1 <= args.duration <= 3600):
        raise InputError("--clients 1..64, --fps 1..120, --duration 1..3600 seconds")
    doc = loadtest.run(args.out, bundle=args.bundle, clients=args.clients, fps=args.fps, duration=args.duration,
                       quick=args.quick, progress=not args.quiet, single_size=tuple(args.single_size),
                       start_bundle=args.start_bundle)
    print(loadtest.table(doc))
    print(f"wrote {args.out / 'bench.json'}")
    return 0


def _add_demo(sub) -> None:
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
    from . import load_bundle, load_environment
    from .engine.frame_path import FramePath
    from .pipeline.capture import capture
    from .pipeline.evaluate import evaluate_capture
    from .pipeline.synth.contact_sheet import before_after_sheet, contact_sheet
    from .pipeline.synth.live import LiveConfig, synthesize_live
    from .pipeline.synth.studio import SynthConfig, synthesize
    from .service.filter import run_filter

    t0 = time.perf_counter()
    # Progress bars on a terminal only: a log file gets one line per stage.
    bars = not args.quiet and sys.stderr.isatty()

    def stage(text: str) -> None:
        print(f"[{time.perf_counter() - t0:5.1f} s] {text}", flush=True)

    from .pipeline.synth.mesh_head import DEMO_HEAD, head_credit

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
            fp = FramePath(bundle, env, focal="ortho")
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


#: --region's help (relight filter, relight live, relight-serve).
_REGION_HELP = ("what mode transfer relights: the whole person (the face from the bundle; hair, ears, neck and "
                "shoulders by the face's change of light carried over them - nothing off the person changes) or "
                "the face alone (the bundle's face mask)")


def _strength(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: give a number from 0 to 1") from None
    if not (0.0 <= v <= 1.0):
        raise argparse.ArgumentTypeError(f"{text!r}: give a number from 0 to 1")
    return v


def _focal(text: str):
    if text.strip().lower() == "ortho":
        return "ortho"
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: give the focal length in pixels, or 'ortho'") from None
    if not (v > 0 and v < 1e6):
        raise argparse.ArgumentTypeError(f"{text!r}: give a positive focal length in pixels, or 'ortho'")
    return v


def _add_filter(sub) -> None:
    from .engine.composite import DEFAULT_MODE, DEFAULT_REGION, MODES, REGIONS

    p = sub.add_parser(
        "filter", help=COMMANDS["filter"],
        description="Relight the face of every frame of a video (any container FFmpeg reads) or a folder of "
                    "images with a reflectance bundle: the head is tracked, its rotation turns the environment "
                    "the other way, and the relit light is warped onto the face. Audio and timestamps are "
                    "kept; OUT appears only when complete. Frames without a face pass through unchanged.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("input", type=Path, metavar="IN", help="video file, or a folder of images (a sequence)")
    p.add_argument("output", type=Path, metavar="OUT",
                   help="video to write (.mp4/.mov/.mkv/.avi: H.264, .webm: VP9), or a folder for PNG frames")
    p.add_argument("--bundle", type=Path, required=True, help="reflectance bundle of this face (relight capture)")
    p.add_argument("--env", required=True, metavar="FILE|builtin:NAME",
                   help="environment to light the face with (lat-long .exr/.hdr/.png or a built-in)")
    p.add_argument("--mode", choices=MODES, default=DEFAULT_MODE,
                   help="transfer: the live face relit for real - its own light measured from it and swapped for "
                        "the target (eyes, mouth, expression kept where lit; the bundle's prediction where the live "
                        "light left the face dark); ambient: the ratio to the capture room's light (the live "
                        "room's light stays); paste: the relit reference face warped in (the paper)")
    p.add_argument("--region", choices=REGIONS, default=DEFAULT_REGION,
                   help=_REGION_HELP)
    p.add_argument("--fixed-env", action="store_true",
                   help="do not turn the environment against the head's rotation (the light follows the face)")
    p.add_argument("--strength", type=_strength, default=1.0, help="blend with the original frame, 0 to 1")
    p.add_argument("--exposure", type=float, default=0.0,
                   help="stops (EV) on top of the automatic exposure matching")
    p.add_argument("--focal", type=_focal, default=None, metavar="PIXELS|ortho",
                   help="the video's focal length in pixels (default: 0.85 x the frame's larger side, a phone or "
                        "webcam); 'ortho' for an orthographic camera such as relight synth's")
    p.add_argument("--fps", type=float, default=30.0, help="frame rate of an image-sequence input")
    p.add_argument("--crf", type=int, default=18, help="output quality (lower = better, bigger)")
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

    from .errors import InputError
    from .service.filter import run_filter

    if not np.isfinite(args.exposure) or abs(args.exposure) > 20:
        raise InputError(f"--exposure {args.exposure}: use stops between -20 and 20")
    if not (1.0 <= args.fps <= 240.0):
        raise InputError(f"--fps {args.fps}: use 1 to 240")
    if not (0 <= args.crf <= 51):
        raise InputError(f"--crf {args.crf}: use 0 to 51")
    if not args.input.exists():
        raise InputError(f"{args.input}: no such file or folder")
    bundle = relight.load_bundle(args.bundle)
    env = relight.load_environment(args.env)
    res = run_filter(args.input, args.output, bundle, env, mode=args.mode, region=args.region,
                     fixed_env=args.fixed_env,
                     strength=args.strength, exposure=args.exposure, focal=args.focal, fps=args.fps, crf=args.crf,
                     report_dir=args.report, virtual_camera=args.virtual_camera, progress=not args.quiet,
                     start_time=t0)
    print(f"wrote {res.out}: {res.summary()}")
    for note in res.notes:
        print(f"note: {note}")
    if args.report:
        print(f"report: {args.report / 'report.json'}")
    return 0


def _add_live(sub) -> None:
    from .engine.composite import DEFAULT_MODE, DEFAULT_REGION, MODES, REGIONS

    p = sub.add_parser(
        "live", help=COMMANDS["live"],
        description="Relight a live camera: frames from a webcam (v4l2 on Linux, avfoundation on macOS, dshow on "
                    "Windows) or a video file played at its own rate and looped, relit with a bundle and sent to "
                    "a virtual camera (pyvirtualcam: v4l2loopback, OBS Virtual Camera) that Zoom, Meet or OBS "
                    "pick as a webcam, to a preview page and/or to a recording. The latest frame always wins: "
                    "a slow frame drops the next, never builds a queue. Keys on a terminal: e next environment, "
                    "[ ] strength -/+0.1, m next mode, q quit; signals: SIGUSR1 next environment, SIGUSR2 "
                    "strength 1 -> 0.5 -> 0, SIGINT/SIGTERM stop cleanly.",
        formatter_class=_DefaultsUnlessNone)
    p.add_argument("--bundle", type=Path, required=True, help="reflectance bundle of this face (relight capture)")
    p.add_argument("--env", required=True, action="append", metavar="FILE|builtin:NAME",
                   help="environment to light the face with; give it again for more (the e key and SIGUSR1 "
                        "switch between them)")
    p.add_argument("--camera", default=None, metavar="DEVICE|FILE",
                   help="camera index or device name (0, /dev/video2, 'FaceTime HD Camera'), or a video file "
                        "(played at its own rate, looped); default: the first camera")
    p.add_argument("--size", type=_size, default=None, metavar="WxH",
                   help="frame size asked of the camera (a file's frames are scaled to it); default: the camera's")
    p.add_argument("--fps", type=float, default=None,
                   help="frame rate asked of the camera and of the output; default: the camera's (a file's own)")
    p.add_argument("--duration", type=float, default=None, metavar="SECONDS",
                   help="stop after this many seconds (default: run until q or Ctrl-C)")
    p.add_argument("--mode", choices=MODES, default=DEFAULT_MODE,
                   help="transfer: the live light measured from the face and swapped for the target; ambient: the "
                        "ratio to the capture room's light; paste: the relit reference face (the paper)")
    p.add_argument("--region", choices=REGIONS, default=DEFAULT_REGION,
                   help=_REGION_HELP)
    p.add_argument("--strength", type=_strength, default=1.0, help="blend with the camera's frame, 0 to 1")
    p.add_argument("--focal", type=_focal, default=None, metavar="PIXELS|ortho",
                   help="the camera's focal length in pixels, or 'ortho' (default: 0.85 x the frame's larger side)")
    p.add_argument("--virtual-camera", action="store_true",
                   help="send the relit frames to a virtual camera (needs the pyvirtualcam extra and a driver; "
                        "without one the command says what to install and exits 2)")
    p.add_argument("--preview", action="store_true",
                   help="show the relit frames on a page on loopback (its URL is printed)")
    p.add_argument("--preview-port", type=int, default=0, help="the preview page's port (0: a free one)")
    p.add_argument("--record", type=Path, default=None, metavar="OUT.mp4",
                   help="record the relit frames (H.264, at the output rate; appears only when complete)")
    p.add_argument("--crf", type=int, default=18, help="the recording's quality (lower = better, bigger)")
    p.add_argument("--stats-json", type=Path, default=None, metavar="FILE",
                   help="write the run's figures (frames in/out, dropped, latency, CPU) as JSON")
    p.set_defaults(func=_live_command)


def _live_command(args) -> int:
    import json

    import numpy as np

    import relight

    from .errors import InputError
    from .imageio import atomic_path
    from .service.live import run_live
    from .service.virtual_camera import VirtualCameraMissing, check_virtual_camera_backend

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


def _serve_arguments(p) -> None:
    from .engine.composite import MODES, REGIONS
    from .service.settings import ServeConfig  # the defaults: the service's own settings

    p.add_argument("bundle", type=Path, help="reflectance bundle to serve (relight capture)")
    p.add_argument("--env", default=ServeConfig.env, metavar="FILE|builtin:NAME", help="starting environment")
    p.add_argument("--host", default=ServeConfig.host,
                   help="address to listen on (beyond loopback - e.g. 0.0.0.0 - a --token is required)")
    p.add_argument("--token", default=None,
                   help="a secret every request must carry (Authorization: Bearer TOKEN or ?token=TOKEN; the "
                        "page's URL is printed with it); default: $RELIGHT_TOKEN, or none on loopback")
    p.add_argument("--allow-origin", action="append", default=[], metavar="ORIGIN",
                   help="a web page origin (https://example.org) allowed to drive this server besides its own "
                        "page; give it again for more")
    p.add_argument("--port", type=int, default=8000, help="port to listen on")
    p.add_argument("--mode", choices=MODES, default=ServeConfig.mode,
                   help="transfer: the live light measured from the face and swapped for the target; ambient: the "
                        "ratio to the capture room's light; paste: the relit reference face (the paper)")
    p.add_argument("--region", choices=REGIONS, default=ServeConfig.region,
                   help=_REGION_HELP)
    p.add_argument("--max-clients", type=int, default=ServeConfig.max_clients, help="most stream clients at once")
    p.add_argument("--focal", type=_focal, default=None, metavar="PIXELS|ortho",
                   help="the frames' focal length in pixels, or 'ortho' (default: 0.85 x the frame's larger side)")


def _serve_command(args) -> int:
    import relight

    from .errors import InputError
    from .service.app import serve

    if not args.bundle.is_file():
        raise InputError(f"{args.bundle}: no such bundle file")
    # A broken bundle (header, sizes): a one-line error here, not a server traceback. The lifespan
    # loads it again and checks every array's CRC, so that pass is not done twice.
    relight.load_bundle(args.bundle, verify=False)
    if not (1 <= args.port <= 65535):
        raise InputError(f"--port {args.port}: use 1 to 65535")
    if not (1 <= args.max_clients <= 1024):
        raise InputError(f"--max-clients {args.max_clients}: use 1 to 1024")
    import os

    from .service.security import check_token, is_loopback

    try:
        token = check_token(args.token if args.token is not None else os.environ.get("RELIGHT_TOKEN"))
    except ValueError as exc:
        raise InputError(f"--token: {exc}") from None
    if token is None and not is_loopback(args.host):
        raise InputError(f"--host {args.host} opens the service to the network: give --token (or set "
                         "RELIGHT_TOKEN) so only its user can drive it, or listen on 127.0.0.1")
    for o in args.allow_origin:
        if o != "*" and not re.match(r"^https?://[^/\s]+$", o):
            raise InputError(f"--allow-origin {o!r}: write an origin as scheme://host[:port], e.g. https://example.org")
    return serve(args.bundle, env=args.env, host=args.host, port=args.port, mode=args.mode, region=args.region,
                 max_clients=args.max_clients, focal=args.focal, token=token,
                 allowed_origins=tuple(args.allow_origin))


def serve_main(argv: list[str] | None = None) -> int:
    """The ``relight-serve`` command (the same as ``relight serve``)."""
    p = argparse.ArgumentParser(prog="relight-serve", description="Serve relighting of video frames over HTTP.",
                                formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    _serve_arguments(p)
    p.add_argument("--verbose", action="store_true", help=VERBOSE_HELP)
    args = parse_args(p, argv)
    return run_command("relight-serve", _serve_command, args)


def _add_serve(sub) -> None:
    sp = sub.add_parser("serve", help=COMMANDS["serve"],
                        description="Keep a bundle loaded and relight frames sent over HTTP (POST /v1/relight); "
                                    "health at /livez and /readyz, Prometheus metrics at /metrics, OpenAPI at /docs.",
                        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    _serve_arguments(sp)
    sp.set_defaults(func=_serve_command)


_ADDERS = {"synth": _add_synth, "capture": _add_capture, "render": _add_render, "bench": _add_bench,
           "demo": _add_demo, "filter": _add_filter, "live": _add_live, "serve": _add_serve}


def _command(argv: list[str] | None) -> str | None:
    """The command named in ``argv`` (the first word that is not an option), or None."""
    for word in sys.argv[1:] if argv is None else argv:
        if not word.startswith("-"):
            return word
    return None


def build_parser(command: str | None = "*") -> argparse.ArgumentParser:
    """The ``relight`` parser: every command's full parser ("*"), or only ``command``'s (the others
    a help line each: what --help lists), or none (None)."""
    from . import __version__

    parser = argparse.ArgumentParser(
        prog="relight", description="Real-time relighting of a human face in video, on a CPU.")
    parser.add_argument("--version", action="version", version=f"relight {__version__}")
    parser.add_argument("--verbose", action="store_true", help=VERBOSE_HELP)
    sub = parser.add_subparsers(title="commands", metavar="COMMAND", required=True)
    for name in COMMANDS:
        if command == "*" or name == command:
            _ADDERS[name](sub)
            # also after the command (relight capture ... --verbose); absent there: the top level's
            sub.choices[name].add_argument("--verbose", action="store_true", default=argparse.SUPPRESS,
                                           help=VERBOSE_HELP)
        else:
            sub.add_parser(name, help=COMMANDS[name])
    return parser


VERBOSE_HELP = "show the OpenCL compiler's messages and, on an error, the traceback"


def set_verbose(on: bool) -> None:
    """``--verbose``: the OpenCL compiler's messages (pyopencl's and PoCL's whole log) and
    tracebacks on errors; also for the processes a command starts (an environment variable)."""
    from .kernels.runtime import VERBOSE_ENV

    if on:
        os.environ[VERBOSE_ENV] = "1"
        os.environ.setdefault("PYOPENCL_COMPILER_OUTPUT", "1")


def run_command(prog: str, func, args) -> int:
    """``func(args)`` with relight's errors as one line on stderr and exit status 2: ours
    (:class:`RelightError`, saying what to change) and the system's (an OSError: the file and the
    reason, e.g. "no space left on device") - a traceback only with --verbose."""
    import traceback

    from .errors import os_reason

    verbose = bool(getattr(args, "verbose", False))
    set_verbose(verbose)
    try:
        return func(args)
    except RelightError as exc:
        if verbose:
            traceback.print_exc()
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:  # the system's word on a file we read or write
        if verbose:
            traceback.print_exc()
        names = " -> ".join(str(n) for n in (exc.filename, exc.filename2) if n)
        print(f"{prog}: error: {names + ': ' if names else ''}{os_reason(exc)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return 130


def main(argv: list[str] | None = None) -> int:
    parser = build_parser(_command(argv))
    args = parse_args(parser, argv)
    return run_command("relight", args.func, args)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
