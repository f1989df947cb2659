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
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import jinja2
from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.openapi.docs import get_redoc_html, get_swagger_ui_html
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
from starlette.types import ASGIApp, Receive, Scope, Send

from chaintwin import __version__
from chaintwin.errors import ChaintwinError
from chaintwin.read.profile import ConveyorProfile
from chaintwin.store.access import secret
from chaintwin.store.store import Store
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


class UploadLimit:
    """Refuse an oversized upload from its declared length, before its body is read.

    Parameters
    ----------
    app : ASGI app
        The application it wraps.
    limit : callable
        The largest upload request, bytes.
    refuse : callable
        The response to an oversized one (413).
    """

    PATHS = ("/api/v1/recordings", "/upload")

    def __init__(
        self, app: ASGIApp, limit: Callable[[], int], refuse: Callable[..., Awaitable[Response]]
    ) -> None:
        self.app = app
        self.limit = limit
        self.refuse = refuse

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "http" and scope["method"] == "POST" and scope["path"] in self.PATHS:
            length = dict(scope["headers"]).get(b"content-length", b"")
            if length.isdigit() and int(length) > self.limit():
                response = await self.refuse(Request(scope, receive))
                await response(scope, receive, send)
                return
        await self.app(scope, receive, send)


def _static_dirs() -> dict[str, Path]:
    import fastapi_offline  # Swagger UI 5 (reads OpenAPI 3.1) and ReDoc, as files
    import plotly  # type: ignore[import-untyped]

    return {
        "plotly": Path(plotly.__file__).parent / "package_data",
        "swagger": Path(fastapi_offline.__file__).parent / "static",
        "app": _HERE / "static",
    }


def _error(status: int, code: str, message: str) -> JSONResponse:
    return JSONResponse({"error": {"code": code, "message": message}}, status_code=status)


def _is_api(request: Request) -> bool:
    return request.url.path.startswith("/api/")


def create_app(
    store: Store,
    profiles: dict[str, ConveyorProfile] | None = None,
    *,
    max_upload_mb: float = 20.0,
    secure_cookies: bool = False,
    live: Any = None,
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
        Mark the session cookie ``Secure`` (behind TLS).
    live : LiveService, optional
        The live service of this process (:mod:`chaintwin.live.service`):
        its sources in the health endpoint, its metrics at ``/metrics``.
    """
    from chaintwin.web import api, pages

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

    async def too_large(request: Request) -> Response:
        message = (
            f"the upload is larger than {state.max_upload_bytes / (1024 * 1024):g} MB; "
            "send fewer files at once"
        )
        if _is_api(request):
            return _error(413, "too_large", message)
        return pages.error_page(request, 413, message)

    # a pure ASGI middleware, not @app.middleware: that one's wrapper cancels a
    # streaming response (the event stream) as soon as its first chunk is sent
    app.add_middleware(UploadLimit, limit=lambda: state.max_upload_bytes, refuse=too_large)
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
        if not _is_api(request):
            return pages.error_page(request, exc.status_code, str(exc.detail))
        return _error(exc.status_code, code, str(exc.detail))

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
        return get_swagger_ui_html(
            openapi_url="/openapi.json",
            title="chaintwin API",
            swagger_js_url="/static/swagger/swagger-ui-bundle.js",
            swagger_css_url="/static/swagger/swagger-ui.css",
            swagger_favicon_url="/static/swagger/favicon.png",
        )

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
            "style-src 'self' 'unsafe-inline'; img-src 'self' data:; worker-src 'self' blob:"
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

    app.include_router(api.router)
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
    from chaintwin.cli.monitor_cmd import load_profiles
    from chaintwin.store.engine import store_url

    folder = os.environ.get("CHAINTWIN_PROFILES")
    profiles = load_profiles(None, Path(folder)) if folder else {}
    app = create_app(Store(store_url(None)), profiles)
    freeze_heap(app)
    return app
