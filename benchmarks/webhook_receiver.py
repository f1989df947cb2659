"""A webhook receiver for the live benchmarks: when each notification arrived.

``bench_live.py`` and ``bench_opcua.py`` point ``serve --notify-url`` at it
and time each notification from its outbox row to its arrival.
"""

from __future__ import annotations

import json
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any

__all__ = ["start_receiver"]


def start_receiver() -> tuple[ThreadingHTTPServer, dict[str, float]]:
    """Serve on a free port of 127.0.0.1 in a daemon thread.

    Returns
    -------
    server : ThreadingHTTPServer
        ``server.server_address[1]`` is the port; ``server.shutdown()`` stops it.
    received : dict of str to float
        Notification id to the time (``time.time()``, s) it first arrived.
    """
    received: dict[str, float] = {}

    class Hook(BaseHTTPRequestHandler):
        def do_POST(self) -> None:
            body = self.rfile.read(int(self.headers["Content-Length"]))
            received.setdefault(json.loads(body)["id"], time.time())
            self.send_response(204)
            self.end_headers()

        def log_message(self, *a: Any) -> None:
            pass

    server = ThreadingHTTPServer(("127.0.0.1", 0), Hook)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    return server, received
