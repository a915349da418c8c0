"""Loaded environment maps kept for reuse (:class:`EnvironmentCache`): the one cache of them that
the frame service and ``relight live`` share - a map is loaded (and turned) once, not per frame.

Maps are (H, 2H, 3) float32 linear radiance as :func:`relight.envmap.load_environment` gives them.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Callable

import numpy as np

from .envmap import load_environment, rotate_environment

#: A turned copy is made with this supersampling (:func:`relight.envmap.rotate_environment`).
TURN_SUPERSAMPLE = 2


class EnvironmentCache:
    """Maps by source (``builtin:NAME``, a file, or a name given to :meth:`put`) and by turn, the
    ``size`` least recently used kept besides the pinned ones (:meth:`pin`, and every map
    :meth:`put` gives). Thread-safe; a map is loaded outside the lock (a slow file does not hold
    the other threads), so two threads asking for the same new one may both load it.

    ``width``: the width to load a source at (None: the source's own), as a function of it."""

    def __init__(self, size: int, width: Callable[[str], int | None] = lambda source: None):
        self.size = int(size)
        self._width = width
        self._maps: OrderedDict[tuple, np.ndarray] = OrderedDict()
        self._pinned: set[str] = set()
        self._lock = threading.Lock()

    def get(self, source: str, rotation: tuple[float, float, float] | None = None) -> np.ndarray:
        """The map of ``source`` turned by ``rotation`` ((yaw, pitch, roll) degrees; None or zeros:
        as it is), loaded and turned on first use. A bad source raises InputError (nothing kept)."""
        turned = rotation is not None and any(rotation)
        key = (source, tuple(rotation) if turned else None)
        with self._lock:
            env = self._maps.get(key)
            base = self._maps.get((source, None))
            if env is not None:
                self._maps.move_to_end(key)
                return env
        if base is None:
            base = load_environment(source, width=self._width(source))
        env = base
        if turned:
            from .directions import rotation_matrix

            env = rotate_environment(base, rotation_matrix(*rotation), supersample=TURN_SUPERSAMPLE)
        with self._lock:
            self._maps[(source, None)] = base
            self._maps[key] = env
            self._trim()
        return env

    def put(self, source: str, env: np.ndarray) -> None:
        """``env`` (validated) becomes the map of ``source``, pinned; its turned copies are dropped."""
        with self._lock:
            for k in [k for k in self._maps if k[0] == source]:
                del self._maps[k]
            self._maps[(source, None)] = env
            self._pinned.add(source)

    def pin(self, sources) -> None:
        """Keep these sources' maps loaded however many others are asked for."""
        with self._lock:
            self._pinned.update(sources)

    def __contains__(self, source: str) -> bool:
        with self._lock:
            return (source, None) in self._maps

    def _trim(self) -> None:
        loose = [k for k in self._maps if k[0] not in self._pinned]
        for k in loose[:max(0, len(loose) - self.size)]:
            del self._maps[k]
