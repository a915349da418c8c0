"""``POST /v1/webrtc/offer`` with a real WebRTC peer (aiortc, the same library a Python client
would use) against a real uvicorn server on loopback: the live clip's frames go out as a video
track, relit frames come back with their timestamps, controls work over the data channel, and
the limits hold (client cap -> 503 + Retry-After, bad offers -> 4xx, a vanished peer is freed)."""

from __future__ import annotations

import asyncio
import json
import time

import numpy as np
import pytest

httpx = pytest.importorskip("httpx", reason="httpx (a test extra) is the client")
aiortc = pytest.importorskip("aiortc", reason="aiortc is a dependency of the service")

from .serving import running_server  # noqa: E402 (after the skips)
from .tolerances import LIVE_CHANGED_CODES, LIVE_CHANGED_SHARE  # noqa: E402

#: Relit frames the peer must receive, and how long it may take (s).
PEER_FRAMES = 20
PEER_TIMEOUT = 60


class ClipTrack(aiortc.MediaStreamTrack):
    """The live clip's frames as a camera track at 30 fps (looped), with 90 kHz timestamps."""

    kind = "video"

    def __init__(self, frames):
        super().__init__()
        self.frames, self.i, self.t0 = frames, 0, None

    async def recv(self):
        from fractions import Fraction

        from av import VideoFrame

        if self.t0 is None:
            self.t0 = time.perf_counter()
        wait = self.t0 + self.i / 30 - time.perf_counter()
        if wait > 0:
            await asyncio.sleep(wait)
        f = VideoFrame.from_ndarray(self.frames[self.i % len(self.frames)], format="rgb24")
        f.pts, f.time_base = self.i * 3000, Fraction(1, 90000)
        self.i += 1
        return f


async def _peer(base, frames, *, controls=None, count=PEER_FRAMES):
    """Connect, collect ``count`` relit frames and the data channel's messages; returns them."""
    pc = aiortc.RTCPeerConnection(aiortc.RTCConfiguration(iceServers=[]))
    channel = pc.createDataChannel("controls")
    got, docs = [], []
    done = asyncio.Event()
    channel.on("message", lambda m: docs.append(json.loads(m)))

    @channel.on("open")
    def _open():
        for c in controls or []:
            channel.send(json.dumps(c))

    @pc.on("track")
    def on_track(track):
        async def read():
            while len(got) < count:
                got.append(await track.recv())
            done.set()
        asyncio.ensure_future(read())

    pc.addTransceiver(ClipTrack(frames), direction="sendrecv")
    await pc.setLocalDescription(await pc.createOffer())
    async with httpx.AsyncClient() as client:
        r = await client.post(f"{base}/v1/webrtc/offer", json={"sdp": pc.localDescription.sdp, "type": "offer"},
                              timeout=60)
    assert r.status_code == 200, r.text
    ans = r.json()
    await pc.setRemoteDescription(aiortc.RTCSessionDescription(sdp=ans["sdp"], type=ans["type"]))
    try:
        await asyncio.wait_for(done.wait(), PEER_TIMEOUT)
    finally:
        await pc.close()
    return got, docs, ans


@pytest.fixture(scope="module")
def server(small_bundle):
    from relight.service.settings import ServeConfig

    with running_server(ServeConfig(bundle=small_bundle.path, focal="ortho", max_clients=1,
                                    idle_timeout=3.0)) as base:
        yield base


@pytest.fixture(scope="module")
def clip_frames(live_clip):
    from relight.video_read import read_frames

    return list(read_frames(live_clip))


def _metric(base, name):
    for line in httpx.get(f"{base}/metrics").text.splitlines():
        if line.startswith(name + " ") or line.startswith(name + "{"):
            return float(line.split()[-1])
    return None


