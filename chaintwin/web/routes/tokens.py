"""Tokens: listed, created (shown once), revoked (admin); each change audited."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import Depends, Request

from chaintwin.errors import ChaintwinError, StoreError
from chaintwin.web.access import audit, create_token, list_tokens, revoke_token
from chaintwin.web.deps import require_role, web_of
from chaintwin.web.models import NewToken, TokenBody, TokenInfo
from chaintwin.web.security import ApiError, Principal

from .common import make_router

__all__ = ["router"]

router = make_router("tokens")

Admin = Annotated[Principal, Depends(require_role("admin"))]
AdminChanges = Annotated[Principal, Depends(require_role("admin", changes=True))]


@router.get("/tokens", response_model=list[TokenInfo])
def tokens(request: Request, _who: Admin) -> list[dict[str, Any]]:
    """Every token (names, roles, lifetimes; never the tokens), admin."""
    return [t.to_dict() for t in list_tokens(web_of(request).store)]


@router.post("/tokens", response_model=NewToken)
def new_token(request: Request, body: TokenBody, who: AdminChanges) -> dict[str, Any]:
    """Create a token (admin); the response is the only time it is shown."""
    store = web_of(request).store
    try:
        token = create_token(store, body.name, body.role, body.expires_days)
    except ChaintwinError as exc:
        raise ApiError(409, "conflict", str(exc)) from None
    audit(store, who.name, "token_create", {"name": body.name, "role": body.role})
    return {"token": token, "name": body.name, "role": body.role}


@router.post("/tokens/{name}/revoke", response_model=TokenInfo)
def revoke(request: Request, name: str, who: AdminChanges) -> dict[str, Any]:
    """Revoke a token by name (admin); its sessions end at once."""
    store = web_of(request).store
    try:
        info = revoke_token(store, name)
    except StoreError as exc:
        raise ApiError(404, "not_found", str(exc)) from None
    audit(store, who.name, "token_revoke", {"name": name})
    out: dict[str, Any] = info.to_dict()
    return out
