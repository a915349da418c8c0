"""Readings of the machine a benchmark runs on (Linux ``/proc``; None or NaN elsewhere)."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def rss_mb(pid: int) -> float:
    """Resident memory of process ``pid`` in MB (``/proc``), NaN where it cannot be read."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return float("nan")


def cpu_jiffies() -> np.ndarray | None:
    """The machine's CPU time counters (``/proc/stat``: user nice system idle iowait irq softirq
    steal), or None off Linux."""
    try:
        fields = Path("/proc/stat").read_text().splitlines()[0].split()
        if fields[0] != "cpu" or len(fields) < 9:
            return None
        return np.array([int(v) for v in fields[1:9]], np.int64)
    except (OSError, ValueError, IndexError):
        return None


def steal_share(before, after) -> float | None:
    """Share of the machine's busy CPU time the hypervisor took (steal) between two readings:
    on a shared VM this, not our code, is what stretches the latency tail."""
    if before is None or after is None:
        return None
    d = after - before
    busy = float(d.sum() - d[3] - d[4])
    return float(d[7]) / busy if busy > 0 else None


def steal_share_of_all(before, after) -> float | None:
    """Share of all the machine's CPU time (idle included) the hypervisor took between two
    :func:`cpu_jiffies` readings: a shared host's noise over a long run."""
    if before is None or after is None:
        return None
    d = after - before
    total = float(d.sum())
    return float(d[7]) / total if total > 0 else None
