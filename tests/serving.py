"""What the service, browser and live tests share: a real relight-serve app on loopback, and
reading a running command's status lines."""

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


def wait_line(proc, word: str, deadline: float) -> str:
    """The first line of ``proc``'s stderr holding ``word``, read until ``deadline`` (time.time());
    AssertionError when it never comes."""
    import time

    while time.time() < deadline:
        line = proc.stderr.readline()
        if not line:
            break
        if word in line:
            return line
    raise AssertionError(f"the command never printed {word!r}")
