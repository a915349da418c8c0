import re
import subprocess
import sys

import numpy as np
import pytest

from relight.cli import build_parser, main

from .tolerances import LIVE_CHANGED_CODES, LIVE_CHANGED_SHARE


def _flags(help_text):
    return set(re.findall(r"--[a-z][a-z-]+", help_text))


def test_every_synth_flag_is_explained(capsys):
    with pytest.raises(SystemExit):
        main(["synth", "--help"])
    text = capsys.readouterr().out
    for flag in ("--seed", "--fps", "--flash-hz", "--duration", "--size", "--truth-env", "--head-motion",
                 "--ambient", "--noise", "--camera-drift", "--quiet"):
        assert flag in text
    # Every option has its own help line, not just its name.
    parser = build_parser()
    synth = parser._subparsers._group_actions[0].choices["synth"]
    assert all(a.help for a in synth._actions)


def test_bad_input_is_one_line_and_status_2(tmp_path, capsys):
    assert main(["synth", str(tmp_path / "o"), "--size", "961x540", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "--size" in err and "Traceback" not in err and err.count("\n") == 1
    assert main(["synth", str(tmp_path / "o"), "--truth-env", "builtin:nope", "--duration", "1",
                 "--size", "192x108", "--quiet"]) == 2
    assert "choose one of" in capsys.readouterr().err


def test_module_entry_point():
    out = subprocess.run([sys.executable, "-m", "relight", "--help"], capture_output=True, text=True, check=True)
    assert "synth" in out.stdout and "demo" in out.stdout
    # each command's own line (the bench's "serve" is another command's)
    assert "serve relighting of video frames over HTTP" in " ".join(out.stdout.split())


@pytest.mark.slow
def test_demo_writes_a_contact_sheet(tmp_path, capsys):
    import cv2

    assert main(["demo", "--out", str(tmp_path), "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "contact sheet:" in out and "accuracy against the truth" in out
    assert f"relight serve {tmp_path / 'face.bundle'}" in out.rstrip().splitlines()[-1]
    sheet = cv2.imread(str(tmp_path / "contact_sheet.png"))
    assert sheet.shape == (5 * 270, 4 * 480, 3) and sheet.std() > 10
    # The relit live clip under each environment, and the before/after sheet (before + 3 envs, 3 moments).
    from relight.cli import DEMO_ENVS
    from relight.video import probe_video

    for name in DEMO_ENVS:
        assert probe_video(tmp_path / f"relit-{name}.mp4").frame_count == \
            probe_video(tmp_path / "live" / "live.mp4").frame_count
        assert f"relit under {name}" in out
    ba = cv2.imread(str(tmp_path / "before_after.png"))
    assert ba.shape == (3 * 270, (1 + len(DEMO_ENVS)) * 480, 3)
    before, after = ba[270:540, :480].astype(int), ba[270:540, 480:960].astype(int)
    assert (np.abs(before - after).max(axis=2) > LIVE_CHANGED_CODES).mean() > LIVE_CHANGED_SHARE
    assert "\r" not in out and len(out.splitlines()) < 30  # a log gets one line per stage, no bars
    assert (tmp_path / "face.bundle").stat().st_size > 1e6 and (tmp_path / "report" / "report.json").exists()


def test_a_command_builds_only_its_own_parser():
    """`relight filter ...` parses without importing the capture pipeline or the web app (start-up
    time), and every command is still listed by --help."""
    code = ("import sys; from relight.cli import build_parser, COMMANDS; p = build_parser('filter'); "
            "p.parse_args(['filter', 'a.mp4', 'b.mp4', '--bundle', 'x.bundle', '--env', 'builtin:sunset']); "
            "print(sorted(m for m in ('fastapi', 'relight.pipeline.capture', 'relight.pipeline.synth.live') "
            "if m in sys.modules)); print(sorted(p._subparsers._group_actions[0].choices) == sorted(COMMANDS))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split("\n")
    assert out[0] == "[]" and out[1] == "True"
    full = build_parser()
    assert all(len(sp._actions) > 1 for sp in full._subparsers._group_actions[0].choices.values())


def test_negative_numbers_are_values_not_flags():
    from relight.cli import negative_values_joined

    argv = ["render", "b", "--light", "-0.5,0.2,0.8", "--exposure", "-1e-3", "--rotate=-3,0,0", "--quiet", "x"]
    assert negative_values_joined(argv) == ["render", "b", "--light=-0.5,0.2,0.8", "--exposure=-1e-3",
                                            "--rotate=-3,0,0", "--quiet", "x"]
    assert negative_values_joined(["--", "--light", "-1"]) == ["--", "--light", "-1"]  # after --: untouched
    assert negative_values_joined(["-h"]) == ["-h"] and negative_values_joined(["--light", "-x"]) == ["--light", "-x"]
