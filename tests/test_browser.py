"""The browser page in a real headless Chromium: webcam (a fake device playing a `relight synth
--live` clip) -> websocket -> relit frames in the page. Chromium comes from Debian's `chromium`
package, which `make install-system` installs (CI calls it); without it the test skips and says so."""

import base64
import json
import shutil
import subprocess
import time

import cv2
import numpy as np
import pytest

httpx = pytest.importorskip("httpx", reason="httpx (a test extra) is the client")

from .serving import free_port, running_server  # noqa: E402 (after the skip: it needs httpx)

#: Relit frames the page must show, and how long it may take (s).
PAGE_FRAMES = 3
PAGE_TIMEOUT = 90


@pytest.fixture(scope="module")
def chromium():
    exe = shutil.which("chromium") or shutil.which("chromium-browser")
    if exe is None:
        pytest.skip("Chromium is not installed: `make install-system` installs it (Debian's apt, as root), "
                    "or install the 'chromium' package yourself")
    return exe


@pytest.fixture(scope="module")
def y4m_clip(tmp_path_factory):
    """A 2 s live clip of the small capture's head (seed 3, 320x180) as .y4m for the fake camera."""
    import av

    from relight.pipeline.synth.live import LiveConfig, synthesize_live
    from relight.video import read_frames

    out = tmp_path_factory.mktemp("live")
    res = synthesize_live(out, LiveConfig(width=320, height=180, duration=2.0, seed=3, yaw=10.0, pitch=5.0,
                                          roll=3.0, audio="none"), progress=False)
    path = out / "live.y4m"
    with av.open(str(path), "w", format="yuv4mpegpipe") as c:
        st = c.add_stream("rawvideo", rate=30)
        st.width, st.height, st.pix_fmt = 320, 180, "yuv420p"
        for f in read_frames(res.video):
            for p in st.encode(av.VideoFrame.from_ndarray(f, format="rgb24").reformat(format="yuv420p")):
                c.mux(p)
        for p in st.encode(None):
            c.mux(p)
    return path


@pytest.fixture(scope="module")
def server(small_bundle):
    from relight.service.settings import ServeConfig

    with running_server(ServeConfig(bundle=small_bundle.path)) as base:
        yield base


class _DevTools:
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


def test_browser_page_streams_the_camera_and_shows_relit_frames(chromium, y4m_clip, server, tmp_path):
    from websockets.sync.client import connect

    port = free_port()
    proc = subprocess.Popen([chromium, "--headless=new", "--no-sandbox", "--disable-gpu",
                             "--use-fake-ui-for-media-stream", "--use-fake-device-for-media-stream",
                             f"--use-file-for-fake-video-capture={y4m_clip}", "--window-size=1280,800",
                             f"--remote-debugging-port={port}", f"--user-data-dir={tmp_path / 'profile'}",
                             "about:blank"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.time() + 60
        page = None
        while page is None:
            try:
                page = next(p for p in httpx.get(f"http://127.0.0.1:{port}/json/list", timeout=2).json()
                            if p.get("type") == "page")
            except (httpx.TransportError, StopIteration, ValueError):
                if time.time() > deadline:
                    pytest.fail("Chromium's DevTools endpoint did not come up")
                time.sleep(0.2)
        with connect(page["webSocketDebuggerUrl"], max_size=None) as ws:
            dev = _DevTools(ws)
            dev("Page.enable")
            dev("Page.navigate", url=f"{server}/")
            shown, deadline = 0, time.time() + PAGE_TIMEOUT
            while shown < PAGE_FRAMES and time.time() < deadline:
                shown = int(dev.js("((document.getElementById('relit') || {dataset: {}}).dataset.frames) || '0'")
                            or 0)
                time.sleep(0.25)
            status = dev.js("document.getElementById('status').textContent")
            assert shown >= PAGE_FRAMES, f"the page showed {shown} relit frames; status: {status}"
            assert "fps" in status and "latency" in status
            rects = json.loads(dev.js("JSON.stringify(['camera', 'relit'].map(i => "
                                      "document.getElementById(i).getBoundingClientRect()))"))
            png = base64.b64decode(dev("Page.captureScreenshot", format="png")["data"])
    finally:
        proc.terminate()
        proc.wait(timeout=20)
    (tmp_path / "page.png").write_bytes(png)
    shot = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
    cam, rel = rects
    assert abs(cam["top"] - rel["top"]) < 2 and rel["left"] > cam["left"] + cam["width"] - 1  # side by side
    for r in (cam, rel):  # both panes show a picture, not a blank box
        crop = shot[int(r["top"]) + 2:int(r["top"] + r["height"]) - 2,
                    int(r["left"]) + 2:int(r["left"] + r["width"]) - 2]
        assert crop.size and crop.std() > 5
    frames = [float(line.split()[-1]) for line in httpx.get(f"{server}/metrics").text.splitlines()
              if line.startswith("relight_frames_total")]
    assert frames and frames[0] >= PAGE_FRAMES
