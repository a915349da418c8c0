"""Work beside the caller on a thread: a generator read ahead (:func:`read_ahead`) and items
written behind (:class:`WriterThread`).

Decoding and encoding run in FFmpeg, which releases the GIL: on a thread of their own they
overlap the caller's per-frame work. Both queues are short (``maxsize`` items), which bounds the
memory held in frames; an error on the thread is raised in the caller.
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Callable, Iterator


def read_ahead(gen_fn, maxsize: int = 4, *, name: str = "relight-reader") -> Iterator:
    """Run the generator ``gen_fn()`` on a thread and yield its items here (its exceptions are
    re-raised here; leaving early stops it)."""
    q: queue.Queue = queue.Queue(maxsize)
    stop = threading.Event()

    def run():
        try:
            for item in gen_fn():
                while not stop.is_set():
                    try:
                        q.put(("item", item), timeout=0.1)
                        break
                    except queue.Full:
                        continue
                if stop.is_set():
                    return
            q.put(("end", None))
        except BaseException as exc:  # handed to the consumer
            q.put(("error", exc))

    th = threading.Thread(target=run, name=name, daemon=True)
    th.start()
    try:
        while True:
            kind, item = q.get()
            if kind == "end":
                return
            if kind == "error":
                raise item
            yield item
    finally:
        stop.set()
        while th.is_alive():
            try:
                q.get_nowait()
            except queue.Empty:
                th.join(timeout=0.05)


class WriterThread:
    """Calls ``fn(item)`` for each item put, in order, on its own thread (bounded queue). After an
    error there the items still queued are dropped, and the error is raised in the caller at the
    next :meth:`put` or at exit (unless the block is already leaving with an error of its own) -
    as it is, or as ``wrap(error)`` (raised from it) when ``wrap`` is given.

    Use as a context manager: the thread starts on entry; the exit waits for every item put."""

    def __init__(self, fn: Callable, maxsize: int = 4, *, name: str = "relight-writer",
                 wrap: Callable[[BaseException], BaseException] | None = None):
        self.fn = fn
        self.wrap = wrap
        self.q: queue.Queue = queue.Queue(maxsize)
        self.error: BaseException | None = None
        self.th = threading.Thread(target=self._run, name=name, daemon=True)

    def _run(self) -> None:
        while True:
            item = self.q.get()
            if item is None:
                return
            if self.error is None:  # after a failure: drained, the caller sees the error
                try:
                    self.fn(item)
                except BaseException as exc:  # re-raised in the caller's thread
                    self.error = exc

    def raise_error(self) -> None:
        """Raise the thread's error (see the class), if it had one."""
        if self.error is None:
            return
        if self.wrap is None:
            raise self.error
        raise self.wrap(self.error) from self.error

    def __enter__(self) -> WriterThread:
        self.th.start()
        return self

    def put(self, item) -> None:
        """Queue ``item`` (not None) for ``fn``; waits while the queue is full."""
        self.raise_error()
        self.q.put(item)

    def __exit__(self, exc_type, exc, tb) -> None:
        self.q.put(None)
        self.th.join()
        if exc_type is None:
            self.raise_error()
