"""Synthetic clips the benchmarks share (cached in their output folder): a bundle captured from a
static studio capture of a head, a live clip of the same head, and the flicker figure.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

#: The capture's flash rate by default (a user's first try: the issue-13 condition).
CAPTURE_HZ = 4.0


def synth_bundle(out: Path, size: tuple[int, int], duration: float, progress: bool, flash_hz: float = CAPTURE_HZ,
            seed: int = 0, head_mesh: str | None = None) -> Path:
    """A bundle captured from a static studio capture of head ``seed`` (or the mesh
    ``head_mesh``) at ``size`` (cached)."""
    from relight.pipeline.capture import capture
    from relight.pipeline.synth.config import SynthConfig
    from relight.pipeline.synth.studio import synthesize

    tag = f"{size[0]}x{size[1]}-{duration:g}s-{flash_hz:g}hz" + (f"-seed{seed}" if seed else "") + head_tag(head_mesh)
    cap = out / f"capture-{tag}"
    bundle = out / f"face-{tag}.bundle"
    if not bundle.exists():
        if not (cap / "capture.mp4").exists():
            if progress:
                print(f"synthesising a {size[0]}x{size[1]} capture ...", flush=True)
            synthesize(cap, SynthConfig(width=size[0], height=size[1], duration=duration, seed=seed, flash_hz=flash_hz,
                                        head_mesh=head_mesh), progress=progress)
        if progress:
            print("capturing it ...", flush=True)
        capture(cap / "capture.mp4", bundle, progress=progress)
    return bundle


def synth_live(out: Path, size: tuple[int, int], duration: float, progress: bool, seed: int = 0,
               head_mesh: str | None = None, fov: float | None = None) -> Path:
    """A live clip of head ``seed`` (or ``head_mesh``) at ``size`` (cached); ``fov``: through a
    pinhole of that field of view at the default distance (``relight synth --fov``)."""
    from relight.pipeline.synth.live_clip import LiveConfig, synthesize_live

    folder = out / (f"live-{size[0]}x{size[1]}-{duration:g}s" + (f"-seed{seed}" if seed else "") + head_tag(head_mesh)
                    + (f"-fov{fov:g}" if fov is not None else ""))
    if not (folder / "truth" / "meta.json").exists():
        if progress:
            print(f"synthesising a {size[0]}x{size[1]} live video ...", flush=True)
        synthesize_live(folder, LiveConfig(width=size[0], height=size[1], duration=duration, seed=seed,
                                           head_mesh=head_mesh, fov=fov), progress=progress)
    return folder


def head_tag(head_mesh: str | None) -> str:
    if head_mesh is None:
        return ""
    return "-" + "".join(ch if ch.isalnum() else "_" for ch in str(head_mesh).removeprefix("builtin:"))


def flicker_step(inp0: np.ndarray, out0: np.ndarray, inp1: np.ndarray, out1: np.ndarray) -> float | None:
    """Flicker between two frames (8-bit codes): the mean absolute change of the output's face
    minus the input's own change there (the face: pixels the filter changed by more than one
    code in the second frame). None without a face."""
    face = np.abs(out1.astype(np.int16) - inp1.astype(np.int16)).max(axis=2) > 1
    if face.sum() < 100:
        return None
    do = np.abs(out1.astype(np.int16) - out0.astype(np.int16)).mean(axis=2)[face].mean()
    di = np.abs(inp1.astype(np.int16) - inp0.astype(np.int16)).mean(axis=2)[face].mean()
    return float(do - di)


def run_filter_process(inp: Path, dst: Path, bundle: Path, env: str, report: Path, *extra: str,
                       focal: str | None = "ortho") -> dict:
    """``relight filter INP DST --bundle BUNDLE --env ENV --focal FOCAL --quiet --report REPORT``
    and ``extra`` flags in a fresh process (``focal``: "ortho" by default - the synthetic studio's
    and the real-face clips are orthographic views -, a number of pixels, or None: no --focal, the
    path finds it): its ``report.json`` with ``wall_s`` added (seconds, start-up included). Raises
    RuntimeError with the end of its error output when it fails."""
    told = [] if focal is None else ["--focal", str(focal)]
    cmd = [sys.executable, "-m", "relight", "filter", str(inp), str(dst), "--bundle", str(bundle), "--env", env,
           *extra, *told, "--quiet", "--report", str(report)]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        what = " ".join(("relight filter", *extra))
        raise RuntimeError(f"{what} failed: {proc.stderr.strip()[-800:]}")
    doc = json.loads((Path(report) / "report.json").read_text())
    doc["wall_s"] = time.perf_counter() - t0
    return doc


def rotation_errors(estimates: dict, truth: list) -> np.ndarray:
    """Degrees between estimated and true head rotations, for the frames with an estimate
    (``estimates``: {frame index as text: (yaw, pitch, roll)}; ``truth``: the clip's meta's
    head_rotation)."""
    from relight.directions import rotation_matrix
    from relight.kernels.relight_inputs import rotation_angle_deg

    return np.asarray([rotation_angle_deg(rotation_matrix(*truth[int(k)]), rotation_matrix(*angles))
                       for k, angles in estimates.items()])
