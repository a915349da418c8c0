"""``relight render``: a bundle's face relit under an environment or one light, to an image."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from .common import COMMANDS, ENV_KINDS, ENV_TURN_HELP

#: --exposure's bound, stops either way: a still image takes a wider range than the frame path's
#: +-20 EV (the light is scaled by 2^EV here, then checked by the relighter).
MAX_EXPOSURE_EV = 40.0


def _vec3(text: str) -> tuple[float, float, float]:
    try:
        vals = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: write three numbers x,y,z") from None
    if len(vals) != 3:
        raise argparse.ArgumentTypeError(f"{text!r}: write three numbers x,y,z")
    return vals


def add_parser(sub) -> None:
    from ..kernels.relighter import DEFAULT_TOLERANCE

    p = sub.add_parser(
        "render", help=COMMANDS["render"],
        description="Relight the reference frame of a bundle (from `relight capture`) under an environment map "
                    "or a single directional light, and write it as an image: EXR is linear, PNG/JPEG are "
                    "sRGB-encoded (clipped to 0-1).",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("bundle", type=Path, help="reflectance bundle")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--env", metavar="FILE|builtin:NAME", help="environment to relight with: " + ENV_KINDS)
    src.add_argument("--light", type=_vec3, metavar="x,y,z",
                     help="one directional light toward x,y,z (camera space), as strong as the capture flash: "
                          "rendering a captured direction reproduces that capture")
    p.add_argument("-o", "--out", type=Path, required=True, help="image to write (.exr, .png, .jpg)")
    p.add_argument("--rotate", type=_vec3, metavar="yaw,pitch,roll",
                   help="head rotation in degrees (R = Ry(yaw) Rx(pitch) Rz(roll)); the environment turns the "
                        "other way")
    p.add_argument("--env-turn", type=float, default=0.0, metavar="DEG", help=ENV_TURN_HELP)
    p.add_argument("--exposure", type=float, default=0.0, help="exposure in stops (EV): the light is scaled by 2^EV")
    acc = p.add_mutually_exclusive_group()
    acc.add_argument("--tolerance", type=float, default=DEFAULT_TOLERANCE,
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

    from .. import load_bundle, load_environment
    from ..colour import decode_srgb8
    from ..directions import ENV_TURN_RANGE_DEG, rotation_matrix, with_env_turn
    from ..errors import InputError
    from ..imageio import write_image
    from ..kernels.relighter import Relighter

    if not np.isfinite(args.exposure) or abs(args.exposure) > MAX_EXPOSURE_EV:
        raise InputError(f"--exposure {args.exposure}: use a number of stops between {-MAX_EXPOSURE_EV:g} and "
                         f"{MAX_EXPOSURE_EV:g}")
    lo, hi = ENV_TURN_RANGE_DEG
    if not (np.isfinite(args.env_turn) and lo <= args.env_turn <= hi):
        raise InputError(f"--env-turn {args.env_turn}: use degrees between {lo:g} and {hi:g}")
    if args.env_turn and args.light is not None:
        raise InputError("--env-turn turns an environment (--env); move --light's x,y,z instead")
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
        rot = with_env_turn(rot, rotation_matrix(args.env_turn, 0.0, 0.0) if args.env_turn else None)
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


