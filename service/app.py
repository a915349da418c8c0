"""``relight-serve``: the frame service (FastAPI + uvicorn).

One process keeps a bundle loaded and relights frames with one :class:`FramePath` (frames are
processed one at a time: the per-frame path already uses both cores). Endpoints so far:

* ``POST /v1/relight`` - body: one encoded frame (``image/png`` or ``image/jpeg``); query:
  ``env`` (a built-in preset name), ``rotation`` (yaw,pitch,roll degrees of the environment),
  ``exposure`` (EV), ``strength`` (0-1), ``mode`` (transfer|ambient|paste). Returns the relit frame in
  the same format (or the one ``Accept`` asks for); headers: ``Server-Timing`` (per-stage ms),
  ``X-Relight-Face`` (``found`` or ``none``: then the frame comes back unchanged).
* ``GET /livez`` (the process answers), ``GET /readyz`` (bundle loaded, kernels built),
  ``GET /metrics`` (Prometheus text: ``relight_frames_total``, ``relight_dropped_frames_total``,
  ``relight_errors_total{kind}``, ``relight_frame_latency_seconds``, ``relight_clients``),
  OpenAPI at ``/docs``.

Limits (each a test): bodies over ``max_body`` bytes -> 413 (read in chunks, never whole);
images whose header says more than ``max_pixels`` -> 413 before decoding; other content types
-> 415; undecodable or truncated images -> 400 with a JSON error; a bad query -> 422. Errors
are counted by kind and never take the server down.
"""

from __future__ import annotations

import asyncio
import json
import os
import time
from contextlib import asynccontextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from fastapi import FastAPI, Query, Request, Response, WebSocket, WebSocketDisconnect
from fastapi.responses import JSONResponse, PlainTextResponse

from relight.imageio import image_size

from .composite import DEFAULT_MODE, MODES

#: Default caps: a 4K frame's worth of raw RGB, and its pixel count.
MAX_BODY = 3840 * 2160 * 3
MAX_PIXELS = 3840 * 2160
CONTENT_TYPES = {"image/png": ".png", "image/jpeg": ".jpg"}
PRESETS = ("studio", "sunset", "window", "uniform", "room")


@dataclass
class ServeConfig:
    """The service's settings (the ``relight-serve`` flags)."""

    bundle: Path
    env: str = "builtin:studio"
    mode: str = DEFAULT_MODE
    max_clients: int = 4
    max_body: int = MAX_BODY
    max_pixels: int = MAX_PIXELS
    focal: float | str | None = None
    announce: str | None = None  # printed once the service is ready (relight-serve: the page's URL)


class ServiceError(Exception):
    """An error a request caused: HTTP status, a kind for the metrics, a message saying what to change."""

    def __init__(self, status: int, kind: str, message: str):
        super().__init__(message)
        self.status, self.kind, self.message = status, kind, message


def decode_frame(data: bytes, content_type: str, max_pixels: int) -> np.ndarray:
    """An encoded PNG/JPEG -> (H, W, 3) uint8 RGB, validated (raises ServiceError)."""
    import cv2

    if content_type not in CONTENT_TYPES:
        raise ServiceError(415, "content_type", f"content type {content_type!r}: send image/png or image/jpeg")
    size = image_size(data)
    if size is None:
        raise ServiceError(400, "undecodable", "the body is not a PNG or JPEG image (no valid header)")
    w, h = size
    if w <= 0 or h <= 0 or w * h > max_pixels:
        raise ServiceError(413, "too_many_pixels", f"image of {w}x{h} pixels: at most {max_pixels} pixels "
                                                   "(downscale the frame)")
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    if img is None or img.shape[0] != h or img.shape[1] != w:
        raise ServiceError(400, "undecodable", "the image could not be decoded (truncated or corrupt)")
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def encode_frame(rgb: np.ndarray, content_type: str) -> bytes:
    import cv2

    ok, buf = cv2.imencode(CONTENT_TYPES[content_type], cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR),
                           [cv2.IMWRITE_JPEG_QUALITY, 92] if content_type == "image/jpeg" else [])
    if not ok:  # pragma: no cover - OpenCV encodes any uint8 RGB frame
        raise ServiceError(500, "encode", "the relit frame could not be encoded")
    return buf.tobytes()


