"""``relight bench serve``: the frame service under load, on loopback, bounded in time.

A real ``relight-serve`` process; N websocket clients each send 640x360 JPEG frames of a
synthetic live video at a fixed rate for a fixed time, then one client 1280x720 frames (latest
frame wins on the server: frames the server had no time for are dropped and counted, never
queued). Each frame is tagged so the client measures its round trip (send -> relit frame back).
Then single ``POST /v1/relight`` requests (JPEG): a frame with a face and a frame of noise at
640x360 and at the single client's size, each request on its own (no session), and the clip's
frames in order under one ``X-Relight-Session`` (its track kept) - medians and p95 of the round
trip beside the floor measured in the same run (the client's JPEG decode and encode of the frame).
Reported: errors, frames returned and relit per second, dropped, round-trip p50/p95/p99 per run,
the share of busy CPU time the hypervisor stole during the run (on a shared VM that, not our
code, stretches the tail), the server's resident memory at start and end (``/proc``), and the
start-up time (launch -> ready) of a first and a second start (kernel cache warm).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np

from .machine import cpu_jiffies, rss_mb, steal_share
from .server import free_port, wait_ready


def tagged_client(url: str, frames: list[bytes], fps: float, duration: float, out: dict) -> None:
    """Send tagged frames at ``fps`` for ``duration`` s. ``out`` gets ``sent``, ``returned``,
    ``rtts`` ((time received - perf_counter, round trip ms) per returned frame), ``errors`` (the
    server's error replies) and, when the connection failed or was cut off, ``failure``."""
    from websockets.sync.client import connect

    sent: dict[int, float] = {}
    rtts: list[tuple[float, float]] = []
    errors: list[str] = []
    stop = threading.Event()
    k = 0
    try:
        with connect(url, max_size=None, open_timeout=20) as ws:
            def receive():
                while not stop.is_set():
                    try:
                        msg = ws.recv(timeout=0.5)
                    except TimeoutError:
                        continue
                    except Exception as exc:  # noqa: BLE001 - cut off while the client still sends
                        if not stop.is_set():
                            out.setdefault("failure", f"receive: {exc!r}")
                        return
                    if isinstance(msg, str):
                        doc = json.loads(msg)
                        if "error" in doc:
                            errors.append(doc["error"])
                        elif doc.get("tag") in sent:
                            now = time.perf_counter()
                            rtts.append((now, (now - sent[doc["tag"]]) * 1e3))

            rx = threading.Thread(target=receive, daemon=True)
            rx.start()
            t0 = time.perf_counter()
            while True:
                due = t0 + k / fps
                now = time.perf_counter()
                if now - t0 >= duration:
                    break
                if due > now:
                    time.sleep(due - now)
                sent[k] = time.perf_counter()
                ws.send(json.dumps({"tag": k}))
                ws.send(frames[k % len(frames)])
                k += 1
            time.sleep(1.0)  # the last results come back
            ws.send(json.dumps({"stats": True}))
            time.sleep(0.5)
            stop.set()
            rx.join(timeout=5)
    except Exception as exc:  # noqa: BLE001 - a client that cannot connect or is cut off
        out.setdefault("failure", repr(exc))
    out.update(sent=k, returned=len(rtts), rtts=rtts, errors=errors)


def client_errors(out: dict) -> int:
    """Errors one :func:`tagged_client` saw: the server's error replies, and a failed connection."""
    return len(out.get("errors", [])) + ("failure" in out)


def _run(url: str, frames, clients: int, fps: float, duration: float) -> dict:
    outs = [{} for _ in range(clients)]
    threads = [threading.Thread(target=tagged_client, args=(url, frames, fps, duration, o)) for o in outs]
    cpu0 = cpu_jiffies()
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    steal = steal_share(cpu0, cpu_jiffies())
    rtts = np.array([ms for o in outs for _, ms in o.get("rtts", [])], dtype=np.float64)
    sent = sum(o.get("sent", 0) for o in outs)
    returned = sum(o.get("returned", 0) for o in outs)
    pct = {f"p{q}": float(np.percentile(rtts, q)) if rtts.size else None for q in (50, 95, 99)}
    return {"clients": clients, "fps": fps, "duration_s": duration, "sent": sent, "returned": returned,
            "dropped": sent - returned, "errors": sum(client_errors(o) for o in outs),
            "failures": [o["failure"] for o in outs if "failure" in o], "rtt_ms": pct, "cpu_steal": steal}


def live_jpegs(out: Path, progress: bool, size: tuple[int, int] = (640, 360)) -> list[bytes]:
    """JPEG frames (quality 85) of a 4 s synthetic live clip at ``size`` (cached in ``out``)."""
    import cv2

    from relight.video_read import read_frames

    from .video import synth_live

    live = synth_live(out, size, 4.0, progress)
    return [cv2.imencode(".jpg", cv2.cvtColor(f, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 85])[1].tobytes()
            for f in read_frames(live / "live.mp4")]


#: Single requests per case (after POST_WARM_UP unmeasured ones).
POST_REQUESTS = 20
POST_WARM_UP = 3


def _post_case(client, url: str, body: bytes, n: int, session: str | None = None, bodies=None) -> dict:
    """Round trips (ms) of ``n`` POSTs of ``body`` (or of ``bodies`` in turn) after the warm-up."""
    headers = {"content-type": "image/jpeg"}
    if session is not None:
        headers["X-Relight-Session"] = session
    ms, faces, errors = [], 0, 0
    for k in range(POST_WARM_UP + n):
        data = bodies[k % len(bodies)] if bodies else body
        t = time.perf_counter()
        r = client.post(url, content=data, headers=headers)
        took = (time.perf_counter() - t) * 1e3
        if k < POST_WARM_UP:
            continue
        errors += r.status_code != 200
        faces += r.headers.get("x-relight-face") == "found"
        ms.append(took)
    a = np.array(ms)
    return {"requests": n, "median_ms": float(np.median(a)), "p95_ms": float(np.percentile(a, 95)),
            "faces": faces, "errors": errors}


def jpeg_floor_ms(body: bytes, n: int = POST_REQUESTS) -> float:
    """The floor of one request on this machine: the median ms of decoding ``body`` (JPEG) and
    encoding it again as the service does (:func:`relight.service.codec.decode_frame`,
    :func:`~relight.service.codec.encode_frame`), in this process."""
    from relight.service.codec import MAX_PIXELS, decode_frame, encode_frame

    times = []
    for _ in range(n):
        t = time.perf_counter()
        encode_frame(decode_frame(body, "image/jpeg", MAX_PIXELS), "image/jpeg")
        times.append((time.perf_counter() - t) * 1e3)
    return float(np.median(times))


def post_requests(base: str, by_size: dict, n: int = POST_REQUESTS) -> dict:
    """``POST /v1/relight`` of single frames (module docstring): per size (``by_size``: "WxH" ->
    the clip's JPEG frames), a frame with a face, a frame of noise - each request on its own -
    and the frames in order in one session."""
    import cv2
    import httpx

    url = f"{base}/v1/relight"
    doc = {}
    with httpx.Client(timeout=60) as client:
        for size, frames in by_size.items():
            face = frames[0]
            shape = cv2.imdecode(np.frombuffer(face, np.uint8), cv2.IMREAD_COLOR).shape
            noise_img = np.random.default_rng(0).integers(0, 256, shape, dtype=np.uint8)
            noise = cv2.imencode(".jpg", noise_img, [cv2.IMWRITE_JPEG_QUALITY, 85])[1].tobytes()
            doc[size] = {"face": _post_case(client, url, face, n), "noise": _post_case(client, url, noise, n),
                         "session": _post_case(client, url, face, n, session=f"bench-{size}", bodies=frames),
                         "floor_ms": jpeg_floor_ms(face)}
    return doc


def start_server(bundle: Path, port: int, clients: int) -> tuple[subprocess.Popen, float]:
    """``relight serve`` in a fresh process and the seconds until /readyz answers 200."""
    env = dict(os.environ, RELIGHT_LOG_LEVEL="warning")
    t0 = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-m", "relight", "serve", str(bundle), "--port", str(port),
                             "--max-clients", str(max(clients, 1)), "--focal", "ortho"], env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    if not wait_ready(f"http://127.0.0.1:{port}", 120, alive=lambda: proc.poll() is None):
        raise RuntimeError(f"relight serve did not become ready: {stop_server(proc)[-500:]}")
    return proc, time.perf_counter() - t0


