"""The served Rerun web viewer, kept on this machine.

Rerun's web viewer asks other hosts for things and no option of rerun-sdk 0.41 turns that
off, so a small ``http.server`` front passes requests on to the ``rerun`` program on a
loopback port, drops the font links, guards ``fetch``, ``XMLHttpRequest``, ``WebSocket`` and
``sendBeacon``, and sends a Content-Security-Policy (docs/recording.md, "The viewers")."""

from __future__ import annotations

import http.client
import re
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

__all__ = ["LoopbackFront", "GUARD"]

#: The page's first script: requests to other hosts fail before they are made.
GUARD = """<script>(function () {
  var here = location.hostname;
  function ok(u) {
    try { var h = new URL(String(u), location.href).hostname; return h === here || h === "127.0.0.1"; }
    catch (e) { return false; }
  }
  var stay = "qchain: the viewer asks no host but this machine";
  var f = window.fetch.bind(window);
  window.fetch = function (r, i) {
    var u = (typeof r === "string" || r instanceof URL) ? r : (r && r.url);
    return ok(u) ? f(r, i) : Promise.reject(new TypeError(stay));
  };
  var open = XMLHttpRequest.prototype.open;
  XMLHttpRequest.prototype.open = function (m, u) {
    if (!ok(u)) { throw new TypeError(stay); }
    return open.apply(this, arguments);
  };
  if (navigator.sendBeacon) { navigator.sendBeacon = function () { return false; }; }
  var WS = window.WebSocket;
  window.WebSocket = function (u, p) { if (!ok(u)) { throw new TypeError(stay); } return new WS(u, p); };
  window.WebSocket.prototype = WS.prototype;
})();</script>"""

_FONT_LINK = re.compile(rb"<link[^>]*fonts\.(googleapis|gstatic)\.com[^>]*>", re.S)


def _csp(grpc_port: int) -> str:
    local = f"'self' http://127.0.0.1:{grpc_port} http://localhost:{grpc_port}"
    return ("default-src 'self'; "
            "script-src 'self' 'unsafe-inline' 'unsafe-eval' 'wasm-unsafe-eval' blob:; "
            "style-src 'self' 'unsafe-inline'; img-src 'self' data: blob:; font-src 'self' data:; "
            f"connect-src {local} blob: data:; worker-src 'self' blob:")


class _QuietServer(ThreadingHTTPServer):
    """The front's server: a client that sends garbage or goes away mid-request is that
    client's trouble, not the run's: no traceback on the run's stderr (the standard
    library's ``handle_error`` prints one)."""

    daemon_threads = True

    def handle_error(self, request, client_address) -> None:
        pass


class LoopbackFront:
    """An HTTP front before the ``rerun`` program's web server.

    Parameters
    ----------
    bind : str
        Address to listen on (127.0.0.1 by default upstream of here).
    port : int
        Port to listen on.
    upstream : int
        Port of the ``rerun`` program's web server on 127.0.0.1.
    grpc_port : int
        Port of the gRPC data server the page connects to (on 127.0.0.1).
    """

    def __init__(self, bind: str, port: int, upstream: int, grpc_port: int):
        csp = _csp(grpc_port)

        class Handler(BaseHTTPRequestHandler):
            protocol_version = "HTTP/1.1"

            def log_message(self, *args) -> None:  # quiet
                pass

            def do_GET(self) -> None:  # noqa: N802 - the http.server API
                conn = http.client.HTTPConnection("127.0.0.1", upstream, timeout=30)
                try:
                    conn.request("GET", self.path, headers={"Accept-Encoding": "identity"})
                    resp = conn.getresponse()
                    body = resp.read()
                    headers = [(k, v) for k, v in resp.getheaders()
                               if k.lower() not in ("content-length", "transfer-encoding", "connection",
                                                    "content-security-policy", "content-encoding")]
                    status = resp.status
                except OSError as exc:
                    self.send_error(502, f"the Rerun web viewer is not reachable ({exc})")
                    return
                finally:
                    conn.close()
                ctype = dict((k.lower(), v) for k, v in headers).get("content-type", "")
                if ctype.startswith("text/html"):
                    body = _FONT_LINK.sub(b"", body)
                    body = body.replace(b"<head>", b"<head>" + GUARD.encode(), 1)
                self.send_response(status)
                for k, v in headers:
                    self.send_header(k, v)
                self.send_header("Content-Security-Policy", csp)
                self.send_header("Content-Length", str(len(body)))
                self.end_headers()
                self.wfile.write(body)

        self.server = _QuietServer((bind, port), Handler)
        self.port = self.server.server_address[1]
        self.thread = threading.Thread(target=self.server.serve_forever, name="qchain-web-front", daemon=True)
        self.thread.start()

    def close(self) -> None:
        self.server.shutdown()
        self.server.server_close()
