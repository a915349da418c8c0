"""The frame service against a real uvicorn server on loopback."""

import json
import sys
import time

import cv2
import numpy as np
import pytest

httpx = pytest.importorskip("httpx", reason="httpx (a test extra) is the client")

from .serving import running_server  # noqa: E402 (after the skip: it needs httpx)

#: Requests the fuzzer generates per API operation (bounded: the suite stays fast).
FUZZ_EXAMPLES = 25


@pytest.fixture(scope="module")
def server(small_bundle):
    from relight.service.settings import ServeConfig

    with running_server(ServeConfig(bundle=small_bundle.path, env="builtin:studio", max_body=2_000_000,
                                    max_pixels=1_000_000)) as base:
        yield base



def _png(rgb):
    return cv2.imencode(".png", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))[1].tobytes()


def test_health_docs_and_metrics(server):
    assert httpx.get(f"{server}/livez").json()["status"] == "alive"
    assert httpx.get(f"{server}/readyz").json()["status"] == "ready"
    assert httpx.get(f"{server}/openapi.json").json()["paths"]["/v1/relight"]
    assert httpx.get(f"{server}/docs").status_code == 200
    page = httpx.get(f"{server}/")
    assert page.status_code == 200 and page.headers["content-type"].startswith("text/html")
    assert "/v1/stream" in page.text and "getUserMedia" in page.text
    from relight.engine.threads import LIVE_SWITCH_INTERVAL_S

    assert sys.getswitchinterval() <= LIVE_SWITCH_INTERVAL_S  # (set while the server runs: its streams' frames first)