def stop_server(proc: subprocess.Popen) -> str:
    """Stop a :func:`start_server` process; what it wrote to stderr (its pipe closed)."""
    proc.terminate()
    try:
        proc.wait(timeout=20)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
    if proc.stderr is None:
        return ""
    with proc.stderr:
        return proc.stderr.read()


#: The single client's frame size (the issue's live case: a 720p webcam).
SINGLE_SIZE = (1280, 720)
#: The load unless told (``--clients``, ``--fps``, ``--duration``): websocket clients at once, the
#: frames per second each sends, seconds of load.
CLIENTS = 4
FPS = 30.0
DURATION_S = 60.0


def run(out: Path, bundle: Path | None = None, clients: int = CLIENTS, fps: float = FPS, duration: float = DURATION_S,
        quick: bool = False, progress: bool = True, single_size: tuple[int, int] = SINGLE_SIZE,
        start_bundle: Path | None = None) -> dict:
    """The N-client load at 640x360, then one client alone at ``single_size``; start-up timed on
    the first start (kernel cache as it was) and on a second one (cache warm)."""
    import httpx

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    if quick:
        duration = min(duration, 8.0)
        single_size = (640, 360)
    if bundle is None:
        from relight.bench.video import synth_bundle

        bundle = synth_bundle(out, (640, 360), 20.0 if quick else 30.0, progress)
    frames = live_jpegs(out, progress)
    single_frames = frames if single_size == (640, 360) else live_jpegs(out, progress, single_size)
    port = free_port()
    base = f"http://127.0.0.1:{port}"
    proc, first_start = start_server(bundle, port, clients)
    try:
        url = f"ws://127.0.0.1:{port}/v1/stream"
        _run(url, frames, 1, fps, 2.0)  # warm-up
        rss_start = rss_mb(proc.pid)
        if progress:
            print(f"{clients} clients x {fps:g} fps x {duration:g} s ...", flush=True)
        load = _run(url, frames, clients, fps, duration)
        load["size"] = [640, 360]
        load["relit_fps"] = load["returned"] / duration
        rss_end = rss_mb(proc.pid)
        if progress:
            print(f"1 client x {fps:g} fps at {single_size[0]}x{single_size[1]} ...", flush=True)
        _run(url, single_frames, 1, fps, 2.0)  # warm-up at this size
        single = _run(url, single_frames, 1, fps, min(duration, 20.0))
        single["size"] = list(single_size)
        single["relit_fps"] = single["returned"] / min(duration, 20.0)
        if progress:
            print("POST /v1/relight: single frames ...", flush=True)
        sizes = {"640x360": frames}
        if single_size != (640, 360):
            sizes["x".join(map(str, single_size))] = single_frames
        posts = post_requests(base, sizes, 8 if quick else POST_REQUESTS)
        metrics = httpx.get(f"{base}/metrics").text
        alive = httpx.get(f"{base}/readyz").status_code == 200
    finally:
        stop_server(proc)
    # Start-up: the served bundle again (kernel cache warm), or twice the one given to time it
    # with (e.g. a 1080p capture's).
    timed = Path(start_bundle) if start_bundle is not None else bundle
    if start_bundle is not None:
        proc, first_start = start_server(timed, port, clients)
        stop_server(proc)
    proc, warm_start = start_server(timed, port, clients)
    stop_server(proc)
    doc = {"load": load, "single": single, "post": posts, "rss_mb": {"start": rss_start, "end": rss_end},
           "start_s": {"first": first_start, "warm": warm_start}, "bundle": str(bundle), "start_bundle": str(timed),
           "ready_after": alive, "server_errors": [ln for ln in metrics.splitlines()
                                                   if ln.startswith("relight_errors_total")]}
    from relight.imageio import atomic_path

    with atomic_path(out / "bench.json") as tmp:
        Path(tmp).write_text(json.dumps(doc, indent=1))
    return doc


