"""The dashboard's pages: login, fleet, conveyor, alarms, upload, audit.

Server-rendered (Jinja2, every value escaped); the charts are drawn in the
browser by Plotly (served from the package) from the JSON API, which the
pages call with the session cookie and their CSRF token. Forms that change
something carry the CSRF token as the field ``csrf``.
"""

from __future__ import annotations

from datetime import datetime
from typing import Annotated, Any

from fastapi import APIRouter, File, Form, Request, UploadFile
from fastapi.responses import HTMLResponse, RedirectResponse, Response

from chaintwin import __version__
from chaintwin.diagnose.state import MAINTENANCE_KINDS
from chaintwin.errors import ChaintwinError
from chaintwin.web.access import (
    audit,
    audit_entries,
    create_token,
    list_tokens,
    revoke_token,
    role_at_least,
    verify_token,
)
from chaintwin.web.routes.alarms import acknowledge_as
from chaintwin.web.routes.conveyors import maintenance_as
from chaintwin.web.routes.recordings import take_uploads
from chaintwin.web.security import COOKIE, SESSION_SECONDS, ApiError, Principal, require
from chaintwin.web.sessions import end_session, open_session

__all__ = ["error_page", "router"]

router = APIRouter(include_in_schema=False)


def _web(request: Request) -> Any:
    return request.app.state.web


def _render(
    request: Request, name: str, principal: Principal | None, code: int = 200, **context: Any
) -> HTMLResponse:
    web = _web(request)
    base = {
        "principal": principal,
        "csrf": principal.csrf if principal is not None else "",
        "version": __version__,
        "can": (lambda role: principal is not None and role_at_least(principal.role, role)),
    }
    page: HTMLResponse = web.templates.TemplateResponse(
        request, name, base | context, status_code=code
    )
    return page


def error_page(request: Request, status: int, message: str) -> HTMLResponse:
    """An error as a page (the API answers JSON instead)."""
    principal = _web(request).principal(request)
    return _render(request, "error.html.j2", principal, status, status=status, message=message)


def _viewer(request: Request) -> Principal:
    return require(_web(request).principal(request), "viewer")


# ------------------------------------------------------------------ login
@router.get("/login", response_class=HTMLResponse)
def login_form(request: Request) -> HTMLResponse:
    """The login form: paste a token."""
    return _render(request, "login.html.j2", None, message=None)


@router.post("/login")
def login(request: Request, token: Annotated[str, Form()]) -> Response:
    """Check the token, set the session cookie, go to the fleet."""
    web = _web(request)
    info = verify_token(web.store, token.strip())
    if info is None:
        return _render(
            request, "login.html.j2", None, 401, message="unknown, revoked or expired token"
        )
    value, _nonce = open_session(web.store, web.session_key, info.name)
    audit(web.store, info.name, "login", {"role": info.role})
    out = RedirectResponse("/", status_code=303)
    out.set_cookie(
        COOKIE,
        value,
        max_age=SESSION_SECONDS,
        httponly=True,
        samesite="strict",
        # over TLS, or behind a trusted proxy that says the request came over https
        secure=web.secure_cookies or request.url.scheme == "https",
        path="/",
    )
    return out


@router.post("/logout")
def logout(request: Request, csrf: Annotated[str, Form()] = "") -> Response:
    """End the session: its row deleted (the cookie stops working anywhere), the cookie cleared."""
    web = _web(request)
    principal = web.principal(request)
    if principal is not None:
        require(principal, "viewer", changes=True, csrf=csrf)
        cookie = request.cookies.get(COOKIE)
        if principal.via == "cookie" and cookie:
            end_session(web.store, web.session_key, cookie)
            audit(web.store, principal.name, "logout", {})
    out = RedirectResponse("/login", status_code=303)
    out.delete_cookie(COOKIE, path="/")
    return out


# ------------------------------------------------------------------ pages
@router.get("/", response_class=HTMLResponse)
def fleet(request: Request) -> HTMLResponse:
    """The fleet: health, open alarms, TLF ranking; refreshes itself."""
    from chaintwin.web.routes.conveyors import fleet_etag, fleet_health

    p = _viewer(request)
    web = _web(request)
    rows, _body = fleet_health(web).snapshot(web.store, fleet_etag(web.store))
    return _render(request, "fleet.html.j2", p, rows=rows)


