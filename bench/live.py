"""``relight bench live``: the live paths measured on the same synthetic clip of a captured head.

1. ``relight live`` (in this process): a clip played as the camera at its own rate (30 fps),
   relit into the preview page with no viewer (the frames as a virtual camera would take them:
   nothing encoded) and, with ``record``, relit and recorded (H.264 at the output rate) as well -
   frames per second in, relit and out, dropped, latency (camera frame read -> relit frame
   ready), CPU share (of one core; 200 % is both cores), per frame size.
2. The browser page in headless Chromium (:mod:`relight.bench.browser`): WebRTC against the
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
    if doc.get("browser"):
        lines += ["", "browser page, 640x360 camera (round trip: camera frame shown -> relit frame shown, ms):",
                  format_results(doc["browser"])]
    elif doc.get("browser_skipped"):
        lines += ["", f"browser page: skipped ({doc['browser_skipped']})"]
    return "\n".join(lines)
