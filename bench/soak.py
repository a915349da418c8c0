"""``relight bench soak``: a real ``relight-serve`` for minutes, with good and bad clients.

Four well-behaved websocket clients send tagged 640x360 JPEG frames at a steady rate the whole
time and measure each frame's round trip; beside them one thread keeps opening misbehaving
clients, in turn:

* ``vanish`` - connects, sends a frame, and drops the TCP connection without a close frame;
* ``garbage`` - binary that is no image, a PNG header claiming 60000x60000 pixels, text that is
  not JSON, JSON nested 5000 deep, a control over the size cap; then closes;
* ``stalled`` - sends frames for a few seconds and never reads a reply (its receive window
  fills; the server must not block the others or queue without bound), then vanishes;
* ``http`` - ``POST /v1/relight`` with a truncated JPEG and with a foreign ``Origin``.

The server's resident memory, open file descriptors and threads are sampled every few seconds
(``/proc``); their slopes are fitted after the first minute (warm-up). Reported: errors seen by
the good clients (error replies, disconnects: must be 0), frames sent/returned/dropped, round
trip p50/p95/p99 per minute, RSS/fd/thread slopes per minute, the misbehaving sessions run, and
whether the server is still ready at the end. Writes bench.json and soak.png.
"""

from __future__ import annotations

import json
import os
import socket
import threading
import time
from pathlib import Path

import numpy as np

from .machine import rss_mb
from .serve import client_errors, live_jpegs, start_server, stop_server, tagged_client
from .server import free_port

#: Good clients, their frame rate, the sampling period of the server's resources (s).
CLIENTS = 4
FPS = 10.0
SAMPLE_S = 5.0
WARMUP_S = 60.0
#: Length of the soak (``--minutes``), and with ``--quick``.
MINUTES = 10.0
QUICK_MINUTES = 2.0


def _proc_counts(pid: int) -> tuple[int, int]:
    """(open file descriptors, threads) of ``pid``; (-1, -1) when /proc cannot tell."""
    try:
        fds = len(os.listdir(f"/proc/{pid}/fd"))
        threads = next(int(ln.split()[1]) for ln in Path(f"/proc/{pid}/status").read_text().splitlines()
                       if ln.startswith("Threads:"))
        return fds, threads
    except (OSError, StopIteration, ValueError):
        return -1, -1


def _cut(ws) -> None:
    """Drop the TCP connection under ``ws``: no close frame, no close handshake awaited."""
    ws.socket.shutdown(socket.SHUT_RDWR)
    ws.socket.close()


def _abandon(session) -> None:
    """Run ``session()`` (which ends by cutting its connection); the client library's own close
    on the dead socket afterwards is not the server's doing and is ignored."""
    from websockets.exceptions import WebSocketException

    done = []
    try:
        session(done)
    except (OSError, WebSocketException):
        if not done:
            raise


def _vanish(url: str, frame: bytes) -> None:
    from websockets.sync.client import connect

    def session(done):
        with connect(url, open_timeout=10) as ws:
            ws.send(frame)
            _cut(ws)
            done.append(True)

    _abandon(session)


def _garbage(url: str) -> int:
    """Send each kind of garbage; the number of error replies the server gave back."""
    import struct
    import zlib

    from websockets.sync.client import connect

    ihdr = struct.pack(">II", 60000, 60000) + b"\x08\x02\x00\x00\x00"
    png = b"\x89PNG\r\n\x1a\n" + struct.pack(">I", 13) + b"IHDR" + ihdr + struct.pack(">I", zlib.crc32(b"IHDR" + ihdr))
    replies = 0
    with connect(url, open_timeout=10, max_size=None) as ws:
        for msg in (os.urandom(5000), png + os.urandom(100), "not json", "[" * 5000 + "]" * 5000,
                    json.dumps({"env": "x" * 5000}), json.dumps({"strength": "loud"})):
            ws.send(msg)
            try:
                doc = json.loads(ws.recv(timeout=5))
                replies += "error" in doc
            except TimeoutError:
                pass
    return replies


def _stalled(url: str, frames: list[bytes], seconds: float) -> None:
    from websockets.exceptions import ConnectionClosed
    from websockets.sync.client import connect

    def session(done):
        with connect(url, open_timeout=10, max_queue=1, max_size=None) as ws:  # stops reading at one message
            t_end = time.perf_counter() + seconds
            k = 0
            while time.perf_counter() < t_end:
                try:
                    ws.send(frames[k % len(frames)])
                except ConnectionClosed:  # the server may close a client that never reads
                    break
                k += 1
                time.sleep(1 / 30)
            if k < 2:
                raise RuntimeError(f"the stalled client sent only {k} frame(s)")
            _cut(ws)
            done.append(True)

    _abandon(session)


