"""``relight live``'s page on loopback: the relit frames (MJPEG, with a before/after split), and
the control surface of the light - a grey and a skin-toned ball lit by it where dragging places
the key light, the environments' thumbnails, uploads (maps and photos), strength, mode,
exposure, turn and spin, fps / latency / CPU, a snapshot, and lights saved by name.

Endpoints (``http://127.0.0.1:PORT/``; loopback only, the Host header must name loopback and a
browser's Origin must be this page's, so no other site can drive it):

* ``GET /`` the page; ``GET /stream.mjpg`` the relit frames (the split, when set, shows the camera
  frame left of it); ``GET /snapshot.png`` the newest relit frame (``?with=camera``: the camera
  frame it was relit from beside it, on its left);
* ``GET /state`` JSON: the choices of environment, the one in use (and its key light's fields),
  strength, mode, exposure, turn, spin, split, the last period's figures, the last light's
  latency (ms from a change asked to the first frame relit with it), the saved lights;
* ``POST /control`` a JSON object with any of ``env`` (a listed source, a preset name or a key
  light ``key:az=..,el=..``), ``strength``, ``mode``, ``exposure``, ``turn``, ``spin``,
  ``split`` (0-1, or null for none);
* ``GET /light.png`` the balls under the light in use (``?env=SOURCE`` another listed one);
  ``GET /thumb.png?env=SOURCE`` an environment's tone-mapped lat-long thumbnail;
* ``POST /upload?photo=true|false`` a map or a photo (body: the file, its type in Content-Type),
  kept under the lights folder and chosen; ``POST /save?name=NAME`` the light in use saved as
  ``NAME.json`` in the lights folder (``--env NAME.json`` gives it back).
"""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path
from urllib.parse import parse_qs, urlsplit

import numpy as np

from relight.directions import ENV_TURN_RANGE_DEG

from ..engine.frame_slot import LatestFrame
from ..service.controls import RANGES
from ..service.security import is_loopback, split_host

#: The MJPEG preview's JPEG quality, and its most frames a second to a viewer (a monitor of the
#: relit camera: RGB and a JPEG are made for it at this rate at most, off the frames' path).
PREVIEW_QUALITY = 80
PREVIEW_FPS = 15.0
#: Largest bodies read: a control, and an uploaded map or photo (bytes).
MAX_CONTROL = 4096
MAX_UPLOAD = 64 << 20
#: Upload types and the file suffix each is kept under.
UPLOAD_TYPES = {"image/jpeg": ".jpg", "image/png": ".png", "image/x-exr": ".exr", "image/vnd.radiance": ".hdr"}
#: The ball preview's and the thumbnails' sizes (pixels).
BALL_SIZE = 96
THUMB_WIDTH = 128
#: The line that says how to use the relit camera in a call.
WEBCAM_HINT = ("To be relit in a call: run relight live with --virtual-camera and pick 'relight' (OBS "
               "Virtual Camera on macOS/Windows, the v4l2loopback device on Linux) as the camera in Zoom, "
               "Meet or Teams.")


def default_lights_dir() -> Path:
    """Where saved lights and uploads go unless told: $XDG_CONFIG_HOME/relight/lights (or
    ~/.config/relight/lights)."""
    import os

    base = os.environ.get("XDG_CONFIG_HOME") or str(Path.home() / ".config")
    return Path(base) / "relight" / "lights"


def split_frame(relit: np.ndarray, src: np.ndarray, split: float) -> np.ndarray:
    """The camera frame left of ``split`` (0-1 of the width), the relit frame right of it, a thin
    white line between."""
    w = relit.shape[1]
    x = int(round(np.clip(split, 0.0, 1.0) * w))
    out = relit.copy()
    out[:, :x] = src[:, :x]
    out[:, max(x - 1, 0):min(x + 1, w)] = 255
    return out