class Metrics:
    """The service's Prometheus metrics, in a registry of their own."""

    def __init__(self):
        from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram

        self.registry = CollectorRegistry()
        self.frames = Counter("relight_frames", "Frames relit", registry=self.registry)
        self.dropped = Counter("relight_dropped_frames", "Stale stream frames dropped", registry=self.registry)
        self.errors = Counter("relight_errors", "Requests that failed, by kind", ["kind"], registry=self.registry)
        self.latency = Histogram("relight_frame_latency_seconds", "Time to relight one frame (s)",
                                 buckets=(0.005, 0.01, 0.015, 0.02, 0.03, 0.05, 0.1, 0.25, 1.0),
                                 registry=self.registry)
        self.clients = Gauge("relight_clients", "Connected stream clients", registry=self.registry)


class Engine:
    """The loaded bundle and per-frame path, one frame at a time; environments cached by name."""

    def __init__(self, config: ServeConfig):
        import relight

        from .frame_path import FramePath

        self.config = config
        self.bundle = relight.load_bundle(config.bundle)
        self._envs: dict = {}
        self.env_name = config.env
        # The service's current environment (PUT /v1/environment): used when a request names none.
        self.default_rotation: tuple[float, float, float] | None = None
        self.default_exposure = 0.0
        self.path = FramePath(self.bundle, self.environment(config.env), mode=config.mode, focal=config.focal)
        self.lock = asyncio.Lock()

    def set_uploaded(self, name: str, env: np.ndarray) -> None:
        """An uploaded (validated) environment becomes the current one under ``name``."""
        self._envs = {k: v for k, v in self._envs.items() if k[0] != name}
        self._envs[(name, None)] = env
        self.env_name = name

    def environment(self, name: str, rotation: tuple[float, float, float] | None = None) -> np.ndarray:
        import relight
        from relight.directions import rotation_matrix
        from relight.envmap import rotate_environment

        key = (name, rotation)
        env = self._envs.get(key)
        if env is None:
            base = self._envs.get((name, None))
            env = relight.load_environment(name) if base is None else base
            if rotation is not None and any(rotation):
                env = rotate_environment(env, rotation_matrix(*rotation), supersample=2)
            if len(self._envs) > 16:
                self._envs.clear()
            self._envs[key] = env
        return env

    def relight(self, rgb: np.ndarray, *, env: str | None, rotation, exposure: float | None, strength: float | None,
                mode: str | None):
        fp = self.path
        if env is None and rotation is None:
            rotation = self.default_rotation
        fp.set_environment(self.environment(env or self.env_name, rotation))
        fp.set_mode(mode or self.config.mode)
        fp.set_strength(1.0 if strength is None else strength)
        fp.set_exposure(self.default_exposure if exposure is None else exposure)
        return fp.process(rgb, time.perf_counter())


def _decode_relight_encode(engine: Engine, data: bytes, ctype: str, max_pixels: int, settings: dict):
    """(encoded relit frame, FrameInfo) of an encoded frame (raises ServiceError/RelightError)."""
    rgb = decode_frame(data, ctype, max_pixels)
    out, info = engine.relight(rgb, **settings)
    return encode_frame(out, ctype), info


def _parse_rotation(text: str | None):
    if not text:
        return None
    try:
        vals = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise ServiceError(422, "bad_query", f"rotation={text!r}: give yaw,pitch,roll in degrees") from None
    if len(vals) != 3 or not all(np.isfinite(vals)) or max(abs(v) for v in vals) > 360:
        raise ServiceError(422, "bad_query", f"rotation={text!r}: give three angles within +-360 degrees")
    return vals


#: Environment uploads: content types and the largest body (bytes).
ENV_TYPES = {"image/vnd.radiance": ".hdr", "image/x-exr": ".exr", "image/aces": ".exr", "image/png": ".png"}
ENV_MAX_BODY = 64 << 20


def _binary_body(*types: str, required: bool = True) -> dict:
    """OpenAPI request body of raw bytes in ``types`` (the handlers read the stream themselves)."""
    schema = {"type": "string", "format": "binary"}
    return {"requestBody": {"required": required, "content": {t: {"schema": schema} for t in types}}}


async def _read_body(request, cap: int) -> bytes:
    declared = request.headers.get("content-length")
    if declared is not None and declared.isdigit() and int(declared) > cap:
        raise ServiceError(413, "too_large", f"body of {declared} bytes: at most {cap}")
    chunks, total = [], 0
    async for chunk in request.stream():
        total += len(chunk)
        if total > cap:
            raise ServiceError(413, "too_large", f"body over {cap} bytes: send a smaller file")
        chunks.append(chunk)
    return b"".join(chunks)


