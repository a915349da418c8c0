"""The service's settings (the ``relight-serve`` flags) and the one dependency that hands them
to the routes: tests override :func:`get_settings` (``app.dependency_overrides``)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from starlette.requests import HTTPConnection

from ..engine.composite import DEFAULT_MODE, DEFAULT_REGION
from ..envmap import BUILTINS
from ..presets import PRESETS as LIGHT_PRESETS
from .codec import MAX_BODY, MAX_PIXELS

#: The environments a request may name (``builtin:NAME``): the studio's built-ins and the
#: presets people recognise (:mod:`relight.presets`).
PRESETS = (*BUILTINS, *LIGHT_PRESETS)
#: The port ``relight-serve`` listens on unless told (``--port``).
DEFAULT_PORT = 8000


@dataclass
class ServeConfig:
    """The service's settings (the ``relight-serve`` flags)."""

    bundle: Path
    env: str = "builtin:studio"
    mode: str = DEFAULT_MODE
    #: What mode transfer relights: the whole person or the face alone (engine.composite.REGIONS).
    region: str = DEFAULT_REGION
    max_clients: int = 4
    max_body: int = MAX_BODY
    max_pixels: int = MAX_PIXELS
    focal: float | str | None = None
    #: Where it listens (the access checks depend on whether that is loopback).
    host: str = "127.0.0.1"
    #: Required of every request but the probes when set (always when binding beyond loopback).
    token: str | None = None
    #: Web page origins allowed to drive it besides this server's own (``*``: any).
    allowed_origins: tuple[str, ...] = ()
    #: POST /v1/relight frames relit or waiting at once; more get 503 + Retry-After.
    max_pending: int = 4
    #: STUN/TURN servers for WebRTC (none: host candidates, for this machine and its network).
    ice_servers: tuple[str, ...] = ()
    #: A WebRTC session closes after this many seconds, or after idle_timeout without a frame.
    session_timeout: float = 4 * 3600.0
    idle_timeout: float = 20.0
    announce: str | None = None  # printed once the service is ready (relight-serve: the page's URL)


def get_settings(conn: HTTPConnection) -> ServeConfig:
    """The running app's settings (set by :func:`relight.service.app.create_app`; HTTP requests
    and websockets alike)."""
    return conn.app.state.settings
