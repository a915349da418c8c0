"""A ``relight-serve`` server for benchmarks and tests: a free loopback port, waiting until ready."""

from __future__ import annotations

import socket
import time
from contextlib import contextmanager


def free_port() -> int:
    """A TCP port free on loopback now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_ready(base: str, timeout: float, *, alive=None) -> bool:
    """Poll ``base``/readyz until it answers 200 (True), or ``timeout`` seconds pass or
    ``alive()`` turns False (False)."""
    import httpx

    deadline = time.time() + timeout
    while True:
        try:
            if httpx.get(f"{base}/readyz", timeout=1).status_code == 200:
                return True
        except httpx.TransportError:
            pass
        if time.time() > deadline or (alive is not None and not alive()):
            return False
        time.sleep(0.1)


@contextmanager
def running_app(config, overrides: dict | None = None, *, timeout: float = 60.0):
    """Serve ``create_app(config)`` (with FastAPI ``dependency_overrides``) with uvicorn on a free
    loopback port in this process; yield its base URL once /readyz answers 200 (RuntimeError
    after ``timeout`` s), stop it afterwards."""
    import threading

    import uvicorn

    from relight.service.app import create_app

    port = free_port()
    app = create_app(config)
    app.dependency_overrides.update(overrides or {})
    srv = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning"))
    th = threading.Thread(target=srv.run, daemon=True)
    th.start()
    base = f"http://127.0.0.1:{port}"
    try:
        if not wait_ready(base, timeout):
            raise RuntimeError("the service did not become ready")
        yield base
    finally:
        srv.should_exit = True
        th.join(timeout=10)
