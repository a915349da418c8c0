"""``relight filter``'s result: the counts and per-frame timings of a run (:class:`FilterResult`)
and its ``report.json`` (:func:`write_report`)."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from relight.imageio import atomic_path
from relight.numerics import EPS_NORM


@dataclass
class FilterResult:
    out: Path
    frames: int = 0
    faces: int = 0
    passed_through: int = 0
    audio: str = "none"
    head_rotation: dict = field(default_factory=dict)
    live_light: dict = field(default_factory=dict)
    timings_ms: dict = field(default_factory=dict)
    wall_s: float = 0.0
    start_s: float = 0.0
    notes: list = field(default_factory=list)
    #: The focal length (px) the frames' poses were solved with at the end: the one told, the
    #: default guess, or the one found (engine.focal); ``focal_found``: whether it was found.
    focal_px: float | None = None
    focal_found: bool = False

    def summary(self) -> str:
        t = self.timings_ms.get("total", {})
        return (f"{self.frames} frames ({self.faces} with a face, {self.passed_through} passed through), audio "
                f"{self.audio}; a frame's latency through the per-frame path median "
                f"{t.get('median', 0):.1f} ms, p99 {t.get('p99', 0):.1f} ms; {self.wall_s:.1f} s in all (start "
                f"{self.start_s:.1f} s, {self.frames / max(self.wall_s - self.start_s, EPS_NORM):.1f} frames per "
                "second "
                "after it)")


def timing_stats(values) -> dict:
    """Median, p90, p99, max and mean of a stage's per-frame times (empty: {})."""
    v = np.asarray(values, dtype=np.float64)
    if not v.size:
        return {}
    return {"median": float(np.median(v)), "p90": float(np.percentile(v, 90)), "p99": float(np.percentile(v, 99)),
            "max": float(v.max()), "mean": float(v.mean())}



def _light_summary(lights: dict) -> dict:
    """Median residual and the count of each status over the frames with a light estimate."""
    if not lights:
        return {}
    res = [v["residual"] for v in lights.values() if v["residual"] == v["residual"]]
    status: dict = {}
    for v in lights.values():
        status[v["status"]] = status.get(v["status"], 0) + 1
    return {"frames": len(lights), "median_residual": float(np.median(res)) if res else None, "status": status}


def write_report(folder: Path, res: FilterResult, inp: Path) -> Path:
    """``report.json``: head_rotation {frame index: [yaw, pitch, roll] deg}, timings, counts."""
    folder.mkdir(parents=True, exist_ok=True)
    doc = {"input": str(inp), "output": str(res.out), "frames": res.frames, "faces": res.faces,
           "passed_through": res.passed_through, "audio": res.audio,
           "head_rotation": res.head_rotation,
           "live_light": res.live_light,
           "live_light_summary": _light_summary(res.live_light),
           "live_light_convention": "mode transfer, per frame: direction (unit, camera space: +X right, +Y up, +Z "
                                    "toward the camera) the light comes from, intensity (flashes of power, the live "
                                    "exposure), colour (linear rgb, luminance 1), residual (RMS of the fit relative to "
                                    "the face's), pixels fitted, status (ok | dark | clipped | few pixels)",
           "head_rotation_convention": "yaw, pitch, roll in degrees, R = Ry(yaw) Rx(pitch) Rz(roll) about camera "
                                       "+Y, +X, +Z (relight camera space), relative to the bundle's reference pose",
           "focal_px": res.focal_px, "focal_found": res.focal_found,
           "timings_ms": res.timings_ms, "wall_s": res.wall_s, "start_s": res.start_s, "notes": res.notes}
    path = folder / "report.json"
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(doc, indent=1))
    return path
