"""The dashboard's alarm lifecycle: the shelve, unshelve, comment and out-of-service forms,
and the alarm KPI page.

The forms carry the CSRF token as the field ``csrf`` and do what the API's
endpoints do (:mod:`chaintwin.web.routes.alarms`).
"""

from __future__ import annotations

from datetime import UTC, datetime, timedelta
from typing import Annotated, Any

from fastapi import APIRouter, Form, Request
from fastapi.responses import HTMLResponse, RedirectResponse, Response

from chaintwin.diagnose.alarm_kpis import KPI_DAYS
from chaintwin.errors import StoreError
from chaintwin.web.pages import _render, _viewer, _web
from chaintwin.web.routes.alarms import comment_as, shelve_as, unshelve_as
from chaintwin.web.routes.conveyors import out_of_service_as
from chaintwin.web.routes.kpis import kpis_of
from chaintwin.web.security import require

__all__ = ["router"]

router = APIRouter(include_in_schema=False)


def _maintainer(request: Request, csrf: str) -> Any:
    return require(_web(request).principal(request), "maintainer", changes=True, csrf=csrf)


def _back() -> Response:
    return RedirectResponse("/alarms", status_code=303)


@router.post("/alarms/{alarm_id}/shelve")
def shelve_form(
    request: Request,
    alarm_id: str,
    why: Annotated[str, Form()],
    minutes: Annotated[float, Form()],
    csrf: Annotated[str, Form()] = "",
) -> Response:
    """The shelve form (maintainer)."""
    p = _maintainer(request, csrf)
    shelve_as(_web(request).store, p.name, alarm_id, why, minutes)
    return _back()


@router.post("/alarms/{alarm_id}/unshelve")
def unshelve_form(request: Request, alarm_id: str, csrf: Annotated[str, Form()] = "") -> Response:
    """The unshelve button (maintainer)."""
    p = _maintainer(request, csrf)
    unshelve_as(_web(request).store, p.name, alarm_id)
    return _back()


@router.post("/alarms/{alarm_id}/comments")
def comment_form(
    request: Request,
    alarm_id: str,
    text: Annotated[str, Form()],
    csrf: Annotated[str, Form()] = "",
) -> Response:
    """The comment form (maintainer)."""
    p = _maintainer(request, csrf)
    comment_as(_web(request).store, p.name, alarm_id, text)
    return _back()


@router.post("/conveyors/{conveyor_id:path}/out-of-service")
def out_of_service_form(
    request: Request,
    conveyor_id: str,
    why: Annotated[str, Form()],
    hours: Annotated[float, Form()],
    csrf: Annotated[str, Form()] = "",
) -> Response:
    """The out-of-service form (maintainer): for ``hours`` from now."""
    p = _maintainer(request, csrf)
    if not 0 < hours <= 24 * 90:
        raise StoreError(f"hours {hours:g} must be above 0 and at most 2160 (90 days)")
    until = datetime.now(UTC) + timedelta(hours=hours)
    out_of_service_as(_web(request).store, p.name, conveyor_id, why, until, end=False)
    return _back()


@router.post("/conveyors/{conveyor_id:path}/in-service")
def in_service_form(
    request: Request, conveyor_id: str, csrf: Annotated[str, Form()] = ""
) -> Response:
    """The back-in-service button (maintainer)."""
    p = _maintainer(request, csrf)
    out_of_service_as(_web(request).store, p.name, conveyor_id, None, None, end=True)
    return _back()


@router.get("/alarm-kpis", response_class=HTMLResponse)
def kpis_page(
    request: Request, since: datetime | None = None, until: datetime | None = None
) -> HTMLResponse:
    """The alarm KPIs of the fleet and each conveyor (default: the last 30 days)."""
    p = _viewer(request)
    kpis = kpis_of(_web(request).store, since, until)
    return _render(request, "alarm_kpis.html.j2", p, kpis=kpis, default_days=KPI_DAYS)
