"""The alarm lifecycle in the JSON API, ``/api/v1``: shelve, unshelve, comments,
conveyors out of service, and the alarm KPIs.

Changes need the role ``maintainer`` and are written to the audit log; the
KPIs need ``viewer``. The functions ``*_as`` serve the API and the dashboard's
forms alike.
"""

from __future__ import annotations

from collections.abc import Callable
from datetime import UTC, datetime, timedelta
from typing import Annotated, Any, TypeVar

from fastapi import APIRouter, Request
from pydantic import AfterValidator, BaseModel, Field

from chaintwin.diagnose.alarm_actions import (
    MAX_SHELVE_MINUTES,
    clear_out_of_service,
    comment_alarm,
    set_out_of_service,
    shelve_alarm,
    unshelve_alarm,
)
from chaintwin.diagnose.alarm_kpis import KPI_DAYS, alarm_kpis
from chaintwin.diagnose.records import date_in_span
from chaintwin.errors import StoreError
from chaintwin.web.access import audit
from chaintwin.web.api import _ERRORS, _web, who
from chaintwin.web.security import ApiError

__all__ = [
    "comment_as",
    "kpis_of",
    "out_of_service_as",
    "router",
    "shelve_as",
    "unshelve_as",
]

T = TypeVar("T")

router = APIRouter(prefix="/api/v1", tags=["api"], responses=_ERRORS)


class ShelveBody(BaseModel):
    """Why and for how long an alarm is shelved."""

    why: str = Field(min_length=1, max_length=2000)
    minutes: float = Field(ge=1, le=MAX_SHELVE_MINUTES)


class CommentBody(BaseModel):
    """A comment on an alarm."""

    text: str = Field(min_length=1, max_length=4000)


class OutOfServiceBody(BaseModel):
    """Why and until when a conveyor is out of service (no ``until``: until put back)."""

    why: str = Field(min_length=1, max_length=2000)
    until: Annotated[
        datetime | None,
        AfterValidator(date_in_span),
        Field(description="Until when (default: until put back), within 1970-01-01..2200-01-01."),
    ] = None


def _on_alarm(store: Any, alarm_id: str, edit: Callable[[dict[str, Any]], T]) -> T:
    """Apply ``edit`` to the health model holding an alarm (404 when there is none)."""
    try:
        conveyor_id = store.alarm_conveyor(alarm_id)
    except StoreError as exc:
        raise ApiError(404, "not_found", str(exc)) from None
    out: T = store.edit_state(conveyor_id, edit)
    return out


def shelve_as(store: Any, name: str, alarm_id: str, why: str, minutes: float) -> Any:
    """Shelve an alarm for the token ``name`` and audit it."""
    alarm = _on_alarm(store, alarm_id, lambda d: shelve_alarm(d, alarm_id, name, why, minutes))
    audit(store, name, "shelve", {"alarm": alarm_id, "why": why, "minutes": minutes})
    return alarm


def unshelve_as(store: Any, name: str, alarm_id: str) -> Any:
    """Unshelve an alarm for the token ``name`` and audit it."""
    alarm = _on_alarm(store, alarm_id, lambda d: unshelve_alarm(d, alarm_id, name))
    audit(store, name, "unshelve", {"alarm": alarm_id})
    return alarm


def comment_as(store: Any, name: str, alarm_id: str, text: str) -> Any:
    """Comment on an alarm for the token ``name`` and audit it."""
    alarm = _on_alarm(store, alarm_id, lambda d: comment_alarm(d, alarm_id, name, text))
    audit(store, name, "comment", {"alarm": alarm_id, "text": text})
    return alarm


def out_of_service_as(
    store: Any, name: str, conveyor_id: str, why: str | None, until: datetime | None, *, end: bool
) -> dict[str, Any]:
    """Take a conveyor out of service (or back, ``end``) for the token ``name``; audit it."""
    if store.profile(conveyor_id) is None:
        raise ApiError(404, "not_found", f"no conveyor '{conveyor_id}' in the store")
    if end:
        window = store.edit_state(conveyor_id, lambda d: clear_out_of_service(d, conveyor_id, name))
        audit(store, name, "in_service", {"conveyor": conveyor_id})
    else:
        window = store.edit_state(
            conveyor_id, lambda d: set_out_of_service(d, conveyor_id, name, why or "", until)
        )
        audit(
            store,
            name,
            "out_of_service",
            {"conveyor": conveyor_id, "why": why, "until": window["until"]},
        )
    return {"conveyor": conveyor_id, **window}


def kpis_of(store: Any, since: datetime | None, until: datetime | None) -> dict[str, Any]:
    """The alarm KPIs of the store's alarms; default the last :data:`KPI_DAYS` days to now."""
    end = until or datetime.now(UTC)
    start = since or (end - timedelta(days=KPI_DAYS))
    try:
        return alarm_kpis(store.alarms(), start, end)
    except ValueError as exc:
        raise ApiError(400, "bad_request", f"since/until: {exc}") from None


@router.post("/alarms/{alarm_id}/shelve")
def shelve(request: Request, alarm_id: str, body: ShelveBody) -> dict[str, Any]:
    """Shelve an alarm for ``minutes`` (maintainer): it neither counts nor notifies until then."""
    p = who(request, "maintainer", changes=True)
    out: dict[str, Any] = shelve_as(
        _web(request).store, p.name, alarm_id, body.why, body.minutes
    ).to_dict()
    return out


@router.post("/alarms/{alarm_id}/unshelve")
def unshelve(request: Request, alarm_id: str) -> dict[str, Any]:
    """End an alarm's shelf now (maintainer)."""
    p = who(request, "maintainer", changes=True)
    out: dict[str, Any] = unshelve_as(_web(request).store, p.name, alarm_id).to_dict()
    return out


@router.post("/alarms/{alarm_id}/comments")
def comment(request: Request, alarm_id: str, body: CommentBody) -> dict[str, Any]:
    """Add a comment to an alarm (maintainer): author and time are recorded."""
    p = who(request, "maintainer", changes=True)
    out: dict[str, Any] = comment_as(_web(request).store, p.name, alarm_id, body.text).to_dict()
    return out


@router.post("/conveyors/{conveyor_id:path}/out-of-service")
def out_of_service(request: Request, conveyor_id: str, body: OutOfServiceBody) -> dict[str, Any]:
    """Take a conveyor out of service until ``until`` (maintainer): its recordings are
    stored and shown, neither judged nor learned."""
    p = who(request, "maintainer", changes=True)
    return out_of_service_as(
        _web(request).store, p.name, conveyor_id, body.why, body.until, end=False
    )


@router.delete("/conveyors/{conveyor_id:path}/out-of-service")
def back_in_service(request: Request, conveyor_id: str) -> dict[str, Any]:
    """Put a conveyor back in service now (maintainer)."""
    p = who(request, "maintainer", changes=True)
    return out_of_service_as(_web(request).store, p.name, conveyor_id, None, None, end=True)


@router.get("/alarm-kpis")
def kpis(
    request: Request, since: datetime | None = None, until: datetime | None = None
) -> dict[str, Any]:
    """Alarm KPIs (EEMUA 191, ISA-18.2) per conveyor and for the fleet over
    ``[since, until)`` (default: the last 30 days)."""
    who(request, "viewer")
    return kpis_of(_web(request).store, since, until)
