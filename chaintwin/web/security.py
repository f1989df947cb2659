"""Who is asking: bearer tokens, the browser's session cookie, CSRF, roles.

* An API call sends ``Authorization: Bearer <token>``; the token is checked
  against the store (keyed SHA-256, :mod:`chaintwin.store.access`).
* A browser logs in once with its token: the server sets an HttpOnly,
  SameSite=Strict cookie holding the token's *name*, an expiry and a CSRF
  nonce, signed with the store's session key (HMAC-SHA256). Every request
  checks that the named token is still active, so revoking a token ends its
  sessions at once. A request that changes something with the cookie must
  carry the nonce (form field ``csrf`` or header ``X-CSRF-Token``); bearer
  calls need none (a browser never sends them on its own).
"""

from __future__ import annotations

import base64
import hashlib
import hmac
import json
import secrets
import time
from dataclasses import dataclass

from fastapi import Request

from chaintwin.store.access import role_at_least, token_by_name, verify_token
from chaintwin.store.store import Store

__all__ = [
    "COOKIE",
    "SESSION_SECONDS",
    "ApiError",
    "Principal",
    "make_session_cookie",
    "principal_of",
    "require",
]

COOKIE = "chaintwin_session"
"""Name of the session cookie."""

SESSION_SECONDS = 12 * 3600
"""A browser session lasts a shift (12 h), or until its token is revoked."""


class ApiError(Exception):
    """An error answered as ``{"error": {"code", "message"}}`` with an HTTP status."""

    def __init__(self, status: int, code: str, message: str) -> None:
        super().__init__(message)
        self.status = status
        self.code = code
        self.message = message


@dataclass(frozen=True, slots=True)
class Principal:
    """The token behind a request: its name and role, and how it came."""

    name: str
    role: str
    via: str  # "bearer" or "cookie"
    csrf: str | None = None


def _sign(key: bytes, payload: bytes) -> str:
    return hmac.new(key, payload, hashlib.sha256).hexdigest()


def make_session_cookie(key: bytes, name: str) -> tuple[str, str]:
    """A signed session cookie value for the token ``name``, and its CSRF nonce."""
    nonce = secrets.token_urlsafe(24)
    body = json.dumps({"n": name, "e": int(time.time()) + SESSION_SECONDS, "c": nonce})
    payload = base64.urlsafe_b64encode(body.encode())
    return payload.decode() + "." + _sign(key, payload), nonce


def _read_cookie(key: bytes, value: str) -> tuple[str, str] | None:
    """``(token name, nonce)`` of a valid, unexpired cookie, else None."""
    payload, _, mac = value.partition(".")
    if not mac or not hmac.compare_digest(_sign(key, payload.encode()), mac):
        return None
    try:
        data = json.loads(base64.urlsafe_b64decode(payload.encode()))
        name, expires, nonce = str(data["n"]), int(data["e"]), str(data["c"])
    except (ValueError, KeyError, TypeError):
        return None
    if expires < time.time():
        return None
    return name, nonce


def principal_of(request: Request, store: Store, session_key: bytes) -> Principal | None:
    """The principal of a request, or None (no or an unknown token, no valid cookie)."""
    header = request.headers.get("authorization", "")
    if header:
        scheme, _, token = header.partition(" ")
        if scheme.lower() != "bearer" or not token:
            return None
        info = verify_token(store, token.strip())
        return None if info is None else Principal(info.name, info.role, "bearer")
    cookie = request.cookies.get(COOKIE)
    if cookie:
        read = _read_cookie(session_key, cookie)
        if read is None:
            return None
        info = token_by_name(store, read[0])
        return None if info is None else Principal(info.name, info.role, "cookie", read[1])
    return None


def require(
    principal: Principal | None, role: str, *, changes: bool = False, csrf: str | None = None
) -> Principal:
    """The principal if it may act with ``role``; ApiError 401/403 otherwise.

    For a request that ``changes`` something, a cookie session must carry its
    CSRF nonce (``csrf``, from the form field or the header).
    """
    if principal is None:
        raise ApiError(401, "unauthorized", "send a valid token: Authorization: Bearer <token>")
    if not role_at_least(principal.role, role):
        raise ApiError(
            403,
            "forbidden",
            f"this needs the role {role}; the token '{principal.name}' is {principal.role}",
        )
    if (
        changes
        and principal.via == "cookie"
        and not (principal.csrf and csrf and hmac.compare_digest(principal.csrf, csrf))
    ):
        raise ApiError(403, "csrf", "the form or request lacks its CSRF token; reload the page")
    return principal
