"""The browser page in a real headless Chromium: webcam (a fake device playing a `relight synth
--live` clip with frame-number bar codes) -> WebRTC or websocket -> relit frames in the page,
their round trip measured from the bar codes (:mod:`relight.bench.browser`). Chromium comes
from Debian's `chromium` package, which `make install-system` installs (CI calls it); without it
the test skips and says so."""

import json
import time

import cv2
import httpx
import numpy as np
import pytest

from relight.bench.browser import barcoded_y4m, chromium_page, measure_page

from .serving import running_server
from .tolerances import LIVE_CHANGED_CODES

#: Relit frames the page must show before measuring, and the seconds measured per transport.
PAGE_FRAMES = 3
MEASURE_S = 4.0


@pytest.fixture(scope="module")
def y4m_clip(live_clip, tmp_path_factory):
    from relight.video_read import read_frames

    return barcoded_y4m(list(read_frames(live_clip)), tmp_path_factory.mktemp("y4m") / "live.y4m")


@pytest.fixture(scope="module")
def server(small_bundle):
    from relight.service.settings import ServeConfig

    with running_server(ServeConfig(bundle=small_bundle.path, focal="ortho")) as base:
        yield base


# WebRTC's run (~24 s with its set-up) is in `make test-slow` (CI runs both); the websocket's here.
@pytest.mark.parametrize("transport", [pytest.param("webrtc", marks=pytest.mark.slow), "websocket"])
def test_browser_page_streams_the_camera_and_shows_relit_frames(chromium, y4m_clip, server, transport, tmp_path):
    shot = tmp_path / "page.png"
    with chromium_page(chromium, y4m_clip) as dev:
        res = measure_page(dev, server, transport, MEASURE_S, min_frames=PAGE_FRAMES, screenshot=shot)
        visible = "relit-video" if transport == "webrtc" else "relit-img"
        rects = json.loads(dev.js(f"JSON.stringify(['camera', '{visible}'].map(i => "
                                  "document.getElementById(i).getBoundingClientRect()))"))
        if transport == "websocket":  # a photo uploaded through the page becomes the light
            photo = np.full((90, 120, 3), 40, np.uint8)
            photo[:, :60] = 230
            cv2.imwrite(str(tmp_path / "beach.jpg"), photo)
            dev.set_files("#upload", tmp_path / "beach.jpg")
            deadline = time.time() + 30
            while httpx.get(f"{server}/v1/environment").json()["current"] != "photo.jpg":
                assert time.time() < deadline, "the page's upload did not reach the service"
                time.sleep(0.2)
            httpx.put(f"{server}/v1/environment?builtin=studio")
    assert res["ok"], f"the page showed {res['frames']} relit frames; status: {res['status']}"
    assert res["transport"] == transport  # WebRTC did not fall back to the websocket
    assert res["frames"] >= PAGE_FRAMES and "fps" in res["status"] and "latency" in res["status"]
    # Round trips from the frames' bar codes: camera frame shown -> its relit frame shown.
    assert res["rtt_n"] >= PAGE_FRAMES and 0 < res["rtt_median_ms"] <= res["rtt_p95_ms"]
    assert res["up_kbps"] > 0 and res["down_kbps"] > 0
    img = cv2.imread(str(shot), cv2.IMREAD_COLOR)
    cam, rel = rects
    assert abs(cam["top"] - rel["top"]) < 40 and rel["left"] > cam["left"] + cam["width"] - 1  # side by side
    for r in (cam, rel):  # both panes show a picture, not a blank box
        crop = img[int(r["top"]) + 2:int(r["top"] + r["height"]) - 2,
                   int(r["left"]) + 2:int(r["left"] + r["width"]) - 2]
        assert crop.size and crop.std() > 5
    name = "relight_webrtc_frames_total" if transport == "webrtc" else "relight_frames_total"
    frames = [float(line.split()[-1]) for line in httpx.get(f"{server}/metrics").text.splitlines()
              if line.startswith(name)]
    assert frames and frames[0] >= PAGE_FRAMES


def test_bar_codes_survive_the_relight(small_bundle, live_clip, tmp_path):
    """The bar code sits outside the face: a relit frame keeps it (else round trips are not measured)."""
    import relight
    from relight.bench.browser import CODE_BITS, CODE_BLOCK
    from relight.engine.frame_path import FramePath
    from relight.engine.frame_settings import FrameSettings
    from relight.video_read import read_frames

    frames = list(read_frames(live_clip))[:8]
    y4m = barcoded_y4m(frames, tmp_path / "c.y4m")
    coded = list(read_frames(y4m))
    fp = FramePath(small_bundle, relight.load_environment("builtin:sunset"), FrameSettings(focal="ortho"))
    for i, f in enumerate(coded):
        out, info = fp.process(f, i / 30)
        mid = CODE_BLOCK // 2
        bits = [out[mid, b * CODE_BLOCK + mid].mean() > 128 for b in range(CODE_BITS + 2)]
        assert sum(int(v) << b for b, v in enumerate(bits[:CODE_BITS])) == i and bits[CODE_BITS:] == [True, False]
    assert info.face
    assert np.abs(out.astype(int) - coded[-1].astype(int)).max() > LIVE_CHANGED_CODES  # and the face was relit
