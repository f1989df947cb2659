"""Who is asking: bearer tokens, the browser's session cookie, CSRF, roles.

* An API call sends ``Authorization: Bearer <token>``; the token is checked
  against the store (keyed SHA-256, :mod:`chaintwin.web.access`).
* A browser logs in once with its token: the server opens a session (a row
  of the store, :mod:`chaintwin.web.sessions`) and sets an HttpOnly,
  SameSite=Strict cookie holding the session's id, signed with the store's
  session key (HMAC-SHA256). Every request checks that the session and its
  token are still active, so logging out or revoking the token ends the
  session at once. A request that changes something with the cookie must
  carry the session's CSRF nonce (form field ``csrf`` or header
  ``X-CSRF-Token``); bearer calls need none (a browser never sends them on
  its own).
* The guard (:mod:`chaintwin.web.guard`) finds the principal before a body is
  read and keeps it in the request's scope (:data:`PRINCIPAL`); the handlers
  read it from there.
"""

from __future__ import annotations

import hmac
from dataclasses import dataclass

from fastapi import Request

from chaintwin.store.store import Store
from chaintwin.web.access import role_at_least, verify_token
from chaintwin.web.sessions import SESSION_SECONDS, session_of

__all__ = [
    "COOKIE",
    "PRINCIPAL",
    "SESSION_SECONDS",
    "ApiError",
    "Principal",
    "principal_from",
    "principal_of",
    "require",
]

COOKIE = "chaintwin_session"
"""Name of the session cookie."""


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


PRINCIPAL = "chaintwin.principal"
"""The key of the request's principal in its ASGI scope (set once found)."""


def principal_from(
    authorization: str, cookie: str | None, store: Store, session_key: bytes
) -> Principal | None:
    """The principal of a request's ``Authorization`` header or session cookie, or None."""
    if authorization:
        scheme, _, token = authorization.partition(" ")
        if scheme.lower() != "bearer" or not token:
            return None
        info = verify_token(store, token.strip())
        return None if info is None else Principal(info.name, info.role, "bearer")
    if cookie:
        found = session_of(store, session_key, cookie)
        return None if found is None else Principal(found.name, found.role, "cookie", found.csrf)
    return None


def principal_of(request: Request, store: Store, session_key: bytes) -> Principal | None:
    """The principal of a request, or None (no or an unknown token, no valid session).

    Found once per request and kept in its scope (the guard may have found it already).
    """
    if PRINCIPAL not in request.scope:
        request.scope[PRINCIPAL] = principal_from(
            request.headers.get("authorization", ""), request.cookies.get(COOKIE), store,
            session_key,
        )  # fmt: skip
    found: Principal | None = request.scope[PRINCIPAL]
    return found


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
