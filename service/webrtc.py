"""WebRTC sessions (aiortc): a browser's camera track in, the relit track back, controls over a
data channel.

``POST /v1/webrtc/offer`` takes the browser's SDP offer and answers it
(:func:`WebRTCSessions.answer`). The browser's video track is read continuously into a one-frame
slot (latest frame wins: a frame the relight had no time for is replaced and counted as
dropped); the track sent back (:func:`relit_track`) relights the newest frame each time the
encoder asks for one, keeping the frame's timestamp. A data channel carries the same JSON
controls as the websocket (:mod:`relight.service.controls`) one way and, after each relit frame,
``{"frame", "latency_ms", "dropped", "face", "pts"}`` the other.

Limits as for the websocket: the stream clients' cap (websockets and WebRTC sessions together),
a session timeout, an idle timeout (no frame for ``idle_timeout`` seconds: the peer vanished),
and a failed or closed connection frees everything (peer connection, tracks, per-frame path).
No STUN or TURN by default (a local service: host candidates reach the browser on this machine
or network; ``relight-serve --ice-server`` adds some).

Units: frames are 8-bit sRGB; the relit frame keeps the received frame's ``pts``/``time_base``.
"""

from __future__ import annotations

import asyncio
import json
import time
import uuid

from relight.errors import RelightError

from ..engine.frame_slot import NewestSlot
from .controls import apply_control, new_settings, parse_control
from .errors import ServiceError

#: Largest SDP offer read (bytes); a browser's is 3-8 KB.
MAX_SDP = 64 * 1024


def _aiortc():
    try:
        import aiortc
    except ImportError:  # pragma: no cover - a dependency of the package
        raise ServiceError(501, "no_webrtc", "this service has no WebRTC (aiortc is not installed)") from None
    return aiortc


def relit_track(source, session: WebRTCSession):
    """A MediaStreamTrack that relights the newest frame of ``source`` for each frame asked of it."""
    from aiortc import MediaStreamTrack
    from aiortc.mediastreams import MediaStreamError

    class RelitTrack(MediaStreamTrack):
        kind = "video"

        def __init__(self):
            super().__init__()
            self._latest = NewestSlot()  # (frame, time it arrived)
            self._fresh = asyncio.Event()
            self._ended = False
            self._pump = asyncio.ensure_future(self._read())

        async def _read(self):
            try:
                while True:
                    frame = await source.recv()
                    session.frames_in += 1
                    session.last_frame = time.monotonic()
                    if self._latest.put((frame, time.perf_counter())):
                        session.dropped += 1
                        session.metrics.dropped.inc()
                    self._fresh.set()
            except (MediaStreamError, asyncio.CancelledError):
                pass
            finally:
                self._ended = True
                self._fresh.set()

        async def recv(self):
            from av import VideoFrame

            while (item := self._latest.take()) is None:
                if self._ended or self.readyState != "live":
                    raise MediaStreamError
                await self._fresh.wait()
                self._fresh.clear()
            frame, t_in = item
            return await session.relight(frame, t_in, VideoFrame)

        def stop(self):
            super().stop()
            self._pump.cancel()

    return RelitTrack()


class WebRTCSession:
    """One peer: its connection, per-frame path (:class:`~relight.service.state.Session`),
    settings and counters."""

    def __init__(self, manager: WebRTCSessions, pc, engine, path_session):
        self.id = uuid.uuid4().hex[:12]
        self.manager = manager
        self.pc = pc
        self.engine = engine
        self.path_session = path_session
        self.metrics = manager.metrics
        self.settings = new_settings()
        self.channel = None
        self.frames_in = self.frames_out = self.dropped = 0
        self.started = self.last_frame = time.monotonic()
        self.closed = False
        self.tracks: list = []

    def control(self, message) -> None:
        """A data channel message: controls (or ``{"stats": true}``); errors go back on the channel."""
        try:
            doc = parse_control(message)
            if isinstance(doc, dict) and doc.get("stats"):
                self.send({"frames": self.frames_out, "dropped": self.dropped, "frames_in": self.frames_in})
                return
            apply_control(self.settings, doc)
        except (ValueError, ServiceError) as exc:
            self.metrics.errors.labels(kind="bad_control").inc()
            self.send({"error": str(exc), "kind": "bad_control"})

    def send(self, doc: dict) -> None:
        ch = self.channel
        if ch is not None and ch.readyState == "open":
            try:
                ch.send(json.dumps(doc))
            except Exception:  # a channel closing under us: the session's close frees it
                pass

    async def relight(self, frame, t_in: float, video_frame_cls):
        """The relit frame of a received one (same pts); the frame itself when relighting fails."""
        engine = self.engine
        rgb = await asyncio.to_thread(frame.to_ndarray, format="rgb24")
        try:
            out, info = await engine.relight_frame(rgb, session=self.path_session, **self.settings)
        except RelightError as exc:
            self.metrics.errors.labels(kind="bad_frame").inc()
            self.send({"error": str(exc), "kind": "bad_frame"})
            return frame
        new = await asyncio.to_thread(video_frame_cls.from_ndarray, out, format="rgb24")
        new.pts, new.time_base = frame.pts, frame.time_base
        latency = time.perf_counter() - t_in
        self.frames_out += 1
        self.metrics.frames.inc()
        self.metrics.webrtc_frames.inc()
        self.metrics.latency.observe(latency)
        self.send({"frame": self.frames_out, "latency_ms": round(latency * 1e3, 2), "dropped": self.dropped,
                   "face": info.face, "pts": frame.pts})
        return new

    async def close(self, why: str = "closed") -> None:
        if self.closed:
            return
        self.closed = True
        for t in self.tracks:
            t.stop()
        await self.pc.close()
        self.manager.forget(self, why)


