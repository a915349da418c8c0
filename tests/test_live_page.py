"""``relight live``'s page as the light's control surface, in a real headless Chromium: a key
light dragged on the lit balls moves the bright side of the relit face (measured on the frames
the run relit), an uploaded photo changes the light, a light saved by name comes back through
``--env``; and the page's endpoints refuse what they should. The camera is a video file played
by ``relight live`` itself; Chromium's fake webcam is not used by this page."""

from __future__ import annotations

import base64
import json
import re
import signal
import subprocess
import sys
import time

import cv2
import httpx
import numpy as np
import pytest

from relight.colour import LUMINANCE, decode_srgb8

from .serving import wait_line
from .tolerances import PAGE_KEY_SIDE_LOG

RELIGHT = [sys.executable, "-m", "relight"]
RUN_TIMEOUT = 150


def _snapshot(url: str) -> tuple[np.ndarray, np.ndarray]:
    """(the camera frame, the frame relit from it) of the newest relit frame."""
    r = httpx.get(url + "snapshot.png?with=camera", timeout=30)
    assert r.status_code == 200
    both = cv2.cvtColor(cv2.imdecode(np.frombuffer(r.content, np.uint8), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
    w = both.shape[1] // 2
    return both[:, :w], both[:, w:]


def _state_until(url: str, ok, timeout: float = 30.0) -> dict:
    deadline = time.time() + timeout
    while time.time() < deadline:
        st = httpx.get(url + "state", timeout=10).json()
        if ok(st):
            return st
        time.sleep(0.1)
    raise AssertionError(f"the page's state never changed as asked: {st}")


def _drag(dev, x0: float, x1: float, y: float) -> None:
    """Drag on the balls from x0 to x1 (0-1 across the grey ball) at height y (0-1, down)."""
    rect = json.loads(dev.js("JSON.stringify(document.getElementById('ball').getBoundingClientRect())"))
    half = rect["width"] / 2

    def at(u):
        return {"x": rect["left"] + u * half, "y": rect["top"] + y * rect["height"]}

    dev("Input.dispatchMouseEvent", type="mousePressed", button="left", clickCount=1, **at(x0))
    for u in np.linspace(x0, x1, 8):
        dev("Input.dispatchMouseEvent", type="mouseMoved", button="left", **at(float(u)))
        time.sleep(0.03)
    dev("Input.dispatchMouseEvent", type="mouseReleased", button="left", clickCount=1, **at(x1))


def _screenshot(dev, path) -> None:
    path.write_bytes(base64.b64decode(dev("Page.captureScreenshot", format="png")["data"]))


def _right_over_left(pair: tuple[np.ndarray, np.ndarray]) -> float:
    """log(right / left) of the relit frame's light against the camera's, over the relit region:
    the mean log luminance ratio relit / camera right of the region's middle minus left of it
    (each snapshot against its own camera frame: the head's motion between snapshots cancels)."""
    cam, relit = pair
    d = np.log(decode_srgb8(relit) @ LUMINANCE + 1e-3) - np.log(decode_srgb8(cam) @ LUMINANCE + 1e-3)
    changed = np.abs(d) > 0.02
    cols = np.nonzero(changed.any(axis=0))[0]
    assert cols.size > 10, "the relit frame did not change the camera's"
    right = np.arange(cam.shape[1])[None, :] > (cols.min() + cols.max()) / 2
    return float(d[changed & right].mean() - d[changed & ~right].mean())


@pytest.mark.slow  # relight live and a headless Chromium (~18 s): `make test-slow`, CI
def test_the_live_page_steers_the_light(chromium, small_bundle, live_clip, tmp_path):
    from relight import load_environment
    from relight.bench.browser import barcoded_y4m, chromium_page
    from relight.video_read import read_frames

    lights, stats = tmp_path / "lights", tmp_path / "stats.json"
    proc = subprocess.Popen(RELIGHT + ["live", "--bundle", str(small_bundle.path), "--env", "builtin:studio",
                                       "--camera", str(live_clip), "--focal", "ortho", "--preview",
                                       "--lights-dir", str(lights), "--duration", "300", "--stats-json", str(stats)],
                            stderr=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    shots = tmp_path / "shots"
    shots.mkdir()
    try:
        deadline = time.time() + RUN_TIMEOUT
        url = re.search(r"http://127\.0\.0\.1:\d+/", wait_line(proc, "preview http://", deadline)).group(0)
        _state_until(url, lambda st: (st["figures"] or {}).get("fps_relit", 0) > 0, RUN_TIMEOUT)
        # The endpoints refuse what they should, and change nothing then.
        assert httpx.post(url + "control", json={"exposure": 99}).status_code == 422
        assert httpx.post(url + "control", json={"env": "/etc/passwd"}).status_code == 422
        evil = {"origin": "http://evil.example"}
        assert httpx.post(url + "control", json={"strength": 1}, headers=evil).status_code == 403
        assert httpx.get(url + "state", headers={"host": "evil.example"}).status_code == 403
        png = {"content-type": "image/png"}
        assert httpx.post(url + "upload", content=b"not an image", headers=png).status_code == 422
        assert httpx.post(url + "save?name=../up").status_code == 422
        assert httpx.get(url + "state").json()["env"] == "builtin:studio"

        y4m = barcoded_y4m(list(read_frames(live_clip))[:4], tmp_path / "fake.y4m")
        with chromium_page(chromium, y4m) as dev:
            dev("Page.navigate", url=url)
            t0 = time.time()
            while not dev.js("!!(window.relightPage && window.relightPage.state)"):
                assert time.time() - t0 < 30, "the page never read the state"
                time.sleep(0.1)
            _screenshot(dev, shots / "1-page.png")
            # Drag the key light to the image's left, then to its right.
            frames = {}
            for side, (x0, x1) in (("left", (0.5, 0.12)), ("right", (0.5, 0.88))):
                _drag(dev, x0, x1, 0.45)
                want = (lambda st: st["key"] is not None and st["key"]["az"] < -40) if side == "left" else \
                    (lambda st: st["key"] is not None and st["key"]["az"] > 40)
                _state_until(url, want)
                time.sleep(1.5)  # frames relit under it (the page's change reaches them in ~0.1-0.3 s here)
                frames[side] = _snapshot(url)
                _screenshot(dev, shots / f"2-key-{side}.png")
            left, right = _right_over_left(frames["left"]), _right_over_left(frames["right"])
            assert right - left > PAGE_KEY_SIDE_LOG, (left, right)
            # Upload a photo bright on its left, through the page's file input.
            photo = np.full((120, 160, 3), 40, np.uint8)
            photo[:, :80] = 235
            cv2.imwrite(str(tmp_path / "beach.jpg"), photo)
            dev.set_files("#file", tmp_path / "beach.jpg")
            _state_until(url, lambda st: st["env"].startswith("photo:"))
            time.sleep(1.5)
            frames["photo"] = _snapshot(url)
            _screenshot(dev, shots / "3-photo.png")
            assert _right_over_left(frames["photo"]) < right - PAGE_KEY_SIDE_LOG  # lit from the left now
            # Save it by name: a small JSON file that --env gives back.
            dev.js("document.getElementById('name').value = 'my-photo-light'; document.getElementById('save').click()")
            t0 = time.time()
            while not (lights / "my-photo-light.json").exists():
                assert time.time() - t0 < 10, "the light was not saved"
                time.sleep(0.1)
            _screenshot(dev, shots / "4-saved.png")
        env = load_environment(lights / "my-photo-light.json")
        assert env.shape[1] == 2 * env.shape[0] and np.isfinite(env).all()
        proc.send_signal(signal.SIGINT)
        proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0
    doc = json.loads(stats.read_text())
    assert len(doc["light_ms"]) >= 3 and all(ms > 0 for ms in doc["light_ms"])  # measured, reported
    for png in shots.glob("*.png"):
        img = cv2.imread(str(png))
        assert img is not None and img.std() > 5
