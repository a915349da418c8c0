"""The newest frame wins: the one-item slot every hand-over of frames between a source and a
slower consumer goes through - ``relight live``'s camera, relight loop and output clock, the
websocket stream's frames and a WebRTC track's (:class:`NewestSlot`; :class:`LatestFrame` adds
a blocking wait for threads). An item nobody took before a newer one came is counted as dropped;
no queue grows anywhere."""

from __future__ import annotations

import threading


class NewestSlot:
    """A one-item slot: :meth:`put` replaces what is there (counting it in :attr:`dropped` when
    nobody took it), :meth:`take` gives the newest item not taken before, without waiting.
    Thread-safe; an asyncio user waits on its own event between takes."""

    def __init__(self):
        self._cond = threading.Condition()
        self._item = None
        self._fresh = False
        self.put_count = 0
        self.dropped = 0

    def put(self, item) -> bool:
        """``item`` becomes the newest; True when it replaced one nobody took (a dropped frame)."""
        with self._cond:
            replaced = self._fresh
            if replaced:
                self.dropped += 1
            self._item, self._fresh = item, True
            self.put_count += 1
            self._cond.notify_all()
        return replaced

    def take(self):
        """The newest item not taken before, or None."""
        with self._cond:
            return self._take()

    def peek(self):
        """The newest item, taken or not (None before the first)."""
        with self._cond:
            return self._item

    def _take(self):
        if not self._fresh:
            return None
        self._fresh = False
        return self._item


class LatestFrame(NewestSlot):
    """A :class:`NewestSlot` whose :meth:`take` can block a thread until something newer comes."""

    def wake(self) -> None:
        """Wake a waiting :meth:`take` (it returns None unless something fresh came)."""
        with self._cond:
            self._cond.notify_all()

    def take(self, timeout: float = 0.0):
        """The newest item not taken before, waiting up to ``timeout`` seconds for one; or None."""
        with self._cond:
            if not self._fresh and timeout > 0:
                self._cond.wait(timeout)
            return self._take()
