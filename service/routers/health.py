"""The browser page, the liveness and readiness probes, Prometheus metrics."""

from __future__ import annotations

from fastapi import APIRouter, Request, Response
from fastapi.responses import JSONResponse, PlainTextResponse

from ..dependencies import MetricsDep, SettingsDep

router = APIRouter()


@router.get("/", summary="The browser page: webcam in, relit frames out", response_class=Response,
            responses={200: {"content": {"text/html": {}}}})
async def page():
    from importlib.resources import files

    html = files("relight.service").joinpath("static/index.html").read_text(encoding="utf-8")
    return Response(html, media_type="text/html")


@router.get("/livez", summary="The process answers")
async def livez():
    return {"status": "alive"}


@router.get("/readyz", summary="Bundle loaded and kernels built")
async def readyz(request: Request, settings: SettingsDep):
    engine = request.app.state.frame_service
    if engine is None:
        return JSONResponse({"status": "loading", "error": request.app.state.load_error}, status_code=503)
    from relight.kernels.runtime import get_runtime

    dev = get_runtime().device
    return {"status": "ready", "bundle": str(settings.bundle), "env": engine.env_name,
            "device": dev.name.strip(), "compute_units": int(dev.max_compute_units)}


@router.get("/metrics", summary="Prometheus metrics", response_class=PlainTextResponse)
async def metrics_endpoint(metrics: MetricsDep):
    from prometheus_client import CONTENT_TYPE_LATEST, generate_latest

    return Response(generate_latest(metrics.registry), media_type=CONTENT_TYPE_LATEST)
