"""``relight-serve``: the frame service (FastAPI + uvicorn).

One process keeps a bundle loaded (its relighter and kernels shared) and relights frames one at a
time under the engine's lock (:class:`~relight.service.state.FrameService`; the per-frame path already
uses both cores): each websocket or WebRTC stream in a per-frame path of its own (its tracker and
live light), every ``POST /v1/relight`` as a first frame in a fresh one. Endpoints:

* ``POST /v1/relight`` - body: one encoded frame (``image/png`` or ``image/jpeg``); query:
  ``env`` (a built-in preset name), ``rotation`` (yaw,pitch,roll degrees of the environment),
  ``exposure`` (EV), ``strength`` (0-1), ``mode`` (transfer|ambient|paste). Returns the relit frame in
  the same format (or the one ``Accept`` asks for); headers: ``Server-Timing`` (per-stage ms),
  ``X-Relight-Face`` (``found`` or ``none``: then the frame comes back unchanged).
* ``GET /livez`` (the process answers), ``GET /readyz`` (bundle loaded, kernels built),
  ``GET /metrics`` (Prometheus text: ``relight_frames_total``, ``relight_dropped_frames_total``,
  ``relight_errors_total{kind}``, ``relight_frame_latency_seconds``, ``relight_clients``),
  OpenAPI at ``/docs``.

Layout (FastAPI's larger applications): this module only assembles - :func:`create_app` makes
the app, its lifespan loads the :class:`~relight.service.state.FrameService` onto ``app.state``, and it
includes one router per resource (:mod:`relight.service.routers`: health, frames, environment,
stream); settings come through one dependency (:func:`relight.service.settings.get_settings`),
frames and bodies through :mod:`relight.service.codec`.

Limits (each a test): bodies over ``max_body`` bytes -> 413 (read in chunks, never whole);
images whose header says more than ``max_pixels`` -> 413 before decoding; other content types
-> 415; undecodable or truncated images -> 400 with a JSON error; a bad query -> 422. Errors
are counted by kind and never take the server down.
"""

from __future__ import annotations

import asyncio
import os
from contextlib import asynccontextmanager
from pathlib import Path

from fastapi import FastAPI
from fastapi.responses import JSONResponse

from ..engine.threads import frames_first
from .codec import MAX_BODY
from .errors import ServiceError
from .routers import environment, frames, health, stream, webrtc
from .security import AccessGuard
from .settings import DEFAULT_PORT, ServeConfig
from .state import FrameService, Metrics
from .webrtc import WebRTCSessions

#: Seconds a 503 (loading, at the client cap) asks the client to wait (Retry-After).
RETRY_AFTER_S = 2


def create_app(config: ServeConfig) -> FastAPI:
    """The FastAPI application (the bundle loads in the lifespan handler; /readyz says when)."""
    from relight.errors import RelightError

    from .codec import clean_stale_uploads

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        clean_stale_uploads()  # folders a killed server left while validating an upload
        try:
            app.state.frame_service = await asyncio.to_thread(FrameService, config)
        except RelightError as exc:
            app.state.load_error = str(exc)
            raise
        if config.announce:
            print(config.announce, flush=True)
        try:
            with frames_first():  # the streams' frames wait less behind their slow stages' Python
                yield
            await app.state.webrtc.close_all()
        finally:
            await asyncio.to_thread(app.state.frame_service.close)  # its workers' threads, after the sessions

    app = FastAPI(title="relight", version="0.1.0", lifespan=lifespan,
                  description="Relight the face in video frames with a reflectance bundle.")
    app.state.settings = config
    app.state.metrics = Metrics()
    app.state.frame_service = None  # set by the lifespan once the bundle is loaded
    app.state.load_error = None
    app.state.clients = 0  # connected stream clients (websockets and WebRTC sessions)
    app.state.webrtc = WebRTCSessions(app.state, app.state.metrics, config)

    @app.exception_handler(ServiceError)
    async def _service_error(request, exc: ServiceError):
        app.state.metrics.errors.labels(kind=exc.kind).inc()
        headers = {"Retry-After": str(RETRY_AFTER_S)} if exc.status == 503 else None
        return JSONResponse({"error": exc.message, "kind": exc.kind}, status_code=exc.status, headers=headers)

    app.state.pending = 0  # POST /v1/relight frames relit or waiting
    app.add_middleware(AccessGuard, bind_host=config.host, token=config.token,
                       allowed_origins=config.allowed_origins,
                       on_refuse=lambda kind: app.state.metrics.errors.labels(kind=kind).inc())
    for router in (health.router, frames.router, environment.router, stream.router, webrtc.router):
        app.include_router(router)
    return app


def serve(bundle: Path, *, env: str = ServeConfig.env, host: str = ServeConfig.host, port: int = DEFAULT_PORT,
          mode: str = ServeConfig.mode, region: str = ServeConfig.region, max_clients: int = ServeConfig.max_clients,
          focal=None, token: str | None = None, allowed_origins: tuple[str, ...] = ()) -> int:
    """Serve ``bundle`` with uvicorn until stopped (``relight serve`` / ``relight-serve``; the
    command line checks its arguments first: :mod:`relight.cli`)."""
    import uvicorn

    shown = "127.0.0.1" if host in ("0.0.0.0", "::", "") else host
    shown = f"[{shown}]" if ":" in shown else shown
    url = f"http://{shown}:{port}"
    query = f"?token={token}" if token else ""
    announce = (f"relight: serving {bundle} - open {url}/{query} (webcam page), {url}/docs (API), "
                f"{url}/metrics; Ctrl-C stops")
    app = create_app(ServeConfig(bundle=bundle, env=env, mode=mode, region=region, max_clients=max_clients, focal=focal,
                                 announce=announce, host=host, token=token, allowed_origins=tuple(allowed_origins)))
    uvicorn.run(app, host=host, port=port, log_level=os.environ.get("RELIGHT_LOG_LEVEL", "info"),
                ws_max_size=MAX_BODY + 1024)
    return 0
