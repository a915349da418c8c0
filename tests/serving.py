"""A real relight-serve app on loopback for the service and browser tests."""

from contextlib import contextmanager

import pytest

from relight.bench.server import free_port, running_app, wait_ready  # noqa: F401 (the tests' helpers)


@contextmanager
def running_server(config, overrides: dict | None = None):
    """:func:`relight.bench.server.running_app`, failing the test when the service does not start."""
    try:
        cm = running_app(config, overrides)
        base = cm.__enter__()
    except RuntimeError as exc:
        pytest.fail(str(exc))
    try:
        yield base
    finally:
        cm.__exit__(None, None, None)
