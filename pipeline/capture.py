"""``relight capture``: a phone video (or an RTI image set) -> reflectance bundle.

Video: :mod:`ingest` (one decoding pass) -> :mod:`samples` (flash separation, registration,
light directions, ambient-free samples) -> :mod:`geometry` -> :mod:`reflectance` (or a fitted
baseline from :mod:`methods`) -> :mod:`bundle`. An RTI image set (``dirs.lp``) enters at the
samples. Every stage is timed; what was dropped and why is counted.

This module runs the whole capture (:func:`capture`); its parts live beside it:
:mod:`capture_types` (options, the prepared samples, the result), :mod:`video_source` (the video
path), :mod:`image_set` (the image-set path and its ``.lp`` parser), :mod:`bundle_arrays` (the
back half: geometry, maps, transport, landmarks -> the bundle's arrays), :mod:`reflectance_maps`
(the maps and horizons) and :mod:`capture_progress` (progress bars, stage timings).
"""

from __future__ import annotations

import os
import time

import cv2
import numpy as np

# `NAME`: also taken from here by the benchmarks (where they lived before the split).
from .bundle_arrays import finish
from .bundle_write import BUNDLE_MODE, write_bundle
from .capture_progress import Progress, StageTimings
from .capture_types import CaptureOptions, CaptureResult
from .image_set import prepare_images
from .video_source import prepare_video


def expected_bundle_bytes(n_samples: int, n_pixels: int, opts: CaptureOptions) -> int:
    """A generous estimate of the bundle's size before it is made (the free-space check):
    per face pixel its sample codes (3 K bytes), horizon, fits and compact transport (~400
    bytes), with --keep-maps the maps twice in float16 (half the map's texels lit), a quarter
    more for what varies, and 1 MB of header and background."""
    per_pixel = 3 * n_samples + 400
    if opts.keep_maps:
        per_pixel += 2 * 3 * 2 * (opts.map_size[0] * opts.map_size[1] // 2) + 6 * n_samples
    return int(1.25 * per_pixel * n_pixels) + (1 << 20)


def capture(source, out, opts: CaptureOptions | None = None, *, images: bool = False, report_dir=None,
            progress: bool = True, file_mode: int = BUNDLE_MODE) -> CaptureResult:
    """Run the whole capture; write the bundle to ``out`` (and a report to ``report_dir``).

    ``file_mode``: the bundle's permission bits (default owner-only: it holds a face). The
    output's folder must have room for the bundle: checked once the samples are known, before
    the long part (maps, transport), and again with the bundle's exact size before writing."""
    from relight.imageio import check_free_space, check_writable

    opts = (opts or CaptureOptions()).validate()
    check_writable(out)
    timings = StageTimings()
    bar = Progress(progress)
    t_all = time.perf_counter()
    # BLAS and OpenCV with as many threads as the machine has, whatever the process set before (a
    # frame path limits them to one): BLAS's sums' order follows the thread count, and the same
    # input must give the same bundle bytes; OpenCV's pools make the capture's images faster.
    from threadpoolctl import threadpool_limits

    blas = threadpool_limits(limits=os.cpu_count() or 1, user_api="blas")
    cv_threads = cv2.getNumThreads()
    cv2.setNumThreads(-1)
    try:
        prep = prepare_images(source, opts, bar, timings) if images else prepare_video(source, opts, bar, timings)
        n_pix = int(prep.mask.sum()) if prep.mask is not None else int(np.prod(prep.images.shape[1:3]))
        check_free_space(out, expected_bundle_bytes(prep.images.shape[0], n_pix, opts), "the bundle")
        arrays, meta, geo, tri = finish(prep, opts, bar, timings)
        t0 = time.perf_counter()
        # (run facts - timings, peak memory - go to the report: the same input gives the same bundle)
        meta["rejected"] = prep.report.get("rejected", {})
        meta["stored"] = sorted(arrays)
        check_free_space(out, sum(np.asarray(a).nbytes for a in arrays.values()) + (1 << 20), "the bundle")
        path = write_bundle(out, meta, arrays, mode=file_mode)
        timings["write"] = time.perf_counter() - t0
    finally:
        bar.close()
        blas.restore_original_limits()
        cv2.setNumThreads(cv_threads)
    timings["total"] = time.perf_counter() - t_all
    report = {k: v for k, v in prep.report.items()}
    report["timings"] = {k: round(v, 3) for k, v in timings.items()}
    report["peak_rss_mb"] = {k: round(v, 1) for k, v in timings.peak_mb.items()}
    result = CaptureResult(bundle=path, report=report, timings=timings, arrays=arrays, prepared=prep, meta=meta)
    if report_dir is not None:
        from .report import write_report

        write_report(report_dir, result, geo, tri)
    return result