@router.get("/conveyors/{conveyor_id:path}", response_class=HTMLResponse)
def conveyor_page(request: Request, conveyor_id: str) -> HTMLResponse:
    """One conveyor: trends with baseline bands and alarms, payloads, latest recording."""
    from chaintwin.web.routes.conveyors import conveyor_data_of

    p = _viewer(request)
    web = _web(request)
    # bounded (its status, health index and features need the newest results; the
    # trends' charts fetch their own series from the API: only their names are
    # worked out here), the verdict the fleet's
    try:
        data = conveyor_data_of(web, conveyor_id, trends=False)
    except ApiError as exc:  # no such conveyor
        return error_page(request, exc.status, exc.message)
    return _render(request, "conveyor.html.j2", p, conveyor_id=conveyor_id, data=data)


@router.get("/alarms", response_class=HTMLResponse)
def alarms_page(request: Request) -> HTMLResponse:
    """Every alarm; maintainers acknowledge and record maintenance here."""
    p = _viewer(request)
    store = _web(request).store
    alarms = sorted(store.alarms(), key=lambda a: (not a.is_open, a.since or ""), reverse=False)
    return _render(
        request,
        "alarms.html.j2",
        p,
        alarms=alarms,
        conveyors=store.conveyors(),
        kinds=MAINTENANCE_KINDS,
    )


@router.post("/alarms/{alarm_id}/acknowledge")
def acknowledge_form(
    request: Request, alarm_id: str, why: Annotated[str, Form()], csrf: Annotated[str, Form()] = ""
) -> Response:
    """The acknowledge form (maintainer)."""
    p = require(_web(request).principal(request), "maintainer", changes=True, csrf=csrf)
    acknowledge_as(_web(request).store, p.name, alarm_id, why)
    return RedirectResponse("/alarms", status_code=303)


@router.post("/conveyors/{conveyor_id:path}/maintenance")
def maintenance_form(
    request: Request,
    conveyor_id: str,
    kind: Annotated[str, Form()],
    why: Annotated[str, Form()],
    csrf: Annotated[str, Form()] = "",
) -> Response:
    """The maintenance form (maintainer): the baseline restarts."""
    p = require(_web(request).principal(request), "maintainer", changes=True, csrf=csrf)
    now = datetime.now().astimezone()
    maintenance_as(_web(request).store, p.name, conveyor_id, kind, why, now)
    return RedirectResponse("/alarms", status_code=303)


@router.get("/upload", response_class=HTMLResponse)
def upload_form(request: Request) -> HTMLResponse:
    """The upload page (maintainer)."""
    p = require(_web(request).principal(request), "maintainer")
    return _render(request, "upload.html.j2", p, done=None)


@router.post("/upload", response_class=HTMLResponse)
async def upload_files(
    request: Request,
    files: Annotated[list[UploadFile], File()],
    csrf: Annotated[str, Form()] = "",
) -> HTMLResponse:
    """Ingest the uploaded files and show what became of each."""
    p = require(_web(request).principal(request), "maintainer", changes=True, csrf=csrf)
    done = await take_uploads(request, files, p.name, frozenset({"csrf"}))
    return _render(request, "upload.html.j2", p, done=done)


@router.get("/audit", response_class=HTMLResponse)
def audit_page(request: Request) -> HTMLResponse:
    """The audit log and the tokens (admin)."""
    p = require(_web(request).principal(request), "admin")
    store = _web(request).store
    return _render(
        request,
        "audit.html.j2",
        p,
        entries=audit_entries(store),
        tokens=list_tokens(store),
        created=None,
    )


@router.post("/tokens", response_class=HTMLResponse)
def create_token_form(
    request: Request,
    name: Annotated[str, Form()],
    role: Annotated[str, Form()],
    csrf: Annotated[str, Form()] = "",
) -> HTMLResponse:
    """Create a token from the browser (admin); shown once."""
    p = require(_web(request).principal(request), "admin", changes=True, csrf=csrf)
    store = _web(request).store
    try:
        token = create_token(store, name, role)
    except ChaintwinError as exc:
        return error_page(request, 409, str(exc))
    audit(store, p.name, "token_create", {"name": name, "role": role})
    return _render(
        request,
        "audit.html.j2",
        p,
        entries=audit_entries(store),
        tokens=list_tokens(store),
        created={"name": name, "role": role, "token": token},
    )


@router.post("/tokens/{name}/revoke")
def revoke_token_form(request: Request, name: str, csrf: Annotated[str, Form()] = "") -> Response:
    """Revoke a token from the browser (admin)."""
    p = require(_web(request).principal(request), "admin", changes=True, csrf=csrf)
    store = _web(request).store
    revoke_token(store, name)
    audit(store, p.name, "token_revoke", {"name": name})
    return RedirectResponse("/audit", status_code=303)
