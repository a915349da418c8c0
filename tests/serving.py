"""A real relight-serve app on loopback for the service and browser tests."""

import socket
import threading
import time
from contextlib import contextmanager

import pytest


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextmanager
def running_server(config):
    """Serve ``create_app(config)`` with uvicorn on a free loopback port; yield its base URL once
    /readyz answers 200 (fails the test after a minute), stop it afterwards."""
    import httpx
    import uvicorn

    from relight.service.app import create_app

    port = free_port()
    srv = uvicorn.Server(uvicorn.Config(create_app(config), host="127.0.0.1", port=port, log_level="warning"))
    th = threading.Thread(target=srv.run, daemon=True)
    th.start()
    base = f"http://127.0.0.1:{port}"
    deadline = time.time() + 60
    while True:
        try:
            if httpx.get(f"{base}/readyz", timeout=1).status_code == 200:
                break
        except httpx.TransportError:
            pass
        if time.time() > deadline:
            pytest.fail("the service did not become ready")
        time.sleep(0.1)
    try:
        yield base
    finally:
        srv.should_exit = True
        th.join(timeout=10)
