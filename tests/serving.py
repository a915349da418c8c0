"""A real relight-serve app on loopback for the service and browser tests."""

import threading
from contextlib import contextmanager

import pytest

from relight.bench.server import free_port, wait_ready


@contextmanager
def running_server(config, overrides: dict | None = None):
    """Serve ``create_app(config)`` (with FastAPI ``dependency_overrides``) with uvicorn on a free
    loopback port; yield its base URL once /readyz answers 200 (fails the test after a minute),
    stop it afterwards."""
    import uvicorn

    from relight.service.app import create_app

    port = free_port()
    app = create_app(config)
    app.dependency_overrides.update(overrides or {})
    srv = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning"))
    th = threading.Thread(target=srv.run, daemon=True)
    th.start()
    base = f"http://127.0.0.1:{port}"
    if not wait_ready(base, 60):
        pytest.fail("the service did not become ready")
    try:
        yield base
    finally:
        srv.should_exit = True
        th.join(timeout=10)