def test_relight_a_png_and_a_jpeg_frame(server, frame):
    r = httpx.post(f"{server}/v1/relight?env=sunset&rotation=20,0,0&strength=0.9", content=_png(frame),
                   headers={"content-type": "image/png"}, timeout=30)
    assert r.status_code == 200 and r.headers["content-type"] == "image/png"
    assert r.headers["x-relight-face"] == "found" and "relight;dur=" in r.headers["server-timing"]
    light = json.loads(r.headers["x-relight-light"])  # transfer: the live light measured from the frame
    assert {"direction", "intensity", "colour", "residual", "status"} <= set(light) and light["intensity"] > 0
    out = cv2.cvtColor(cv2.imdecode(np.frombuffer(r.content, np.uint8), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
    assert out.shape == frame.shape and np.abs(out.astype(int) - frame.astype(int)).sum(axis=2).max() > 10
    jpg = cv2.imencode(".jpg", cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))[1].tobytes()
    r = httpx.post(f"{server}/v1/relight?mode=paste", content=jpg, headers={"content-type": "image/jpeg",
                                                                              "accept": "image/png"}, timeout=30)
    assert r.status_code == 200 and r.headers["content-type"] == "image/png"
    m = httpx.get(f"{server}/metrics").text
    assert "relight_frames_total" in m and "relight_frame_latency_seconds_bucket" in m


def test_a_key_light_is_an_environment_in_every_request(server, frame):
    """env=key:... (POST /v1/relight), builtin=key:... (PUT /v1/environment) and the stream's
    {"env": "key:..."} take a key light placed by hand: from the image's right it brightens the
    face's right half against a key from the left; a bad field is a 422 naming it."""
    from websockets.sync.client import connect

    from relight.colour import LUMINANCE, decode_srgb8

    halves = {}
    for az in (60, -60):
        r = httpx.post(f"{server}/v1/relight?env=key:az={az},el=10,fill=0", content=_png(frame),
                       headers={"content-type": "image/png"}, timeout=30)
        assert r.status_code == 200 and r.headers["x-relight-face"] == "found", r.text
        out = cv2.cvtColor(cv2.imdecode(np.frombuffer(r.content, np.uint8), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
        changed = (out != frame).any(axis=2)
        cols = np.nonzero(changed.any(axis=0))[0]
        right = np.arange(frame.shape[1])[None, :] > (cols.min() + cols.max()) / 2
        lum = decode_srgb8(out) @ LUMINANCE
        halves[az] = lum[changed & right].mean() / lum[changed & ~right].mean()
    assert halves[60] > 1.2 * halves[-60], halves
    r = httpx.post(f"{server}/v1/relight?env=key:az=500", content=_png(frame), headers={"content-type": "image/png"},
                   timeout=30)
    assert r.status_code == 422 and r.json()["kind"] == "bad_query" and "az" in r.json()["error"]
    for az in (60, -60):  # the page's lit balls: the grey ball's bright side is the key's
        r = httpx.get(f"{server}/v1/environment/light.png?env=key:az={az},fill=0", timeout=30)
        assert r.status_code == 200 and r.headers["content-type"] == "image/png"
        balls = cv2.imdecode(np.frombuffer(r.content, np.uint8), cv2.IMREAD_GRAYSCALE).astype(float)
        h, w = balls.shape
        assert w == 2 * h
        grey = balls[:, : w // 2]
        brighter_right = grey[:, h // 2:].mean() > grey[:, : h // 2].mean() + 20
        assert brighter_right == (az > 0), az
    assert httpx.get(f"{server}/v1/environment/light.png?env=key:az=999").status_code == 422
    assert httpx.get(f"{server}/v1/environment/light.png").status_code == 200  # the current one
    assert "/v1/environment/light.png" in httpx.get(f"{server}/").text  # the page shows and drags it
    r = httpx.put(f"{server}/v1/environment?builtin=key:kelvin=3000,az=-40")
    assert r.status_code == 200 and r.json()["current"].startswith("builtin:key:az=-40,el=25,")
    assert httpx.put(f"{server}/v1/environment?builtin=key:kelvin=99").status_code == 422
    httpx.put(f"{server}/v1/environment?builtin=studio")
    with connect(server.replace("http://", "ws://") + "/v1/stream", open_timeout=10) as ws:
        ws.send(json.dumps({"env": "key:az=30,power=2"}))
        ws.send(json.dumps({"env": "key:power=-1"}))
        doc = json.loads(ws.recv(timeout=30))
        assert doc["kind"] == "bad_control" and "power" in doc["error"], doc
        ws.send(json.dumps({"spin": 30}))  # the environment spun, degrees per second: accepted
        ws.send(json.dumps({"spin": 1e4}))
        doc = json.loads(ws.recv(timeout=30))
        assert doc["kind"] == "bad_control" and "spin" in doc["error"], doc
        ws.send(_png(frame))
        while not isinstance(msg := ws.recv(timeout=30), bytes):  # a spinning stream relights
            assert "error" not in json.loads(msg), msg


def test_each_request_is_relit_as_a_first_frame(server, frame):
    """POST /v1/relight keeps nothing of one caller's frames for the next (a track, filters and
    a live light of its own each time): the same frame after another caller's moved frame comes
    back as it did the first time."""
    def post(img):
        r = httpx.post(f"{server}/v1/relight?env=sunset", content=_png(img), headers={"content-type": "image/png"},
                       timeout=30)
        assert r.status_code == 200 and r.headers["x-relight-face"] == "found"
        return r.content

    first = post(frame)
    moved = np.ascontiguousarray(np.roll(frame, (6, -9), axis=(0, 1)))
    post(moved)  # another caller's frame: its face elsewhere, its own light
    assert post(frame) == first


def test_a_named_session_keeps_its_track_between_requests(server, frame):
    """POST /v1/relight with a session id (header or query) goes on from that client's last frame:
    the session counts its frames, another name starts its own, none is relit on its own as ever,
    and a malformed id is refused (422)."""
    def post(img, **kw):
        r = httpx.post(f"{server}/v1/relight?env=sunset", content=_png(img), timeout=30,
                       headers={"content-type": "image/png", **kw.get("headers", {})}, params=kw.get("params"))
        assert r.status_code == 200 and r.headers["x-relight-face"] == "found", r.text
        return r

    first = post(frame, headers={"X-Relight-Session": "alice"})
    assert first.headers["x-relight-session"] == "alice" and first.headers["x-relight-session-frames"] == "1"
    moved = np.ascontiguousarray(np.roll(frame, (2, -3), axis=(0, 1)))
    again = post(moved, params={"session": "alice"})
    assert again.headers["x-relight-session-frames"] == "2"  # the same session, by the query this time
    assert post(frame, headers={"X-Relight-Session": "bob"}).headers["x-relight-session-frames"] == "1"
    assert "x-relight-session" not in post(frame).headers
    r = httpx.post(f"{server}/v1/relight", content=_png(frame), timeout=30,
                   headers={"content-type": "image/png", "X-Relight-Session": "no spaces/allowed"})
    assert r.status_code == 422 and "session" in r.text


def test_a_frame_without_a_face_comes_back_unchanged(server, frame):
    blank = np.full_like(frame, 120)
    r = httpx.post(f"{server}/v1/relight", content=_png(blank), headers={"content-type": "image/png"}, timeout=30)
    assert r.status_code == 200 and r.headers["x-relight-face"] == "none"
    out = cv2.imdecode(np.frombuffer(r.content, np.uint8), cv2.IMREAD_COLOR)
    assert np.array_equal(cv2.cvtColor(out, cv2.COLOR_BGR2RGB), blank)


def test_bad_requests_get_clear_errors_and_the_server_stays_ready(server, frame):
    png = _png(frame)
    cases = [
        (dict(content=png, headers={"content-type": "text/plain"}), 415, "content_type"),
        (dict(content=png[: len(png) // 2], headers={"content-type": "image/png"}), 400, "undecodable"),
        (dict(content=b"\x00" * 100, headers={"content-type": "image/png"}), 400, "undecodable"),
        (dict(content=b"\x00" * 2_100_000, headers={"content-type": "image/png"}), 413, "too_large"),
        (dict(content=_png(np.zeros((1200, 1000, 3), np.uint8)), headers={"content-type": "image/png"}), 413,
         "too_many_pixels"),
    ]
    for kwargs, status, kind in cases:
        r = httpx.post(f"{server}/v1/relight", timeout=30, **kwargs)
        assert r.status_code == status, (kind, r.text)
        assert r.json()["kind"] == kind and r.json()["error"]
    for query in ("env=mars", "rotation=1,2", "strength=2", "mode=glow", "exposure=nan"):
        r = httpx.post(f"{server}/v1/relight?{query}", content=png, headers={"content-type": "image/png"}, timeout=30)
        assert r.status_code == 422, (query, r.text)
    assert httpx.get(f"{server}/readyz").status_code == 200
    m = httpx.get(f"{server}/metrics").text
    assert 'relight_errors_total{kind="too_large"}' in m and 'relight_errors_total{kind="undecodable"}' in m


def test_stream_relights_latest_frames_and_takes_controls(server, frame):
    import json

    from websockets.sync.client import connect

    url = server.replace("http://", "ws://") + "/v1/stream"
    png = _png(frame)
    with connect(url, max_size=None, open_timeout=10) as ws:
        ws.send(json.dumps({"env": "window", "strength": 0.7}))
        ws.send(json.dumps({"tag": 7}))  # echoed with this frame's result (round-trip timing)
        ws.send(png)
        first = None
        while first is None:
            msg = ws.recv(timeout=30)
            if isinstance(msg, str) and "latency_ms" in json.loads(msg):
                first = json.loads(msg)
        assert first["tag"] == 7
        for _ in range(4):  # a burst: the stale ones are dropped, not queued
            ws.send(png)
        got_frame, stats = None, None
        deadline = time.time() + 30
        while time.time() < deadline and (got_frame is None or stats is None):
            msg = ws.recv(timeout=30)
            if isinstance(msg, bytes):
                got_frame = msg
            else:
                doc = json.loads(msg)
                if "latency_ms" in doc:
                    stats = doc
        assert got_frame is not None and stats is not None and stats["face"]
        assert stats["light"]["status"] in ("ok", "dark", "clipped") and len(stats["light"]["direction"]) == 3
        ws.send(json.dumps({"mode": "ambient"}))
        ws.send(json.dumps({"mode": "glow"}))
        while True:
            msg = ws.recv(timeout=30)
            if isinstance(msg, bytes):  # a relit frame of the burst still on its way (its steps overlap)
                continue
            doc = json.loads(msg)
            if doc.get("kind") == "bad_control":
                assert "ambient" in doc["error"]
                break
        out = cv2.imdecode(np.frombuffer(got_frame, np.uint8), cv2.IMREAD_COLOR)
        assert out.shape == frame.shape
        try:  # let the burst finish: every frame is either relit or dropped
            while True:
                ws.recv(timeout=3)
        except TimeoutError:
            pass
        ws.send(json.dumps({"stats": True}))
        seen = None
        while seen is None:
            msg = ws.recv(timeout=30)
            if isinstance(msg, str) and "frames" in json.loads(msg) and "latency_ms" not in json.loads(msg):
                seen = json.loads(msg)
        assert seen["frames"] + seen["dropped"] == 5 and seen["frames"] >= 2
        ws.send(json.dumps({"env": "mars"}))
        while True:
            msg = ws.recv(timeout=30)
            if isinstance(msg, str) and "error" in json.loads(msg):
                assert json.loads(msg)["kind"] == "bad_control"
                break
    assert httpx.get(f"{server}/readyz").status_code == 200


def test_a_streams_frames_come_back_in_order_through_its_overlapping_steps(server, frame):
    """A client's frames are decoded, relit and encoded at once (the next decoded while one is
    relit, the last encoded meanwhile): what comes back is in the order sent, a broken frame in
    the middle gets its error and the frames after it go on, and every frame is relit or dropped."""
    import json

    from websockets.sync.client import connect

    url = server.replace("http://", "ws://") + "/v1/stream"
    png = _png(frame)
    sent, tags, errors = 12, [], []

    def read(until_error: bool) -> None:
        try:
            while True:
                msg = ws.recv(timeout=5)
                if isinstance(msg, str):
                    doc = json.loads(msg)
                    if "tag" in doc:
                        tags.append(doc["tag"])
                    elif "error" in doc:
                        errors.append(doc["kind"])
                        if until_error:
                            return
        except TimeoutError:
            pass

    with connect(url, max_size=None, open_timeout=10) as ws:
        for k in range(sent):
            ws.send(json.dumps({"tag": k}))
            ws.send(png if k != 5 else b"\x89PNG" + b"\x00" * 64)
            if k == 5:
                read(until_error=True)  # (its error, before a newer frame could replace it)
            time.sleep(1 / 30)
        read(until_error=False)
        ws.send(json.dumps({"stats": True}))
        doc = json.loads(ws.recv(timeout=30))
    assert tags == sorted(tags) and len(set(tags)) == len(tags) and tags[-1] == sent - 1, tags
    assert 5 not in tags and errors == ["undecodable"]
    assert doc["frames"] == len(tags) and doc["frames"] + doc["dropped"] + 1 == sent
    assert httpx.get(f"{server}/readyz").status_code == 200


def test_stream_limits_clients_and_message_size(server, frame):
    from contextlib import ExitStack

    from websockets.exceptions import ConnectionClosed
    from websockets.sync.client import connect

    url = server.replace("http://", "ws://") + "/v1/stream"
    with ExitStack() as stack:
        for _ in range(4):
            stack.enter_context(connect(url, open_timeout=10))
        time.sleep(0.3)
        with connect(url, open_timeout=10) as extra:
            with pytest.raises(ConnectionClosed) as info:
                extra.recv(timeout=10)
            assert info.value.rcvd.code == 1013
    # The four slots come free once their handlers end (each made its own per-frame path first).
    deadline = time.time() + 30
    while time.time() < deadline and "relight_clients 0.0" not in httpx.get(f"{server}/metrics").text:
        time.sleep(0.1)
    with connect(url, max_size=None, open_timeout=10) as ws:
        ws.send(b"\x89PNG" + b"\x00" * 2_100_000)
        with pytest.raises(ConnectionClosed) as info:
            ws.recv(timeout=10)
        assert info.value.rcvd.code == 1009
    m = httpx.get(f"{server}/metrics").text
    assert 'relight_errors_total{kind="too_many_clients"}' in m and "relight_clients" in m


def test_environment_endpoints_choose_upload_validate_and_preview(server, frame, tmp_path):
    from websockets.sync.client import connect

    from relight import load_environment
    from relight.colour import encode_srgb8
    from relight.imageio import write_image

    doc = httpx.get(f"{server}/v1/environment").json()
    assert "sunset" in doc["builtins"] and doc["current"] == "builtin:studio"
    r = httpx.put(f"{server}/v1/environment?builtin=sunset&rotation=30,0,0&exposure=0.5")
    assert r.status_code == 200 and r.json()["current"] == "builtin:sunset" and r.json()["rotation"] == [30, 0, 0]
    env = load_environment("builtin:window", width=128)
    write_image(tmp_path / "env.exr", env)
    r = httpx.put(f"{server}/v1/environment", content=(tmp_path / "env.exr").read_bytes(),
                  headers={"content-type": "image/x-exr"}, timeout=30)
    assert r.status_code == 200 and r.json()["current"] == "uploaded.exr"
    p = httpx.get(f"{server}/v1/environment/preview.png")
    assert p.status_code == 200 and p.headers["content-type"] == "image/png"
    prev = cv2.imdecode(np.frombuffer(p.content, np.uint8), cv2.IMREAD_COLOR)
    assert prev.shape[1] == 2 * prev.shape[0] and prev.shape[0] <= 256
    r = httpx.post(f"{server}/v1/relight", content=_png(frame), headers={"content-type": "image/png"}, timeout=30)
    assert r.status_code == 200 and r.headers["x-relight-face"] == "found"  # relit under the uploaded map
    bad = env.copy()
    bad[3, 4, 1] = np.nan
    import OpenImageIO as oiio  # written directly: relight's own writer refuses non-finite images

    out = oiio.ImageOutput.create(str(tmp_path / "bad.exr"))
    out.open(str(tmp_path / "bad.exr"), oiio.ImageSpec(bad.shape[1], bad.shape[0], 3, "float"))
    out.write_image(bad)
    out.close()
    square = np.ones((64, 64, 3), np.float32)
    write_image(tmp_path / "square.exr", square)
    for path, kind in ((tmp_path / "bad.exr", "bad_environment"), (tmp_path / "square.exr", "bad_environment")):
        r = httpx.put(f"{server}/v1/environment", content=path.read_bytes(), headers={"content-type": "image/x-exr"},
                      timeout=30)
        assert r.status_code == 400 and r.json()["kind"] == kind, r.text
    r = httpx.put(f"{server}/v1/environment", content=b"hello", headers={"content-type": "text/plain"})
    assert r.status_code == 415
    r = httpx.put(f"{server}/v1/environment", content=b"\x00" * 1000, headers={"content-type": "image/x-exr"})
    assert r.status_code == 400
    assert httpx.get(f"{server}/v1/environment").json()["current"] == "uploaded.exr"  # the bad ones changed nothing
    # JPEG: a 2:1 lat-long map as it is; any picture with ?photo=true (a square one too)
    jpg = cv2.imencode(".jpg", cv2.cvtColor(encode_srgb8(np.clip(env, 0, 1)), cv2.COLOR_RGB2BGR))[1].tobytes()
    r = httpx.put(f"{server}/v1/environment", content=jpg, headers={"content-type": "image/jpeg"}, timeout=30)
    assert r.status_code == 200 and r.json()["current"] == "uploaded.jpg", r.text
    photo = np.full((90, 120, 3), 40, np.uint8)
    photo[:, :60] = 230  # bright on its left
    square = cv2.imencode(".jpg", photo[:, :90])[1].tobytes()
    r = httpx.put(f"{server}/v1/environment", content=square, headers={"content-type": "image/jpeg"}, timeout=30)
    assert r.status_code == 400 and r.json()["kind"] == "bad_environment"  # not a map
    r = httpx.put(f"{server}/v1/environment?photo=true", content=cv2.imencode(".jpg", photo)[1].tobytes(),
                  headers={"content-type": "image/jpeg"}, timeout=30)
    assert r.status_code == 200 and r.json()["current"] == "photo.jpg", r.text
    prev = cv2.imdecode(np.frombuffer(httpx.get(f"{server}/v1/environment/preview.png").content, np.uint8),
                        cv2.IMREAD_GRAYSCALE).astype(float)
    h, w = prev.shape
    # lit from the image's left, -X: the map's third quarter (its quarter width is +X)
    assert prev[:, 5 * w // 8: 7 * w // 8].mean() > prev[:, w // 8: 3 * w // 8].mean() + 20
    with connect(server.replace("http://", "ws://") + "/v1/stream", open_timeout=10) as ws:
        ws.send(json.dumps({"env": "sunset"}))
        ws.send(json.dumps({"env": "current"}))  # back to the service's own: the photo
        ws.send(_png(frame))
        while not isinstance(msg := ws.recv(timeout=30), bytes):
            assert "error" not in json.loads(msg), msg
    assert "/v1/environment?photo=" in httpx.get(f"{server}/").text  # the page uploads photos
    r = httpx.put(f"{server}/v1/environment?photo=true", content=square[: len(square) // 3],
                  headers={"content-type": "image/jpeg"}, timeout=30)
    assert r.status_code == 400 and r.json()["kind"] == "bad_environment"
    httpx.put(f"{server}/v1/environment?builtin=studio&rotation=0,0,0&exposure=0")


@pytest.mark.slow  # ~17 s of generated requests: `make test-slow`, CI (bench fuzz covers the readers)
def test_fuzzing_the_http_api_from_its_openapi_schema_never_gets_a_server_error(server):
    schemathesis = pytest.importorskip("schemathesis", reason="schemathesis (a test extra) is the fuzzer")
    from hypothesis import HealthCheck, given, settings

    schema = schemathesis.openapi.from_url(f"{server}/openapi.json")
    operations = [r.ok() for r in schema.get_all_operations()]
    assert {f"{o.method.upper()} {o.path}" for o in operations} >= {"POST /v1/relight", "PUT /v1/environment"}
    for op in operations:
        @settings(max_examples=FUZZ_EXAMPLES, deadline=None, derandomize=True, database=None,
                  suppress_health_check=list(HealthCheck))
        @given(case=op.as_strategy())
        def check(case):
            response = case.call(base_url=server, timeout=30)
            assert response.status_code < 500, (case.method, case.path, response.status_code, response.text[:300])

        check()
    assert httpx.get(f"{server}/readyz").status_code == 200
    httpx.put(f"{server}/v1/environment?builtin=studio&rotation=0,0,0&exposure=0")


def test_vanished_and_silent_stream_clients_hold_nothing(server, frame):
    from websockets.sync.client import connect

    url = server.replace("http://", "ws://") + "/v1/stream"
    png = _png(frame)

    def clients() -> float:
        return next(float(line.split()[-1]) for line in httpx.get(f"{server}/metrics").text.splitlines()
                    if line.startswith("relight_clients "))

    with connect(url, open_timeout=10) as ws:  # a client that sends and never reads, then vanishes
        for _ in range(3):
            ws.send(png)
        ws.socket.close()  # no close handshake: the network just goes away
    deadline = time.time() + 20
    while clients() > 0 and time.time() < deadline:
        time.sleep(0.2)
    assert clients() == 0
    r = httpx.post(f"{server}/v1/relight", content=png, headers={"content-type": "image/png"}, timeout=30)
    assert r.status_code == 200 and httpx.get(f"{server}/readyz").status_code == 200


def test_make_serve_prints_the_page_url_and_serves(small_bundle, tmp_path):
    """`make serve` (on any bundle via DEMO_BUNDLE): ready, the page's URL printed; a broken
    bundle stops relight-serve with a one-line error, not a server traceback."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    from relight.bench.server import wait_ready

    from .serving import free_port

    root = Path(__file__).resolve().parents[1]
    port = free_port()
    env = dict(os.environ, RELIGHT_LOG_LEVEL="warning")
    stamp = tmp_path / "installed"  # the venv this test runs in counts as installed
    stamp.touch()
    proc = subprocess.Popen(["make", "--no-print-directory", "-C", str(root), "serve", f"PORT={port}",
                             f"DEMO_BUNDLE={small_bundle.path}", f"BIN={Path(sys.executable).parent}",
                             f"STAMP={stamp}"],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            start_new_session=True)
    try:
        lines = []
        deadline = time.time() + 60
        while time.time() < deadline and not any("open http" in ln for ln in lines):
            line = proc.stdout.readline()
            assert line, "make serve ended early:\n" + "".join(lines)
            lines.append(line)
        assert any(f"open http://127.0.0.1:{port}/ " in ln for ln in lines), lines
        assert wait_ready(f"http://127.0.0.1:{port}", 10)
        assert httpx.get(f"http://127.0.0.1:{port}/").status_code == 200
    finally:
        os.killpg(proc.pid, 15)
        proc.wait(timeout=20)
        proc.stdout.close()

    broken = tmp_path / "broken.bundle"
    broken.write_bytes(small_bundle.path.read_bytes()[:5000])
    run = subprocess.run([str(Path(sys.executable).parent / "relight-serve"), str(broken)],
                         capture_output=True, text=True, timeout=60)
    assert run.returncode == 2 and "Traceback" not in run.stderr
    assert run.stderr.strip().startswith("relight-serve: error:") and "truncated" in run.stderr


def test_settings_come_through_one_dependency_tests_can_override(small_bundle, frame):
    """The routes read the settings through ``get_settings`` (FastAPI's dependency): overriding
    it changes the limits of the HTTP routes and the websocket alike."""
    from websockets.exceptions import ConnectionClosed
    from websockets.sync.client import connect

    from relight.service.settings import ServeConfig, get_settings

    from .serving import running_server

    png = cv2.imencode(".png", np.ascontiguousarray(frame[..., ::-1]))[1].tobytes()
    assert len(png) > 1000
    tight = ServeConfig(bundle=small_bundle.path, max_body=1000)
    with running_server(ServeConfig(bundle=small_bundle.path), {get_settings: lambda: tight}) as base:
        r = httpx.post(f"{base}/v1/relight", content=png, headers={"content-type": "image/png"})
        assert r.status_code == 413 and r.json()["kind"] == "too_large"
        with connect(base.replace("http://", "ws://") + "/v1/stream", open_timeout=10) as ws:
            ws.send(png)
            with pytest.raises(ConnectionClosed) as info:
                ws.recv(timeout=10)
            assert info.value.rcvd.code == 1009  # over the overridden 1000 bytes
