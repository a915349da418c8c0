"""What the routes depend on, from ``app.state`` (FastAPI dependencies)."""

from __future__ import annotations

from typing import Annotated

from fastapi import Depends
from starlette.requests import HTTPConnection

from .errors import ServiceError
from .settings import ServeConfig, get_settings
from .state import FrameService, Metrics


def get_metrics(conn: HTTPConnection) -> Metrics:
    """The app's Prometheus metrics (HTTP requests and websockets alike)."""
    return conn.app.state.metrics


def get_frame_service(conn: HTTPConnection) -> FrameService:
    """The loaded engine, or 503 while the bundle is still loading."""
    engine = conn.app.state.frame_service
    if engine is None:
        raise ServiceError(503, "not_ready", "the service is still loading its bundle; retry shortly")
    return engine


#: Route parameter types (FastAPI's ``Annotated`` dependencies).
ServiceDep = Annotated[FrameService, Depends(get_frame_service)]
MetricsDep = Annotated[Metrics, Depends(get_metrics)]
SettingsDep = Annotated[ServeConfig, Depends(get_settings)]
