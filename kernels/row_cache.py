"""The relighter's cache of texel rows: for a bundle that stores a recipe instead of its maps,
the maps of single texels (all face pixels) that the compact kernel relights exactly, made on
first use or ahead of it on a thread of their own.

:class:`RowCache` holds them in one (n_slots, 3, P) float16 array the kernel reads in place
(slots reused least recently used first); :func:`row_slots` sizes it. Which rows
:meth:`relight.kernels.relighter.Relighter.prefetch_rows` makes ahead: those of the brightest
texels (:func:`prefetch_texels`) at each head turn of a grid (:func:`prefetch_turns`).
"""

from __future__ import annotations

import atexit
import weakref

import numpy as np

from relight.directions import rotation_matrix
from relight.errors import InputError

from .runtime import aligned_zeros
from .texel_lights import EnvLights, split_direct, texel_light

#: Texel rows a recipe bundle's Relighter keeps made (each 6 bytes per face pixel): as many as
#: ROW_CACHE_BYTES hold, within ROW_SLOTS_RANGE. A row costs ~35 ms to make at 100k face pixels;
#: a sun crossing the texels of a head turning +-30 deg yaw, +-15 deg pitch visits ~80-100 of
#: them (measured: 82 rows in 10 s of the live clip), so a cache of 64 made rows again and again.
ROW_CACHE_BYTES = 128 << 20
ROW_SLOTS_RANGE = (64, 512)
#: :meth:`relight.kernels.relighter.Relighter.prefetch_rows`: the head turns (degrees) whose
#: exact texels are made ahead - a seated person's range (the synthetic live clips turn +-30
#: yaw, +-15 pitch) on a 5-degree grid (a texel is 5.6 degrees wide at 64x32).
PREFETCH_YAW_DEG = 35.0
PREFETCH_PITCH_DEG = 20.0
PREFETCH_STEP_DEG = 5.0


def prefetch_turns(yaw_deg: float = PREFETCH_YAW_DEG, pitch_deg: float = PREFETCH_PITCH_DEG,
                   step_deg: float = PREFETCH_STEP_DEG) -> list[tuple[float, float]]:
    """The head turns (yaw, pitch) in degrees whose texel rows are made ahead: a grid
    ``step_deg`` apart within +-``yaw_deg`` and +-``pitch_deg``, the smaller turns first."""
    span = lambda lim: np.arange(-lim, lim + step_deg / 2, step_deg)  # noqa: E731
    return sorted(((y, p) for y in span(yaw_deg) for p in span(pitch_deg)), key=lambda a: np.hypot(*a))


def prefetch_texels(lights: EnvLights, turns, n_direct: int, map_size, texels: np.ndarray, scale: float,
                    cone) -> list[int]:
    """The stored texels (positions in ``map_texels``) relit exactly under ``lights`` at each head
    turn of ``turns`` ((yaw, pitch) degrees: :func:`prefetch_turns`), turn by turn: the
    ``n_direct`` brightest of each (:func:`relight.kernels.texel_lights.split_direct`) of the
    light :func:`relight.kernels.texel_lights.texel_light` makes with ``map_size``, ``texels``,
    ``scale`` and ``cone`` (the Relighter's), repeats left in."""
    out: list[int] = []
    for y, p in turns:
        lp = texel_light(lights, rotation_matrix(float(y), float(p), 0.0), map_size, texels, scale, cone)
        out += split_direct(lp, n_direct)[0].tolist()
    return out


