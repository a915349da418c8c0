"""``relight bench live``: the live paths measured on the same synthetic clip of a captured head.

1. ``relight live`` (in this process): a clip played as the camera at its own rate (30 fps),
   relit into the preview page with no viewer (the frames as a virtual camera would take them:
   nothing encoded) and, with ``record``, relit and recorded (H.264 at the output rate) as well -
   frames per second in, relit and out, dropped, latency (camera frame read -> relit frame
   ready), CPU share (of one core; 200 % is both cores), per frame size.
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

#: Frame sizes ``relight live`` is measured at.
SIZES = ((640, 360), (1280, 720))
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
    from relight.service.live import StatusLine, run_live

    from .video import synth_bundle

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    sizes = SIZES[:1] if quick else SIZES
    seconds = min(seconds, QUICK_SECONDS) if quick else seconds
    bundle_path = synth_bundle(out, (640, 360), 20.0 if quick else 30.0, progress)
    bundle = relight.load_bundle(bundle_path)
    doc: dict = {"live": [], "browser": []}
    for size in sizes:
        clip = _clip(out, size, progress)
        for recorded in (False, True) if record else (False,):
            if progress:
                print(f"relight live {size[0]}x{size[1]}{', recorded' if recorded else ''} for {seconds:g} s ...",
                      flush=True)
            res = run_live(bundle, ["builtin:sunset"], camera=str(clip), duration=seconds, focal="ortho",
                           preview=True, record=out / f"live-{size[0]}x{size[1]}.mp4" if recorded else None,
                           status=StatusLine(io.StringIO()))
            doc["live"].append(res.as_json())
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


def _drag_run(bundle, clip: Path, seconds: float) -> dict:
    """``relight live`` with its page, a key light swept across the face at DRAG_HZ by POST
    /control once the run is relighting: each change's latency to the relit frames."""
    import threading
    import time

    import httpx
    import numpy as np

    from relight.service.live import StatusLine, run_live

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
    from .browser import format_results

    lines = ["relight live (a clip played as the camera at 30 fps; the preview page with no viewer, and recorded):",
             f"{'size':>10s} {'sink':>9s} {'in fps':>7s} {'relit':>6s} {'out':>6s} {'dropped':>8s} {'lat p50':>8s} "
             f"{'p95':>6s} {'CPU %':>6s}"]
    for r in doc["live"]:
        lat = r["latency_ms"]
        sink = "recorded" if r.get("record") else "preview"
        lines.append(f"{r['size'][0]:>5d}x{r['size'][1]:<4d} {sink:>9s} {r['fps_in']:7.1f} {r['fps_relit']:6.1f} "
                     f"{r['fps_out']:6.1f} {r['dropped']:8d} {lat.get('median', 0):8.1f} {lat.get('p95', 0):6.1f} "
                     f"{r['cpu_percent']:6.0f}")
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
