"""``/v1/stream``: a websocket of encoded frames in and relit frames out, latest frame wins."""

from __future__ import annotations

import asyncio
import time

from fastapi import APIRouter, WebSocket, WebSocketDisconnect

from relight.errors import RelightError
from relight.imageio import image_size

from ...engine.frame_slot import NewestSlot
from ..codec import decode_frame, encode_frame
from ..controls import apply_control, new_settings, parse_control
from ..dependencies import MetricsDep, SettingsDep
from ..errors import ServiceError

router = APIRouter()


@router.websocket("/v1/stream")
async def stream(ws: WebSocket, config: SettingsDep, metrics: MetricsDep):
    """Binary messages: encoded frames in, relit frames out (latest frame wins: a frame that
    arrives while another waits replaces it and counts as dropped; once a frame has the engine,
    the next one to arrive is decoded meanwhile, and a relit frame is encoded and sent while the
    next is relit: a client's frames go through three steps at once, in order). Text messages: JSON
    controls ``{"env": "sunset", "rotation": [yaw, pitch, roll], "strength": 0.8, "mode":
    "paste", "exposure": 0}`` and ``{"stats": true}``; after each relit frame a JSON text
    message ``{"frame", "latency_ms", "dropped", "face", "timings"}``."""
    state = ws.app.state
    engine = state.frame_service  # None while loading: the socket is closed with 1013, not refused
    await ws.accept()  # (closing before the handshake would be an HTTP 403, not a close code)
    if engine is None:
        await ws.close(code=1013, reason="loading; try again shortly")
        return
    if state.clients >= config.max_clients:
        metrics.errors.labels(kind="too_many_clients").inc()
        await ws.close(code=1013, reason=f"at most {config.max_clients} clients; try again later")
        return
    state.clients += 1
    metrics.clients.inc()
    try:
        session = await engine.new_session()  # this client's own tracker and filters
    except BaseException:
        state.clients -= 1
        metrics.clients.dec()
        raise
    client = _Client(ws, config, metrics, engine, session)
    try:
        await asyncio.gather(client.reader(), client.worker())
    finally:
        state.clients -= 1
        metrics.clients.dec()


def _drop(ahead) -> None:
    """A frame taken but not relit: its decode cancelled, or its error retrieved (not logged)."""
    if ahead is not None:
        if ahead[0].done():
            if not ahead[0].cancelled():
                ahead[0].exception()
        else:
            ahead[0].cancel()