def _http(base: str) -> list[int]:
    import httpx

    jpeg = b"\xff\xd8\xff\xe0" + os.urandom(2000)
    codes = [httpx.post(f"{base}/v1/relight", content=jpeg, headers={"content-type": "image/jpeg"}, timeout=30)
             .status_code,
             httpx.post(f"{base}/v1/relight", content=jpeg, timeout=30,
                        headers={"content-type": "image/jpeg", "origin": "http://evil.example"}).status_code]
    return codes


def _misbehave(url: str, base: str, frames: list[bytes], until: float, out: dict) -> None:
    kinds = ("vanish", "garbage", "stalled", "http")
    counts = {k: 0 for k in kinds}
    failures: list[str] = []
    replies = 0
    codes: dict[int, int] = {}
    i = 0
    while time.perf_counter() < until - 6:
        kind = kinds[i % len(kinds)]
        try:
            if kind == "vanish":
                _vanish(url, frames[0])
            elif kind == "garbage":
                replies += _garbage(url)
            elif kind == "stalled":
                _stalled(url, frames, 4.0)
            else:
                for c in _http(base):
                    codes[c] = codes.get(c, 0) + 1
            counts[kind] += 1
        except Exception as exc:  # noqa: BLE001 - a refusal (e.g. client cap) is recorded, not fatal
            failures.append(f"{kind}: {exc!r}"[:200])
        i += 1
        time.sleep(1.0)
    out.update(sessions=counts, garbage_error_replies=replies, http_codes=codes, failures=failures)


def _slope(t: np.ndarray, v: np.ndarray) -> float | None:
    """Least-squares slope of v per minute over the samples after the warm-up."""
    keep = (t >= min(WARMUP_S, t.max() / 2)) & np.isfinite(v) & (v >= 0)
    if keep.sum() < 3:
        return None
    return float(np.polyfit(t[keep] / 60.0, v[keep], 1)[0])


def run(out: Path, *, minutes: float = MINUTES, bundle: Path | None = None, progress: bool = True) -> dict:
    import httpx

    from relight.imageio import atomic_path

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    if bundle is None:
        from .video import synth_bundle

        bundle = synth_bundle(out, (640, 360), 20.0, progress)
    frames = live_jpegs(out, progress)
    port = free_port()
    base, url = f"http://127.0.0.1:{port}", f"ws://127.0.0.1:{port}/v1/stream"
    proc, _ = start_server(bundle, port, CLIENTS + 3)  # the good clients and room for the bad ones
    duration = minutes * 60.0
    samples = []
    try:
        t_start = time.perf_counter()
        until = t_start + duration
        goods = [{} for _ in range(CLIENTS)]
        bad: dict = {}
        threads = [threading.Thread(target=tagged_client, args=(url, frames, FPS, duration, o)) for o in goods]
        threads.append(threading.Thread(target=_misbehave, args=(url, base, frames, until, bad)))
        for th in threads:
            th.start()
        next_print = 60.0
        while any(th.is_alive() for th in threads):
            t = time.perf_counter() - t_start
            fds, nthreads = _proc_counts(proc.pid)
            samples.append((t, rss_mb(proc.pid), fds, nthreads))
            if progress and t >= next_print:
                print(f"  {t / 60:.0f} min: RSS {samples[-1][1]:.0f} MB, {fds} fds, {nthreads} threads", flush=True)
                next_print += 60.0
            time.sleep(SAMPLE_S)
        for th in threads:
            th.join()
        ready = httpx.get(f"{base}/readyz", timeout=10).status_code == 200
        metrics = httpx.get(f"{base}/metrics", timeout=10).text
    finally:
        stop_server(proc)
    s = np.array(samples, dtype=np.float64)
    per_minute = []
    all_rtts = [(t - t_start, ms) for g in goods for t, ms in g.get("rtts", [])]
    error_texts = [e for g in goods for e in g.get("errors", []) + ([g["failure"]] if "failure" in g else [])]
    for m in range(int(np.ceil(duration / 60.0))):
        r = np.array([v for t, v in all_rtts if m * 60 <= t < (m + 1) * 60])
        per_minute.append({"minute": m + 1, "returned": int(r.size),
                           **{f"p{q}": float(np.percentile(r, q)) if r.size else None for q in (50, 95, 99)}})
    doc = {
        "minutes": minutes, "clients": CLIENTS, "fps": FPS, "bundle": str(bundle),
        "good": {"sent": sum(g.get("sent", 0) for g in goods), "returned": sum(g.get("returned", 0) for g in goods),
                 "errors": sum(client_errors(g) for g in goods),
                 "error_texts": error_texts[:20]},
        "bad": bad, "per_minute": per_minute, "ready_after": ready,
        "rss_mb": {"first": float(s[0, 1]), "last": float(s[-1, 1]), "max": float(np.nanmax(s[:, 1])),
                   "slope_per_min": _slope(s[:, 0], s[:, 1])},
        "fds": {"first": int(s[0, 2]), "last": int(s[-1, 2]), "max": int(s[:, 2].max()),
                "slope_per_min": _slope(s[:, 0], s[:, 2])},
        "threads": {"first": int(s[0, 3]), "last": int(s[-1, 3]), "max": int(s[:, 3].max()),
                    "slope_per_min": _slope(s[:, 0], s[:, 3])},
        "samples": s.tolist(),
        "server_errors": [ln for ln in metrics.splitlines() if ln.startswith("relight_errors_total")],
    }
    doc["good"]["dropped"] = doc["good"]["sent"] - doc["good"]["returned"]
    with atomic_path(out / "bench.json") as tmp:
        Path(tmp).write_text(json.dumps(doc, indent=1))
    _plot(doc, out / "soak.png")
    return doc


