"""``relight live``'s controls while running: keys on a terminal (``e`` next environment,
``[``/``]`` strength -/+ 0.1, ``m`` next mode, ``q`` quit) and signals (``SIGUSR1`` next
environment, ``SIGUSR2`` strength 1 -> 0.5 -> 0 -> 1; ``SIGINT``/``SIGTERM`` stop), into
:class:`Controls`, which the loop applies between frames."""

from __future__ import annotations

import os
import signal
import sys
import threading

import numpy as np

from relight.errors import InputError

from ..engine.composite import MODES

#: Strength steps SIGUSR2 cycles through, and a key's strength step.
STRENGTH_CYCLE = (1.0, 0.5, 0.0)
STRENGTH_STEP = 0.1


class Controls:
    """The settings a running loop takes from keys and signals (applied between frames)."""

    def __init__(self, envs: list[str], mode: str, strength: float):
        if not envs:
            raise InputError("no environment: pass --env (a .exr/.hdr/.png file or builtin:NAME)")
        self.envs = list(envs)
        self.env_i = 0
        self.mode = mode
        self.strength = float(strength)
        self.stop_reason = ""
        self.changed = threading.Event()
        self.stop = threading.Event()

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
