"""The web service's door: who asks before any body is read, bounded bodies, headers.

:class:`Guard` is a pure ASGI middleware in front of the application:

* a request that carries a body (``POST``, ``PUT``, ``PATCH``, ``DELETE``)
  has its principal found from its headers (bearer token or session cookie)
  *before* a byte of the body is read, and kept in the scope for the
  handlers (:data:`~chaintwin.web.security.PRINCIPAL`); an API call or an
  upload without a valid one is answered 401 (a page: a redirect to the
  login) at once, nothing read, nothing written;
* the body is then counted as it arrives: an upload may hold the upload
  limit (and :data:`MULTIPART_SLACK_BYTES` for the parts' headers), any
  other body :data:`FORM_LIMIT_BYTES` (the login form carries its token in
  the body, the forms their CSRF token); a body that passes its limit is
  refused 413 as soon as it does, whether it declared its length or not
  (chunked), and one that stalls for :data:`BODY_IDLE_S` 408;
* login attempts are counted per client (:class:`LoginAttempts`): beyond
  :data:`LOGIN_ATTEMPTS` a minute, 429 with ``Retry-After``;
* every response carries the security headers (:data:`SECURITY_HEADERS`).
"""

from __future__ import annotations

import asyncio
import math
import time
from collections import OrderedDict, deque
from collections.abc import Awaitable, Callable
from typing import Any

from fastapi.concurrency import run_in_threadpool
from starlette.requests import Request
from starlette.responses import Response
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from chaintwin.web.security import PRINCIPAL, Principal

__all__ = [
    "BODY_IDLE_S",
    "FORM_LIMIT_BYTES",
    "LOGIN_ATTEMPTS",
    "MULTIPART_SLACK_BYTES",
    "SECURITY_HEADERS",
    "UPLOAD_PATHS",
    "Guard",
    "LoginAttempts",
]

FORM_LIMIT_BYTES = 64 * 1024
"""Largest body of a request other than an upload (the login and other forms, JSON), bytes."""

MULTIPART_SLACK_BYTES = 64 * 1024
"""What an upload's body may hold beside its files (the parts' headers, boundaries), bytes."""

BODY_IDLE_S = 30.0
"""A body that sends nothing for this long is refused (408), s."""

UPLOAD_PATHS = frozenset({"/api/v1/recordings", "/upload"})
"""The requests whose bodies are files (the upload limit, not the form limit)."""

BODY_METHODS = frozenset({"POST", "PUT", "PATCH", "DELETE"})
"""The methods whose requests are guarded before their bodies are read."""

LOGIN_ATTEMPTS = 10
"""Login attempts a client may make in :data:`LOGIN_WINDOW_S` (429 beyond)."""

LOGIN_WINDOW_S = 60.0
"""The window login attempts are counted in, s."""

CONTENT_SECURITY_POLICY = "; ".join(
    (
        "default-src 'self'",
        "script-src 'self'",  # no inline script: the pages start from their static files
        # Plotly and Swagger UI set styles from their scripts
        "style-src 'self' 'unsafe-inline'",
        "img-src 'self' data: blob:",
        "font-src 'self' data:",
        "connect-src 'self'",
        "object-src 'none'",
        "base-uri 'none'",
        "form-action 'self'",
        "frame-ancestors 'none'",
    )
)
"""The pages' Content-Security-Policy: everything from the server itself, never framed."""

SECURITY_HEADERS: tuple[tuple[bytes, bytes], ...] = (
    (b"content-security-policy", CONTENT_SECURITY_POLICY.encode()),
    (b"x-content-type-options", b"nosniff"),
    (b"x-frame-options", b"DENY"),
    (b"referrer-policy", b"same-origin"),
)
"""Headers every response carries (unless it sets its own)."""

Refuse = Callable[[Request, int, str, str, dict[str, str]], Awaitable[Response]]
"""Builds the answer to a refused request: (request, status, code, message, headers)."""


