"""Who may use the web service: tokens with roles, the audit log, shared secrets.

Tokens are random (32 bytes, URL-safe, prefixed ``ct_``) and stored only as
a keyed SHA-256 (HMAC with a key kept in the store's ``secrets`` table): a
slow password hash is not needed for random tokens, and a stolen store does
not give the tokens away. The key and the session-cookie key are created on
first use, so every ``serve`` process and ``token create`` on the same store
share them. Roles rank ``viewer < maintainer < admin``.
"""

from __future__ import annotations

import hashlib
import hmac
import secrets
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from typing import Any

from sqlalchemy import select
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from chaintwin.errors import StoreError
from chaintwin.store.schema import AuditRow, SecretRow, TokenRow
from chaintwin.store.store import Store

__all__ = [
    "ROLES",
    "TokenInfo",
    "audit",
    "audit_entries",
    "create_token",
    "list_tokens",
    "revoke_token",
    "role_at_least",
    "secret",
    "verify_token",
]

ROLES = ("viewer", "maintainer", "admin")
"""The roles, lowest first."""

TOKEN_PREFIX = "ct_"
"""Start of every token (so a leaked one is recognisable in a scan)."""

MAX_NAME_LENGTH = 100
"""Longest token name, characters."""

MAX_DAYS = 36500
"""Longest token lifetime, days."""


@dataclass(frozen=True, slots=True)
class TokenInfo:
    """A token as the store knows it (never the token itself)."""

    name: str
    role: str
    created_at: str
    expires_at: str | None
    revoked_at: str | None

    @property
    def active(self) -> bool:
        """Neither revoked nor expired."""
        if self.revoked_at is not None:
            return False
        return self.expires_at is None or self.expires_at > datetime.now(UTC).isoformat()

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (``token list --json``)."""
        return {
            "name": self.name,
            "role": self.role,
            "created_at": self.created_at,
            "expires_at": self.expires_at,
            "revoked_at": self.revoked_at,
            "active": self.active,
        }


def role_at_least(role: str, needed: str) -> bool:
    """Whether ``role`` ranks at or above ``needed``."""
    return role in ROLES and ROLES.index(role) >= ROLES.index(needed)


_SECRETS: dict[tuple[str, str], bytes] = {}
"""The keys read, per (store URL, name): a key never changes once created."""


def secret(store: Store, name: str) -> bytes:
    """The store's random key ``name`` (32 bytes), created on first use.

    Two processes creating it at once agree: the second insert fails on the
    primary key and reads the first one's. Kept in the process once read
    (every token check needs the token key: a read of the store less per
    request).
    """
    known = _SECRETS.get((store.url, name))
    if known is not None:
        return known
    key = _read_or_create_secret(store, name)
    _SECRETS[(store.url, name)] = key
    return key


def _read_or_create_secret(store: Store, name: str) -> bytes:
    with Session(store.engine) as s:
        row = s.get(SecretRow, name)
        if row is not None:
            return bytes.fromhex(row.value)
    value = secrets.token_hex(32)
    try:
        with Session(store.engine) as s, s.begin():
            s.add(SecretRow(name=name, value=value))
    except IntegrityError:
        with Session(store.engine) as s:
            row = s.get(SecretRow, name)
            assert row is not None
            return bytes.fromhex(row.value)
    return bytes.fromhex(value)


def _hash(store: Store, token: str) -> str:
    return hmac.new(secret(store, "token_key"), token.encode(), hashlib.sha256).hexdigest()


def create_token(store: Store, name: str, role: str, expires_days: float | None = None) -> str:
    """Create a token; returns it (the only time it is seen).

    Raises
    ------
    StoreError
        For an unknown role, an empty or too long name, a name already used
        (revoked names stay, so the audit log keeps meaning), or a
        non-positive lifetime.
    """
    if role not in ROLES:
        raise StoreError(f"role '{role}' is not one of {', '.join(ROLES)}", field="role")
    if not name.strip() or len(name) > MAX_NAME_LENGTH or not name.isprintable():
        raise StoreError(
            f"token name must be 1-{MAX_NAME_LENGTH} printable characters", field="name"
        )
    if expires_days is not None and not 0 < expires_days <= MAX_DAYS:
        raise StoreError(
            f"--expires-days {expires_days} must be from 0 to {MAX_DAYS} (100 years)",
            field="expires_days",
        )
    token = TOKEN_PREFIX + secrets.token_urlsafe(32)
    now = datetime.now(UTC)
    expires = None if expires_days is None else (now + timedelta(days=expires_days)).isoformat()
    row = TokenRow(
        name=name,
        role=role,
        token_hash=_hash(store, token),
        created_at=now.isoformat(),
        expires_at=expires,
        revoked_at=None,
    )
    try:
        with Session(store.engine) as s, s.begin():
            s.add(row)
    except IntegrityError:
        raise StoreError(
            f"a token named '{name}' exists already (revoked ones too); choose another name",
            field="name",
        ) from None
    return token


def _info(row: TokenRow) -> TokenInfo:
    return TokenInfo(row.name, row.role, row.created_at, row.expires_at, row.revoked_at)


def list_tokens(store: Store) -> list[TokenInfo]:
    """Every token (revoked and expired ones too), oldest first."""
    with Session(store.engine) as s:
        rows = s.scalars(select(TokenRow).order_by(TokenRow.created_at, TokenRow.name))
        return [_info(r) for r in rows]


def revoke_token(store: Store, name: str) -> TokenInfo:
    """Revoke a token by name; it stops working at once.

    Raises
    ------
    StoreError
        When no token has that name.
    """
    with Session(store.engine) as s, s.begin():
        row = s.get(TokenRow, name)
        if row is None:
            raise StoreError(f"no token named '{name}' (see `chaintwin token list`)", field="name")
        if row.revoked_at is None:
            row.revoked_at = datetime.now(UTC).isoformat()
        return _info(row)


def verify_token(store: Store, token: str) -> TokenInfo | None:
    """The active token matching ``token``, or None (unknown, revoked or expired)."""
    if not token.startswith(TOKEN_PREFIX) or len(token) > 200:
        return None
    digest = _hash(store, token)
    with Session(store.engine) as s:
        row = s.scalars(select(TokenRow).where(TokenRow.token_hash == digest)).first()
        if row is None or not hmac.compare_digest(row.token_hash, digest):
            return None
        info = _info(row)
    return info if info.active else None


def token_by_name(store: Store, name: str) -> TokenInfo | None:
    """The active token named ``name`` (for a session cookie), or None."""
    with Session(store.engine) as s:
        row = s.get(TokenRow, name)
        info = None if row is None else _info(row)
    return info if info is not None and info.active else None


def audit(store: Store, who: str, action: str, detail: dict[str, Any]) -> None:
    """Write one entry of the audit log (who did what, now)."""
    with Session(store.engine) as s, s.begin():
        s.add(AuditRow(at=datetime.now(UTC).isoformat(), who=who, action=action, detail=detail))


def audit_entries(store: Store, limit: int = 500) -> list[dict[str, Any]]:
    """The newest entries of the audit log, newest first."""
    with Session(store.engine) as s:
        rows = s.scalars(select(AuditRow).order_by(AuditRow.id.desc()).limit(limit))
        return [
            {"at": r.at, "who": r.who, "action": r.action, "detail": dict(r.detail)} for r in rows
        ]
