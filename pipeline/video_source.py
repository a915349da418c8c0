"""The capture's video path: a phone video through :mod:`ingest` (one decoding pass) and
:mod:`samples` (flash separation, registration, light directions, ambient-free samples) to the
:class:`~relight.pipeline.capture_types.Prepared` samples the back half starts from, with the
run's report (flashes, transforms, what was rejected)."""

from __future__ import annotations

import time

from .capture_progress import Progress
from .capture_types import CaptureOptions, Prepared
from .ingest import ingest
from .samples import collect_samples


def prepare_video(path, opts: CaptureOptions, progress: Progress, timings: dict) -> Prepared:
    """Stages 1-3 on a capture video."""
    from relight.video_read import probe_video

    t0 = time.perf_counter()
    expected = probe_video(path).frame_count
    total = [0]

    def frame_cb(n):
        total[0] += n
        progress("decode", total[0], max(expected, total[0]))

    ing = ingest(path, face=opts.face, sphere_hint=opts.samples.sphere, progress=frame_cb,
                 face_pixels=opts.face_pixels)
    timings["ingest"] = time.perf_counter() - t0
    smp = collect_samples(ing, opts.samples, progress=progress)
    timings.update({f"samples_{k}": v for k, v in smp.timings.items()})
    x0, y0 = smp.origin
    face_local = None
    if ing.face_box is not None:
        fx, fy, fw, fh = ing.face_box
        face_local = (fx - x0, fy - y0, fw, fh)
    # the capture's camera as the sphere's directions took it (--focal, or found from the ball): a
    # focal length in px of the video's frames, recorded in px of the working frame, or None -
    # orthographic (the rig lifts the reference the same way)
    focal = smp.camera["focal_px"]
    scale = {"capture_scale": ing.scale, "source_size": list(ing.source_size or ing.size),
             "camera_focal": None if focal is None else float(focal) * ing.scale}
    report = {
        "flash_frames": [int(f) for f in smp.flash.flash_frames],
        "flash_peaks": [int(f) for f in smp.flash.peaks],
        "dark_frames": [int(f) for f in smp.flash.dark],
        "flash_hz": smp.flash.flash_hz,
        "flash_hz_estimated": smp.flash.estimated,
        "light_dirs": {str(f): [round(float(x), 6) for x in d] for f, d in smp.light_dirs.items()},
        "transforms": {str(f): [round(float(x), 5) for x in m] for f, m in smp.motions.items()},
        "transform_center": list(smp.motion_center),
        "reference_frame": smp.reference_frame,
        "rejected": dict(smp.rejected),
        "sphere": list(smp.circle) if smp.circle else None,
        "sphere_source": ing.sphere_source,
        "camera": dict(smp.camera),
        "face_box": list(ing.face_box) if ing.face_box else None,
        "face_source": ing.face_source,
        "notes": list(ing.notes),
        "pulse_frames": smp.pulse_frames,
        "_trace": ing.face_trace().tolist(),
        "_level": smp.flash.level.tolist(),
        "_track_quality": {str(k): list(v) for k, v in smp.track_quality.items()},
        "fps": ing.fps,
        **scale,
    }
    background = ing.still
    return Prepared(images=smp.images, dirs=smp.dirs, clipped=smp.clipped, ambient=smp.ambient,
                    background=background, origin=smp.origin, frame_size=ing.size, face_local=face_local,
                    mask=None, meta={"source": str(path), "kind": "video", "fps": ing.fps, **scale}, report=report)
