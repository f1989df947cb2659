"""The web service: dashboard pages and the JSON API over a results store.

:func:`create_app` builds the FastAPI application; ``chaintwin serve`` runs
it under uvicorn. Everything it loads in a browser comes from the package
(Plotly's, Swagger UI's and ReDoc's JavaScript under ``/static``), nothing from the
network.

Every error of the API has one shape, ``{"error": {"code", "message"}}``;
a page answers a missing login with a redirect to ``/login``.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import jinja2
from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.openapi.docs import get_redoc_html
from fastapi.responses import (
    FileResponse,
    HTMLResponse,
    JSONResponse,
    RedirectResponse,
    Response,
)
from fastapi.staticfiles import StaticFiles
from fastapi.templating import Jinja2Templates
from starlette.exceptions import HTTPException as StarletteHTTPException

from chaintwin import __version__
from chaintwin.errors import ChaintwinError
from chaintwin.read.profile import ConveyorProfile
from chaintwin.store.store import Store
from chaintwin.web.access import secret
from chaintwin.web.guard import LOGIN_ATTEMPTS, Guard, LoginAttempts
from chaintwin.web.security import ApiError, Principal, principal_of

__all__ = ["WebState", "create_app", "freeze_heap"]

_HERE = Path(__file__).parent


@dataclass
class WebState:
    """What the request handlers share: the store, the profiles, the settings."""

    store: Store
    profiles: dict[str, ConveyorProfile]
    max_upload_bytes: int
    session_key: bytes
    templates: Jinja2Templates
    secure_cookies: bool = False
    extra: dict[str, Any] = field(default_factory=dict)

    def principal(self, request: Request) -> Principal | None:
        """Who is asking (None: nobody known)."""
        return principal_of(request, self.store, self.session_key)


def _static_dirs() -> dict[str, Path]:
    import fastapi_offline  # Swagger UI 5 (reads OpenAPI 3.1) and ReDoc, as files
    import plotly  # type: ignore[import-untyped]

    return {
        "plotly": Path(plotly.__file__).parent / "package_data",
        "swagger": Path(fastapi_offline.__file__).parent / "static",
        "app": _HERE / "static",
    }


def _error(
    status: int, code: str, message: str, headers: dict[str, str] | None = None
) -> JSONResponse:
    return JSONResponse(
        {"error": {"code": code, "message": message}}, status_code=status, headers=headers
    )


def _is_api(request: Request) -> bool:
    return request.url.path.startswith("/api/")


_DOCS_PAGE = """<!doctype html>
<html lang="en">
<head>
<meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<link rel="stylesheet" href="/static/swagger/swagger-ui.css">
<link rel="icon" href="/static/swagger/favicon.png">
<title>chaintwin API</title>
</head>
<body>
<div id="swagger-ui"></div>
<script src="/static/swagger/swagger-ui-bundle.js"></script>
<script src="/static/app/swagger-init.js"></script>
</body>
</html>
"""
"""Swagger UI at ``/docs``, started from a static file (the CSP allows no inline script)."""


def create_app(
    store: Store,
    profiles: dict[str, ConveyorProfile] | None = None,
    *,
    max_upload_mb: float = 20.0,
    secure_cookies: bool = False,
    live: Any = None,
    login_attempts: int = LOGIN_ATTEMPTS,
) -> FastAPI:
    """The web application over ``store``.

    Parameters
    ----------
    store : Store
        An open results store (written to: acknowledgements, maintenance,
        uploads, the audit log).
    profiles : dict, optional
        Profiles by conveyor id that uploads are weighed and monitored with
        (with the store's own for conveyors it holds).
    max_upload_mb : float
        Largest upload request, MB (413 beyond).
    secure_cookies : bool
        Mark the session cookie ``Secure`` (served over TLS); behind a trusted
        proxy (``serve --forwarded-allow-ips``) it is marked so whenever the
        proxy says the request came over https.
    live : LiveService, optional
        The live service of this process (:mod:`chaintwin.live.service`):
        its sources in the health endpoint, its metrics at ``/metrics``.
    login_attempts : int
        Login attempts a client may make a minute (429 with ``Retry-After`` beyond).
    """
    from chaintwin.web import alarm_pages, pages
    from chaintwin.web.routes import ROUTERS

    app = FastAPI(
        title="chaintwin",
        version=__version__,
        summary="Condition monitoring and dynamic weighing of chain conveyors",
        docs_url=None,
        redoc_url=None,
    )
    # every value escaped, whatever the templates' file names end with
    env = jinja2.Environment(
        loader=jinja2.FileSystemLoader(str(_HERE / "templates")), autoescape=True
    )
    templates = Jinja2Templates(env=env)
    state = WebState(
        store=store,
        profiles=dict(profiles or {}),
        max_upload_bytes=int(max_upload_mb * 1024 * 1024),
        session_key=secret(store, "session_key"),
        templates=templates,
        secure_cookies=secure_cookies,
    )
    if live is not None:
        state.extra["live"] = live
    app.state.web = state

    async def refuse(
        request: Request, status: int, code: str, message: str, headers: dict[str, str]
    ) -> Response:
        """The guard's refusals: the API's JSON error; a page's error page or the login."""
        if _is_api(request):
            return _error(status, code, message, headers)
        if status == 401:
            return RedirectResponse("/login", status_code=303)
        page = pages.error_page(request, status, message)
        page.headers.update(headers)
        return page

    # a pure ASGI middleware, not @app.middleware: that one's wrapper cancels a
    # streaming response (the event stream) as soon as its first chunk is sent
    app.add_middleware(
        Guard,
        principal=state.principal,
        upload_limit=lambda: state.max_upload_bytes,
        refuse=refuse,
        logins=LoginAttempts(attempts=login_attempts),
    )
    from chaintwin.web.trace import SlowTrace, slow_ms, watch_connections

    threshold = slow_ms()
    if threshold is not None:  # CHAINTWIN_TRACE_SLOW_MS: what pauses the server
        app.add_middleware(SlowTrace, threshold_ms=threshold)
        watch_connections(store.engine)

    for name, folder in _static_dirs().items():
        app.mount(f"/static/{name}", StaticFiles(directory=str(folder)), name=f"static-{name}")

    @app.exception_handler(ApiError)
    async def api_error(request: Request, exc: ApiError) -> Response:
        if not _is_api(request) and exc.status == 401:
            return RedirectResponse("/login", status_code=303)
        if not _is_api(request):
            return pages.error_page(request, exc.status, exc.message)
        return _error(exc.status, exc.code, exc.message)

    @app.exception_handler(ChaintwinError)
    async def bad_input(request: Request, exc: ChaintwinError) -> Response:
        message = str(exc).splitlines()[0] if str(exc) else exc.__class__.__name__
        if not _is_api(request):
            return pages.error_page(request, 400, message)
        return _error(400, "bad_request", message)

    @app.exception_handler(StarletteHTTPException)
    async def http_error(request: Request, exc: StarletteHTTPException) -> Response:
        code = {404: "not_found", 405: "method_not_allowed", 413: "too_large"}.get(
            exc.status_code, "http_error"
        )
        headers = dict(exc.headers or {})  # 405: Allow
        if not _is_api(request):
            page = pages.error_page(request, exc.status_code, str(exc.detail))
            page.headers.update(headers)
            return page
        return _error(exc.status_code, code, str(exc.detail), headers)

    @app.exception_handler(RequestValidationError)
    async def invalid(request: Request, exc: RequestValidationError) -> Response:
        first = exc.errors()[0] if exc.errors() else {}
        where = ".".join(str(p) for p in first.get("loc", ()))
        message = f"{where}: {first.get('msg', 'invalid request')}" if where else "invalid request"
        if not _is_api(request):
            return pages.error_page(request, 422, message)
        return _error(422, "invalid", message)

    @app.get("/favicon.ico", include_in_schema=False)
    async def favicon() -> FileResponse:
        return FileResponse(_static_dirs()["swagger"] / "favicon.png")

    @app.get("/docs", include_in_schema=False)
    async def docs() -> HTMLResponse:
        return HTMLResponse(_DOCS_PAGE)

    @app.get("/redoc", include_in_schema=False)
    async def redoc() -> HTMLResponse:
        page = get_redoc_html(
            openapi_url="/openapi.json",
            title="chaintwin API",
            redoc_js_url="/static/swagger/redoc.standalone.js",
            redoc_favicon_url="/static/swagger/favicon.png",
            with_google_fonts=False,
        )
        # ReDoc always asks its vendor's site for a logo: the page's own images only
        page.headers["Content-Security-Policy"] = (
            "default-src 'self'; script-src 'self' 'unsafe-inline' blob:; "
            "style-src 'self' 'unsafe-inline'; img-src 'self' data:; worker-src 'self' blob:; "
            "frame-ancestors 'none'"
        )
        return page

    @app.get("/metrics", include_in_schema=False)
    def metrics(request: Request) -> Response:
        # Prometheus scrapes from this machine, or with a viewer token
        client = request.client.host if request.client is not None else ""
        if client not in ("127.0.0.1", "::1", "localhost"):
            who = state.principal(request)
            if who is None:  # a scraper, not a browser: no redirect to the login page
                return _error(401, "unauthorized", "GET /metrics needs a viewer token")
        service = state.extra.get("live")
        if service is None:
            from chaintwin.live.metrics import Metrics

            service_metrics = state.extra.setdefault("metrics", Metrics(store, lambda: 0.0))
        else:
            service_metrics = service.metrics
        from chaintwin.live.metrics import CONTENT_TYPE

        return Response(service_metrics.text(), media_type=CONTENT_TYPE)

    for router in ROUTERS:  # the API, one router per resource
        app.include_router(router)
    app.include_router(alarm_pages.router)  # before pages' /conveyors/{id:path} routes
    app.include_router(pages.router)
    return app


def freeze_heap(app: FastAPI | None = None) -> int:
    """Import what the handlers import on first use, collect, and freeze the heap.

    Python's collection of its oldest generation walks every object it
    tracks: some 250 000 in a serving process (the libraries, the app),
    which took 170-310 ms on the 2-core machine of ``bench_serve`` (traced
    with ``CHAINTWIN_TRACE_SLOW_MS``) and came about once a minute under 50
    polling dashboards, setting their p99. :func:`gc.freeze` moves the
    objects alive at start-up out of the collector's sight for good (they
    live as long as the process anyway), so a full collection walks only
    what was made since. Call it once, after the app is built and before it
    serves. Returns the number of objects frozen.
    """
    import gc
    import importlib

    for name in (  # what the handlers import lazily: loaded and frozen now
        "chaintwin.report.data",
        "chaintwin.web.fleet",
        "chaintwin.web.events",
        "chaintwin.web.waterfall",
        "chaintwin.live.metrics",
        "chaintwin.model.rigid",
    ):
        importlib.import_module(name)
    if app is not None:
        app.openapi()  # built once on first use of /docs or /openapi.json
        env = app.state.web.templates.env
        for template in env.list_templates():
            env.get_template(template)
    gc.collect()
    gc.freeze()
    return gc.get_freeze_count()


def app_from_environment() -> FastAPI:  # pragma: no cover - used by uvicorn --factory
    """The app for ``uvicorn --factory chaintwin.web.app:app_from_environment``.

    Reads ``CHAINTWIN_DB`` and optionally ``CHAINTWIN_PROFILES``.
    """
    from chaintwin.read.profile import load_profiles
    from chaintwin.store.engine import store_url

    folder = os.environ.get("CHAINTWIN_PROFILES")
    profiles = load_profiles(folder) if folder else {}
    app = create_app(Store(store_url(None)), profiles)
    freeze_heap(app)
    return app
