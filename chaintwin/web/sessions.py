"""Browser sessions kept in the store: opened at login, ended at logout or expiry.

The cookie holds a random session id and its signature (HMAC-SHA256 with
the store's session key); the store keeps a SHA-256 of the id (never the id
itself, so a copy of the store opens no session), the token it was opened
with, its CSRF nonce and its expiry. Every request with the cookie reads the
row together with its token: a session ends when its row is deleted
(logout), when it expires, or when its token is revoked or expires.
"""

from __future__ import annotations

import hashlib
import hmac
import secrets
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta

from sqlalchemy import delete, select
from sqlalchemy.orm import Session

from chaintwin.store.schema import TokenRow, WebSessionRow
from chaintwin.store.store import Store

__all__ = ["SESSION_SECONDS", "OpenSession", "end_session", "open_session", "session_of"]

SESSION_SECONDS = 12 * 3600
"""A browser session lasts a shift (12 h), or until logout or its token is revoked."""


@dataclass(frozen=True, slots=True)
class OpenSession:
    """A valid session: its token's name and role, and its CSRF nonce."""

    name: str
    role: str
    csrf: str


def _sign(key: bytes, session_id: str) -> str:
    return hmac.new(key, session_id.encode(), hashlib.sha256).hexdigest()


def _id_hash(session_id: str) -> str:
    return hashlib.sha256(session_id.encode()).hexdigest()


def _session_id(key: bytes, cookie: str) -> str | None:
    """The session id of a cookie whose signature is right, else None."""
    session_id, _, mac = cookie.partition(".")
    if not session_id or len(cookie) > 200 or not hmac.compare_digest(_sign(key, session_id), mac):
        return None
    return session_id


def open_session(store: Store, key: bytes, token_name: str) -> tuple[str, str]:
    """Open a session for the token ``token_name``: the cookie's value and the CSRF nonce.

    The sessions already expired are deleted on the way (the table holds
    only the living ones and those expired since the last login).
    """
    session_id = secrets.token_urlsafe(32)
    nonce = secrets.token_urlsafe(24)
    now = datetime.now(UTC)
    row = WebSessionRow(
        id_hash=_id_hash(session_id),
        token_name=token_name,
        csrf=nonce,
        created_at=now.isoformat(),
        expires_at=(now + timedelta(seconds=SESSION_SECONDS)).isoformat(),
    )
    with Session(store.engine) as s, s.begin():
        s.execute(delete(WebSessionRow).where(WebSessionRow.expires_at < now.isoformat()))
        s.add(row)
    return f"{session_id}.{_sign(key, session_id)}", nonce


def session_of(store: Store, key: bytes, cookie: str) -> OpenSession | None:
    """The session a cookie opens (None: a bad signature, ended, expired, its token not active)."""
    session_id = _session_id(key, cookie)
    if session_id is None:
        return None
    now = datetime.now(UTC).isoformat()
    query = (
        select(WebSessionRow.csrf, TokenRow.name, TokenRow.role)
        .join(TokenRow, TokenRow.name == WebSessionRow.token_name)
        .where(
            WebSessionRow.id_hash == _id_hash(session_id),
            WebSessionRow.expires_at > now,
            TokenRow.revoked_at.is_(None),
            (TokenRow.expires_at.is_(None)) | (TokenRow.expires_at > now),
        )
    )
    with Session(store.engine) as s:
        row = s.execute(query).first()
    return None if row is None else OpenSession(row.name, row.role, row.csrf)


def end_session(store: Store, key: bytes, cookie: str) -> bool:
    """Delete the session a cookie holds (logout); whether there was one."""
    session_id = _session_id(key, cookie)
    if session_id is None:
        return False
    with Session(store.engine) as s, s.begin():
        done = s.execute(delete(WebSessionRow).where(WebSessionRow.id_hash == _id_hash(session_id)))
    return bool(getattr(done, "rowcount", 0))
