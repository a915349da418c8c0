"""``relight filter``: a virtual-camera-style batch filter over a video or an image sequence.

Decodes any container FFmpeg reads (PyAV), relights each frame with :class:`FramePath`, and
writes the result: H.264 in .mp4/.mov/.mkv/.avi, VP9 in .webm, or PNG frames when OUT is a
folder. The audio stream is copied packet for packet (re-encoded to AAC only when the output
container cannot hold its codec) and every frame keeps its timestamp, so variable frame rate
survives. OUT appears only complete (temporary file + rename). Frames where nothing can be done
(no face) pass through unchanged and are counted.

The per-frame timings cover the per-frame path only (track + pose + relight + warp +
composite); decoding and encoding run beside it and are reported separately.

The run loop is here (:func:`run_filter`); the work by input and output is in
:mod:`relight.apps.filter_video` (video -> video) and :mod:`relight.apps.filter_frames`
(image sequences, PNG frames), the two-thread per-frame path in
:mod:`relight.engine.frame_pipeline`, the result and its report in
:mod:`relight.apps.filter_report`.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from relight.errors import InputError
from relight.video_write import DEFAULT_CRF, DEFAULT_PRESET, check_preset

from ..engine.composite import DEFAULT_MODE, DEFAULT_REGION
from ..engine.frame_pipeline import FramePipeline
from .filter_frames import (
    filter_sequence,
    filter_video_frames,
    is_folder_output,
)
from .filter_report import FilterResult, timing_stats, write_report
from .filter_video import filter_video


def run_filter(inp, out, bundle, env, *, mode: str = DEFAULT_MODE, fixed_env: bool = False, strength: float = 1.0,
               exposure: float = 0.0, focal: float | None = None, fps: float = 30.0, crf: int = DEFAULT_CRF,
               region: str = DEFAULT_REGION, env_turn: float = 0.0, env_spin: float = 0.0,
               preset: str = DEFAULT_PRESET, report_dir=None, virtual_camera: bool = False, progress: bool = True,
               frame_path=None,
               start_time: float | None = None) -> FilterResult:
    """Relight the faces of ``inp`` (a video file or a folder of images) into ``out``."""
    from tqdm import tqdm

    from ..engine.frame_path import FramePath
    from ..engine.frame_settings import FrameSettings

    t_start = time.perf_counter() if start_time is None else start_time
    inp, out = Path(inp), Path(out)
    check_preset(preset)
    if inp.resolve() == out.resolve():
        raise InputError(f"{out}: the output would overwrite the input; choose another name")
    settings = FrameSettings(mode=mode, strength=strength, fixed_env=fixed_env, focal=focal, exposure=exposure,
                             region=region, env_turn=env_turn, env_spin=env_spin)
    fp = frame_path or FramePath(bundle, env, settings)
    res = FilterResult(out=out)
    res.start_s = time.perf_counter() - t_start
    stages: dict[str, list] = {k: [] for k in ("track", "pose", "relight", "light", "warp", "composite", "total")}
    cam = None

    def handle(rgb, t, index):
        return record(rgb, *fp.process(rgb, t), index)

    def record(rgb, frame_out, info, index):
        nonlocal cam
        res.frames += 1
        if info.face:
            res.faces += 1
            res.head_rotation[str(index)] = [round(a, 3) for a in info.angles]
            if info.light is not None:
                res.live_light[str(index)] = info.light.as_json()
        else:
            res.passed_through += 1
        for k in stages:
            stages[k].append(info.timings.get(k, 0.0))
        if virtual_camera:
            if cam is None:
                from .virtual_camera import VirtualCamera

                cam = VirtualCamera((rgb.shape[1], rgb.shape[0]), fps)
            cam.send(frame_out if isinstance(frame_out, np.ndarray) else frame_out.to_rgb())
        return frame_out

    try:
        if inp.is_dir():
            filter_sequence(inp, out, handle, fps, crf, res, progress, tqdm, preset)
        elif is_folder_output(out):
            filter_video_frames(inp, out, FramePipeline(fp, record), res, progress, tqdm)
        else:
            filter_video(inp, out, FramePipeline(fp, record), crf, res, progress, tqdm, preset)
    finally:
        if cam is not None:
            cam.close()
        if frame_path is None:  # made here: its threads stopped here
            fp.close()
    if res.frames == 0:
        raise InputError(f"{inp}: no frames could be read")
    res.timings_ms = {k: timing_stats(v) for k, v in stages.items()}
    res.focal_px, res.focal_found = fp.frames_focal, fp.focal_found
    res.wall_s = time.perf_counter() - t_start
    if res.faces == 0:
        res.notes.append("no face was found in any frame: the output is the input, unchanged")
    if report_dir is not None:
        write_report(Path(report_dir), res, inp)
    return res
