"""A turned head found on its first frame (issue 49): the scanned head rendered at every start
pose of :data:`YAWS` x :data:`PITCHES` (degrees, ``relight synth --live --start-yaw/--start-pitch``'s
frame 0: the room's light, the sensor's noise) at each of :data:`SIZES`, and on each frame

* ``haar``: OpenCV's frontal Haar cascade (what found faces before issue 48's detector) - a box
  whose centre is on the head;
* ``detector``: the path's detector (:class:`relight.engine.face_detect.FaceDetector`) on the
  frame's tracking image, as the path searches (at most 270 rows, whatever the frame's size) -
  the same test - and the CPU ms of a search (both of its threads: the later squares run on a
  second);
* ``path``: a fresh per-frame path (``FramePath``, reset before each frame, ``--focal ortho``:
  the studio's camera) relit the frame: a face tracked and posed on its first frame, and the
  pose's error against the truth (deg).

Goal (issue 49): the face found on the first frame up to |yaw| 45 deg and |pitch| 25 deg (the
poses of :data:`GOAL_YAW` / :data:`GOAL_PITCH` or less), a search <= 15 ms at 720p. Writes
``first_frame.json`` and ``first_frame.png`` (a grid per size: found or not, the pose's error).
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import cv2
import numpy as np

YAWS = (-60, -45, -30, -15, 0, 15, 30, 45, 60)
PITCHES = (-30, -15, 0, 15, 30)
SIZES = ((640, 360), (1280, 720), (1920, 1080))
GOAL_YAW, GOAL_PITCH = 45, 25
HEAD = "builtin:lee-perry-smith"
#: The frames' noise seed (the sensor's counter-based noise, as a clip's frame 0 has).
NOISE_FRAME = 0


def _on_head(box, coverage: np.ndarray) -> bool:
    """Whether a detection box's centre lies on the head (coverage > 1/2 within 2 px)."""
    h, w = coverage.shape
    cx, cy = int(round(0.5 * (box[0] + box[2]))), int(round(0.5 * (box[1] + box[3])))
    y0, y1, x0, x1 = max(cy - 2, 0), min(cy + 3, h), max(cx - 2, 0), min(cx + 3, w)
    return y1 > y0 and x1 > x0 and bool((coverage[y0:y1, x0:x1] > 0.5).any())