def test_webrtc_peer_gets_relit_frames_with_their_timestamps(server, clip_frames):
    got, docs, ans = asyncio.run(_peer(server, clip_frames, controls=[{"env": "sunset"}, {"strength": 7}]))
    assert len(got) == PEER_FRAMES and ans["type"] == "answer" and ans["session"]
    pts = [f.pts for f in got]
    assert pts == sorted(pts) and len(set(pts)) == len(pts)  # the relit track runs forward in time
    stats = [d for d in docs if "latency_ms" in d]
    assert stats and all(d["latency_ms"] > 0 for d in stats)
    # Each relit frame names the camera frame it came from: the sender's 90 kHz timestamps (a
    # multiple of 3000 for 30 fps, within the RTP clock's rounding).
    assert all(min(d["pts"] % 3000, 3000 - d["pts"] % 3000) <= 2 for d in stats)
    assert any(d.get("face") for d in stats)
    assert any(d.get("kind") == "bad_control" and "strength" in d["error"] for d in docs)  # told, not dropped
    # Relit: a received frame is none of the clip's frames (sunset replaced the clip's light).
    last = got[-1].to_ndarray(format="rgb24").astype(int)
    changed = min((np.abs(last - f.astype(int)).max(axis=2) > LIVE_CHANGED_CODES).mean() for f in clip_frames)
    assert changed > LIVE_CHANGED_SHARE
    assert _metric(server, "relight_webrtc_frames_total") >= len(stats)
    deadline = time.time() + 10  # the closed peer frees its session
    while _metric(server, "relight_webrtc_sessions") and time.time() < deadline:
        time.sleep(0.2)
    assert _metric(server, "relight_webrtc_sessions") == 0
    assert _metric(server, "relight_clients") == 0


def test_client_cap_answers_503_with_retry_after_and_bad_offers_4xx(server, clip_frames):
    async def run():
        pc = aiortc.RTCPeerConnection(aiortc.RTCConfiguration(iceServers=[]))
        pc.addTransceiver(ClipTrack(clip_frames), direction="sendrecv")
        await pc.setLocalDescription(await pc.createOffer())
        async with httpx.AsyncClient() as client:
            first = await client.post(f"{server}/v1/webrtc/offer", json={"sdp": pc.localDescription.sdp,
                                                                         "type": "offer"}, timeout=60)
            second = await client.post(f"{server}/v1/webrtc/offer", json={"sdp": pc.localDescription.sdp,
                                                                          "type": "offer"}, timeout=60)
        # This peer never completes the connection (no answer applied): it vanished. The idle
        # timeout (3 s here) must free its slot.
        await pc.close()
        return first, second

    first, second = asyncio.run(run())
    assert first.status_code == 200
    assert second.status_code == 503 and second.headers["retry-after"] and "at most 1" in second.json()["error"]
    deadline = time.time() + 15
    while _metric(server, "relight_webrtc_sessions") and time.time() < deadline:
        time.sleep(0.25)
    assert _metric(server, "relight_webrtc_sessions") == 0 and _metric(server, "relight_clients") == 0
    text = httpx.get(f"{server}/metrics").text
    assert 'relight_webrtc_sessions_closed_total{reason="idle_timeout"}' in text
    for body, status in ((b"not json", 422), (json.dumps({"sdp": "v=0", "type": "answer"}).encode(), 422),
                         (json.dumps({"sdp": "v=0\r\n", "type": "offer"}).encode(), 422),
                         (json.dumps({"sdp": "x" * 70_000, "type": "offer"}).encode(), 413),
                         (json.dumps({"sdp": "v=0\r\nm=video 9 UDP/TLS/RTP/SAVPF 96\r\n", "type": "offer"}).encode(),
                          422)):
        r = httpx.post(f"{server}/v1/webrtc/offer", content=body, headers={"content-type": "application/json"})
        assert r.status_code == status, (body[:60], r.status_code, r.text)
        assert "error" in r.json()
    assert httpx.get(f"{server}/readyz").status_code == 200  # still serving
    assert _metric(server, "relight_clients") == 0
