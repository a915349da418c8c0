"""What every ``relight`` command shares: the commands' help lines, argument types (sizes,
strengths, focal lengths), the negative-number-friendly parsing, ``--verbose`` and the one-line
errors (:func:`run_command`)."""

from __future__ import annotations

import argparse
import os
import re
import sys

from ..errors import RelightError

#: The commands in the order --help lists them, and each one's line there. Only the command being
#: run has its full parser built (importing what its defaults come from); the others are a line each,
#: so `relight filter ...` does not import the capture pipeline or the web app to parse its arguments.
COMMANDS = {
    "synth": "simulate a two-phone capture of a synthetic head, with its ground truth",
    "capture": "turn a capture video (or an RTI image set) into a reflectance bundle",
    "render": "relight a bundle's face under an environment or one light, to an image",
    "presets": "one face under every built-in light and preset, as a contact sheet",
    "bench": "benchmarks that print measured figures",
    "demo": "synthesise a capture, turn it into a bundle, show both (what `make demo` runs)",
    "filter": "relight the face in a video (a virtual-camera-style batch filter)",
    "live": "relight a live camera into a virtual camera, a preview page or a recording",
    "serve": "serve relighting of video frames over HTTP (also: relight-serve)",
}


def name_table(helps: dict[str, str]) -> str:
    """Names and their one-line helps as aligned rows (what ``relight`` and ``relight bench`` alone
    print), each row indented and ending in a newline."""
    width = max(map(len, helps))
    return "".join(f"  {name:<{width}}  {text}\n" for name, text in helps.items())


def parse_size(text: str) -> tuple[int, int]:
    """WIDTHxHEIGHT (``--size 960x540``) -> (width, height)."""
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


class DefaultsUnlessNone(argparse.ArgumentDefaultsHelpFormatter):
    """Shows defaults, except None (those flags say in their help what they default to)."""

    def _get_help_string(self, action):
        if action.default is None:
            return action.help
        return super()._get_help_string(action)


#: --region's help (relight filter, relight live, relight-serve).
#: What every --env accepts, after each command's own first words.
ENV_KINDS = ("a 2:1 lat-long map (.exr/.hdr/.png/.jpg), a built-in (builtin:studio, sunset, window, uniform, room, "
             "point:x,y,z) or a key light placed by hand: builtin:key:az=30,el=25,size=30,kelvin=5000,fill=0.3,"
             "power=1 (azimuth and elevation in degrees toward the image's right and up, disc diameter in degrees, "
             "colour temperature, fill share, flashes; every field optional), or any picture as the light: "
             "photo:PATH (a photo of a place, a virtual background)")
#: --env-turn and --env-spin (render, filter, live): one convention with the HTTP API's rotation.
ENV_TURN_HELP = ("turn the environment about the vertical by DEG degrees: every light moves DEG degrees in azimuth "
                 "toward the image's right (as the HTTP API's rotation=DEG,0,0; turning the environment by +DEG "
                 "lights the face as turning the head by -DEG does)")
ENV_SPIN_HELP = ("spin the environment about the vertical, DEG_PER_S degrees per second of the video's time "
                 "(positive: toward the image's right), starting from --env-turn")
REGION_HELP = ("what mode transfer relights: the whole person (the face from the bundle; hair, ears, neck and "
               "shoulders by the face's change of light carried over them - nothing off the person changes) or "
               "the face alone (the bundle's face mask)")


def parse_strength(text: str) -> float:
    """--strength: a blend from 0 to 1."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: give a number from 0 to 1") from None
    if not (0.0 <= v <= 1.0):
        raise argparse.ArgumentTypeError(f"{text!r}: give a number from 0 to 1")
    return v


def focal_default() -> str:
    """What --focal defaults to, in words: found from the tracked head (:mod:`relight.engine.focal`),
    starting from the frame path's guess (:data:`relight.engine.pose.DEFAULT_FOCAL`)."""
    from ..engine.pose import DEFAULT_FOCAL

    return (f"found from the head over its first frames - first after 5, refined up to 40 (~1.3 s) - "
            f"{DEFAULT_FOCAL:g} x the frame's larger side until then")


def parse_focal(text: str):
    """--focal: a focal length in pixels, or 'ortho' (an orthographic camera)."""
    if text.strip().lower() == "ortho":
        return "ortho"
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: give the focal length in pixels, or 'ortho'") from None
    if not (v > 0 and v < 1e6):
        raise argparse.ArgumentTypeError(f"{text!r}: give a positive focal length in pixels, or 'ortho'")
    return v


#: --verbose's help (every command, and relight / relight-serve themselves).
VERBOSE_HELP = "show the OpenCL compiler's messages and, on an error, the traceback"


def set_verbose(on: bool) -> None:
    """``--verbose``: the OpenCL compiler's messages (pyopencl's and PoCL's whole log) and
    tracebacks on errors; also for the processes a command starts (an environment variable)."""
    from ..kernels.runtime import VERBOSE_ENV

    if on:
        os.environ[VERBOSE_ENV] = "1"
        os.environ.setdefault("PYOPENCL_COMPILER_OUTPUT", "1")


def run_command(prog: str, func, args) -> int:
    """``func(args)`` with relight's errors as one line on stderr and exit status 2: ours
    (:class:`RelightError`, saying what to change) and the system's (an OSError: the file and the
    reason, e.g. "no space left on device") - a traceback only with --verbose."""
    import traceback

    from ..errors import os_reason

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

