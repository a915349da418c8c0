"""``relight live``'s preview page: the relit frames as MJPEG on loopback, for a browser."""

from __future__ import annotations

import threading

import numpy as np

from .live_camera import LatestFrame

#: The MJPEG preview's JPEG quality.
PREVIEW_QUALITY = 80


class PreviewServer:
    """The relit frames as MJPEG on loopback (``http://127.0.0.1:PORT/``): a browser shows it."""

    def __init__(self, slot: LatestFrame, port: int = 0):
        from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

        self.slot = slot
        preview = self

        class Handler(BaseHTTPRequestHandler):
            def log_message(self, *args):  # quiet
                pass

            def do_GET(self):  # noqa: N802 (http.server's name)
                if self.path == "/":
                    body = (b"<!doctype html><title>relight live</title><body style='margin:0;background:#000'>"
                            b"<img src='/stream.mjpg' style='width:100%'></body>")
                    self.send_response(200)
                    self.send_header("Content-Type", "text/html")
                    self.send_header("Content-Length", str(len(body)))
                    self.end_headers()
                    self.wfile.write(body)
                    return
                if self.path != "/stream.mjpg":
                    self.send_error(404)
                    return
                self.send_response(200)
                self.send_header("Content-Type", "multipart/x-mixed-replace; boundary=frame")
                self.end_headers()
                last = None
                try:
                    while not preview.closed.is_set():
                        item = preview.slot.peek()
                        if item is None or item is last:
                            preview.closed.wait(0.01)
                            continue
                        last = item
                        jpeg = preview.encode(item.as_rgb())
                        self.wfile.write(b"--frame\r\nContent-Type: image/jpeg\r\nContent-Length: "
                                         + str(len(jpeg)).encode() + b"\r\n\r\n" + jpeg + b"\r\n")
                except (BrokenPipeError, ConnectionResetError):
                    return

        self.closed = threading.Event()
        self.httpd = ThreadingHTTPServer(("127.0.0.1", port), Handler)
        self.httpd.daemon_threads = True
        self.url = f"http://127.0.0.1:{self.httpd.server_address[1]}/"
        self._thread = threading.Thread(target=self.httpd.serve_forever, name="relight-preview", daemon=True)
        self._thread.start()

    @staticmethod
    def encode(rgb: np.ndarray) -> bytes:
        import cv2

        bgr = cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)
        ok, buf = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, PREVIEW_QUALITY])
        return buf.tobytes() if ok else b""

    def close(self) -> None:
        self.closed.set()
        self.httpd.shutdown()
        self.httpd.server_close()
