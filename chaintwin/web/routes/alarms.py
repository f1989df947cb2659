"""Alarms: listed, acknowledged, shelved and unshelved, commented.

Changes need the role ``maintainer`` and are written to the audit log;
reading needs ``viewer``. The functions ``*_as`` serve the API and the
dashboard's forms alike.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Annotated, Any, Literal, TypeVar

from fastapi import Depends, Request

from chaintwin.diagnose.alarm_actions import comment_alarm, shelve_alarm, unshelve_alarm
from chaintwin.diagnose.records import LIFECYCLES
from chaintwin.diagnose.state import acknowledge_alarm
from chaintwin.errors import StoreError
from chaintwin.web.access import audit
from chaintwin.web.deps import require_role, web_of
from chaintwin.web.models import AcknowledgeBody, Alarm, CommentBody, ShelveBody
from chaintwin.web.security import ApiError, Principal

from .common import make_router

__all__ = ["acknowledge_as", "comment_as", "router", "shelve_as", "unshelve_as"]

T = TypeVar("T")

router = make_router("alarms")

Viewer = Annotated[Principal, Depends(require_role("viewer"))]
Maintainer = Annotated[Principal, Depends(require_role("maintainer", changes=True))]


def _on_alarm(store: Any, alarm_id: str, edit: Callable[[dict[str, Any]], T]) -> T:
    """Apply ``edit`` to the health model holding an alarm (404 when there is none)."""
    try:
        conveyor_id = store.alarm_conveyor(alarm_id)
    except StoreError as exc:
        raise ApiError(404, "not_found", str(exc)) from None
    out: T = store.edit_state(conveyor_id, edit)
    return out


def acknowledge_as(store: Any, name: str, alarm_id: str, why: str) -> Any:
    """Acknowledge an alarm for the token ``name`` and audit it (API and form alike)."""
    alarm = _on_alarm(store, alarm_id, lambda d: acknowledge_alarm(d, alarm_id, name, why))
    audit(store, name, "acknowledge", {"alarm": alarm_id, "why": why})
    return alarm


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


# an alarm's optional fields (merged, limit, closed_at, closed_by) appear only when they apply
@router.get("/alarms", response_model=list[Alarm], response_model_exclude_unset=True)
def alarms(
    request: Request,
    _who: Viewer,
    state: Literal["open", "closed"] | None = None,
    acknowledged: bool | None = None,
    lifecycle: Literal[LIFECYCLES] | None = None,  # type: ignore[valid-type]
) -> list[dict[str, Any]]:
    """Alarms of every conveyor, oldest first, optionally filtered (``state=open``: not closed;
    ``lifecycle``: unacknowledged, acknowledged, returned_unacknowledged, shelved,
    out_of_service or closed)."""
    out = []
    for a in web_of(request).store.alarms():
        if state is not None and (a.is_open != (state == "open")):
            continue
        if acknowledged is not None and ((a.acknowledged is not None) != acknowledged):
            continue
        if lifecycle is not None and a.lifecycle() != lifecycle:
            continue
        out.append(a.to_dict())
    return out


@router.post(
    "/alarms/{alarm_id}/acknowledge", response_model=Alarm, response_model_exclude_unset=True
)
def acknowledge(
    request: Request, alarm_id: str, body: AcknowledgeBody, who: Maintainer
) -> dict[str, Any]:
    """Acknowledge an open alarm (maintainer): it stays open, no longer fails scripts."""
    out: dict[str, Any] = acknowledge_as(
        web_of(request).store, who.name, alarm_id, body.why
    ).to_dict()
    return out


@router.post("/alarms/{alarm_id}/shelve", response_model=Alarm, response_model_exclude_unset=True)
def shelve(request: Request, alarm_id: str, body: ShelveBody, who: Maintainer) -> dict[str, Any]:
    """Shelve an alarm for ``minutes`` (maintainer): it neither counts nor notifies until then."""
    store = web_of(request).store
    out: dict[str, Any] = shelve_as(store, who.name, alarm_id, body.why, body.minutes).to_dict()
    return out


@router.post("/alarms/{alarm_id}/unshelve", response_model=Alarm, response_model_exclude_unset=True)
def unshelve(request: Request, alarm_id: str, who: Maintainer) -> dict[str, Any]:
    """End an alarm's shelf now (maintainer)."""
    out: dict[str, Any] = unshelve_as(web_of(request).store, who.name, alarm_id).to_dict()
    return out


@router.post("/alarms/{alarm_id}/comments", response_model=Alarm, response_model_exclude_unset=True)
def comment(request: Request, alarm_id: str, body: CommentBody, who: Maintainer) -> dict[str, Any]:
    """Add a comment to an alarm (maintainer): author and time are recorded."""
    out: dict[str, Any] = comment_as(web_of(request).store, who.name, alarm_id, body.text).to_dict()
    return out
