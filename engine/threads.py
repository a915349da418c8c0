"""The per-frame path's threads: the process's thread pools (:func:`limit_threads`) and the worker
for the slow maps (:class:`Worker`)."""
from __future__ import annotations

from contextlib import contextmanager

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


#: The OS niceness of a live source's slow stages' threads (:class:`Worker` ``background``): the
#: frames' threads come first on the cores and the slow stages, which the frames do not wait for,
#: take what is left. Measured with :data:`LIVE_SWITCH_INTERVAL_S` (``relight live``, the 720p
#: bench clip, three fresh runs each, interleaved): latency p95 65.7 -> 57.1 ms, dropped 7.0 -> 6.6
#: %, CPU 159 -> 150 % (docs/performance.md).
BACKGROUND_NICE = 10
#: The interpreter's thread switch interval while a live source runs (seconds; Python's default
#: 0.005): a frame's thread waiting for the GIL behind a slow stage's Python waits up to this.
LIVE_SWITCH_INTERVAL_S = 0.001


@contextmanager
def frames_first(interval_s: float = LIVE_SWITCH_INTERVAL_S):
    """While the block runs, the interpreter's switch interval at most ``interval_s`` (a live
    source's frames wait less behind its slow stages' Python); the one before restored after."""
    import sys

    before = sys.getswitchinterval()
    sys.setswitchinterval(min(before, interval_s))
    try:
        yield
    finally:
        sys.setswitchinterval(before)


def lower_priority(nice: int = BACKGROUND_NICE) -> bool:
    """Raise the calling thread's niceness by ``nice`` (Linux: each thread has its own; elsewhere,
    and where the OS refuses, nothing changes). True when done."""
    import os
    import sys
    import threading

    if not sys.platform.startswith("linux"):
        return False
    try:
        tid = threading.get_native_id()
        os.setpriority(os.PRIO_PROCESS, tid, min(os.getpriority(os.PRIO_PROCESS, tid) + int(nice), 19))
    except OSError:
        return False
    return True


class Worker:
    """One worker thread, made on first use, for the per-frame path's slow maps (the person's
    maps, the live light's fits): one job at a time, in the order given (the person's matte model
    is one and never runs twice at once). ``submit(fn, *args)`` returns a
    :class:`concurrent.futures.Future`. ``background``: the thread runs at a lower OS priority
    (:data:`BACKGROUND_NICE`) - a live source's slow stages, which no frame waits for; a single
    request's wait for its results, so they run at the frame's own priority. :meth:`close` stops
    the thread (the owner's job: a FramePath closes the workers it made, the service its own)."""

    def __init__(self, name: str = "relight-maps", background: bool = False):
        self.name = name
        self.background = bool(background)
        self._pool = None

    def submit(self, fn, *args):
        if self._pool is None:
            from concurrent.futures import ThreadPoolExecutor

            self._pool = ThreadPoolExecutor(1, thread_name_prefix=self.name,
                                            initializer=lower_priority if self.background else None)
        return self._pool.submit(fn, *args)

    def close(self) -> None:
        """Stop the thread once its job is done (jobs not started are cancelled); a later
        :meth:`submit` starts a new one. Whoever made the worker closes it."""
        pool, self._pool = self._pool, None
        if pool is not None:
            pool.shutdown(wait=True, cancel_futures=True)
