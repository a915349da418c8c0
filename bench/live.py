"""``relight bench live``: the live paths measured on the same synthetic clip of a captured head.

1. ``relight live`` (in this process): a clip played as the camera at its own rate (30 fps),
   relit into the preview page with no viewer (the frames as a virtual camera would take them:
   nothing encoded) and, with ``record``, relit and recorded (H.264 at the output rate) as well -
   frames per second in, relit and out, dropped, latency (camera frame read -> relit frame
   ready), CPU share (of one core; 200 % is both cores), per frame size: the median of RUNS runs
   after a warm-up run, beside the machine's floor measured in the same run (:mod:`.floor`:
   decoding the clip alone, and with a constant light field applied); at 1280x720 also with the
   preview page open and viewed (a client pulling its MJPEG stream).
2. The page steering the light (``relight live``'s ``POST /control``): a key light dragged
   across the face, 10 positions a second, per frame size - how long each change takes to reach
   the relit frames (ms from the control's arrival to the first frame relit with it), and the
   frame rate meanwhile.
3. The browser page in headless Chromium (:mod:`relight.bench.browser`): WebRTC against the
   websocket on the same 640x360 clip - fps, round trip from the frames' bar codes, bandwidth.

Writes OUT/bench.json; figures are medians over the run after a start (kernels, first frame).
"""

from __future__ import annotations

import io
import json
from pathlib import Path

#: Frame sizes ``relight live`` is measured at, and the runs whose medians are reported.
SIZES = ((640, 360), (1280, 720), (1920, 1080))
RUNS = 3
#: The size measured with the preview viewed as well.
VIEWED = (1280, 720)
#: Seconds measured per case (``--seconds``), and at most that with ``--quick``.
SECONDS = 15.0
QUICK_SECONDS = 6.0
#: The dragged key light: positions sent per second, and its azimuth's sweep (degrees).
DRAG_HZ = 10.0
DRAG_AZ = (-60.0, 60.0)


def _clip(out: Path, size, progress: bool) -> Path:
    from .video import synth_live

    return synth_live(out, size, 4.0, progress) / "live.mp4"


def run(out: Path, *, quick: bool = False, progress: bool = True, seconds: float = SECONDS,
        browser: bool = True, record: bool = False) -> dict:
    import relight

    from . import floor
    from .video import synth_bundle

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    sizes = SIZES[:1] if quick else SIZES
    seconds = min(seconds, QUICK_SECONDS) if quick else seconds
    bundle_path = synth_bundle(out, (640, 360), 20.0 if quick else 30.0, progress)
    bundle = relight.load_bundle(bundle_path)
    doc: dict = {"live": [], "browser": [], "floor": []}
    for size in sizes:
        clip = _clip(out, size, progress)
        if progress:
            print(f"the floor at {size[0]}x{size[1]} (decode alone; decode + a constant field) ...", flush=True)
        doc["floor"].append(floor.measure(clip, frames=120, runs=1 if quick else RUNS))
        viewed = (False, True) if size == VIEWED and not quick else (False,)
        for recorded in (False, True) if record else (False,):
            for view in viewed:
                if progress:
                    what = ", recorded" if recorded else ", the preview viewed" if view else ""
                    print(f"relight live {size[0]}x{size[1]}{what}: {1 if quick else RUNS} runs of {seconds:g} s "
                          "after a warm-up ...", flush=True)
                doc["live"].append(_median_runs(bundle, clip, size, seconds, 1 if quick else RUNS,
                                                out / f"live-{size[0]}x{size[1]}.mp4" if recorded else None, view))
        if size[0] <= 1280:
            if progress:
                print(f"relight live {size[0]}x{size[1]}, a key light dragged on its page for {seconds:g} s ...",
                      flush=True)
            doc.setdefault("drag", []).append(_drag_run(bundle, clip, seconds))
    if browser:
        from .browser import find_chromium, run_browser_bench

        if find_chromium() is None:
            doc["browser_skipped"] = "Chromium is not installed (make install-system)"
        else:
            if progress:
                print(f"browser page: webrtc, then websocket, {seconds:g} s each ...", flush=True)
            doc["browser"] = run_browser_bench(bundle_path, _clip(out, (640, 360), progress), seconds=seconds)
    (out / "bench.json").write_text(json.dumps(doc, indent=1))
    return doc


def _one_run(bundle, clip: Path, seconds: float, record, viewed: bool) -> dict:
    """One ``relight live`` run of the clip as the camera (the preview page open; ``viewed``: a
    client pulling its MJPEG stream all along): its result as JSON."""
    import threading

    import httpx

    from relight.apps.live import run_live
    from relight.apps.live_status import StatusLine

    ready: dict = {}
    stop = threading.Event()
    pulled = {"bytes": 0}

    def view():
        while "url" not in ready and not stop.is_set():
            stop.wait(0.05)
        try:
            with httpx.stream("GET", ready["url"] + "stream.mjpg", timeout=10) as r:
                for chunk in r.iter_bytes():
                    pulled["bytes"] += len(chunk)
                    if stop.is_set():
                        break
        except (httpx.HTTPError, KeyError):
            pass

    viewer = threading.Thread(target=view, daemon=True) if viewed else None
    if viewer is not None:
        viewer.start()
    try:
        res = run_live(bundle, ["builtin:sunset"], camera=str(clip), duration=seconds, focal="ortho", preview=True,
                       record=record, status=StatusLine(io.StringIO()),
                       on_ready=lambda r: ready.setdefault("url", r.preview))
    finally:
        stop.set()
        if viewer is not None:
            viewer.join(timeout=15)
    doc = res.as_json()
    doc["viewed"] = viewed
    doc["viewer_mb"] = round(pulled["bytes"] / 1e6, 2) if viewed else None
    return doc