class WebRTCSessions:
    """The app's WebRTC sessions (on ``app.state.webrtc``): made by :meth:`answer`, watched for
    timeouts, all closed at shutdown."""

    def __init__(self, state, metrics, config):
        self.state, self.metrics, self.config = state, metrics, config
        self.sessions: dict[str, WebRTCSession] = {}
        self._watch = None

    async def answer(self, offer: dict) -> dict:
        """The SDP answer to a browser's offer ``{"sdp": ..., "type": "offer"}`` (raises ServiceError)."""
        aiortc = _aiortc()
        if not isinstance(offer, dict) or offer.get("type") != "offer" or not isinstance(offer.get("sdp"), str):
            raise ServiceError(422, "bad_offer", 'send {"sdp": "<the offer>", "type": "offer"}')
        if len(offer["sdp"]) > MAX_SDP:
            raise ServiceError(413, "too_large", f"SDP offers are at most {MAX_SDP} bytes")
        if "m=video" not in offer["sdp"]:
            raise ServiceError(422, "bad_offer", "the offer has no video: add the camera's track (sendrecv)")
        engine = self.state.frame_service
        if engine is None:
            raise ServiceError(503, "not_ready", "the service is still loading its bundle; retry shortly")
        if self.state.clients >= self.config.max_clients:
            self.metrics.errors.labels(kind="too_many_clients").inc()
            raise ServiceError(503, "too_many_clients", f"at most {self.config.max_clients} clients; try again later")
        self.state.clients += 1  # held from here: a failed setup gives it back in forget()
        self.metrics.clients.inc()
        servers = [aiortc.RTCIceServer(u) for u in self.config.ice_servers]
        pc = aiortc.RTCPeerConnection(aiortc.RTCConfiguration(iceServers=servers))
        session = None
        try:
            path_session = await engine.new_session()
            session = WebRTCSession(self, pc, engine, path_session)
            self.sessions[session.id] = session
            self.metrics.webrtc_sessions.inc()
            self.metrics.webrtc_sessions_total.inc()

            @pc.on("track")
            def on_track(track):
                if track.kind == "video":
                    relit = relit_track(track, session)
                    session.tracks.append(relit)
                    pc.addTrack(relit)

            @pc.on("datachannel")
            def on_datachannel(channel):
                session.channel = channel
                channel.on("message", session.control)

            @pc.on("connectionstatechange")
            async def on_state():
                if pc.connectionState in ("failed", "closed"):
                    await session.close(pc.connectionState)

            try:
                await pc.setRemoteDescription(aiortc.RTCSessionDescription(sdp=offer["sdp"], type="offer"))
                if not session.tracks:
                    raise ServiceError(422, "bad_offer", "the offer's video is not sent: make the camera's "
                                                         "transceiver sendrecv")
                await pc.setLocalDescription(await pc.createAnswer())
            except ServiceError:
                raise
            except (ValueError, TypeError, AttributeError, KeyError, IndexError) as exc:
                raise ServiceError(422, "bad_offer", f"the SDP offer cannot be used: {exc}") from None
            self._ensure_watch()
            return {"sdp": pc.localDescription.sdp, "type": pc.localDescription.type, "session": session.id}
        except BaseException:
            if session is not None:
                await session.close("setup failed")
            else:
                await pc.close()
                self.state.clients -= 1
                self.metrics.clients.dec()
            raise

    def forget(self, session: WebRTCSession, why: str) -> None:
        if self.sessions.pop(session.id, None) is not None:
            self.state.clients -= 1
            self.metrics.clients.dec()
            self.metrics.webrtc_sessions.dec()
            self.metrics.webrtc_closed.labels(reason=why).inc()

    def _ensure_watch(self) -> None:
        if self._watch is None or self._watch.done():
            self._watch = asyncio.ensure_future(self._watcher())

    async def _watcher(self) -> None:
        """Closes sessions past the session timeout or idle (no frame) past the idle timeout."""
        while self.sessions:
            await asyncio.sleep(min(1.0, self.config.idle_timeout / 4))
            now = time.monotonic()
            for s in list(self.sessions.values()):
                if now - s.started > self.config.session_timeout:
                    await s.close("session_timeout")
                elif now - s.last_frame > self.config.idle_timeout:
                    await s.close("idle_timeout")

    async def close_all(self) -> None:
        for s in list(self.sessions.values()):
            await s.close("shutdown")
        if self._watch is not None:
            self._watch.cancel()
