"""Shared fixtures: the real data folder and small synthetic captures (made once per run: the
pytest-xdist workers share them through a folder the first worker makes, the others wait)."""

from __future__ import annotations

from pathlib import Path

import pytest

from .once import made_once, synthesized

ROOT = Path(__file__).resolve().parents[1]
SHARED_DATA = ROOT.parent / "shared" / "data"


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """../shared/data (real light probes and the RTI capture); skips when it is absent."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"real test data not found at {SHARED_DATA} (only in the project's workspace)")
    return SHARED_DATA


@pytest.fixture(scope="session")
def chromium() -> str:
    """A headless Chromium's executable (the browser page's and relight live's page's tests); skips
    when it is absent."""
    from relight.bench.browser import find_chromium

    exe = find_chromium()
    if exe is None:
        pytest.skip("Chromium is not installed: `make install-system` installs it (Debian's apt, as root), "
                    "or install the 'chromium' package yourself")
    return exe


@pytest.fixture(scope="session")
def small_capture(tmp_path_factory):
    """A 6-second 320x180 synthetic capture with a point environment among the truth envs."""
    from relight.pipeline.synth.config import DEFAULT_TRUTH_ENVS, SynthConfig

    cfg = SynthConfig(width=320, height=180, duration=6.0, seed=3,
                      truth_envs=DEFAULT_TRUTH_ENVS + ("builtin:point:0.8,0.1,0.6",))
    return synthesized(tmp_path_factory, "small-capture", cfg), cfg


@pytest.fixture(scope="session")
def small_bundle(small_capture, tmp_path_factory):
    """A bundle captured from ``small_capture`` (the synthetic truth stays in small_capture)."""
    from relight import load_bundle
    from relight.pipeline.capture import capture

    res, _ = small_capture
    folder = made_once(tmp_path_factory, "small-bundle",
                       lambda folder: capture(res.video, folder / "face.bundle", progress=False))
    return load_bundle(folder / "face.bundle")


@pytest.fixture(scope="session")
def live_clip(tmp_path_factory) -> Path:
    """A 2 s live clip (MP4) of the small capture's head (seed 3, 320x180), turning a little:
    the camera of `relight live`'s tests and the browser's fake webcam."""
    from relight.pipeline.synth.live_clip import LiveConfig, synthesize_live

    def make(folder: Path):
        synthesize_live(folder, LiveConfig(width=320, height=180, duration=2.0, seed=3, yaw=10.0, pitch=5.0,
                                           roll=3.0, audio="none"), progress=False)

    return made_once(tmp_path_factory, "live-clip", make) / "live.mp4"


@pytest.fixture(scope="session")
def frame(small_capture):
    """A no-flash frame of ``small_capture`` (RGB uint8): what the service tests send."""
    import json

    from relight.video_read import read_frames

    res, _ = small_capture
    meta = json.loads((res.truth / "meta.json").read_text())
    dark = [i for i, f in enumerate(meta["flash_fraction"]) if f == 0.0]
    for i, f in enumerate(read_frames(res.video)):
        if i == dark[0]:
            return f


# The per-frame path's test modules (test_filter, test_tracking, test_composite) share these two:
# a short clip of the small capture's no-flash frames and a frame path on the small bundle (one
# of each per module; test_person and test_bench_live_frame have a `clip` of their own).
@pytest.fixture(scope="module")
def clip(small_capture, tmp_path_factory):
    """45 no-flash frames of the small capture (a face under room light that moves a little),
    re-encoded with a 440 Hz audio track."""
    import json

    import numpy as np

    from relight.video_read import read_frames
    from relight.video_write import VideoWriter

    res, cfg = small_capture
    meta = json.loads((res.truth / "meta.json").read_text())
    dark = {i for i, f in enumerate(meta["flash_fraction"]) if f == 0.0}
    frames = [f for i, f in enumerate(read_frames(res.video)) if i in dark][:45]
    path = tmp_path_factory.mktemp("clip") / "clip.mp4"
    t = np.arange(int(48000 * len(frames) / cfg.fps)) / 48000.0
    with VideoWriter(path, cfg.fps, (cfg.width, cfg.height), audio=0.2 * np.sin(2 * np.pi * 440 * t)) as wr:
        for f in frames:
            wr.write(f)
    return path, frames


@pytest.fixture(scope="module")
def frame_path(small_bundle):
    from relight import load_environment
    from relight.engine.frame_path import FramePath
    from relight.engine.frame_settings import FrameSettings

    # the face's composite (the tests of the whole person make their own paths); the studio's
    # frames are orthographic: told so, as a user tells a webcam's focal length or leaves it found
    return FramePath(small_bundle, load_environment("builtin:sunset"), FrameSettings(region="face", focal="ortho"))
