"""The service itself: its health (no token), the store's counts, the change events."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import Depends, Header, Request
from fastapi.responses import StreamingResponse

from chaintwin import __version__
from chaintwin.store.engine import safe_url
from chaintwin.store.migrate import revision_of
from chaintwin.web.deps import require_role, web_of
from chaintwin.web.models import Health, StoreCounts
from chaintwin.web.security import Principal

from .common import make_router

__all__ = ["router"]

router = make_router("service")

Viewer = Annotated[Principal, Depends(require_role("viewer"))]


@router.get("/health", response_model=Health)
def health(request: Request) -> dict[str, Any]:
    """The service and its store (no token needed): cheap enough to poll.

    The store's schema revision and number of conveyors (a small table);
    ``/api/v1/store`` counts the large ones. The store's ``url`` (its
    password hidden) only with a token: null for anonymous callers. With a token, in a process
    running live sources, ``live`` holds each source's state (who follows
    it, counts, scopes missed, last error) and the ingest queue's depth.
    """
    web = web_of(request)
    with web.store.engine.connect() as connection:
        revision = revision_of(connection)
    known = web.principal(request) is not None
    live = None
    service = web.extra.get("live")
    if service is not None and known:
        live = service.health()
    return {
        "live": live,
        "status": "ok",
        "version": __version__,
        "store": {
            # the store's address (its password hidden) only to a caller with a token
            "url": safe_url(web.store.url) if known else None,
            "revision": revision,
            "conveyors": len(web.store.conveyors()),
        },
    }


@router.get("/store", response_model=StoreCounts)
def store_counts(request: Request, _who: Viewer) -> dict[str, Any]:
    """How much the store holds: recordings, results, alarms, calibrations (viewer)."""
    web = web_of(request)
    return {"url": safe_url(web.store.url), **web.store.counts()}


_EVENT_DATA = {
    "type": "object",
    "required": ["id", "results", "states", "conveyors", "open_alarms", "changed"],
    "properties": {
        "id": {"type": "string", "description": "The store's signature (Last-Event-ID)"},
        "results": {"type": "integer"},
        "states": {"type": "integer"},
        "conveyors": {"type": "integer"},
        "open_alarms": {"type": "integer"},
        "changed": {
            "type": "array",
            "items": {"type": "string", "enum": ["results", "alarms", "conveyors"]},
        },
    },
}
"""The data of a ``ready`` or ``update`` event (JSON)."""

_EVENT_SCHEMA = {
    "type": "object",
    "required": ["event", "data"],
    "properties": {
        "event": {"type": "string", "enum": ["ready", "update"]},
        "id": {"type": "string"},
        "retry": {"type": "integer"},
        "data": {
            "type": "string",
            "contentMediaType": "application/json",
            "contentSchema": _EVENT_DATA,
        },
    },
}
"""One event of ``GET /api/v1/events``."""


@router.get(
    "/events",
    response_class=StreamingResponse,
    responses={
        200: {
            "description": "A server-sent event stream (text/event-stream): `ready` when it "
            "opens, `update` when results are stored or alarms change; it ends after "
            "15 s and the browser reconnects",
            # each event, as an event-stream parser gives it (OpenAPI 3.1: the schema of
            # a text/event-stream is that of one event)
            "content": {"text/event-stream": {"schema": _EVENT_SCHEMA}},
        }
    },
)
async def events(
    request: Request,
    _who: Viewer,
    last_event_id: Annotated[str | None, Header(max_length=100)] = None,
) -> StreamingResponse:
    """Server-sent events when the store changes (viewer): the pages refresh on them.

    The store is looked at once a second per server process, for all
    listeners together; each ``update`` event's data says what changed
    (``results``, ``alarms``, ``conveyors``) and carries the store's
    signature (``id``, sent back as ``Last-Event-ID`` on reconnecting).
    """
    web = web_of(request)
    feed = web.extra.get("feed")
    if feed is None:
        from chaintwin.web.events import ChangeFeed

        feed = web.extra.setdefault("feed", ChangeFeed(web.store))
    from chaintwin.web import events as stream

    return StreamingResponse(
        stream.event_stream(feed, last_event_id, stream.STREAM_S),
        media_type="text/event-stream",
        headers={"Cache-Control": "no-cache", "X-Accel-Buffering": "no"},
    )