def _plot(doc: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from relight.imageio import atomic_path

    s = np.array(doc["samples"])
    fig, ax = plt.subplots(1, 3, figsize=(13, 3.6))
    ax[0].plot(s[:, 0] / 60, s[:, 1])
    ax[0].set(xlabel="minutes", ylabel="server RSS (MB)",
              title=f"RSS, slope {_fmt(doc['rss_mb']['slope_per_min'])} MB/min")
    ax[1].plot(s[:, 0] / 60, s[:, 2], label="open fds")
    ax[1].plot(s[:, 0] / 60, s[:, 3], label="threads")
    ax[1].set(xlabel="minutes", title="file descriptors and threads")
    ax[1].legend()
    pm = doc["per_minute"]
    for q in ("p50", "p95", "p99"):
        ax[2].plot([m["minute"] for m in pm], [m[q] if m[q] is not None else np.nan for m in pm], "o-", label=q)
    ax[2].set(xlabel="minute", ylabel="round trip (ms)", title=f"{doc['clients']} clients x {doc['fps']:g} fps")
    ax[2].legend()
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=100)
    plt.close(fig)


def _fmt(v) -> str:
    return "-" if v is None else f"{v:+.2f}"


def table(doc: dict) -> str:
    g, b = doc["good"], doc["bad"]
    lines = [f"soak: {doc['minutes']:g} min, {doc['clients']} good clients x {doc['fps']:g} fps; server ready after: "
             f"{doc['ready_after']}",
             f"good clients: {g['sent']} frames sent, {g['returned']} returned, {g['dropped']} dropped "
             f"(latest frame wins), errors {g['errors']}",
             f"misbehaving sessions: {b.get('sessions')}, error replies to garbage {b.get('garbage_error_replies')}, "
             f"HTTP codes {b.get('http_codes')}, failures {len(b.get('failures', []))}",
             f"RSS {doc['rss_mb']['first']:.0f} -> {doc['rss_mb']['last']:.0f} MB (max {doc['rss_mb']['max']:.0f}), "
             f"slope {_fmt(doc['rss_mb']['slope_per_min'])} MB/min after the first minute",
             f"open fds {doc['fds']['first']} -> {doc['fds']['last']} (max {doc['fds']['max']}), slope "
             f"{_fmt(doc['fds']['slope_per_min'])}/min; threads {doc['threads']['first']} -> {doc['threads']['last']}, "
             f"slope {_fmt(doc['threads']['slope_per_min'])}/min",
             "", "| minute | returned | p50 ms | p95 ms | p99 ms |", "|---|---|---|---|---|"]
    for m in doc["per_minute"]:
        lines.append(f"| {m['minute']} | {m['returned']} | " + " | ".join(
            "-" if m[q] is None else f"{m[q]:.0f}" for q in ("p50", "p95", "p99")) + " |")
    return "\n".join(lines)