def _load_uploaded_environment(body: bytes, suffix: str) -> np.ndarray:
    """Validate an uploaded environment exactly as a file would be (written to a temporary file)."""
    import tempfile

    import relight
    from relight.errors import RelightError

    with tempfile.TemporaryDirectory(prefix="relight-env-") as tmp:
        path = Path(tmp) / f"upload{suffix}"
        path.write_bytes(body)
        try:
            return relight.load_environment(path)
        except RelightError as exc:
            raise ServiceError(400, "bad_environment", str(exc).replace(str(path), "the uploaded environment")) \
                from None


def _preview_png(env: np.ndarray, exposure_ev: float) -> bytes:
    """The environment scaled to at most 512x256, Reinhard tone-mapped, sRGB PNG."""
    import cv2

    from relight.colour import encode_srgb8, luminance

    h, w = env.shape[:2]
    s = min(1.0, 256.0 / h)
    small = cv2.resize(env, (max(int(w * s), 2), max(int(h * s), 1)), interpolation=cv2.INTER_AREA) if s < 1 else env
    small = small * np.float32(2.0 ** exposure_ev)
    lum = luminance(small)[..., None]
    mapped = small / (1.0 + lum)
    ok, buf = cv2.imencode(".png", cv2.cvtColor(encode_srgb8(np.clip(mapped, 0, 1)), cv2.COLOR_RGB2BGR))
    return buf.tobytes()


