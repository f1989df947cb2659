"""The web server's connections: how long they may idle, how many at once.

uvicorn closes a kept-alive connection that stays idle after a response
(``timeout_keep_alive``), but not one that never completes a request: a
client that opens connections and sends nothing, or a request's headers a
byte at a time, held a file descriptor each for ever, until the process ran
out of them. :class:`GuardedH11Protocol` gives every request's headers
:data:`HEADERS_TIMEOUT_S` from its first byte (from the connection's opening
for the first request) and closes the connections beyond the concurrency
bound at once; :func:`connection_limit` puts that bound below the process's
file limit; :func:`server_config` is uvicorn's configuration with them.
"""

from __future__ import annotations

import asyncio
import logging
import resource
from pathlib import Path
from typing import Any

import uvicorn
from uvicorn.protocols.http.h11_impl import H11Protocol

__all__ = [
    "FILES_RESERVED",
    "HEADERS_TIMEOUT_S",
    "KEEP_ALIVE_S",
    "MAX_HEADERS_BYTES",
    "GuardedH11Protocol",
    "connection_limit",
    "server_config",
]

log = logging.getLogger("chaintwin.live.web")

HEADERS_TIMEOUT_S = 10.0
"""A request's headers must arrive within this long of their first byte
(a new connection's, of its opening), s; the connection is closed otherwise."""

KEEP_ALIVE_S = 75
"""An idle kept-alive connection is closed after this long, s. Dashboards poll
every few seconds: longer than that (uvicorn's default of 5 s races a 5 s poll)."""

MAX_HEADERS_BYTES = 16 * 1024
"""Largest request line and headers, bytes (h11's limit of an incomplete event)."""

FILES_RESERVED = 256
"""File descriptors kept back from the connections: the store, the watched
folders, the log, temporary files of uploads."""


def connection_limit(reserved: int = FILES_RESERVED) -> tuple[int, int]:
    """The bound on concurrent connections and the file limit it is taken from.

    Three quarters of the process's soft limit on open files
    (``RLIMIT_NOFILE``), and at least :data:`FILES_RESERVED` below it; never
    fewer than 16.
    """
    soft, _hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft == resource.RLIM_INFINITY:
        soft = 1 << 20
    return max(16, min(soft - reserved, soft * 3 // 4)), soft


class GuardedH11Protocol(H11Protocol):
    """uvicorn's HTTP/1.1 protocol with a deadline for headers and a hard connection bound."""

    headers_timeout_s: float = HEADERS_TIMEOUT_S
    refused_logged: bool = False

    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        """Count the connection in; close it at once beyond the bound, else start its deadline."""
        self._deadline: asyncio.TimerHandle | None = None
        super().connection_made(transport)
        if self.limit_concurrency is not None and len(self.connections) > self.limit_concurrency:
            if not GuardedH11Protocol.refused_logged:  # once: a flood must not flood the log
                GuardedH11Protocol.refused_logged = True
                log.warning(
                    "more than %d connections at once: the ones beyond are closed at once "
                    "(logged only once)",
                    self.limit_concurrency,
                )
            self.transport.close()
            return
        self._start_deadline()

    def _start_deadline(self) -> None:
        if self._deadline is None:
            self._deadline = self.loop.call_later(self.headers_timeout_s, self._too_slow)

    def _stop_deadline(self) -> None:
        if self._deadline is not None:
            self._deadline.cancel()
            self._deadline = None

    def _waiting_for_headers(self) -> bool:
        return self.cycle is None or self.cycle.response_complete

    def data_received(self, data: bytes) -> None:
        """Feed the bytes in; a request's first bytes start its deadline, its headers end it."""
        if self._waiting_for_headers():
            self._start_deadline()
        super().data_received(data)
        if not self._waiting_for_headers():
            self._stop_deadline()

    def connection_lost(self, exc: Exception | None) -> None:
        """Forget the deadline with the connection."""
        self._stop_deadline()
        super().connection_lost(exc)

    def _too_slow(self) -> None:
        self._deadline = None
        if self._waiting_for_headers() and not self.transport.is_closing():
            self.transport.close()


def server_config(
    app: Any,
    *,
    host: str,
    port: int,
    ssl_certfile: Path | None = None,
    ssl_keyfile: Path | None = None,
    forwarded_allow_ips: str | None = None,
    headers_timeout_s: float = HEADERS_TIMEOUT_S,
    keep_alive_s: int = KEEP_ALIVE_S,
) -> uvicorn.Config:
    """uvicorn's configuration of ``serve``: the connection guards, the trusted proxies.

    Parameters
    ----------
    app : ASGI app
        The application.
    host, port : str, int
        Where to listen.
    ssl_certfile, ssl_keyfile : Path, optional
        TLS served by uvicorn itself.
    forwarded_allow_ips : str, optional
        The proxies whose ``X-Forwarded-For`` and ``X-Forwarded-Proto`` are
        believed (comma-separated addresses or networks, ``*`` for any);
        uvicorn's default (``FORWARDED_ALLOW_IPS``, else 127.0.0.1) if None.
    headers_timeout_s : float
        :data:`HEADERS_TIMEOUT_S`.
    keep_alive_s : int
        :data:`KEEP_ALIVE_S`.
    """
    limit, files = connection_limit()
    log.info("serving at most %d connections at once (open-file limit %d)", limit, files)
    protocol = type("Guarded", (GuardedH11Protocol,), {"headers_timeout_s": headers_timeout_s})
    return uvicorn.Config(
        app,
        host=host,
        port=port,
        log_level="warning",
        http=protocol,
        ssl_certfile=str(ssl_certfile) if ssl_certfile else None,
        ssl_keyfile=str(ssl_keyfile) if ssl_keyfile else None,
        proxy_headers=True,
        forwarded_allow_ips=forwarded_allow_ips,
        timeout_keep_alive=keep_alive_s,
        limit_concurrency=limit,
        h11_max_incomplete_event_size=MAX_HEADERS_BYTES,
        # a stop waits for the requests in hand, not for ever
        timeout_graceful_shutdown=20,
    )
