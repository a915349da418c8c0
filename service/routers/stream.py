"""``/v1/stream``: a websocket of encoded frames in and relit frames out, latest frame wins."""

from __future__ import annotations

import asyncio
import time

from fastapi import APIRouter, WebSocket, WebSocketDisconnect

from relight.errors import RelightError
from relight.imageio import image_size

from ..controls import apply_control, new_settings, parse_control
from ..dependencies import MetricsDep, SettingsDep
from ..errors import ServiceError

router = APIRouter()


@router.websocket("/v1/stream")
async def stream(ws: WebSocket, config: SettingsDep, metrics: MetricsDep):
    """Binary messages: encoded frames in, relit frames out (latest frame wins: a frame that
    arrives while another waits replaces it and counts as dropped). Text messages: JSON
    controls ``{"env": "sunset", "rotation": [yaw, pitch, roll], "strength": 0.8, "mode":
    "paste", "exposure": 0}`` and ``{"stats": true}``; after each relit frame a JSON text
    message ``{"frame", "latency_ms", "dropped", "face", "timings"}``."""
    state = ws.app.state
    engine = state.engine  # None while loading: the socket is closed with 1013, not refused
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
    settings = new_settings()
    latest: dict = {"data": None, "type": None, "t": 0.0, "tag": None}
    pending: dict = {}
    counts = {"frames": 0, "dropped": 0}
    wake = asyncio.Event()
    closed = asyncio.Event()

    async def send_json(doc):
        try:
            await ws.send_json(doc)
        except (WebSocketDisconnect, RuntimeError):
            closed.set()

    async def reader():
        try:
            while True:
                msg = await ws.receive()
                if msg["type"] == "websocket.disconnect":
                    break
                if msg.get("bytes") is not None:
                    data = msg["bytes"]
                    if len(data) > config.max_body:
                        metrics.errors.labels(kind="too_large").inc()
                        await ws.close(code=1009, reason=f"frame over {config.max_body} bytes")
                        break
                    if latest["data"] is not None:
                        counts["dropped"] += 1
                        metrics.dropped.inc()
                    latest.update(data=data, t=time.perf_counter(), tag=pending.pop("tag", None))
                    wake.set()
                elif msg.get("text") is not None:
                    try:
                        doc = parse_control(msg["text"])
                        if isinstance(doc, dict) and doc.get("stats"):
                            await send_json({"frames": counts["frames"], "dropped": counts["dropped"]})
                        elif isinstance(doc, dict) and set(doc) == {"tag"}:
                            pending["tag"] = doc["tag"]  # echoed with the next frame's result
                        else:
                            apply_control(settings, doc)
                    except (ValueError, ServiceError) as exc:
                        metrics.errors.labels(kind="bad_control").inc()
                        await send_json({"error": str(exc), "kind": "bad_control"})
        except (WebSocketDisconnect, RuntimeError):
            pass
        finally:
            closed.set()
            wake.set()

    async def worker():
        while not closed.is_set():
            await wake.wait()
            wake.clear()
            data, t_in, tag = latest["data"], latest["t"], latest["tag"]
            latest["data"] = None
            if data is None:
                continue
            try:
                size = image_size(data)
                ctype = "image/png" if data[:4] == b"\x89PNG" else "image/jpeg"
                if size is None:
                    raise ServiceError(400, "undecodable", "the frame is not a PNG or JPEG image")
                # Decode, relight and encode in one hop off the event loop (which keeps reading
                # the other clients' frames meanwhile).
                payload, info = await engine.decode_relight_encode(data, ctype, config.max_pixels, settings,
                                                                   session)
            except (ServiceError, RelightError) as exc:
                kind = exc.kind if isinstance(exc, ServiceError) else "bad_request"
                metrics.errors.labels(kind=kind).inc()
                await send_json({"error": str(exc), "kind": kind})
                continue
            try:
                await ws.send_bytes(payload)
            except (WebSocketDisconnect, RuntimeError):
                closed.set()
                break
            counts["frames"] += 1
            metrics.frames.inc()
            latency = time.perf_counter() - t_in
            metrics.latency.observe(latency)
            doc = {"frame": counts["frames"], "latency_ms": round(latency * 1e3, 2), "dropped": counts["dropped"],
                   "face": info.face, "timings": {k: round(v, 2) for k, v in info.timings.items()}}
            if info.light is not None:
                doc["light"] = info.light.as_json()
            if tag is not None:
                doc["tag"] = tag
            await send_json(doc)

    try:
        await asyncio.gather(reader(), worker())
    finally:
        state.clients -= 1
        metrics.clients.dec()

