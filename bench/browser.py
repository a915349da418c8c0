"""The browser page in a real headless Chromium, measured: WebRTC against the websocket on the
same clip (``relight bench browser``; the browser test runs it briefly).

Chromium's fake webcam plays a clip whose frames carry their number as a bar code in the top
left corner (8 bits, 12x12 px blocks, a white and a black sync block; outside the face, so the
relit frame keeps it). A script added to the page reads the code of every camera frame the page
shows and of every relit frame that comes back: the round trip of a frame is the time between
the two (camera frame shown -> its relit frame shown: encode, network, server, decode, display).
Bandwidth is the page's own counters (WebRTC: the peer connection's RTP bytes; websocket: the
JPEG messages' bytes), kbit/s averaged over the run.
"""

from __future__ import annotations

import base64
import json
import shutil
import subprocess
import tempfile
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np

#: The bar code: bits, block size (px at 320x180), and where it sits.
CODE_BITS = 8
CODE_BLOCK = 12
#: Round trips longer than this (ms) are a code seen again after the clip looped, not a frame.
MAX_RTT_MS = 2000


def find_chromium() -> str | None:
    return shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")


def barcoded_y4m(frames, path: Path, fps: int = 30) -> Path:
    """Write ``frames`` (RGB uint8, 320 px wide or more) as a .y4m for Chromium's fake camera,
    each with its index (mod 256) as a bar code in the top-left corner."""
    import av

    h, w = frames[0].shape[:2]
    s = w / 320.0
    blk = int(round(CODE_BLOCK * s))
    with av.open(str(path), "w", format="yuv4mpegpipe") as c:
        st = c.add_stream("rawvideo", rate=fps)
        st.width, st.height, st.pix_fmt = w, h, "yuv420p"
        for i, f in enumerate(frames):
            f = f.copy()
            bits = [(i >> b) & 1 for b in range(CODE_BITS)] + [1, 0]  # data, then the sync blocks
            for b, v in enumerate(bits):
                f[:blk, b * blk:(b + 1) * blk] = 255 if v else 0
            for p in st.encode(av.VideoFrame.from_ndarray(f, format="rgb24").reformat(format="yuv420p")):
                c.mux(p)
        for p in st.encode(None):
            c.mux(p)
    return path


#: Added to the page: reads the bar codes of camera and relit frames, keeps round trips.
HARNESS_JS = """
(() => {
  const BITS = @BITS@, BLOCK = @BLOCK@, MAX_RTT = @MAX_RTT@, ROW = BLOCK * (BITS + 2);
  const c = document.createElement("canvas"); c.width = 320; c.height = 180;
  const cx = c.getContext("2d", {willReadFrequently: true});
  const rt = window.__rt = {cam: {}, rtts: [], camFrames: 0, relitFrames: 0, kbps: []};
  function code(el) {
    cx.drawImage(el, 0, 0, 320, 180);
    const d = cx.getImageData(0, 0, ROW, BLOCK).data, mid = Math.floor(BLOCK / 2);
    const bit = (b) => { const i = 4 * (mid * ROW + b * BLOCK + mid); return (d[i] + d[i + 1] + d[i + 2]) / 3; };
    if (bit(BITS) < 160 || bit(BITS + 1) > 96) return -1;  // sync blocks: white, black
    let v = 0;
    for (let b = 0; b < BITS; b++) if (bit(b) > 128) v |= 1 << b;
    return v;
  }
  const cam = document.getElementById("camera");
  const onCam = (now) => {
    const k = code(cam);
    if (k >= 0 && !(k in rt.cam && now - rt.cam[k] < MAX_RTT)) rt.cam[k] = now;
    rt.camFrames++;
    cam.requestVideoFrameCallback(onCam);
  };
  cam.requestVideoFrameCallback(onCam);
  const relit = (el, now) => {
    const k = code(el);
    rt.relitFrames++;
    if (k >= 0 && k in rt.cam && now - rt.cam[k] > 0 && now - rt.cam[k] < MAX_RTT) rt.rtts.push(now - rt.cam[k]);
  };
  const vid = document.getElementById("relit-video");
  const onVid = (now) => { relit(vid, now); vid.requestVideoFrameCallback(onVid); };
  vid.requestVideoFrameCallback(onVid);
  const img = document.getElementById("relit-img");
  img.addEventListener("load", () => relit(img, performance.now()));
  setInterval(() => {
    const s = window.relightStats;
    if (s && s.frames) rt.kbps.push([s.up_kbps, s.down_kbps]);
  }, 1000);
})();
""".replace("@BITS@", str(CODE_BITS)).replace("@BLOCK@", str(CODE_BLOCK)).replace("@MAX_RTT@", str(MAX_RTT_MS))


