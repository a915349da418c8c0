"""``relight live``'s controls while running: keys on a terminal (``e`` next environment,
``[``/``]`` strength -/+ 0.1, ``m`` next mode, ``q`` quit), signals (``SIGUSR1`` next
environment, ``SIGUSR2`` strength 1 -> 0.5 -> 0 -> 1; ``SIGINT``/``SIGTERM`` stop) and the
preview page's controls (:mod:`.live_preview`: any environment, a key light dragged, exposure,
turn, spin), into :class:`Controls`, which the loop applies between frames."""

from __future__ import annotations

import os
import signal
import sys
import threading

import numpy as np

from relight.env_cache import EnvironmentCache
from relight.errors import InputError

from ..engine.composite import MODES

#: Strength steps SIGUSR2 cycles through, and a key's strength step.
STRENGTH_CYCLE = (1.0, 0.5, 0.0)
STRENGTH_STEP = 0.1
#: Environments kept loaded (the --env ones, the page's choices, uploads): the oldest page choice
#: is forgotten beyond this; and the longest list of choices the page may grow.
ENV_CACHE = 8
MAX_ENVS = 64
#: A key light from the page is drawn at this width (the relighter takes any map to 128 x 64 cells
#: of light, 2.8 degrees; the key's smallest disc is 1 degree across): 5 ms instead of 25 at 512,
#: for a key dragged on the page.
KEY_WIDTH = 256


def key_width(source: str) -> int | None:
    """The width an environment ``source`` is loaded at: KEY_WIDTH for a key light, else its own."""
    return KEY_WIDTH if source.startswith("builtin:key") else None


class Controls:
    """The settings a running loop takes from keys and signals (applied between frames)."""

    def __init__(self, envs: list[str], mode: str, strength: float, *, exposure: float = 0.0, turn: float = 0.0,
                 spin: float = 0.0):
        if not envs:
            raise InputError("no environment: pass --env (a .exr/.hdr/.png file or builtin:NAME)")
        self.envs = list(envs)
        self.env_i = 0
        self.mode = mode
        self.strength = float(strength)
        self.exposure, self.turn, self.spin = float(exposure), float(turn), float(spin)
        self.split: float | None = None  # the preview's before/after split (0-1 from the left), or none
        self.stop_reason = ""
        self.changed = threading.Event()
        self.stop = threading.Event()
        self.lock = threading.Lock()  # the page's handler threads and the loop
        self._cache = EnvironmentCache(ENV_CACHE, width=key_width)  # the --env ones pinned below
        self.changed_at = 0.0  # perf_counter of the last change (the page's light latency counts from it)
        self.fixed = len(self.envs)  # the first `fixed` of envs came from the command line (kept loaded)
        self._cache.pin(self.envs)
        self.wake = lambda: None  # called on a page's change: the loop stops waiting for the next frame

    @property
    def env(self) -> str:
        """The environment source in use."""
        return self.envs[self.env_i]

    def environment(self, source: str | None = None):
        """The map of ``source`` (default: the one in use), loaded on first use and kept (the
        ENV_CACHE last; the --env ones always)."""
        return self._cache.get(self.env if source is None else source)

    def select(self, source: str) -> None:
        """Use ``source`` from the next frame (loaded first, on the caller's thread: a bad one
        raises InputError and changes nothing); added to the choices when new. A key light
        replaces the last key light chosen, so dragging one does not grow the list."""
        import time

        self.environment(source)
        with self.lock:
            if source not in self.envs:
                if source.startswith("builtin:key") and self.envs[-1].startswith("builtin:key") \
                        and len(self.envs) > self.fixed:
                    self.envs[-1] = source
                elif len(self.envs) >= MAX_ENVS:
                    raise InputError(f"{MAX_ENVS} environments are listed already; restart to add more")
                else:
                    self.envs.append(source)
            self.env_i = self.envs.index(source)
            self.changed_at = time.perf_counter()
        self.changed.set()
        self.wake()

    def set_values(self, **values) -> None:
        """Set ``strength``, ``mode``, ``exposure``, ``turn``, ``spin`` or ``split`` (checked by
        the caller) from the next frame."""
        import time

        with self.lock:
            for k, v in values.items():
                if k not in ("strength", "mode", "exposure", "turn", "spin", "split"):
                    raise KeyError(k)
                setattr(self, k, v)
            self.changed_at = time.perf_counter()
        self.changed.set()
        self.wake()

    def wanted(self) -> tuple:
        """What the loop applies: (environment source, mode, strength, exposure, turn, spin)."""
        with self.lock:
            return self.env, self.mode, self.strength, self.exposure, self.turn, self.spin

    def next_env(self, *_):
        self.env_i = (self.env_i + 1) % len(self.envs)
        self.changed.set()

    def cycle_strength(self, *_):
        later = [s for s in STRENGTH_CYCLE if s < self.strength - 1e-6]
        self.strength = later[0] if later else STRENGTH_CYCLE[0]
        self.changed.set()

    def step_strength(self, step: float):
        self.strength = float(np.clip(round(self.strength + step, 2), 0.0, 1.0))
        self.changed.set()

    def next_mode(self):
        self.mode = MODES[(MODES.index(self.mode) + 1) % len(MODES)]
        self.changed.set()

    def quit(self, reason: str):
        self.stop_reason = self.stop_reason or reason
        self.stop.set()

    def key(self, ch: str) -> None:
        {"e": self.next_env, "]": lambda: self.step_strength(STRENGTH_STEP),
         "[": lambda: self.step_strength(-STRENGTH_STEP), "m": self.next_mode,
         "q": lambda: self.quit("key q")}.get(ch, lambda: None)()


def key_reader(controls: Controls):
    """Read single keys from a terminal (POSIX) until stopped; returns a restore function."""
    if not sys.stdin.isatty() or os.name != "posix":
        return lambda: None
    import select
    import termios
    import tty

    fd = sys.stdin.fileno()
    saved = termios.tcgetattr(fd)
    tty.setcbreak(fd)

    def run():
        while not controls.stop.is_set():
            r, _, _ = select.select([fd], [], [], 0.2)
            if r:
                controls.key(os.read(fd, 1).decode(errors="ignore"))

    threading.Thread(target=run, name="relight-keys", daemon=True).start()
    return lambda: termios.tcsetattr(fd, termios.TCSADRAIN, saved)


def install_signals(controls: Controls):
    """SIGINT/SIGTERM stop, SIGUSR1/SIGUSR2 switch (main thread only); returns a restore function."""
    if threading.current_thread() is not threading.main_thread():
        return lambda: None
    saved = {}

    def stop(signum, _frame):
        controls.quit(signal.Signals(signum).name)

    handlers = {signal.SIGINT: stop, signal.SIGTERM: stop}
    if hasattr(signal, "SIGUSR1"):
        handlers[signal.SIGUSR1] = controls.next_env
        handlers[signal.SIGUSR2] = controls.cycle_strength
    for s, h in handlers.items():
        saved[s] = signal.signal(s, h)

    def restore():
        for s, h in saved.items():
            signal.signal(s, h)
    return restore
