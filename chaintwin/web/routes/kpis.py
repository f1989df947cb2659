"""The alarm KPIs (EEMUA 191, ISA-18.2) per conveyor and for the fleet."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta
from typing import Annotated, Any

from fastapi import Depends, Request

from chaintwin.diagnose.alarm_kpis import KPI_DAYS, alarm_kpis
from chaintwin.web.deps import require_role, web_of
from chaintwin.web.models import AlarmKpis
from chaintwin.web.security import ApiError, Principal

from .common import make_router

__all__ = ["kpis_of", "router"]

router = make_router("alarms")


def kpis_of(store: Any, since: datetime | None, until: datetime | None) -> dict[str, Any]:
    """The alarm KPIs of the store's alarms; default the last :data:`KPI_DAYS` days to now."""
    end = until or datetime.now(UTC)
    start = since or (end - timedelta(days=KPI_DAYS))
    try:
        return alarm_kpis(store.alarms(), start, end)
    except ValueError as exc:
        raise ApiError(400, "bad_request", f"since/until: {exc}") from None


@router.get("/alarm-kpis", response_model=AlarmKpis)
def kpis(
    request: Request,
    _who: Annotated[Principal, Depends(require_role("viewer"))],
    since: datetime | None = None,
    until: datetime | None = None,
) -> dict[str, Any]:
    """Alarm KPIs (EEMUA 191, ISA-18.2) per conveyor and for the fleet over
    ``[since, until)`` (default: the last 30 days)."""
    return kpis_of(web_of(request).store, since, until)