def _ms(v) -> str:
    return "-" if v is None else f"{v:.1f}"


def table(doc: dict) -> str:
    lines = []
    for name in ("load", "single"):
        r = doc[name]
        q = r["rtt_ms"]
        size = "x".join(str(v) for v in r.get("size", (640, 360)))
        lines.append(f"{name:6s}: {r['clients']} client(s) x {r['fps']:g} fps of {size} x {r['duration_s']:g} s: sent "
                     f"{r['sent']}, relit {r['returned']}, dropped {r['dropped']}, errors {r['errors']}; round trip "
                     f"p50 {_ms(q['p50'])} ms, p95 {_ms(q['p95'])} ms, p99 {_ms(q['p99'])} ms; hypervisor steal "
                     + ("-" if r.get("cpu_steal") is None else f"{100 * r['cpu_steal']:.0f} %") + " of busy CPU")
        if "relit_fps" in r:
            lines.append(f"        relit frames per second, all clients: {r['relit_fps']:.1f}")
    for size, cases in doc.get("post", {}).items():
        parts = []
        for case in ("face", "noise", "session"):
            c = cases[case]
            parts.append(f"{case} {c['median_ms']:.0f} ms (p95 {c['p95_ms']:.0f}, faces {c['faces']}/{c['requests']}"
                         + (f", errors {c['errors']}" if c["errors"] else "") + ")")
        lines.append(f"POST /v1/relight {size} JPEG, median round trip: " + ", ".join(parts)
                     + f"; floor (JPEG decode + encode here) {cases['floor_ms']:.1f} ms")
    st = doc.get("start_s")
    if st:
        lines.append(f"start (process launch -> /readyz 200) of {doc.get('start_bundle', '')}: {st['first']:.2f} s the "
                     f"first time, {st['warm']:.2f} s again (kernel cache warm)")
    rss = doc["rss_mb"]
    lines.append(f"server memory (RSS): {rss['start']:.0f} MB before the load, {rss['end']:.0f} MB after; "
                 f"ready afterwards: {doc['ready_after']}")
    return "\n".join(lines)
