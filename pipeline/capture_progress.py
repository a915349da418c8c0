"""A capture's stage bookkeeping: :class:`Progress` (a tqdm bar per stage) and
:class:`StageTimings` (seconds per stage, with the process's peak memory when each ended; freed
heap handed back to the system between stages)."""

from __future__ import annotations

from tqdm import tqdm


class Progress:
    """Progress of a capture: one tqdm bar per stage (or none when not ``enabled``)."""

    def __init__(self, enabled: bool):
        self.enabled = enabled
        self.bar = None
        self.name = None

    def __call__(self, name: str, done: int, total: int):
        if not self.enabled:
            return
        if self.name != name:
            self.close()
            self.bar = tqdm(total=total, desc=name, leave=False)
            self.name = name
        self.bar.n = done
        self.bar.refresh()

    def close(self):
        if self.bar is not None:
            self.bar.close()
            self.bar = None
            self.name = None


class StageTimings(dict):
    """Stage name -> seconds; each entry also notes the process's peak memory (RSS high-water
    mark, MB) when the stage ended, in :attr:`peak_mb` (which stage made the peak)."""

    def __init__(self):
        super().__init__()
        self.peak_mb: dict[str, float] = {}

    def __setitem__(self, key, value):
        super().__setitem__(key, value)
        _trim_heap()  # a stage's freed arrays back to the system before the next one allocates
        self.peak_mb[key] = _peak_rss_mb()

    def update(self, other=(), **kw):
        for k, v in dict(other, **kw).items():
            self[k] = v


def _trim_heap() -> None:
    """Return freed heap memory to the system (glibc's malloc_trim; elsewhere nothing). glibc
    raises its mmap threshold as large arrays are freed, so later mid-size arrays (a frame's
    crop, a chunk's temporaries) come from the heap, which it keeps resident after they are
    freed: on a 1080p capture that held ~0.5 GB nobody used into the next stages."""
    global _MALLOC_TRIM
    if _MALLOC_TRIM is None:
        try:
            import ctypes

            _MALLOC_TRIM = ctypes.CDLL(None).malloc_trim
        except (OSError, AttributeError):
            _MALLOC_TRIM = False
    if _MALLOC_TRIM:
        _MALLOC_TRIM(0)


_MALLOC_TRIM = None


def _peak_rss_mb() -> float:
    try:
        import resource
    except ImportError:  # not on Windows
        return float("nan")
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # kB on Linux