def create_app(config: ServeConfig):
    """The FastAPI application (the bundle loads in the lifespan handler; /readyz says when)."""
    from relight.errors import RelightError

    state: dict = {"engine": None, "error": None}
    metrics = Metrics()

    @asynccontextmanager
    async def lifespan(app):
        try:
            state["engine"] = await asyncio.to_thread(Engine, config)
        except RelightError as exc:
            state["error"] = str(exc)
            raise
        if config.announce:
            print(config.announce, flush=True)
        yield

    app = FastAPI(title="relight", version="0.1.0", lifespan=lifespan,
                  description="Relight the face in video frames with a reflectance bundle.")
    app.state.metrics = metrics
    app.state.relight = state

    @app.exception_handler(ServiceError)
    async def _service_error(request, exc: ServiceError):
        metrics.errors.labels(kind=exc.kind).inc()
        return JSONResponse({"error": exc.message, "kind": exc.kind}, status_code=exc.status)

    @app.get("/", summary="The browser page: webcam in, relit frames out", response_class=Response,
             responses={200: {"content": {"text/html": {}}}})
    async def page():
        from importlib.resources import files

        html = files("relight.service").joinpath("static/index.html").read_text(encoding="utf-8")
        return Response(html, media_type="text/html")

    @app.get("/livez", summary="The process answers")
    async def livez():
        return {"status": "alive"}

    @app.get("/readyz", summary="Bundle loaded and kernels built")
    async def readyz():
        if state["engine"] is None:
            return JSONResponse({"status": "loading", "error": state["error"]}, status_code=503)
        from relight.kernels.runtime import get_runtime

        dev = get_runtime().device
        return {"status": "ready", "bundle": str(config.bundle), "env": state["engine"].env_name,
                "device": dev.name.strip(), "compute_units": int(dev.max_compute_units)}

    @app.get("/metrics", summary="Prometheus metrics", response_class=PlainTextResponse)
    async def metrics_endpoint():
        from prometheus_client import CONTENT_TYPE_LATEST, generate_latest

        return Response(generate_latest(metrics.registry), media_type=CONTENT_TYPE_LATEST)

    @app.post("/v1/relight", summary="Relight one frame", openapi_extra=_binary_body("image/png", "image/jpeg"),
              responses={200: {"content": {"image/png": {}, "image/jpeg": {}}}, 400: {}, 413: {}, 415: {}, 422: {}})
    async def relight_frame(request: Request,
                            env: str | None = Query(None, description="built-in preset: " + ", ".join(PRESETS)),
                            rotation: str | None = Query(None, description="environment yaw,pitch,roll (degrees)"),
                            exposure: float | None = Query(None, ge=-20, le=20, description="stops (EV)"),
                            strength: float | None = Query(None, ge=0, le=1, description="blend, 0 to 1"),
                            mode: str | None = Query(None, pattern="^(transfer|ambient|paste)$",
                                                     description="transfer (the live light measured and swapped), "
                                                                 "ambient (ratio to the capture room), paste")):
        engine = state["engine"]
        if engine is None:
            raise ServiceError(503, "not_ready", "the service is still loading its bundle; retry shortly")
        if env is not None and env not in PRESETS:
            raise ServiceError(422, "bad_query", f"env={env!r}: use one of {', '.join(PRESETS)}")
        rot = _parse_rotation(rotation)
        ctype = (request.headers.get("content-type") or "").split(";")[0].strip().lower()
        if ctype not in CONTENT_TYPES:
            raise ServiceError(415, "content_type", f"content type {ctype or 'none'!r}: send image/png or image/jpeg")
        rgb = decode_frame(await _read_body(request, config.max_body), ctype, config.max_pixels)
        accept = (request.headers.get("accept") or "").lower()
        out_type = "image/jpeg" if "image/jpeg" in accept and "image/png" not in accept else \
            "image/png" if "image/png" in accept and "image/jpeg" not in accept else ctype
        t0 = time.perf_counter()
        async with engine.lock:
            try:
                out, info = await asyncio.to_thread(engine.relight, rgb, env=f"builtin:{env}" if env else None,
                                                    rotation=rot, exposure=exposure, strength=strength, mode=mode)
            except RelightError as exc:
                raise ServiceError(400, "bad_request", str(exc)) from None
        metrics.latency.observe(time.perf_counter() - t0)
        metrics.frames.inc()
        timing = ", ".join(f"{k};dur={v:.2f}" for k, v in info.timings.items())
        headers = {"Server-Timing": timing, "X-Relight-Face": "found" if info.face else "none"}
        if not info.face and info.note:
            headers["X-Relight-Note"] = info.note
        if info.light is not None:
            headers["X-Relight-Light"] = json.dumps(info.light.as_json(), separators=(",", ":"))
        return Response(encode_frame(out, out_type), media_type=out_type, headers=headers)

    @app.get("/v1/environment", summary="The current environment and the built-ins")
    async def get_environment():
        engine = _ready()
        return {"current": engine.env_name, "rotation": engine.default_rotation, "exposure": engine.default_exposure,
                "builtins": list(PRESETS)}

    @app.put("/v1/environment", summary="Choose a built-in or upload an environment (.hdr/.exr/.png)",
             openapi_extra=_binary_body(*ENV_TYPES, required=False), responses={400: {}, 413: {}, 415: {}, 422: {}})
    async def put_environment(request: Request,
                              builtin: str | None = Query(None, description="a built-in: " + ", ".join(PRESETS)),
                              rotation: str | None = Query(None, description="yaw,pitch,roll (degrees)"),
                              exposure: float | None = Query(None, ge=-20, le=20, description="stops (EV)")):
        engine = _ready()
        rot = _parse_rotation(rotation)
        ctype = (request.headers.get("content-type") or "").split(";")[0].strip().lower()
        body = await _read_body(request, ENV_MAX_BODY)
        if builtin is not None:
            if builtin not in PRESETS:
                raise ServiceError(422, "bad_query", f"builtin={builtin!r}: use one of {', '.join(PRESETS)}")
            async with engine.lock:
                await asyncio.to_thread(engine.environment, f"builtin:{builtin}")
                engine.env_name = f"builtin:{builtin}"
        elif body:
            suffix = ENV_TYPES.get(ctype)
            if suffix is None:
                raise ServiceError(415, "content_type", f"content type {ctype or 'none'!r}: send "
                                   + ", ".join(ENV_TYPES) + " (an .hdr, .exr or .png lat-long map)")
            env = await asyncio.to_thread(_load_uploaded_environment, body, suffix)
            async with engine.lock:
                engine.set_uploaded("uploaded" + suffix, env)
        if rot is not None:
            engine.default_rotation = rot
        if exposure is not None:
            engine.default_exposure = float(exposure)
        return await get_environment()

    @app.get("/v1/environment/preview.png", summary="The current environment, tone-mapped",
             response_class=Response, responses={200: {"content": {"image/png": {}}}})
    async def preview_environment():
        engine = _ready()
        env = engine.environment(engine.env_name, engine.default_rotation)
        return Response(await asyncio.to_thread(_preview_png, env, engine.default_exposure), media_type="image/png")

    def _ready() -> Engine:
        engine = state["engine"]
        if engine is None:
            raise ServiceError(503, "not_ready", "the service is still loading its bundle; retry shortly")
        return engine

    @app.websocket("/v1/stream")
    async def stream(ws: WebSocket):
        """Binary messages: encoded frames in, relit frames out (latest frame wins: a frame that
        arrives while another waits replaces it and counts as dropped). Text messages: JSON
        controls ``{"env": "sunset", "rotation": [yaw, pitch, roll], "strength": 0.8, "mode":
        "paste", "exposure": 0}`` and ``{"stats": true}``; after each relit frame a JSON text
        message ``{"frame", "latency_ms", "dropped", "face", "timings"}``."""
        engine = state["engine"]
        await ws.accept()  # (closing before the handshake would be an HTTP 403, not a close code)
        if engine is None:
            await ws.close(code=1013, reason="loading; try again shortly")
            return
        if state.setdefault("clients", 0) >= config.max_clients:
            metrics.errors.labels(kind="too_many_clients").inc()
            await ws.close(code=1013, reason=f"at most {config.max_clients} clients; try again later")
            return
        state["clients"] += 1
        metrics.clients.inc()
        settings: dict = {"env": None, "rotation": None, "strength": None, "mode": None, "exposure": None}
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

        def control(doc: dict):
            if not isinstance(doc, dict):
                raise ServiceError(422, "bad_control", "control messages are JSON objects")
            if "env" in doc:
                if doc["env"] not in PRESETS:
                    raise ServiceError(422, "bad_control", f"env {doc['env']!r}: use one of {', '.join(PRESETS)}")
                settings["env"] = f"builtin:{doc['env']}"
            if "rotation" in doc:
                settings["rotation"] = _parse_rotation(",".join(str(v) for v in doc["rotation"]))
            for key, lo, hi in (("strength", 0.0, 1.0), ("exposure", -20.0, 20.0)):
                if key in doc:
                    v = doc[key]
                    if not isinstance(v, int | float) or not (lo <= v <= hi):
                        raise ServiceError(422, "bad_control", f"{key} {v!r}: use {lo:g} to {hi:g}")
                    settings[key] = float(v)
            if "mode" in doc:
                if doc["mode"] not in MODES:
                    raise ServiceError(422, "bad_control", f"mode: one of {', '.join(MODES)}")
                settings["mode"] = doc["mode"]

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
                            doc = json.loads(msg["text"])
                            if isinstance(doc, dict) and doc.get("stats"):
                                await send_json({"frames": counts["frames"], "dropped": counts["dropped"]})
                            elif isinstance(doc, dict) and set(doc) == {"tag"}:
                                pending["tag"] = doc["tag"]  # echoed with the next frame's result
                            else:
                                control(doc)
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
                    async with engine.lock:
                        # Decode, relight and encode in one hop off the event loop (which keeps
                        # reading the other clients' frames meanwhile).
                        payload, info = await asyncio.to_thread(_decode_relight_encode, engine, data, ctype,
                                                                config.max_pixels, settings)
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
            state["clients"] -= 1
            metrics.clients.dec()

    return app


def serve(bundle: Path, *, env: str = "builtin:studio", host: str = "127.0.0.1", port: int = 8000,
          mode: str = DEFAULT_MODE, max_clients: int = 4, focal=None) -> int:
    """Serve ``bundle`` with uvicorn until stopped (``relight serve`` / ``relight-serve``; the
    command line checks its arguments first: :mod:`relight.cli`)."""
    import uvicorn

    shown = "127.0.0.1" if host in ("0.0.0.0", "::", "") else host
    shown = f"[{shown}]" if ":" in shown else shown
    url = f"http://{shown}:{port}"
    announce = (f"relight: serving {bundle} - open {url}/ (webcam page), {url}/docs (API), "
                f"{url}/metrics; Ctrl-C stops")
    app = create_app(ServeConfig(bundle=bundle, env=env, mode=mode, max_clients=max_clients, focal=focal,
                                 announce=announce))
    uvicorn.run(app, host=host, port=port, log_level=os.environ.get("RELIGHT_LOG_LEVEL", "info"),
                ws_max_size=MAX_BODY + 1024)
    return 0
