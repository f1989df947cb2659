"""The JSON API, ``/api/v1``, one router per resource (OpenAPI at ``/openapi.json``).

Reading needs the role ``viewer``, acknowledging, maintenance and uploads
``maintainer``, tokens and the audit log ``admin``; ``/api/v1/health``
needs none. A browser session's changes carry ``X-CSRF-Token``. Each
operation declares its body (:mod:`chaintwin.web.models`) and the role it
needs (:func:`chaintwin.web.deps.require_role`).

The routers are included in :data:`ROUTERS`' order: the routes under
``/conveyors/{id}/...`` before ``/conveyors/{id}`` itself (an id may hold ``/``).
"""

from __future__ import annotations

from fastapi import APIRouter

from . import alarms, audit, conveyors, kpis, recordings, service, tokens

__all__ = ["ROUTERS"]

ROUTERS: tuple[APIRouter, ...] = (
    service.router,
    alarms.router,
    kpis.router,
    conveyors.router,
    recordings.router,
    tokens.router,
    audit.router,
)
"""The API's routers, in the order they are included."""