class PreviewServer:
    """The page and its endpoints (see the module docstring) on ``127.0.0.1:port``. ``slot``: the
    relit frames (:class:`RelitFrame` items); ``controls``: the run's :class:`.live_controls.
    Controls` (None: the page shows the frames only); ``status``: the status line (its figures);
    ``result``: the run's :class:`.live_status.LiveResult` (its light latencies)."""

    def __init__(self, slot: LatestFrame, port: int = 0, *, controls=None, status=None, result=None,
                 lights_dir=None):
        from http.server import ThreadingHTTPServer

        self.slot = slot
        self.controls, self.status, self.result = controls, status, result
        self.lights_dir = Path(lights_dir) if lights_dir is not None else default_lights_dir()
        self.closed = threading.Event()
        self.httpd = ThreadingHTTPServer(("127.0.0.1", port), _handler(self))
        self.httpd.daemon_threads = True
        self.port = self.httpd.server_address[1]
        self.url = f"http://127.0.0.1:{self.port}/"
        self._thread = threading.Thread(target=self.httpd.serve_forever, name="relight-preview", daemon=True)
        self._thread.start()

    @staticmethod
    def encode(rgb: np.ndarray, ext: str = ".jpg") -> bytes:
        """(H, W, 3) uint8 RGB as a JPEG (:func:`relight.service.codec.jpeg_from_rgb`, as the
        service's frames) or, ``ext`` ".png", a PNG."""
        import cv2

        if ext == ".jpg":
            from ..service.codec import jpeg_from_rgb

            return jpeg_from_rgb(rgb, PREVIEW_QUALITY)
        ok, buf = cv2.imencode(ext, cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
        return buf.tobytes() if ok else b""

    def frame_rgb(self, item) -> np.ndarray:
        """A relit item as shown: the split applied when one is set (a frame kept in its planes
        converted by OpenCV's fast path: a viewer's picture, not a recording)."""
        from relight.video_yuv import view_rgb

        rgb = view_rgb(item.rgb)
        split = self.controls.split if self.controls is not None else None
        if split is not None and item.src is not None:
            src = view_rgb(item.src)
            if src.shape == rgb.shape:
                return split_frame(rgb, src, split)
        return rgb

    # ------------------------------------------------------------------ the page's state and controls
    def choices(self) -> list[str]:
        """The environments the page lists: the run's (command line, chosen, uploaded), then the
        built-ins and presets not among them."""
        from relight.envmap import BUILTINS
        from relight.presets import PRESETS

        c = self.controls
        with c.lock:
            listed = list(c.envs)
        more = [f"builtin:{n}" for n in (*BUILTINS, *PRESETS)]
        return listed + [s for s in more if s not in listed]

    def state(self) -> dict:
        from ..engine.composite import MODES

        c = self.controls
        env, mode, strength, ev, turn, spin = c.wanted()
        saved = sorted(p.stem for p in self.lights_dir.glob("*.json")) if self.lights_dir.is_dir() else []
        return {"envs": self.choices(), "env": env, "key": _key_fields(env), "mode": mode, "modes": list(MODES),
                "strength": strength, "exposure": ev, "turn": turn, "spin": spin, "split": c.split,
                "ranges": {k: _RANGES[k] for k in ("exposure", "turn", "spin")},
                "figures": self.status.figures if self.status is not None else {},
                "light_ms": self.result.light_ms[-1] if self.result is not None and self.result.light_ms else None,
                "saved": saved, "lights_dir": str(self.lights_dir), "webcam": WEBCAM_HINT}

    def control(self, doc) -> dict:
        """Apply a control object (see the module docstring); ValueError saying what to change."""
        from relight.errors import InputError

        from ..engine.composite import MODES

        if not isinstance(doc, dict):
            raise ValueError("controls are a JSON object")
        ranges = _RANGES
        values = {}
        for key, (lo, hi) in ranges.items():
            if key in doc:
                v = doc[key]
                if key == "split" and v is None:
                    values[key] = None
                    continue
                if isinstance(v, bool) or not isinstance(v, int | float) or not (lo <= v <= hi):
                    raise ValueError(f"{key} {v!r}: use {lo:g} to {hi:g}")
                values[key] = float(v)
        if "mode" in doc:
            if doc["mode"] not in MODES:
                raise ValueError(f"mode: one of {', '.join(MODES)}")
            values["mode"] = doc["mode"]
        unknown = set(doc) - set(ranges) - {"mode", "env"}
        if unknown:
            raise ValueError(f"unknown control(s) {', '.join(sorted(unknown))}")
        if "env" in doc:
            source = self._source(doc["env"])
            try:
                self.controls.select(source)
            except InputError as exc:
                raise ValueError(str(exc)) from None
        if values:
            self.controls.set_values(**values)
        return self.state()

    def _source(self, name) -> str:
        """A page's environment name as a source the run may load: a listed one, a preset, a key."""
        from relight.errors import InputError
        from relight.key_light import key_source

        if not isinstance(name, str) or len(name) > 4096:
            raise ValueError("env: name a listed environment, a preset or a key light key:az=..,el=..")
        if name in self.choices():
            return name
        try:
            source = key_source(name)
        except InputError as exc:
            raise ValueError(str(exc)) from None
        if source is not None:
            return source
        raise ValueError(f"env {name!r}: choose a listed environment, a preset or a key light key:az=..,el=..")

    def upload(self, body: bytes, ctype: str, photo: bool, name: str = "") -> dict:
        """A map or photo uploaded (``name``: the user's file name, kept in the stored one) and
        chosen; ValueError for another type, an empty body or a file that does not load."""
        import hashlib
        import re

        suffix = UPLOAD_TYPES.get(ctype)
        if suffix is None:
            raise ValueError(f"content type {ctype or 'none'!r}: send {', '.join(UPLOAD_TYPES)}")
        if not body:
            raise ValueError("the upload is empty")
        folder = self.lights_dir / "uploads"
        folder.mkdir(parents=True, exist_ok=True)
        stem = re.sub(r"[^A-Za-z0-9_-]+", "-", Path(name).stem)[:40].strip("-")
        digest = hashlib.sha256(body).hexdigest()[:10]
        path = folder / (f"{stem}-{digest}{suffix}" if stem else f"{digest}{suffix}")
        if not path.exists():
            from relight.imageio import atomic_path

            with atomic_path(path) as tmp:
                Path(tmp).write_bytes(body)
        return self._choose_upload(path, photo)

    def _choose_upload(self, path: Path, photo: bool) -> dict:
        from relight.errors import InputError

        source = f"photo:{path}" if photo else str(path)
        try:
            self.controls.select(source)  # loaded (validated) first: a bad file changes nothing
        except InputError as exc:
            path.unlink(missing_ok=True)
            raise ValueError(str(exc).replace(str(path), "the uploaded file")) from None
        return self.state()

    def save(self, name: str) -> dict:
        from relight.errors import InputError
        from relight.saved_light import light_document, save_light

        env, _, _, ev, turn, _ = self.controls.wanted()
        prefix = "photo:" if env.startswith("photo:") else ""
        path = Path(env[len(prefix):])
        if not env.startswith("builtin:") and path.is_absolute():
            try:  # an upload: named relative to the lights folder, which keeps it
                env = prefix + str(path.relative_to(self.lights_dir))
            except ValueError:
                pass
        try:
            out = save_light(self.lights_dir, name, light_document(env, turn, ev))
        except InputError as exc:
            raise ValueError(str(exc)) from None
        return {"saved": str(out), "use": f"--env {out}"}

    def light_png(self, source: str | None = None) -> bytes:
        from relight.light_preview import balls_png

        c = self.controls
        env = c.environment(source) if source is not None else c.environment()
        return balls_png(env, BALL_SIZE, c.turn if source is None else 0.0)

    def thumb_png(self, source: str) -> bytes:
        from relight.colour import encode_srgb8, luminance
        from relight.light_preview import shrunk

        small = shrunk(self.controls.environment(source), THUMB_WIDTH)
        mapped = small / (1.0 + luminance(small)[..., None] / max(float(np.percentile(luminance(small), 90)), 1e-6))
        return self.encode(encode_srgb8(np.clip(mapped, 0.0, 1.0)), ".png")

    def close(self) -> None:
        self.closed.set()
        self.httpd.shutdown()
        self.httpd.server_close()


#: The page's numeric controls and their ranges: the stream's (service.controls.RANGES: strength,
#: exposure, spin), the environment's turn, and the before/after split (0-1 of the width).
_RANGES = {**RANGES, "turn": ENV_TURN_RANGE_DEG, "split": (0.0, 1.0)}


def _key_fields(source: str) -> dict | None:
    """A key light's fields when ``source`` is one, else None."""
    if not (source == "builtin:key" or source.startswith("builtin:key:")):
        return None
    from dataclasses import asdict

    from relight.key_light import KeyLight

    return asdict(KeyLight.parse(source[len("builtin:key:"):]))


def _handler(preview: PreviewServer):
    """The request handler class of ``preview``'s page (:class:`_PageHandler` bound to it)."""
    from http.server import BaseHTTPRequestHandler

    page = (Path(__file__).parent / "static" / "live.html").read_bytes()

    class Handler(_PageHandler, BaseHTTPRequestHandler):
        pass

    Handler.preview, Handler.page = preview, page
    return Handler


def _query(url) -> dict:
    """A URL's query as {name: its last value}."""
    return {k: v[-1] for k, v in parse_qs(url.query).items()}


class _PageHandler:
    """The page's requests (mixed into an ``http.server.BaseHTTPRequestHandler`` by
    :func:`_handler`, which sets ``preview``: the :class:`PreviewServer`, and ``page``: the HTML)."""

    preview: PreviewServer
    page: bytes

    def log_message(self, *args):  # quiet
        pass

    def _send(self, code: int, body: bytes, ctype: str) -> None:
        self.send_response(code)
        self.send_header("Content-Type", ctype)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        self.end_headers()
        self.wfile.write(body)

    def _json(self, code: int, doc) -> None:
        self._send(code, json.dumps(doc).encode(), "application/json")

    def _allowed(self) -> bool:
        """Host names loopback (no DNS rebinding); a browser's Origin is this page's."""
        host, _ = split_host(self.headers.get("Host", ""))
        origin = self.headers.get("Origin")
        if host and not is_loopback(host):
            self._json(403, {"error": "the page answers localhost/127.0.0.1 only", "kind": "bad_host"})
            return False
        if origin is not None:
            u = urlsplit(origin)
            if not (is_loopback(u.hostname or "") and u.port == self.preview.port):
                self._json(403, {"error": f"Origin {origin!r} may not drive relight live", "kind": "bad_origin"})
                return False
        return True

    # ------------------------------------------------------------------ GET
    def do_GET(self):  # noqa: N802 (http.server's name)
        if not self._allowed():
            return
        url = urlsplit(self.path)
        query = _query(url)
        try:
            return self._get(url.path, query)
        except (BrokenPipeError, ConnectionResetError):
            return
        except Exception as exc:  # a page's request never stops the run
            return self._json(400, {"error": str(exc), "kind": "bad_request"})

    def _get(self, path: str, query: dict):
        """A GET answered by its path (see the module docstring)."""
        preview = self.preview
        if path == "/":
            return self._send(200, self.page, "text/html; charset=utf-8")
        if path == "/stream.mjpg":
            return self._stream()
        if path == "/snapshot.png":
            return self._snapshot(query)
        if preview.controls is None:
            return self._json(404, {"error": "not found", "kind": "not_found"})
        if path == "/state":
            return self._json(200, preview.state())
        if path in ("/light.png", "/thumb.png"):
            source = query.get("env")
            if source is not None and source not in preview.choices():
                return self._json(404, {"error": f"env {source!r} is not listed", "kind": "not_found"})
            if path == "/thumb.png" and source is None:
                source = preview.controls.env
            body = preview.light_png(source) if path == "/light.png" else preview.thumb_png(source)
            return self._send(200, body, "image/png")
        return self._json(404, {"error": "not found", "kind": "not_found"})

    def _snapshot(self, query: dict):
        """The newest relit frame as a PNG (``with=camera``: its camera frame on its left)."""
        item = self.preview.slot.peek()
        if item is None:
            return self._json(503, {"error": "no relit frame yet", "kind": "not_ready"})
        rgb = item.as_rgb()
        if query.get("with") == "camera" and item.src is not None:  # [camera | relit], one frame's
            from relight.video_yuv import as_rgb

            rgb = np.hstack([as_rgb(item.src), rgb])
        return self._send(200, self.preview.encode(rgb, ".png"), "image/png")

    def _stream(self):
        """The relit frames as MJPEG (at most PREVIEW_FPS a second, a frame once) until the server closes."""
        preview = self.preview
        self.send_response(200)
        self.send_header("Content-Type", "multipart/x-mixed-replace; boundary=frame")
        self.send_header("Cache-Control", "no-store")
        self.end_headers()
        last, due = None, 0.0
        while not preview.closed.is_set():
            item = preview.slot.peek()
            wait = due - time.perf_counter()
            if item is None or item is last or wait > 0:
                preview.closed.wait(max(min(wait, 0.05), 0.005))
                continue
            last, due = item, time.perf_counter() + 1.0 / PREVIEW_FPS
            jpeg = preview.encode(preview.frame_rgb(item))
            self.wfile.write(b"--frame\r\nContent-Type: image/jpeg\r\nContent-Length: "
                             + str(len(jpeg)).encode() + b"\r\n\r\n" + jpeg + b"\r\n")

    # ------------------------------------------------------------------ POST
    def do_POST(self):  # noqa: N802
        if not self._allowed():
            return
        if self.preview.controls is None:
            return self._json(404, {"error": "not found", "kind": "not_found"})
        url = urlsplit(self.path)
        query = _query(url)
        try:
            length = int(self.headers.get("Content-Length") or 0)
        except ValueError:
            return self._json(400, {"error": "bad Content-Length", "kind": "bad_request"})
        limit = MAX_UPLOAD if url.path == "/upload" else MAX_CONTROL
        if length < 0 or length > limit:
            return self._json(413, {"error": f"at most {limit} bytes", "kind": "too_large"})
        body = self.rfile.read(length) if length else b""
        try:
            return self._post(url.path, query, body)
        except (ValueError, UnicodeDecodeError, RecursionError) as exc:
            return self._json(422, {"error": str(exc), "kind": "bad_control"})
        except Exception as exc:  # a page's request never stops the run
            return self._json(400, {"error": str(exc), "kind": "bad_request"})

    def _post(self, path: str, query: dict, body: bytes):
        """A POST answered by its path: a control, an upload, a light saved (see the module docstring)."""
        preview = self.preview
        if path == "/control":
            return self._json(200, preview.control(json.loads(body.decode("utf-8") or "null")))
        if path == "/upload":
            ctype = (self.headers.get("Content-Type") or "").split(";")[0].strip().lower()
            photo = query.get("photo", "false").lower() in ("1", "true", "yes")
            return self._json(200, preview.upload(body, ctype, photo, query.get("name", "")))
        if path == "/save":
            return self._json(200, preview.save(query.get("name", "")))
        return self._json(404, {"error": "not found", "kind": "not_found"})