class DevTools:
    """Just enough of the Chrome DevTools protocol: call a method, wait for its result."""

    def __init__(self, ws):
        self.ws, self.n = ws, 0

    def __call__(self, method, **params):
        self.n += 1
        self.ws.send(json.dumps({"id": self.n, "method": method, "params": params}))
        while True:
            msg = json.loads(self.ws.recv(timeout=30))
            if msg.get("id") == self.n:
                if "error" in msg:
                    raise RuntimeError(f"{method}: {msg['error']}")
                return msg.get("result", {})

    def js(self, expression):
        return self("Runtime.evaluate", expression=expression, returnByValue=True)["result"].get("value")

    def set_files(self, selector: str, *paths) -> None:
        """Choose ``paths`` in the page's file input ``selector``, as a user picking files does
        (its change event fires)."""
        root = self("DOM.getDocument")["root"]["nodeId"]
        node = self("DOM.querySelector", nodeId=root, selector=selector)["nodeId"]
        self("DOM.setFileInputFiles", files=[str(p) for p in paths], nodeId=node)


@contextmanager
def chromium_page(chromium: str, y4m: Path, *, timeout: float = 60.0):
    """A headless Chromium whose fake webcam plays ``y4m``; yields a :class:`DevTools` on its page."""
    import httpx
    from websockets.sync.client import connect

    from .server import free_port

    port = free_port()
    with tempfile.TemporaryDirectory(prefix="relight-chromium-", ignore_cleanup_errors=True) as profile:
        proc = subprocess.Popen([chromium, "--headless=new", "--no-sandbox", "--disable-gpu",
                                 "--use-fake-ui-for-media-stream", "--use-fake-device-for-media-stream",
                                 f"--use-file-for-fake-video-capture={y4m}", "--window-size=1280,800",
                                 # host candidates as addresses (not mDNS names) on this machine
                                 "--disable-features=WebRtcHideLocalIpsWithMdns",
                                 f"--remote-debugging-port={port}", f"--user-data-dir={profile}", "about:blank"],
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            deadline = time.time() + timeout
            page = None
            while page is None:
                try:
                    page = next(p for p in httpx.get(f"http://127.0.0.1:{port}/json/list", timeout=2).json()
                                if p.get("type") == "page")
                except (httpx.TransportError, StopIteration, ValueError):
                    if time.time() > deadline or proc.poll() is not None:
                        raise RuntimeError("Chromium's DevTools endpoint did not come up") from None
                    time.sleep(0.2)
            with connect(page["webSocketDebuggerUrl"], max_size=None) as ws:
                dev = DevTools(ws)
                dev("Page.enable")
                yield dev
        finally:
            proc.terminate()
            try:
                proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                proc.kill()


def measure_page(dev: DevTools, base: str, transport: str, seconds: float, *, min_frames: int = 3,
                 start_timeout: float = 90.0, screenshot: Path | None = None) -> dict:
    """Open the page with ``?transport=...``, wait for relit frames, measure for ``seconds``."""
    dev("Page.navigate", url=f"{base}/?transport={transport}")
    deadline = time.time() + start_timeout
    while time.time() < deadline:
        ready = dev.js("document.readyState === 'complete' && !!document.getElementById('relit-video')")
        if ready:
            break
        time.sleep(0.1)
    dev.js(HARNESS_JS)
    shown = 0
    while shown < min_frames and time.time() < deadline:
        shown = int(dev.js("+(document.getElementById('relit').dataset.frames || 0)") or 0)
        time.sleep(0.25)
    status = dev.js("document.getElementById('status').textContent")
    if shown < min_frames:
        return {"transport": transport, "frames": shown, "status": status, "ok": False}
    dev.js("window.__rt.rtts = []; window.__rt.kbps = []; window.__rt.t0 = performance.now(); "
           "window.__rt.f0 = +document.getElementById('relit').dataset.frames")
    time.sleep(seconds)
    doc = json.loads(dev.js("JSON.stringify({rt: window.__rt, stats: window.relightStats, now: performance.now(), "
                            "frames: +document.getElementById('relit').dataset.frames})"))
    rt, st = doc["rt"], doc["stats"]
    rtts = np.asarray(rt["rtts"], dtype=np.float64)
    kbps = np.asarray(rt["kbps"], dtype=np.float64).reshape(-1, 2)
    out = {"transport": st["transport"], "ok": True, "status": dev.js("document.getElementById('status').textContent"),
           "frames": doc["frames"] - rt["f0"], "seconds": (doc["now"] - rt["t0"]) / 1e3,
           "rtt_n": int(rtts.size), "server_latency_ms": st["latency_ms"], "dropped": st["dropped"]}
    out["fps"] = out["frames"] / max(out["seconds"], 1e-6)
    if rtts.size:
        out.update(rtt_median_ms=float(np.median(rtts)), rtt_p95_ms=float(np.percentile(rtts, 95)))
    if kbps.size:
        out.update(up_kbps=float(kbps[:, 0].mean()), down_kbps=float(kbps[:, 1].mean()))
    if screenshot is not None:
        screenshot.write_bytes(base64.b64decode(dev("Page.captureScreenshot", format="png")["data"]))
    return out


def run_browser_bench(bundle: Path, clip: Path, *, seconds: float = 20.0, transports=("webrtc", "websocket"),
                      focal="ortho", out_json: Path | None = None) -> list[dict]:
    """Serve ``bundle``, play ``clip`` as Chromium's webcam, measure each transport in turn."""
    from relight.service.settings import ServeConfig
    from relight.video_read import read_frames

    from .server import running_app

    chromium = find_chromium()
    if chromium is None:
        raise RuntimeError("Chromium is not installed: `make install-system` (Debian's chromium package)")
    results = []
    with tempfile.TemporaryDirectory(prefix="relight-browser-") as tmp:
        y4m = barcoded_y4m(list(read_frames(clip)), Path(tmp) / "clip.y4m")
        with running_app(ServeConfig(bundle=Path(bundle), focal=focal)) as base:
            for transport in transports:
                with chromium_page(chromium, y4m) as dev:
                    results.append(measure_page(dev, base, transport, seconds))
    if out_json is not None:
        from relight.imageio import atomic_path

        with atomic_path(out_json) as t:
            Path(t).write_text(json.dumps(results, indent=1))
    return results


def format_results(results: list[dict]) -> str:
    lines = [f"{'transport':10s} {'fps':>6s} {'RTT p50':>8s} {'RTT p95':>8s} {'n':>5s} {'server':>7s} "
             f"{'up kbit/s':>10s} {'down kbit/s':>11s}"]
    for r in results:
        if not r.get("ok"):
            lines.append(f"{r['transport']:10s} no relit frames ({r.get('status')})")
            continue
        lines.append(f"{r['transport']:10s} {r['fps']:6.1f} {r.get('rtt_median_ms', float('nan')):8.1f} "
                     f"{r.get('rtt_p95_ms', float('nan')):8.1f} {r['rtt_n']:5d} {r['server_latency_ms']:7.1f} "
                     f"{r.get('up_kbps', float('nan')):10.0f} {r.get('down_kbps', float('nan')):11.0f}")
    return "\n".join(lines)
