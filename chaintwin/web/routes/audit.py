"""The audit log (admin): who changed what, when."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import Depends, Query, Request

from chaintwin.web.access import audit_entries
from chaintwin.web.deps import require_role, web_of
from chaintwin.web.models import AuditEntry
from chaintwin.web.security import Principal

from .common import make_router

__all__ = ["router"]

router = make_router("audit")


@router.get("/audit", response_model=list[AuditEntry])
def audit_log(
    request: Request,
    _who: Annotated[Principal, Depends(require_role("admin"))],
    limit: Annotated[int, Query(ge=1, le=5000)] = 500,
) -> list[dict[str, Any]]:
    """The audit log, newest first (admin)."""
    return audit_entries(web_of(request).store, limit)
