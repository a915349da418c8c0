"""The per-frame path's threads: the process's thread pools (:func:`limit_threads`) and the worker
for the slow maps (:class:`Worker`)."""
from __future__ import annotations

import cv2


def limit_threads() -> None:
    """One thread for NumPy's BLAS and for OpenCV in this process: the per-frame path's matrix
    products and image operations are small, and the pools' idle threads spin after each call,
    taking the cores from the tracker, the OpenCL kernels and the codec's threads. Measured:
    BLAS at 640x360, 31 -> 12-15 ms of CPU per frame; OpenCV on the 720p clip (region person),
    78.6 -> 61.6 ms of CPU per frame at the same wall time (52 -> 49 ms). Called by
    :class:`.frame_path.FramePath`; set ``RELIGHT_BLAS_THREADS`` / ``RELIGHT_CV_THREADS`` to keep more (a
    capture in the same process sets its own: :func:`relight.pipeline.capture.capture`)."""
    import os

    blas = int(os.environ.get("RELIGHT_BLAS_THREADS", "1") or 1)
    cv = int(os.environ.get("RELIGHT_CV_THREADS", "1") or 1)
    cv2.setNumThreads(max(cv, 1))
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # pragma: no cover - a dependency; without it the path is only slower
        return
    threadpool_limits(limits=max(blas, 1), user_api="blas")


class Worker:
    """One worker thread, made on first use, for the per-frame path's slow maps (the person's
    maps, the live light's fits): one job at a time, in the order given (the person's matte model
    is one and never runs twice at once). ``submit(fn, *args)`` returns a
    :class:`concurrent.futures.Future`."""

    def __init__(self, name: str = "relight-maps"):
        self.name = name
        self._pool = None

    def submit(self, fn, *args):
        if self._pool is None:
            from concurrent.futures import ThreadPoolExecutor

            self._pool = ThreadPoolExecutor(1, thread_name_prefix=self.name)
        return self._pool.submit(fn, *args)