class _Client:
    """One websocket client's stream: its ``reader`` task takes messages (frames into a one-frame
    slot, controls into its settings), its ``worker`` task takes frames through decode, relight and
    encode + send, overlapping; ``wake`` tells the worker a frame arrived, ``closed`` that the
    socket is done."""

    def __init__(self, ws: WebSocket, config, metrics, engine, session):
        self.ws, self.config, self.metrics = ws, config, metrics
        self.engine, self.session = engine, session
        self.settings = new_settings()
        self.latest = NewestSlot()  # (bytes, time it arrived, tag)
        self.pending: dict = {}
        self.counts = {"frames": 0, "dropped": 0}
        self.wake = asyncio.Event()
        self.closed = asyncio.Event()

    async def send_json(self, doc) -> None:
        """A JSON text message, the socket marked closed when it is gone."""
        try:
            await self.ws.send_json(doc)
        except (WebSocketDisconnect, RuntimeError):
            self.closed.set()

    # ------------------------------------------------------------------ the reader task
    async def reader(self) -> None:
        """The client's messages until it leaves (or sends a frame over the limit)."""
        try:
            while True:
                msg = await self.ws.receive()
                if msg["type"] == "websocket.disconnect":
                    break
                if msg.get("bytes") is not None:
                    if not await self._frame_in(msg["bytes"]):
                        break
                elif msg.get("text") is not None:
                    await self._control_in(msg["text"])
        except (WebSocketDisconnect, RuntimeError):
            pass
        finally:
            self.closed.set()
            self.wake.set()

    async def _frame_in(self, data: bytes) -> bool:
        """An encoded frame into the slot (the one waiting dropped); False when it is too large
        (the socket closed with 1009)."""
        if len(data) > self.config.max_body:
            self.metrics.errors.labels(kind="too_large").inc()
            await self.ws.close(code=1009, reason=f"frame over {self.config.max_body} bytes")
            return False
        if self.latest.put((data, time.perf_counter(), self.pending.pop("tag", None))):
            self.counts["dropped"] += 1
            self.metrics.dropped.inc()
        self.wake.set()
        return True

    async def _control_in(self, text: str) -> None:
        """A JSON text message: stats asked for, a tag for the next frame, or controls applied."""
        try:
            doc = parse_control(text)
            if isinstance(doc, dict) and doc.get("stats"):
                await self.send_json({"frames": self.counts["frames"], "dropped": self.counts["dropped"]})
            elif isinstance(doc, dict) and set(doc) == {"tag"}:
                self.pending["tag"] = doc["tag"]  # echoed with the next frame's result
            else:
                apply_control(self.settings, doc)
        except (ValueError, ServiceError) as exc:
            self.metrics.errors.labels(kind="bad_control").inc()
            await self.send_json({"error": str(exc), "kind": "bad_control"})

    # ------------------------------------------------------------------ the worker task
    def take(self):
        """The newest frame the reader holds, its decode started off the event loop: (Task of
        (the frame - RGB or a JPEG's planes -, content type), time it arrived, tag), or None when none waits."""
        item = self.latest.take()
        if item is None:
            return None
        data, t_in, tag = item
        return asyncio.ensure_future(asyncio.to_thread(self.decode, data)), t_in, tag

    def decode(self, data: bytes):
        """An encoded frame decoded (on a thread): (the frame, its content type)."""
        ctype = "image/png" if data[:4] == b"\x89PNG" else "image/jpeg"
        if image_size(data) is None:
            raise ServiceError(400, "undecodable", "the frame is not a PNG or JPEG image")
        return decode_frame(data, ctype, self.config.max_pixels, planes=True), ctype  # (a JPEG in its planes)

    async def send(self, out, ctype: str, info, t_in: float, tag) -> None:
        """Encode a relit frame off the event loop and send it with its JSON."""
        try:
            payload = await asyncio.to_thread(encode_frame, out, ctype)
        except ServiceError as exc:
            self.metrics.errors.labels(kind=exc.kind).inc()
            await self.send_json({"error": str(exc), "kind": exc.kind})
            return
        try:
            await self.ws.send_bytes(payload)
        except (WebSocketDisconnect, RuntimeError):
            self.closed.set()
            self.wake.set()
            return
        self.counts["frames"] += 1
        self.metrics.frames.inc()
        latency = time.perf_counter() - t_in
        self.metrics.latency.observe(latency)
        doc = {"frame": self.counts["frames"], "latency_ms": round(latency * 1e3, 2),
               "dropped": self.counts["dropped"], "face": info.face,
               "timings": {k: round(v, 2) for k, v in info.timings.items()}}
        if info.light is not None:
            doc["light"] = info.light.as_json()
        if tag is not None:
            doc["tag"] = tag
        await self.send_json(doc)

    async def relit_while_next_decodes(self, rgb, ahead):
        """This client's frame relit (under the engine's lock); once it has the engine, the newest
        frame that arrived is decoded meanwhile, ready for the next turn. Returns (the relight's
        task, done: its result or its error; ahead - kept either way). (Not before the frame has
        the engine: a frame taken while the other clients' frames hold it would wait two turns,
        not one - its newer ones dropped.)"""
        started = asyncio.Event()
        job = asyncio.ensure_future(self.engine.relight_frame(rgb, session=self.session, started=started,
                                                              **self.settings))
        # (never cancelled: the path finishes its frame on its thread; an error left is retrieved)
        job.add_done_callback(lambda t: t.cancelled() or t.exception())
        has_engine = asyncio.ensure_future(started.wait())
        arrived = None
        try:
            await asyncio.wait({job, has_engine}, return_when=asyncio.FIRST_COMPLETED)
            while ahead is None and not job.done():
                arrived = asyncio.ensure_future(self.wake.wait())
                done, _ = await asyncio.wait({job, arrived}, return_when=asyncio.FIRST_COMPLETED)
                if arrived in done:
                    self.wake.clear()
                    ahead = self.take()
                arrived.cancel()
            await asyncio.wait({job})
        except BaseException:  # (the handler cancelled: the client left)
            _drop(ahead)
            raise
        finally:
            has_engine.cancel()
            if arrived is not None:
                arrived.cancel()
        return job, ahead

    async def worker(self) -> None:
        """Frames through three overlapping steps (each on its own thread): the next frame decoded
        while this one is relit, and the last relit frame encoded and sent meanwhile; in order
        (an error, too: after the frames before it)."""
        ahead = sending = None
        try:
            while not self.closed.is_set():
                if ahead is None:
                    await self.wake.wait()
                    self.wake.clear()
                    ahead = self.take()
                    if ahead is None:
                        continue
                (decoding, t_in, tag), ahead = ahead, None
                try:
                    rgb, ctype = await decoding
                    job, ahead = await self.relit_while_next_decodes(rgb, ahead)
                    out, info = job.result()
                except (ServiceError, RelightError) as exc:
                    if sending is not None:
                        await sending  # (the frame before the error leaves first)
                        sending = None
                    kind = exc.kind if isinstance(exc, ServiceError) else "bad_request"
                    self.metrics.errors.labels(kind=kind).inc()
                    await self.send_json({"error": str(exc), "kind": kind})
                    continue
                if sending is not None:
                    await sending  # (frames leave in order)
                sending = asyncio.ensure_future(self.send(out, ctype, info, t_in, tag))
        finally:
            if sending is not None:
                await asyncio.gather(sending, return_exceptions=True)
            _drop(ahead)
