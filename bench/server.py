"""A ``relight-serve`` server for benchmarks and tests: a free loopback port, waiting until ready."""

from __future__ import annotations

import socket
import time


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