def _median_runs(bundle, clip: Path, size, seconds: float, runs: int, record, viewed: bool) -> dict:
    """A warm-up run, then ``runs`` runs: the medians of their figures (fps, dropped share, latency
    p95, CPU), each run's kept too."""
    import numpy as np

    _one_run(bundle, clip, min(seconds, 4.0), None, False)  # kernels compiled, caches warm
    each = [_one_run(bundle, clip, seconds, record, viewed) for _ in range(runs)]
    doc = dict(each[len(each) // 2])
    for key in ("fps_in", "fps_relit", "fps_out", "cpu_percent", "dropped", "frames_in"):
        doc[key] = float(np.median([r[key] for r in each]))
    doc["dropped_share"] = float(np.median([r["dropped"] / max(r["frames_in"], 1) for r in each]))
    doc["latency_ms"] = {k: float(np.median([r["latency_ms"].get(k, 0.0) for r in each]))
                         for k in ("median", "p95", "p99", "max")}
    doc["runs"] = each
    return doc


def _drag_run(bundle, clip: Path, seconds: float) -> dict:
    """``relight live`` with its page, a key light swept across the face at DRAG_HZ by POST
    /control once the run is relighting: each change's latency to the relit frames."""
    import threading
    import time

    import httpx
    import numpy as np

    from relight.apps.live import run_live
    from relight.apps.live_status import StatusLine

    ready: dict = {}
    got: dict = {}
    runner = threading.Thread(target=lambda: got.setdefault("res", run_live(
        bundle, ["builtin:sunset"], camera=str(clip), duration=seconds + 4.0, focal="ortho", preview=True,
        status=StatusLine(io.StringIO()), on_ready=lambda r: ready.setdefault("url", r.preview))), daemon=True)
    runner.start()
    while "url" not in ready and runner.is_alive():
        time.sleep(0.05)
    sent = 0
    if "url" in ready:
        time.sleep(3.0)  # past the start (kernels, the first frames)
        t_end = time.perf_counter() + seconds
        while time.perf_counter() < t_end:
            phase = (sent * 0.05) % 2.0
            az = DRAG_AZ[0] + (DRAG_AZ[1] - DRAG_AZ[0]) * (phase if phase <= 1 else 2 - phase)
            httpx.post(ready["url"] + "control", json={"env": f"key:az={az:.1f},el=15"}, timeout=10)
            sent += 1
            time.sleep(1.0 / DRAG_HZ)
    runner.join()
    res = got["res"]
    ms = np.asarray(res.light_ms, dtype=np.float64)
    return {"size": res.size, "sent": sent, "applied": int(ms.size), "fps_relit": res.fps_relit,
            "dropped": res.dropped, "light_ms": {"median": float(np.median(ms)), "p95": float(np.percentile(ms, 95)),
                                                 "max": float(ms.max())} if ms.size else {}}


def table(doc: dict) -> str:
    from . import floor
    from .browser import format_results

    lines = ["relight live (a clip played as the camera at 30 fps; the preview page with no viewer, viewed, and "
             "recorded; medians of the runs after a warm-up; CPU % of one core, every thread):",
             f"{'size':>10s} {'sink':>9s} {'in fps':>7s} {'relit':>6s} {'out':>6s} {'dropped':>8s} {'lat p50':>8s} "
             f"{'p95':>6s} {'CPU %':>6s}"]
    for r in doc["live"]:
        lat = r["latency_ms"]
        sink = "recorded" if r.get("record") else "viewed" if r.get("viewed") else "preview"
        dropped = f"{100 * r.get('dropped_share', 0):.1f} %"
        lines.append(f"{r['size'][0]:>5d}x{r['size'][1]:<4d} {sink:>9s} {r['fps_in']:7.1f} {r['fps_relit']:6.1f} "
                     f"{r['fps_out']:6.1f} {dropped:>8s} {lat.get('median', 0):8.1f} {lat.get('p95', 0):6.1f} "
                     f"{r['cpu_percent']:6.0f}")
    for f in doc.get("floor", []):
        lines.append(floor.line(f))
    if doc.get("drag"):
        lines += ["", "relight live's page: a key light dragged (10 positions a second); ms from each change "
                      "to the first frame relit with it:",
                  f"{'size':>10s} {'sent':>5s} {'applied':>8s} {'median':>7s} {'p95':>6s} {'max':>6s} "
                  f"{'relit fps':>9s}"]
        for r in doc["drag"]:
            ms = r["light_ms"]
            lines.append(f"{r['size'][0]:>5d}x{r['size'][1]:<4d} {r['sent']:5d} {r['applied']:8d} "
                         f"{ms.get('median', 0):7.1f} {ms.get('p95', 0):6.1f} {ms.get('max', 0):6.1f} "
                         f"{r['fps_relit']:9.1f}")
    if doc.get("browser"):
        lines += ["", "browser page, 640x360 camera (round trip: camera frame shown -> relit frame shown, ms):",
                  format_results(doc["browser"])]
    elif doc.get("browser_skipped"):
        lines += ["", f"browser page: skipped ({doc['browser_skipped']})"]
    return "\n".join(lines)
