"""Who may drive a relight server: a pure ASGI middleware in front of every route.

A relight server runs on the user's machine beside a video call; web pages the user visits run
there too. Three checks (each a test in ``tests/test_security.py``):

* **Origin** (cross-site websocket hijacking, cross-site requests): a request or websocket
  handshake that carries an ``Origin`` header - every browser request a page makes to another
  site does - is refused (HTTP 403; a websocket closed before it opens) unless the origin is
  this server seen from this machine (``http(s)://localhost|127.0.0.1|[::1]:<the listening
  port>``), the page this server served when bound beyond loopback (the request's own host), or
  one of ``--allow-origin``. Clients that are not browsers send no ``Origin`` and pass.
* **Host** (DNS rebinding: a site whose name is made to resolve to 127.0.0.1 is same-origin with
  itself): on a loopback bind, the ``Host`` header must name loopback (or an allowed origin's
  host).
* **Token**: required when binding beyond loopback (``--token`` or ``RELIGHT_TOKEN``; the
  command refuses to start without one), optional otherwise; sent as ``Authorization: Bearer
  TOKEN`` or ``?token=TOKEN`` (the browser page passes its own URL's on), compared in constant
  time. ``/livez`` and ``/readyz`` stay open (probes).
"""

from __future__ import annotations

import hmac
import json
from urllib.parse import parse_qs, urlsplit

#: Host names that mean this machine.
LOOPBACK_NAMES = ("localhost", "127.0.0.1", "::1")
#: Paths open without a token (liveness and readiness probes).
OPEN_PATHS = ("/livez", "/readyz")
#: Shortest token accepted (characters).
MIN_TOKEN = 16


def is_loopback(host: str) -> bool:
    host = host.strip().strip("[]").lower()
    return host in LOOPBACK_NAMES or host.startswith("127.")


def split_host(value: str) -> tuple[str, int | None]:
    """("host", port) of a Host header or an origin's netloc (IPv6 in brackets)."""
    try:
        u = urlsplit("//" + value)
        return (u.hostname or "").lower(), u.port
    except ValueError:
        return "", None


def check_token(token: str | None) -> str | None:
    """The token, checked (None: no token); raises ValueError saying what to change."""
    if token is None or token == "":
        return None
    if len(token) < MIN_TOKEN or not token.isprintable() or " " in token:
        raise ValueError(f"the token must be at least {MIN_TOKEN} printable characters without spaces "
                         "(e.g. python -c 'import secrets; print(secrets.token_urlsafe(24))')")
    return token


class AccessGuard:
    """ASGI middleware applying the Origin, Host and token checks (see the module docstring)."""

    def __init__(self, app, *, bind_host: str, token: str | None, allowed_origins=(), on_refuse=None):
        self.app = app
        self.loopback_bind = is_loopback(bind_host)
        self.token = token.encode() if token else None
        self.allowed = {o.rstrip("/").lower() for o in allowed_origins}
        self.allowed_hosts = {split_host(urlsplit(o).netloc)[0] for o in self.allowed if o != "*"}
        self.on_refuse = on_refuse  # called with the refusal's kind (metrics)

    def origin_ok(self, origin: str, host_header: str, server_port: int | None) -> bool:
        origin = origin.rstrip("/").lower()
        if "*" in self.allowed or origin in self.allowed:
            return True
        u = urlsplit(origin)
        if u.scheme not in ("http", "https"):
            return False
        try:
            port = u.port or (443 if u.scheme == "https" else 80)
        except ValueError:
            return False
        if is_loopback(u.hostname or "") and port == server_port:
            return True
        # Beyond loopback (a token guards it): the page this server served, on the host it was asked for.
        return not self.loopback_bind and u.netloc == host_header.lower() and bool(host_header)

    def _refusal(self, scope) -> tuple[int, str, str] | None:
        headers = {k.decode("latin-1").lower(): v.decode("latin-1") for k, v in scope.get("headers", [])}
        host_header = headers.get("host", "")
        server_port = (scope.get("server") or (None, None))[1]
        if self.loopback_bind and host_header:
            name, _ = split_host(host_header)
            if not is_loopback(name) and name not in self.allowed_hosts:
                return 403, "bad_host", (f"Host {host_header!r} is not this machine: a loopback-bound relight "
                                         "server answers localhost/127.0.0.1 only (add --allow-origin for others)")
        origin = headers.get("origin")
        if origin is not None and not self.origin_ok(origin, host_header, server_port):
            return 403, "bad_origin", (f"Origin {origin!r} may not drive this relight server; start it with "
                                       f"--allow-origin {origin} to allow that page")
        if self.token is not None and scope.get("path") not in OPEN_PATHS:
            given = None
            auth = headers.get("authorization", "")
            if auth.lower().startswith("bearer "):
                given = auth[7:].strip()
            else:
                q = parse_qs(scope.get("query_string", b"").decode("latin-1"))
                given = (q.get("token") or [None])[0]
            if given is None or not hmac.compare_digest(given.encode(), self.token):
                return 401, "bad_token", ("a token is required: send 'Authorization: Bearer TOKEN' or add "
                                          "?token=TOKEN (the one relight-serve was started with)")
        return None

    async def __call__(self, scope, receive, send):
        if scope["type"] not in ("http", "websocket"):
            return await self.app(scope, receive, send)
        refusal = self._refusal(scope)
        if refusal is None:
            return await self.app(scope, receive, send)
        status, kind, message = refusal
        if self.on_refuse is not None:
            self.on_refuse(kind)
        if scope["type"] == "websocket":
            await receive()  # websocket.connect
            await send({"type": "websocket.close", "code": 1008, "reason": message[:120]})
            return
        body = json.dumps({"error": message, "kind": kind}).encode()
        await send({"type": "http.response.start", "status": status,
                    "headers": [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode())]
                    + ([(b"www-authenticate", b"Bearer")] if status == 401 else [])})
        await send({"type": "http.response.body", "body": body})
