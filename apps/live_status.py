"""What ``relight live`` reports: the status line once a second (frames per second in and out,
dropped, latency, CPU share, the environment, the live light) and the run's result
(:class:`LiveResult`, what ``--stats-json`` writes)."""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .live_controls import Controls

#: Seconds between status lines (and the window the rates are measured over).
STATUS_PERIOD = 1.0


@dataclass
class LiveResult:
    """What a ``relight live`` run did (``--stats-json`` writes it)."""

    camera: str = ""
    size: tuple[int, int] = (0, 0)
    wall_s: float = 0.0
    frames_in: int = 0
    frames_relit: int = 0
    frames_out: int = 0  # frames the sinks got (the output clock's ticks once a frame existed)
    dropped: int = 0
    faces: int = 0
    fps_in: float = 0.0
    fps_relit: float = 0.0
    fps_out: float = 0.0
    latency_ms: dict = field(default_factory=dict)
    cpu_percent: float = 0.0
    virtual_camera: str | None = None
    record: str | None = None
    preview: str | None = None
    stopped_by: str = ""
    switches: list = field(default_factory=list)
    #: ms from each change the page (or a key) asked for to the first frame relit with it
    light_ms: list = field(default_factory=list)
    #: seconds the path took to build and run every kernel before the camera's first frame
    warm_up_s: float = 0.0
    #: the camera's pixel format, and how many of its frames were kept in their Y'CbCr planes
    camera_format: str | None = None
    frames_in_planes: int = 0

    def as_json(self) -> dict:
        from dataclasses import asdict

        return asdict(self)


class StatusLine:
    """One status line a second: rewritten in place on a terminal, a line per period in a log."""

    def __init__(self, stream=None, period: float = STATUS_PERIOD):
        self.stream = stream or sys.stderr
        self.tty = self.stream.isatty()
        self.period = period
        self.t_last = time.perf_counter()
        self.cpu_last = time.process_time()
        self.counts_last = (0, 0)
        self.latencies: list[float] = []
        self.light = ""
        #: the last period's figures, for the page: fps in and relit, dropped, latency, CPU share
        self.figures: dict = {}

    def due(self) -> bool:
        return time.perf_counter() - self.t_last >= self.period

    def show(self, frames_in: int, relit: int, dropped: int, controls: Controls) -> float:
        now, cpu = time.perf_counter(), time.process_time()
        dt = max(now - self.t_last, 1e-6)
        cpu_share = 100.0 * (cpu - self.cpu_last) / dt
        a, b = self.counts_last
        lat = f"{np.median(self.latencies):.0f} ms" if self.latencies else "-"
        self.figures = {"fps_in": round((frames_in - a) / dt, 1), "fps_relit": round((relit - b) / dt, 1),
                        "dropped": dropped, "cpu_percent": round(cpu_share),
                        "latency_ms": {"median": round(float(np.median(self.latencies)), 1),
                                       "p95": round(float(np.percentile(self.latencies, 95)), 1)}
                        if self.latencies else None, "light": self.light}
        env = Path(controls.env).name if not controls.env.startswith("builtin:") else controls.env
        line = (f"in {(frames_in - a) / dt:5.1f} fps  out {(relit - b) / dt:5.1f} fps  dropped {dropped}  "
                f"latency {lat}  CPU {cpu_share:3.0f}%  {env} x{controls.strength:.2f} {controls.mode}"
                f"{'  light ' + self.light if self.light else ''}")
        self.stream.write(("\r\x1b[2K" + line) if self.tty else line + "\n")
        self.stream.flush()
        self.t_last, self.cpu_last, self.counts_last = now, cpu, (frames_in, relit)
        self.latencies = []
        return cpu_share

    def close(self):
        if self.tty:
            self.stream.write("\n")
            self.stream.flush()


def light_text(light) -> str:
    """The live light's direction for the status line (azimuth, elevation), or "" with none."""
    if light is None or light.status != "ok":
        return ""
    x, y, z = light.direction
    az, el = np.degrees(np.arctan2(x, z)), np.degrees(np.arcsin(np.clip(y, -1, 1)))
    return f"from az {az:+.0f} el {el:+.0f} deg"
