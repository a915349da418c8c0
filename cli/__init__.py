"""The ``relight`` command line (and ``relight-serve``): a module per command family.

Commands, in the order ``relight --help`` lists them (``relight COMMAND --help`` for each one's flags):

- ``synth`` (:mod:`.synth`): simulate a two-phone capture of a synthetic head, with its ground truth;
  with ``--live``, a live video of the head instead
- ``capture`` (:mod:`.capture`): turn a capture video (or an RTI image set) into a reflectance bundle
- ``render`` (:mod:`.render`): relight a bundle's face under an environment or one light, to an image
- ``presets`` (:mod:`.presets`): one face under every built-in light and preset, as a contact sheet
- ``bench`` (:mod:`.bench`): benchmarks that print measured figures - ``relight bench`` capture,
  relight, video, serve, live, fuzz, crash, soak, accuracy
- ``demo`` (:mod:`.demo`): what ``make demo`` runs - synthesise a capture, turn it into a bundle, show
  both, relight a live clip of the head
- ``filter`` (:mod:`.filter`): relight the face in a video (a virtual-camera-style batch filter)
- ``live`` (:mod:`.live`): relight a live camera into a virtual camera, a preview page or a recording
- ``serve`` (:mod:`.serve`): serve relighting of video frames over HTTP; also the ``relight-serve``
  command (:func:`serve_main`)

What they share - argument types, the parsing that takes negative numbers as values, ``--verbose``
and the error handling - is :mod:`.common`. Only the command being run has its full parser built.
Every error a user can cause ends in one line saying what to change, exit status 2.
"""

from __future__ import annotations

import argparse
import sys

from . import bench, capture, demo, filter, live, presets, render, serve, synth
from .common import (
    COMMANDS,
    VERBOSE_HELP,
    DefaultsUnlessNone,
    name_table,
    negative_values_joined,
    parse_args,
    run_command,
    set_verbose,
)
from .demo import DEMO_CLIP_S, DEMO_ENVS

__all__ = ["COMMANDS", "DEMO_CLIP_S", "DEMO_ENVS", "VERBOSE_HELP", "build_parser", "commands_text", "main",
           "negative_values_joined", "parse_args", "run_command", "serve_main", "set_verbose"]

#: Each command's parser builder (``add_parser(subparsers)``), by command name.
_ADDERS = {"synth": synth.add_parser, "capture": capture.add_parser, "render": render.add_parser,
           "presets": presets.add_parser,
           "bench": bench.add_parser, "demo": demo.add_parser, "filter": filter.add_parser,
           "live": live.add_parser, "serve": serve.add_parser}


def _command(argv: list[str] | None) -> str | None:
    """The command named in ``argv`` (the first word that is not an option), or None."""
    for word in sys.argv[1:] if argv is None else argv:
        if not word.startswith("-"):
            return word
    return None


def build_parser(command: str | None = "*") -> argparse.ArgumentParser:
    """The ``relight`` parser: every command's full parser ("*"), or only ``command``'s (the others
    a help line each: what --help lists), or none (None)."""
    from .. import __version__

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


def commands_text() -> str:
    """What ``relight`` alone prints: the commands, one line each."""
    rows = name_table(COMMANDS)
    return (f"usage: relight COMMAND ...\n\nReal-time relighting of a human face in video, on a CPU.\n\n"
            f"commands:\n{rows}\n'relight COMMAND --help' lists a command's flags; 'relight --help' the options.\n")


def main(argv: list[str] | None = None) -> int:
    """The ``relight`` command (alone: the commands, one line each, exit status 0)."""
    words = sys.argv[1:] if argv is None else argv
    if _command(argv) is None and not {"-h", "--help", "--version"} & set(words):
        sys.stdout.write(commands_text())
        return 0
    parser = build_parser(_command(argv))
    args = parse_args(parser, argv)
    return run_command("relight", args.func, args)


def serve_main(argv: list[str] | None = None) -> int:
    """The ``relight-serve`` command (the same as ``relight serve``)."""
    p = argparse.ArgumentParser(prog="relight-serve", description="Serve relighting of video frames over HTTP.",
                                formatter_class=DefaultsUnlessNone)
    serve.add_arguments(p)
    p.add_argument("--verbose", action="store_true", help=VERBOSE_HELP)
    args = parse_args(p, argv)
    return run_command("relight-serve", serve.serve_command, args)
