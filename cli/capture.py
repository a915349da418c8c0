"""``relight capture``: a capture video (or an RTI image set) into a reflectance bundle."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from .common import COMMANDS, parse_focal, parse_size


def _box(text: str) -> tuple[int, int, int, int]:
    try:
        vals = tuple(int(round(float(v))) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: write the box as x,y,w,h in pixels") from None
    if len(vals) != 4 or vals[2] <= 0 or vals[3] <= 0:
        raise argparse.ArgumentTypeError(f"{text!r}: write the box as x,y,w,h with positive w and h")
    return vals


def _capture_focal(text: str):
    """--focal: 'auto', 'ortho' (None: orthographic) or a focal length in pixels."""
    if text.strip().lower() == "auto":
        return "auto"
    try:
        f = parse_focal(text)
    except argparse.ArgumentTypeError as exc:
        raise argparse.ArgumentTypeError(f"{exc}, or 'auto' (found from the mirror sphere)") from None
    return None if f == "ortho" else f


def _circle(text: str) -> tuple[float, float, float]:
    try:
        vals = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: write the sphere as cx,cy,r in pixels") from None
    if len(vals) != 3 or vals[2] <= 0:
        raise argparse.ArgumentTypeError(f"{text!r}: write the sphere as cx,cy,r with r > 0")
    return vals


def add_parser(sub) -> None:
    from ..pipeline.bundle_write import BUNDLE_MODE
    from ..pipeline.capture_types import TRANSFERS, CaptureOptions
    from ..pipeline.methods import METHODS
    from ..pipeline.samples import SampleOptions  # the defaults: the pipeline's own options

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
    p.add_argument("--method", default=CaptureOptions.method, choices=METHODS,
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
    p.add_argument("--model-reach", type=float, default=CaptureOptions.model_reach, metavar="DEG",
                   help="how far (degrees) beyond the captured directions the shading model's light reaches; "
                        "less: smaller bundle and faster capture, darker under light from behind the head")
    p.add_argument("--map-size", type=parse_size, default=CaptureOptions.map_size, metavar="WxH",
                   help="reflectance map size (2:1)")
    p.add_argument("--sphere", type=_circle, metavar="cx,cy,r", help="mirror sphere centre and radius (pixels) "
                   "instead of finding it")
    p.add_argument("--face", type=_box, metavar="x,y,w,h", help="face box (pixels) instead of detecting it")
    p.add_argument("--flash-hz", type=float, help="flash rate in Hz (estimated from the video when not given)")
    p.add_argument("--flash-threshold", type=float, default=SampleOptions.flash_threshold,
                   help="least brightness (linear, 0-1) a flash must add to the face over the dark frames")
    p.add_argument("--focal", type=_capture_focal, default=SampleOptions.focal, metavar="PX|auto|ortho",
                   help="the capture camera's focal length in pixels of the video's frames (the mirror sphere is "
                        "read through that pinhole); 'auto' (default): found from the ball's outline, which a "
                        "pinhole stretches off its axis - orthographic when the outline says nothing of it (a ball "
                        "near the frame's centre); 'ortho': an orthographic camera (before issue 49, the default)")
    p.add_argument("--highlight", default=SampleOptions.highlight, choices=("blob", "paper"),
                   help="highlight position: whole blob (default) or the paper's 0.85 threshold")
    p.add_argument("--no-registration", action="store_true", help="leave out head-motion registration")
    p.add_argument("--no-ambient-subtraction", action="store_true",
                   help="keep the room light in the flash samples (the paper's choice)")
    p.add_argument("--mesh", type=Path, help="a mesh (any format trimesh reads) aligned to the reference camera, "
                   "vertices (column, -row, height) in pixels, instead of photometric-stereo geometry")
    p.add_argument("--export-mesh", type=Path, metavar="FILE", help="write the estimated head as a mesh (.ply, .obj)")
    p.add_argument("--transfer", choices=TRANSFERS, default=CaptureOptions.transfer,
                   help="with --images: how the set's PNG/JPEG/TIFF files encode light - srgb (phones, most RTI "
                        "sets) or linear (a camera's raw response, e.g. Extended Yale B); EXR/HDR are always linear")
    p.add_argument("--face-pixels", type=int, default=CaptureOptions.face_pixels, metavar="N",
                   help="work on the head at about N pixels: larger captures (1080p, 4K) are downscaled as they "
                        "are decoded, bounding time and memory; the bundle records the scale (0: never downscale)")
    p.add_argument("--keep-maps", action="store_true",
                   help="also store the maps themselves, texel- and pixel-major, and the flash samples in float16 "
                        "(~25 KB per face pixel: the exact path and the accuracy bench start at once); without it "
                        "the bundle holds what the maps are made of (~1 KB per face pixel) and makes any texel "
                        "on demand")
    p.add_argument("--store-tolerance", type=float, default=CaptureOptions.store_tolerance, metavar="TOL",
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
    from ..errors import InputError
    from ..kernels.bundle_format import Field
    from ..pipeline.capture import capture
    from ..pipeline.capture_types import CaptureOptions
    from ..pipeline.samples import SampleOptions

    if (args.video is None) == (args.images is None):
        raise InputError("give either a capture video or --images DIR (not both)")
    if args.images is None and args.transfer != CaptureOptions.transfer:
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
    print(f"wrote {res.bundle} ({res.arrays[Field.LIGHT_DIRS].shape[0]} light samples, "
          f"{res.arrays[Field.PIXELS].size} pixels, {res.bundle.stat().st_size / 1e6:.0f} MB)")
    print(f"dropped: {rej}")
    for note in res.report.get("notes", []):
        print(f"note: {note}")
    print("timings: " + ", ".join(f"{k} {v:.1f}s" for k, v in res.timings.items()))
    return 0


