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
def test_relight_alone_lists_its_commands():
    """`relight` with no command (the console script, as a user types it) lists every command with
    its one line and exits 0; `--verbose` alone is still no command."""
    import shutil
    from pathlib import Path

    from relight.cli import COMMANDS

    exe = Path(sys.executable).parent / "relight"
    cmd = [str(exe)] if exe.exists() else [shutil.which("relight")]
    for extra in ([], ["--verbose"]):
        out = subprocess.run(cmd + extra, capture_output=True, text=True, timeout=60)
        assert out.returncode == 0, out.stderr
        assert out.stderr == ""
        lines = out.stdout.splitlines()
        for name, text in COMMANDS.items():
            assert sum(1 for line in lines if line.split()[:1] == [name] and line.rstrip().endswith(text)) == 1, name
    # a wrong command is still an error that names the choices
    bad = subprocess.run(cmd + ["nope"], capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "invalid choice" in bad.stderr
    # `relight bench` alone lists the benchmarks the same way
    bench = subprocess.run(cmd + ["bench"], capture_output=True, text=True, timeout=60)
    assert bench.returncode == 0 and bench.stderr == ""
    names = [line.split()[0] for line in bench.stdout.splitlines() if line.startswith("  ")]
    assert names == ["capture", "relight", "video", "serve", "live", "fuzz", "crash", "soak", "accuracy"]


@pytest.mark.slow  # the whole demo (~40 s: a 12 s capture, three relit clips): `make test-slow`, CI
def test_demo_writes_a_contact_sheet(tmp_path, capsys):
    import cv2

    assert main(["demo", "--out", str(tmp_path), "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "contact sheet:" in out and "accuracy against the truth" in out
    assert f"relight serve {tmp_path / 'face.bundle'}" in out.rstrip().splitlines()[-1]
    sheet = cv2.imread(str(tmp_path / "contact_sheet.png"))
    # five rows of tiles, and the scanned head's credit line under them
    assert sheet.shape[1:] == (4 * 480, 3) and 5 * 270 < sheet.shape[0] <= 5 * 270 + 60 and sheet.std() > 10
    from relight.pipeline.synth.mesh_head import DEMO_HEAD

    assert DEMO_HEAD.startswith("builtin:")  # the demo shows the scan shipped with relight
    assert sheet[5 * 270:].max() > 150  # (the credit's text)
    # The relit live clip under each environment, and the before/after sheet (before + 3 envs, 3 moments).
    from relight.cli import DEMO_ENVS
    from relight.video_read import probe_video

    for name in DEMO_ENVS:
        assert probe_video(tmp_path / f"relit-{name}.mp4").frame_count == \
            probe_video(tmp_path / "live" / "live.mp4").frame_count
        assert f"relit under {name}" in out
    ba = cv2.imread(str(tmp_path / "before_after.png"))
    assert ba.shape[1:] == ((1 + len(DEMO_ENVS)) * 480, 3) and 3 * 270 < ba.shape[0] <= 3 * 270 + 60
    before, after = ba[270:540, :480].astype(int), ba[270:540, 480:960].astype(int)
    assert (np.abs(before - after).max(axis=2) > LIVE_CHANGED_CODES).mean() > LIVE_CHANGED_SHARE
    assert "\r" not in out and len(out.splitlines()) < 30  # a log gets one line per stage, no bars
    assert (tmp_path / "face.bundle").stat().st_size > 1e6 and (tmp_path / "report" / "report.json").exists()


def test_a_command_builds_only_its_own_parser():
    """`relight filter ...` parses without importing the capture pipeline or the web app (start-up
    time), and every command is still listed by --help."""
    code = ("import sys; from relight.cli import build_parser, COMMANDS; p = build_parser('filter'); "
            "p.parse_args(['filter', 'a.mp4', 'b.mp4', '--bundle', 'x.bundle', '--env', 'builtin:sunset']); "
            "print(sorted(m for m in ('fastapi', 'relight.pipeline.capture', 'relight.pipeline.synth.live_clip') "
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


def _in_small_mount(folder, cmd, *, size="64k", read_only=False):
    """Run ``cmd`` with a fresh tmpfs of ``size`` (read-only with ``read_only``) mounted on
    ``folder``, in a user and mount namespace of its own (no root needed); None when this system
    does not allow that (then the caller skips)."""
    import shlex
    import shutil

    unshare = shutil.which("unshare")
    if unshare is None:
        return None
    opts = f"size={size}" + (",ro" if read_only else "")
    script = f"mount -t tmpfs -o {opts} tmpfs {shlex.quote(str(folder))} || exit 97; exec {shlex.join(map(str, cmd))}"
    r = subprocess.run([unshare, "-rm", "sh", "-c", script], capture_output=True, text=True, timeout=180)
    return None if r.returncode == 97 or "unshare failed" in r.stderr else r


def test_an_output_that_cannot_be_written_is_one_clear_line(small_bundle, small_capture, tmp_path, capsys,
                                                            monkeypatch):
    """Writes the system refuses (a file size limit: the same path as a full disk) are
    `relight: error: cannot write PATH: <reason>` and status 2, no traceback, nothing left
    behind; a capture whose output folder has not the room for the bundle says so before the
    long part, with the sizes."""
    render = [sys.executable, "-m", "relight", "render", str(small_bundle.path), "--env", "builtin:window", "-o"]
    full, ro = tmp_path / "full", tmp_path / "ro"
    full.mkdir()
    ro.mkdir()
    # a file system with 64 kB (the EXR is larger), and a read-only one
    r = _in_small_mount(full, render + [str(full / "out.exr")])
    if r is None:
        pytest.skip("no user/mount namespaces here (unshare -rm) to mount a small file system in")
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert r.stderr.strip() == f"relight: error: cannot write {full / 'out.exr'}: no space left on device", r.stderr
    r = _in_small_mount(ro, render + [str(ro / "out.png")], read_only=True)
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert f"relight: error: cannot write {ro / 'out.png'}: read-only file system" in r.stderr, r.stderr
    capture = [sys.executable, "-m", "relight", "capture", str(small_capture[0].video), "-o", str(full / "b.bundle")]
    r = _in_small_mount(full, capture)
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert "cannot write" in r.stderr and "no space left on device" in r.stderr and "MB free" in r.stderr, r.stderr
    assert not any(full.iterdir()) and not any(ro.iterdir())  # (the mounts are gone; nothing left under them)
    # a capture is refused before its long part when the folder lacks the room (checked free space)
    import shutil

    from relight.imageio import check_free_space

    real = shutil.disk_usage
    monkeypatch.setattr(shutil, "disk_usage", lambda p: real(p)._replace(free=3_000_000))
    with pytest.raises(OSError, match="no space left on device .*3.0 MB free"):
        check_free_space(tmp_path / "b.bundle", 23_000_000, "the bundle")
    assert main(["render", str(small_bundle.path), "--env", "builtin:window", "-o",
                 str(tmp_path / "x" / "y.png")]) == 0  # (a missing folder is made)


@pytest.mark.slow  # a whole capture more (~11 s): `make test-slow`, CI
def test_files_are_owner_only_for_bundles_and_follow_the_umask_otherwise(small_capture, small_bundle, tmp_path,
                                                                         capsys):
    """A bundle (a person's face) is 0600 unless widened with --file-mode; images, videos and
    reports get 0666 less the umask, as other tools' files (0644 under 022, 0640 under 027)."""
    import os
    import stat

    from relight.imageio import write_image
    from relight.pipeline.bundle_write import write_bundle

    res, _ = small_capture
    old = os.umask(0o027)
    try:
        png = write_image(tmp_path / "a.png", np.zeros((4, 4, 3), np.uint8))
        assert stat.S_IMODE(png.stat().st_mode) == 0o640
        os.umask(0o022)
        png = write_image(tmp_path / "a.png", np.zeros((4, 4, 3), np.uint8))
        assert stat.S_IMODE(png.stat().st_mode) == 0o644
        bundle = small_bundle.path  # the suite's capture of this video, by capture() as the CLI runs it
        assert stat.S_IMODE(bundle.stat().st_mode) == 0o600
        wide = write_bundle(tmp_path / "c.bundle", small_bundle.meta, dict(small_bundle.arrays), mode=0o640)
        assert stat.S_IMODE(wide.stat().st_mode) == 0o640
        assert "timings" not in small_bundle.meta  # run facts are the report's: the same input, the same bundle
        again = tmp_path / "again.bundle"
        assert main(["capture", str(res.video), "-o", str(again), "--quiet", "--file-mode", "644"]) == 0
        assert stat.S_IMODE(again.stat().st_mode) == 0o644
        assert again.read_bytes() == bundle.read_bytes()
        with pytest.raises(SystemExit):
            main(["capture", str(res.video), "-o", str(again), "--file-mode", "400"])
    finally:
        os.umask(old)


def test_kernels_build_without_compiler_messages_and_verbose_shows_them(tmp_path):
    """Every OpenCL program builds with no compiler output on this CPU (a fresh PoCL cache; the
    kernels' own warnings were a PyOpenCL CompilerWarning at every start); --verbose turns
    pyopencl's compiler output on for whatever PoCL says."""
    import os

    # (the programs with 16-wide vectors: where clang warned; every program is built by the suite)
    code = ("import warnings; warnings.simplefilter('error')\n"
            "from relight.kernels.runtime import build_program\n"
            "from relight.kernels.compositor import program_options\n"
            "for name, opts in [('reflectance', ('-DUSE_SPLINE=1', '-DSPLINE_ROOT25=1')),\n"
            "                   ('relight', ('-cl-denorms-are-zero',)), ('composite', program_options())]:\n"
            "    build_program(name, opts)\n"
            "print('built')\n")
    env = dict(os.environ, POCL_CACHE_DIR=str(tmp_path / "pocl"), PYOPENCL_COMPILER_OUTPUT="1")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, env=env)
    assert r.returncode == 0 and "built" in r.stdout and "warning" not in r.stderr.lower(), r.stderr[-2000:]
    from relight.cli import set_verbose
    from relight.kernels.runtime import VERBOSE_ENV, compiler_output_wanted

    saved = {k: os.environ.get(k) for k in (VERBOSE_ENV, "PYOPENCL_COMPILER_OUTPUT")}
    try:
        for k in saved:
            os.environ.pop(k, None)
        assert not compiler_output_wanted()
        set_verbose(True)
        assert compiler_output_wanted() and os.environ["PYOPENCL_COMPILER_OUTPUT"] == "1"
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
