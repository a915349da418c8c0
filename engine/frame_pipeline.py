"""The per-frame path in two stages on two threads (:class:`FramePipeline`): what ``relight
filter`` and ``relight live`` run each frame through."""

from __future__ import annotations


class FramePipeline:
    """The per-frame path in two stages on two threads: :meth:`FramePath.front` (track, pose)
    of frame N+1 on the calling thread beside :meth:`FramePath.back` (relight, live light, warp,
    composite) of frame N on a worker - OpenCV, PoCL and BLAS release the GIL, so the second
    core does work the serial path left it idle for (measured on the synthetic live clips:
    25-27 -> 21 ms a frame at 640x360, 40 -> 34 at 1280x720). The tracker takes the live-lit
    reference a frame later than in the serial path (it is handed over between frames:
    :meth:`FramePath.commit_reference`), so runs are repeatable. ``record(rgb, out, info,
    index)`` books a finished frame and returns the frame to write; ``done(out, pts)`` writes it."""

    def __init__(self, fp, record):
        from concurrent.futures import ThreadPoolExecutor

        self.fp, self.record = fp, record
        self.done = None
        self._pool = ThreadPoolExecutor(1, thread_name_prefix="relight-back")
        self._pending = None
        self._applied: list = []  # changes queued on the worker (apply), checked as frames end
        self.wake = None  # called (on the worker) when a frame's second stage ends: see poll()

    def apply(self, change) -> None:
        """Run ``change()`` (a new environment, mode, strength...: what the second stage reads) on
        the worker after the frame in flight and before the next one's second stage - without
        waiting for the frame in flight (a light dragged on relight live's page reaches the next
        frame a frame sooner). The first stage of the next frame may run meanwhile: it reads
        none of it (the tracker, the pose)."""
        self._applied.append(self._pool.submit(change))

    def put(self, rgb, t: float, index: int, pts) -> None:
        front = self.fp.front(rgb, t)
        self.drain()
        fut = self._pool.submit(self.fp.back, front, True)
        if self.wake is not None:
            fut.add_done_callback(lambda _f: self.wake())
        self._pending = (fut, rgb, index, pts)

    def poll(self) -> bool:
        """Hand the frame in flight to ``done`` if its second stage has ended (a live source
        does not wait for the next frame to deliver this one: a frame's less latency)."""
        if self._pending is not None and self._pending[0].done():
            self.drain()
            return True
        return False

    def drain(self) -> None:
        """Finish the frame in flight (if any) and hand it to ``done``."""
        if self._pending is None:
            return
        fut, rgb, index, pts = self._pending
        self._pending = None
        frame_out, info = fut.result()
        for done in [f for f in self._applied if f.done()]:
            self._applied.remove(done)
            done.result()  # a change that failed fails the run here, not silently
        self.fp.commit_reference()
        self.done(self.record(rgb, frame_out, info, index), pts)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        if self._pending is not None:  # an error elsewhere: let the worker finish, drop its frame
            self._pending[0].exception()
            self._pending = None
        self._pool.shutdown(wait=True)
        return False