class LoginAttempts:
    """Login attempts per client in a sliding window (in this process).

    Parameters
    ----------
    attempts : int
        Attempts allowed per ``window_s``.
    window_s : float
        The window, s.
    clients : int
        Most clients remembered (the oldest forgotten first): memory stays
        bounded whatever addresses arrive.
    clock : callable
        The time, s (monotonic).
    """

    def __init__(
        self,
        attempts: int = LOGIN_ATTEMPTS,
        window_s: float = LOGIN_WINDOW_S,
        clients: int = 10_000,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.attempts = attempts
        self.window_s = window_s
        self.clients = clients
        self.clock = clock
        self._seen: OrderedDict[str, deque[float]] = OrderedDict()

    def wait_s(self, client: str) -> float | None:
        """Count an attempt of ``client``; None if allowed, else the seconds to wait."""
        now = self.clock()
        times = self._seen.pop(client, None) or deque()
        while times and times[0] <= now - self.window_s:
            times.popleft()
        self._seen[client] = times  # the newest last
        if len(self._seen) > self.clients:
            self._seen.popitem(last=False)
        if len(times) >= self.attempts:
            return times[0] + self.window_s - now
        times.append(now)
        return None


class _Refused(Exception):
    """A body refused while it was being read (its answer is sent instead of the app's)."""

    def __init__(self, status: int, code: str, message: str) -> None:
        super().__init__(message)
        self.status = status
        self.code = code
        self.message = message


def _with_security_headers(send: Send) -> Send:
    async def sending(message: Message) -> None:
        if message["type"] == "http.response.start":
            headers = list(message.get("headers", []))
            present = {name.lower() for name, _value in headers}
            headers += [(n, v) for n, v in SECURITY_HEADERS if n not in present]
            message = {**message, "headers": headers}
        await send(message)

    return sending


async def _no_body() -> Message:
    return {"type": "http.request", "body": b"", "more_body": False}


class Guard:
    """The ASGI middleware of the module notes.

    Parameters
    ----------
    app : ASGI app
        The application it guards.
    principal : callable
        The principal of a request (blocking: run in a worker thread), or None.
    upload_limit : callable
        The largest upload's files, bytes.
    refuse : callable
        The answer to a refused request (API: the JSON error; a page: its page
        or a redirect to the login).
    logins : LoginAttempts, optional
        The login attempts counted (one per application by default).
    """

    def __init__(
        self,
        app: ASGIApp,
        principal: Callable[[Request], Principal | None],
        upload_limit: Callable[[], int],
        refuse: Refuse,
        logins: LoginAttempts | None = None,
    ) -> None:
        self.app = app
        self.principal = principal
        self.upload_limit = upload_limit
        self.refuse = refuse
        self.logins = logins if logins is not None else LoginAttempts()

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        send = _with_security_headers(send)
        if scope["method"] not in BODY_METHODS:
            await self.app(scope, receive, send)
            return
        request = Request(scope)  # its headers only: the body is not read here
        path: str = scope["path"]

        async def answer(status: int, code: str, message: str, **headers: str) -> None:
            response = await self.refuse(request, status, code, message, headers)
            await response(scope, _no_body, send)

        if path == "/login":
            client = scope["client"][0] if scope.get("client") else ""
            wait = self.logins.wait_s(client)
            if wait is not None:
                seconds = max(1, math.ceil(wait))
                await answer(
                    429,
                    "too_many_requests",
                    f"too many login attempts from {client}; try again in {seconds} s",
                    **{"Retry-After": str(seconds)},
                )
                return
        elif PRINCIPAL not in scope:
            scope[PRINCIPAL] = await run_in_threadpool(self.principal, request)
        upload = path in UPLOAD_PATHS
        if scope.get(PRINCIPAL) is None and (upload or path.startswith("/api/")):
            await answer(401, "unauthorized", "send a valid token: Authorization: Bearer <token>")
            return
        limit = self.upload_limit() + MULTIPART_SLACK_BYTES if upload else FORM_LIMIT_BYTES
        too_large = _Refused(
            413, "too_large", _too_large(self.upload_limit() if upload else limit, upload)
        )
        declared = request.headers.get("content-length", "")
        if declared.isdigit() and int(declared) > limit:
            await answer(too_large.status, too_large.code, too_large.message)
            return
        await self._bounded(scope, receive, send, request, limit, too_large)

    async def _bounded(
        self,
        scope: Scope,
        receive: Receive,
        send: Send,
        request: Request,
        limit: int,
        too_large: _Refused,
    ) -> None:
        """Run the app on a body counted as it arrives; its refusal sent instead of the app's."""
        state: dict[str, Any] = {"read": 0, "ended": False, "refused": None, "started": False}

        async def counted() -> Message:
            if state["ended"]:  # the body is in: a listener for the disconnect waits freely
                return await receive()
            try:
                message = await asyncio.wait_for(receive(), BODY_IDLE_S)
            except TimeoutError:
                state["refused"] = _Refused(
                    408, "timeout", f"the request's body sent nothing for {BODY_IDLE_S:g} s"
                )
                raise state["refused"] from None
            if message["type"] == "http.request":
                state["read"] += len(message.get("body", b""))
                state["ended"] = not message.get("more_body", False)
                if state["read"] > limit:
                    state["refused"] = too_large
                    raise too_large
            return message

        async def sending(message: Message) -> None:
            refused: _Refused | None = state["refused"]
            if refused is None:
                state["started"] = True
                await send(message)
            elif message["type"] == "http.response.start" and not state["started"]:
                state["started"] = True  # the app's answer to a broken body: ours instead
                response = await self.refuse(
                    request, refused.status, refused.code, refused.message, {}
                )
                await response(scope, _no_body, send)

        try:
            await self.app(scope, counted, sending)
        except _Refused as refused:
            if not state["started"]:
                state["started"] = True
                response = await self.refuse(
                    request, refused.status, refused.code, refused.message, {}
                )
                await response(scope, _no_body, send)


def _too_large(limit: int, upload: bool) -> str:
    mb = limit / (1024 * 1024)
    if upload:
        return f"the upload is larger than {mb:g} MB; send fewer files at once"
    return f"the request's body is larger than {limit // 1024} kB; send less"