def run(out: Path, *, quick: bool = False, progress: bool = True) -> dict:
    """Every pose at every size (quick: 640x360 alone, every other yaw). Returns the document."""
    import relight
    from relight.directions import rotation_matrix
    from relight.engine.face_detect import FaceDetector
    from relight.engine.frame_path import FramePath
    from relight.engine.frame_settings import FrameSettings
    from relight.engine.tracking_image import tracking_image
    from relight.imageio import atomic_path
    from relight.kernels.relight_inputs import rotation_angle_deg
    from relight.pipeline.synth.live_clip import LiveConfig, LiveScene

    from .clips import synth_bundle

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    sizes, yaws = (SIZES, YAWS) if not quick else (SIZES[:1], YAWS[::2])
    bundle = relight.load_bundle(synth_bundle(out, (640, 360), 12.0 if quick else 24.0, progress, head_mesh=HEAD))
    haar = cv2.CascadeClassifier(cv2.data.haarcascades + "haarcascade_frontalface_default.xml")
    detector = FaceDetector()
    fp = FramePath(bundle, relight.load_environment("builtin:sunset"), FrameSettings(focal="ortho"))
    rows = []
    for w, h in sizes:
        if progress:
            print(f"first frames at {w}x{h} ...", flush=True)
        scene = LiveScene(LiveConfig(width=w, height=h, duration=1.0, seed=0, head_mesh=HEAD))
        for pitch in PITCHES:
            for yaw in yaws:
                r = rotation_matrix(float(yaw), float(pitch), 0.0)
                linear, coverage = scene.render(r)
                rgb = scene.expose(linear, NOISE_FRAME)
                grey = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
                boxes = haar.detectMultiScale(grey, scaleFactor=1.1, minNeighbors=5, minSize=(h // 8, h // 8))
                found_haar = any(_on_head((x, y, x + bw, y + bh), coverage) for x, y, bw, bh in boxes)
                # the search as the path runs it: on the tracking image (at most TRACK_ROWS rows,
                # made for every frame anyway), whatever the frame's size
                grey, ts, _ = tracking_image(rgb)
                t0 = time.process_time()
                faces = detector.detect(grey)
                search_ms = (time.process_time() - t0) * 1e3
                found_det = any(_on_head(f.box / ts, coverage) for f in faces)
                fp.reset()
                _, info = fp.process(rgb, 0.0)
                err = rotation_angle_deg(r, rotation_matrix(*info.angles)) if info.face else None
                rows.append({"size": [w, h], "yaw": yaw, "pitch": pitch, "haar": found_haar, "detector": found_det,
                             "search_ms": search_ms, "path": bool(info.face), "pose_error_deg": err,
                             "in_goal": abs(yaw) <= GOAL_YAW and abs(pitch) <= GOAL_PITCH})
    doc = {"rows": rows, "yaws": list(yaws), "pitches": list(PITCHES), "sizes": [list(s) for s in sizes],
           "goal": {"yaw": GOAL_YAW, "pitch": GOAL_PITCH, "search_ms_720p": 15.0}, "summary": summary(rows)}
    with atomic_path(out / "first_frame.json") as tmp:
        Path(tmp).write_text(json.dumps(doc, indent=1))
    plot(doc, out / "first_frame.png")
    return doc


def summary(rows: list) -> list:
    """Per size: the share found by each way within the goal's poses and over all, the search's
    median ms, the path's median pose error."""
    out = []
    for size in sorted({tuple(r["size"]) for r in rows}):
        rs = [r for r in rows if tuple(r["size"]) == size]
        goal = [r for r in rs if r["in_goal"]]
        errs = [r["pose_error_deg"] for r in rs if r["pose_error_deg"] is not None]
        out.append({"size": list(size), "poses": len(rs), "goal_poses": len(goal),
                    **{f"{k}_goal": sum(r[k] for r in goal) for k in ("haar", "detector", "path")},
                    **{f"{k}_all": sum(r[k] for r in rs) for k in ("haar", "detector", "path")},
                    "search_ms": float(np.median([r["search_ms"] for r in rs])),
                    "pose_error_median_deg": float(np.median(errs)) if errs else None})
    return out


def plot(doc: dict, path: Path) -> Path:
    """A grid per size and way (rows: Haar, the detector, the path): a cell per pose, green where
    the face was found (the path's: its pose error printed), grey where not; the goal's poses
    framed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Rectangle

    yaws, pitches, sizes = doc["yaws"], doc["pitches"], doc["sizes"]
    ways = (("haar", "Haar cascade (before)"), ("detector", "the detector (after)"), ("path", "the path, frame 0"))
    fig, axes = plt.subplots(len(ways), len(sizes), figsize=(4.2 * len(sizes), 2.6 * len(ways)), squeeze=False)
    for j, size in enumerate(sizes):
        rs = {(r["yaw"], r["pitch"]): r for r in doc["rows"] if r["size"] == size}
        for i, (key, title) in enumerate(ways):
            ax = axes[i][j]
            grid = np.array([[1.0 if rs[(y, p)][key] else 0.0 for y in yaws] for p in pitches])
            ax.imshow(grid, cmap="RdYlGn", vmin=-0.3, vmax=1.3, aspect="auto")
            for a, p in enumerate(pitches):
                for b, y in enumerate(yaws):
                    r = rs[(y, p)]
                    if key == "path" and r["pose_error_deg"] is not None:
                        ax.text(b, a, f"{r['pose_error_deg']:.0f}", ha="center", va="center", fontsize=7)
                    if r["in_goal"]:
                        ax.add_patch(Rectangle((b - 0.5, a - 0.5), 1, 1, fill=False, lw=0.6, ec="k"))
            ax.set_xticks(range(len(yaws)), [str(y) for y in yaws], fontsize=7)
            ax.set_yticks(range(len(pitches)), [str(p) for p in pitches], fontsize=7)
            ax.set_title(f"{title}, {size[0]}x{size[1]}", fontsize=8)
            if j == 0:
                ax.set_ylabel("pitch (deg)", fontsize=7)
            if i == len(ways) - 1:
                ax.set_xlabel("yaw (deg)", fontsize=7)
    fig.suptitle("A turned head's first frame: found (green) or not; framed: the goal's poses; numbers: the "
                 "pose's error (deg)", fontsize=9)
    fig.tight_layout()
    from relight.imageio import atomic_path

    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)
    return path


def table(doc: dict) -> str:
    lines = ["| size | found in the goal's poses: Haar / detector / path | over all poses | search ms (median) "
             "| path's pose error, median |", "|---|---|---|---|---|"]
    for s in doc["summary"]:
        n, m = s["goal_poses"], s["poses"]
        err = "-" if s["pose_error_median_deg"] is None else f"{s['pose_error_median_deg']:.1f} deg"
        lines.append(f"| {s['size'][0]}x{s['size'][1]} | {s['haar_goal']} / {s['detector_goal']} / {s['path_goal']} "
                     f"of {n} | {s['haar_all']} / {s['detector_all']} / {s['path_all']} of {m} | "
                     f"{s['search_ms']:.1f} | {err} |")
    return "\n".join(lines)
