"""Who may drive a relight server (a real uvicorn server on loopback): a page on another site is
refused (cross-site websocket hijacking, cross-site requests, DNS rebinding), a token is required
beyond loopback and checked, and a burst of frames gets 503 + Retry-After instead of a queue."""

from __future__ import annotations

import asyncio
import os

import cv2
import pytest

httpx = pytest.importorskip("httpx", reason="httpx (a test extra) is the client")

from .serving import running_server  # noqa: E402 (after the skip)

TOKEN = "s3cret-token-for-the-tests-0123"


def _ws(base: str, **kw):
    from websockets.sync.client import connect

    return connect(base.replace("http://", "ws://") + "/v1/stream" + kw.pop("query", ""), open_timeout=10, **kw)


@pytest.fixture(scope="module")
def loopback(small_bundle):
    from relight.service.settings import ServeConfig

    with running_server(ServeConfig(bundle=small_bundle.path, allowed_origins=("https://friend.example",))) as base:
        yield base


@pytest.fixture(scope="module")
def tokened(small_bundle):
    from relight.service.settings import ServeConfig

    # As `relight-serve --host 0.0.0.0 --token T` would (the access rules of a network bind),
    # while the socket itself stays on loopback for the test.
    with running_server(ServeConfig(bundle=small_bundle.path, host="0.0.0.0", token=TOKEN)) as base:
        yield base


def test_a_page_on_another_site_cannot_drive_the_websocket(loopback):
    from websockets.exceptions import InvalidStatus

    port = loopback.rsplit(":", 1)[1]
    with pytest.raises(InvalidStatus) as info:
        with _ws(loopback, origin="http://evil.example"):
            pass
    assert info.value.response.status_code == 403
    for origin in (f"http://127.0.0.1:{port}", f"http://localhost:{port}", "https://friend.example", None):
        with _ws(loopback, origin=origin) as ws:  # its own page, an allowed origin, a non-browser client
            ws.send('{"stats": true}')
            assert "frames" in ws.recv(timeout=10)
    with pytest.raises(InvalidStatus):
        with _ws(loopback, origin="http://127.0.0.1:1"):  # another local server's page
            pass


def test_cross_site_requests_and_rebound_hosts_are_refused(loopback, frame):
    png = cv2.imencode(".png", cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))[1].tobytes()
    for headers in ({"origin": "http://evil.example"}, {"host": "evil.example:80"}, {"origin": "null"}):
        for method, path, kw in (("POST", "/v1/relight", {"content": png, "headers": {"content-type": "image/png"}}),
                                 ("POST", "/v1/webrtc/offer", {"json": {"sdp": "v=0", "type": "offer"}}),
                                 ("PUT", "/v1/environment?builtin=sunset", {}), ("GET", "/metrics", {})):
            kw = {**kw, "headers": {**kw.get("headers", {}), **headers}}
            r = httpx.request(method, loopback + path, timeout=30, **kw)
            assert r.status_code == 403, (headers, path, r.status_code)
            assert r.json()["kind"] in ("bad_origin", "bad_host") and "allow-origin" in r.json()["error"]
    r = httpx.post(loopback + "/v1/relight", content=png, headers={"content-type": "image/png"}, timeout=60)
    assert r.status_code == 200  # the same request without a foreign origin
    assert 'relight_errors_total{kind="bad_origin"}' in httpx.get(loopback + "/metrics").text


def test_a_network_bind_needs_the_token(tokened):
    from websockets.exceptions import InvalidStatus

    assert httpx.get(tokened + "/readyz").status_code == 200 and httpx.get(tokened + "/livez").status_code == 200
    for headers, params in (({}, {}), ({"authorization": "Bearer wrong-token-0123456789"}, {}),
                            ({}, {"token": TOKEN[:-1]}), ({"authorization": TOKEN}, {})):
        r = httpx.get(tokened + "/v1/environment", headers=headers, params=params)
        assert r.status_code == 401 and r.headers["www-authenticate"] == "Bearer", (headers, params)
    assert httpx.get(tokened + "/v1/environment", headers={"authorization": f"Bearer {TOKEN}"}).status_code == 200
    assert httpx.get(tokened + "/v1/environment", params={"token": TOKEN}).status_code == 200
    page = httpx.get(tokened + "/", params={"token": TOKEN})
    assert page.status_code == 200 and "token" in page.text  # the page passes its URL's token on
    with pytest.raises(InvalidStatus):
        with _ws(tokened):
            pass
    host = tokened.split("//")[1]
    with _ws(tokened, query=f"?token={TOKEN}", origin=f"http://{host}") as ws:  # its own page, with the token
        ws.send('{"stats": true}')
        assert "frames" in ws.recv(timeout=10)


def test_relight_serve_refuses_a_network_bind_without_a_token(small_bundle, capsys, monkeypatch):
    import uvicorn

    from relight.cli import serve_main

    def served(*args, **kwargs):  # a refusal that failed would serve here: fail, not hang
        raise AssertionError("relight-serve started serving")

    monkeypatch.setattr(uvicorn, "run", served)
    for name in [n for n in os.environ if n.startswith("RELIGHT")]:  # (no token from the environment)
        monkeypatch.delenv(name)
    for extra, says in ((["--host", "0.0.0.0"], "--token"), (["--host", "0.0.0.0", "--token", "short"], "16"),
                        (["--allow-origin", "evil.example"], "scheme://host")):
        try:
            code = serve_main([str(small_bundle.path), *extra])
        except SystemExit as e:
            code = e.code
        err = capsys.readouterr().err
        assert code == 2 and says in err, err


def test_a_burst_of_frames_gets_503_with_retry_after_not_a_queue(small_bundle, frame):
    from relight.service.settings import ServeConfig

    png = cv2.imencode(".png", cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))[1].tobytes()

    async def burst(base):
        async with httpx.AsyncClient(timeout=120) as client:
            return await asyncio.gather(*[client.post(base + "/v1/relight", content=png,
                                                      headers={"content-type": "image/png"}) for _ in range(8)])

    with running_server(ServeConfig(bundle=small_bundle.path, max_pending=2)) as base:
        res = asyncio.run(burst(base))
        codes = sorted(r.status_code for r in res)
        assert set(codes) == {200, 503} and codes.count(200) >= 2, codes
        busy = [r for r in res if r.status_code == 503]
        assert all(r.headers["retry-after"] and r.json()["kind"] == "busy" for r in busy)
        assert httpx.post(base + "/v1/relight", content=png, headers={"content-type": "image/png"},
                          timeout=60).status_code == 200  # served again once the burst is through