def row_slots(n_pixels: int) -> int:
    """Texel rows the cache keeps for a bundle of ``n_pixels`` face pixels."""
    lo, hi = ROW_SLOTS_RANGE
    return int(min(max(ROW_CACHE_BYTES // max(6 * int(n_pixels), 1), lo), hi))


#: Row caches whose prefetch may be running: stopped at exit (a daemon thread inside an OpenCL
#: call while the interpreter shuts down could crash it).
_PREFETCHING: weakref.WeakSet = weakref.WeakSet()


@atexit.register
def _stop_prefetches() -> None:
    for cache in list(_PREFETCHING):
        cache.stop_prefetch()


class RowCache:
    """Texel rows (maps of single texels, all pixels) of a recipe bundle, made on first use - or
    ahead of it on a thread of their own (:meth:`prefetch`).

    ``rows`` (n_slots, 3, P) float16 is the memory the compact kernel reads them from; slots
    are reused least recently used first, never one the current call or the one before it (a
    launch still pending) asked for.
    """

    def __init__(self, bundle, n_slots: int):
        import threading

        from .recipe_cl import RecipeRows

        self.bundle = bundle
        self.rows = aligned_zeros((n_slots, 3, max(bundle.n_pixels, 1)), np.float16)
        self.maker = RecipeRows(bundle.recipe, self.rows)
        self.buf = self.maker.rows_buf  # what the compact kernel reads the rows from
        self._slot_of: dict[int, int] = {}
        self._texel_in = -np.ones(n_slots, dtype=np.int64)
        self._used = np.zeros(n_slots, dtype=np.int64)
        self._clock = 0
        self.made = 0  # texel rows made so far (a figure for benchmarks)
        self.prefetched = 0  # of them, made ahead by prefetch()
        self._lock = threading.Condition()
        self._flight: dict[int, int] = {}  # texel -> slot of rows the prefetch thread is making
        self._prefetch = None  # (thread, stop event)
        self._stopping: list = []  # prefetch threads told to stop, finishing their launch

    def _free_slots(self, n: int, keep: set, spare_recent: bool = True) -> list[int]:
        """``n`` slots to fill, least recently used first, none in ``keep`` or in flight, nor
        (``spare_recent``) used by the last two calls; their old texels forgotten. Under the lock."""
        busy = keep | set(self._flight.values())
        recent = self._clock - 1 if spare_recent else np.iinfo(np.int64).max
        free = [int(s) for s in np.argsort(self._used, kind="stable")
                if int(s) not in busy and (self._used[s] < recent or self._texel_in[s] < 0)][:n]
        for s in free:
            old = int(self._texel_in[s])
            if old >= 0:
                del self._slot_of[old]
                self._texel_in[s] = -1
        return free

    def slots(self, index: np.ndarray) -> np.ndarray:
        """(n,) slots holding the stored texels ``index`` (positions in ``map_texels``), made now if
        missing (or waited for, when the prefetch thread is making them)."""
        index = np.asarray(index, dtype=np.int64).ravel()
        if index.size > len(self._used):
            raise InputError(f"{index.size} exact texels at once: at most {len(self._used)}")
        with self._lock:
            self._clock += 1
            wanted = [int(t) for t in dict.fromkeys(index.tolist())]
            while any(t in self._flight for t in wanted):
                self._lock.wait(timeout=1.0)
            missing = [t for t in wanted if t not in self._slot_of]
            if missing:
                keep = {self._slot_of[t] for t in wanted if t in self._slot_of}
                free = self._free_slots(len(missing), keep)
                if len(free) < len(missing):  # everything recent: take the oldest slots anyway
                    free += self._free_slots(len(missing) - len(free), keep | set(free), spare_recent=False)
                tex = np.asarray(self.bundle.map_texels, dtype=np.int64)[np.asarray(missing)]
                self.maker.make(tex, np.asarray(free))
                for s, t in zip(free, missing, strict=True):
                    self._slot_of[t] = s
                    self._texel_in[s] = t
                self.made += len(missing)
            out = np.array([self._slot_of[t] for t in index.tolist()], dtype=np.int64)
            self._used[out] = self._clock
        return out

    def prefetch(self, index, batch: int = 8) -> None:
        """Make the rows of texels ``index`` (most wanted first; or a function giving them, called
        on the thread) on a thread of their own, on a
        command queue of their own, ``batch`` a launch (a launch costs ~20 ms plus ~10 ms a texel
        at 100k pixels: one at a time, as frames ask, costs 2-3x more), at most half the slots;
        a prefetch already running is told to stop after its current launch, not waited for (a
        new environment every frame - a key light dragged on the page - would wait ~60 ms each;
        the rows it makes are the bundle's, good for any light). Frames that ask for a row a
        thread is making wait for it; the others go on."""
        import threading

        self.stop_prefetch(wait=False)
        stop = threading.Event()

        def run():
            import pyopencl as cl

            nonlocal index
            if callable(index):  # worked out on this thread too
                index = index()
            index = [int(t) for t in dict.fromkeys(np.asarray(index, dtype=np.int64).ravel().tolist())]
            index = index[:len(self._used) // 2]
            queue = cl.CommandQueue(self.maker.queue.context)
            texels = np.asarray(self.bundle.map_texels, dtype=np.int64)
            for i in range(0, len(index), batch):
                if stop.is_set():
                    return
                with self._lock:
                    todo = [t for t in index[i:i + batch] if t not in self._slot_of and t not in self._flight]
                    free = self._free_slots(len(todo), set())
                    todo = todo[:len(free)]
                    for t, s in zip(todo, free, strict=True):
                        self._flight[t] = s
                if not todo:
                    continue
                try:
                    self.maker.make(texels[np.asarray(todo)], np.asarray(free), queue=queue)
                finally:
                    with self._lock:
                        for t, s in zip(todo, free, strict=True):
                            del self._flight[t]
                            self._slot_of[t] = s
                            self._texel_in[s] = t
                            self._used[s] = self._clock  # as if asked for now: not the next to go
                        self.made += len(todo)
                        self.prefetched += len(todo)
                        self._lock.notify_all()

        thread = threading.Thread(target=run, name="relight-rows", daemon=True)
        self._prefetch = (thread, stop)
        _PREFETCHING.add(self)
        thread.start()

    def stop_prefetch(self, wait: bool = True) -> None:
        """Stop a running prefetch after its current launch; ``wait``: for it and for every one
        stopped before (at exit, and before the device goes)."""
        if self._prefetch is not None:
            thread, stop = self._prefetch
            stop.set()
            self._prefetch = None
            self._stopping.append(thread)
        self._stopping = [t for t in self._stopping if t.is_alive()]
        if wait:
            for t in self._stopping:
                t.join()
            self._stopping = []
