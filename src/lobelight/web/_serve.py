"""The web folder served on localhost (``lobelight view --web``): the standard library's HTTP
server, bound to the loopback interface only; a remote machine is reached through an SSH
tunnel."""

from __future__ import annotations

import functools
import http.server
import socket
from pathlib import Path
from typing import ClassVar

from ..errors import InputError

__all__ = ["make_server", "serve", "tunnel_hint"]


class _Handler(http.server.SimpleHTTPRequestHandler):
    """Static files of one folder; JavaScript typed as such, requests not logged."""

    extensions_map: ClassVar[dict[str, str]] = {
        **http.server.SimpleHTTPRequestHandler.extensions_map,
        ".js": "text/javascript",
    }

    def log_message(self, format, *args):
        pass


def make_server(folder, port: int = 8000, host: str = "127.0.0.1") -> http.server.HTTPServer:
    """An HTTP server of ``folder`` on ``host:port`` (0: a free port), not yet serving."""
    folder = Path(folder)
    if not (folder / "index.html").is_file():
        raise InputError(str(folder), "has no index.html: not a web export")
    if not 0 <= int(port) <= 65535:
        raise InputError("--port", f"must be in 0..65535, got {port}")
    handler = functools.partial(_Handler, directory=str(folder))
    try:
        return http.server.ThreadingHTTPServer((host, int(port)), handler)
    except OSError as e:
        raise InputError("--port", f"cannot listen on {host}:{port} ({e.strerror})") from None


def tunnel_hint(port: int) -> str:
    """How to open the page from another machine: an SSH tunnel to this one."""
    return (
        f"from another machine: ssh -L {port}:localhost:{port} {socket.gethostname()} "
        f"then open http://localhost:{port}/"
    )


def serve(folder, port: int = 8000, *, announce=print) -> None:
    """Serve ``folder`` on localhost until interrupted, after announcing its URL and the
    SSH tunnel that reaches it."""
    server = make_server(folder, port)
    p = server.server_address[1]
    announce(f"lobelight web viewer: http://localhost:{p}/  (Ctrl-C stops it)")
    announce(tunnel_hint(p))
    try:
        server.serve_forever()
    except KeyboardInterrupt:
        pass
    finally:
        server.server_close()
