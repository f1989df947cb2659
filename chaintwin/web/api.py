"""The JSON API, ``/api/v1`` (OpenAPI at ``/openapi.json``, docs at ``/docs``).

Reading needs the role ``viewer``, acknowledging, maintenance and uploads
``maintainer``, tokens and the audit log ``admin``; ``/api/v1/health``
needs none. A browser session's changes carry ``X-CSRF-Token``.
"""

from __future__ import annotations

import hashlib
import math
import re
import tempfile
import threading
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
import orjson
from fastapi import APIRouter, Form, Header, Query, Request, Response, UploadFile
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import StreamingResponse
from pydantic import AfterValidator, BaseModel, ConfigDict, Field

from chaintwin import __version__
from chaintwin.diagnose.records import LIFECYCLES, date_in_span
from chaintwin.diagnose.state import acknowledge_alarm, add_maintenance
from chaintwin.errors import ChaintwinError, StoreError
from chaintwin.store.engine import safe_url
from chaintwin.store.migrate import revision_of
from chaintwin.store.queries import recording_by_hash, results_page, store_signature
from chaintwin.web.access import (
    audit,
    audit_entries,
    create_token,
    list_tokens,
    revoke_token,
)
from chaintwin.web.security import ApiError, Principal, require

__all__ = ["router"]


class ErrorDetail(BaseModel):
    """What went wrong: a stable code and a one-line message."""

    code: str
    message: str


class ErrorBody(BaseModel):
    """Every error of the API."""

    error: ErrorDetail


_ERRORS: dict[int | str, dict[str, Any]] = {
    status: {"model": ErrorBody, "description": text}
    for status, text in (
        (400, "Bad input (the message says what to do)"),
        (401, "No or an unknown token"),
        (403, "The token's role is too low, or a browser change lacks its CSRF token"),
        (404, "No such conveyor, alarm, feature or recording"),
        (409, "A token of that name exists"),
        (413, "The upload is too large"),
        (422, "The request does not match its schema"),
    )
}

router = APIRouter(prefix="/api/v1", tags=["api"], responses=_ERRORS)

PLOT_POINTS = 1000
"""Most samples of a channel returned for plotting (evenly thinned)."""

TREND_POINTS = 1000
"""Default ``max_points`` of a trend: the newest 500 results in full, the older history
thinned to 500 (:func:`~chaintwin.store.queries.trend_rows`)."""

PAGE_POINTS = 200
"""Results a conveyor's page and ``GET /api/v1/conveyors/{id}`` read (status, health
index, features): the newest 100 and 100 of the older history."""

_upload_lock = threading.Lock()


def _web(request: Request) -> Any:
    return request.app.state.web


def who(request: Request, role: str, *, changes: bool = False) -> Principal:
    """The request's principal with at least ``role`` (ApiError 401/403 otherwise)."""
    csrf = request.headers.get("x-csrf-token")
    return require(_web(request).principal(request), role, changes=changes, csrf=csrf)


def _finite(x: Any) -> Any:
    return None if isinstance(x, float) and not math.isfinite(x) else x


# ------------------------------------------------------------------ models
class Health(BaseModel):
    """The service's state."""

    status: Literal["ok"]
    version: str
    store: dict[str, Any]
    live: dict[str, Any] | None = None
    """With a token, in a process running live sources: each source's state."""


class AcknowledgeBody(BaseModel):
    """Why an alarm is acknowledged."""

    why: str = Field(min_length=1, max_length=2000)


class MaintenanceBody(BaseModel):
    """A maintenance event (the CLI's kinds)."""

    kind: str = Field(min_length=1, max_length=20)
    why: str = Field(min_length=1, max_length=2000)
    at: Annotated[
        datetime | None,
        AfterValidator(date_in_span),
        Field(description="When it was done (default now), within 1970-01-01..2200-01-01."),
    ] = None


class TokenBody(BaseModel):
    """A token to create."""

    name: str = Field(min_length=1, max_length=100)
    role: Literal["viewer", "maintainer", "admin"]
    expires_days: float | None = Field(default=None, gt=0, le=36500)


class UploadForm(BaseModel):
    """An upload: files, and nothing else (any other part is refused, 422)."""

    model_config = ConfigDict(extra="forbid")
    files: list[UploadFile] = Field(min_length=1)


class UploadedFile(BaseModel):
    """What became of one uploaded file."""

    file: str
    status: Literal["stored", "already_stored", "refused"]
    reason: str | None
    """Why a refused file was refused (null for the others)."""
    recording_id: str | None
    """The stored recording's id (its content's SHA-256); null for a refused file."""


class UploadResult(BaseModel):
    """What became of each uploaded file."""

    files: list[UploadedFile]


# ------------------------------------------------------------------ reading
@router.get("/health", response_model=Health)
def health(request: Request) -> dict[str, Any]:
    """The service and its store (no token needed): cheap enough to poll.

    The store's schema revision and number of conveyors (a small table);
    ``/api/v1/store`` counts the large ones. The store's ``url`` (its
    password hidden) only with a token: null for anonymous callers. With a token, in a process
    running live sources, ``live`` holds each source's state (who follows
    it, counts, scopes missed, last error) and the ingest queue's depth.
    """
    web = _web(request)
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


@router.get("/store")
def store_counts(request: Request) -> dict[str, Any]:
    """How much the store holds: recordings, results, alarms, calibrations (viewer)."""
    who(request, "viewer")
    web = _web(request)
    return {"url": safe_url(web.store.url), **web.store.counts()}


def fast_json(content: Any) -> Response:
    """A JSON response encoded by orjson at once (the polled lists: no generic encoder)."""
    return Response(orjson.dumps(content), media_type="application/json")


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
    last_event_id: Annotated[str | None, Header(max_length=100)] = None,
) -> StreamingResponse:
    """Server-sent events when the store changes (viewer): the pages refresh on them.

    The store is looked at once a second per server process, for all
    listeners together; each ``update`` event's data says what changed
    (``results``, ``alarms``, ``conveyors``) and carries the store's
    signature (``id``, sent back as ``Last-Event-ID`` on reconnecting).
    """
    who(request, "viewer")
    web = _web(request)
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


def fleet_etag(store: Any) -> str:
    """The fleet's ETag: its store signature (and this version's way of computing it)."""
    return f'W/"{__version__}-{store_signature(store).id}"'


def _matches(if_none_match: str | None, etag: str) -> bool:
    if if_none_match is None:
        return False
    tags = [t.strip() for t in if_none_match.split(",")]
    return "*" in tags or etag in tags or etag.removeprefix("W/") in tags


@router.get(
    "/conveyors",
    response_model=list[dict[str, Any]],
    responses={304: {"description": "Not modified: If-None-Match holds the current ETag"}},
)
def conveyors(
    request: Request,
    if_none_match: Annotated[str | None, Header(max_length=2000)] = None,
) -> Response:
    """Each conveyor: its verdict, open alarms, latest payload and TLF, last recording time.

    ``health``, ``health_since``, ``ne107`` and ``ne107_since``: the verdict
    (:func:`chaintwin.diagnose.verdict.verdict`, the same in every view);
    ``status``: the latest result's status. ``health_index``: the largest
    normalised deviation of its monitored features from their baseline
    (``deviation``, of ``worst_feature``: 0 at the baseline, 1 at the alarm
    limit, the median of the latest 10 recordings), at least 1 with a
    standing alarm; null while no baseline judges its recordings. Higher is
    worse.

    The response's ``ETag`` changes exactly when the store's results,
    health models, conveyors or open alarms do: a poll sending it back as
    ``If-None-Match`` gets 304 without the rows being read (a browser's
    ``fetch`` does this by itself: the response says ``Cache-Control:
    no-cache``).
    """
    who(request, "viewer")
    store = _web(request).store
    # the signature first: a change while the rows are read makes the next poll read again
    etag = fleet_etag(store)
    headers = {"ETag": etag, "Cache-Control": "no-cache"}
    if _matches(if_none_match, etag):
        return Response(status_code=304, headers=headers)
    _rows, body = fleet_health(_web(request)).snapshot(store, etag)
    return Response(body, media_type="application/json", headers=headers)


def fleet_health(web: Any) -> Any:
    """The process's :class:`~chaintwin.web.fleet.FleetHealth`."""
    from chaintwin.web.fleet import FleetHealth

    return web.extra.setdefault("fleet_health", FleetHealth())


def _conveyor(
    request: Request, conveyor_id: str, *, bands: bool = False, max_points: int | None = None
) -> Any:
    from chaintwin.report.data import conveyor_data

    store = _web(request).store
    if store.profile(conveyor_id) is None:
        raise ApiError(404, "not_found", f"no conveyor '{conveyor_id}' in the store")
    return conveyor_data(
        store,
        conveyor_id,
        waterfall=0,
        forecast_bands=bands,
        max_points=PAGE_POINTS if max_points is None else max_points,
        latest=False,
        stored_forecasts=True,
    )


@router.get("/conveyors/{conveyor_id:path}/recordings", response_model=dict[str, Any])
def recordings(
    request: Request,
    conveyor_id: str,
    since: str | None = None,
    until: str | None = None,
    limit: Annotated[int, Query(ge=1, le=1000)] = 100,
    cursor: str | None = None,
) -> Response:
    """Stored results, newest first by recording time, cursor-paginated."""
    who(request, "viewer")
    store = _web(request).store
    if store.profile(conveyor_id) is None:
        raise ApiError(404, "not_found", f"no conveyor '{conveyor_id}' in the store")
    page = results_page(store, conveyor_id, since=since, until=until, limit=limit, cursor=cursor)
    return fast_json({"items": page.items, "next_cursor": page.next_cursor})


def _trend(data: Any, conveyor_id: str, trend: Any, max_points: int) -> dict[str, Any]:
    """One feature's trend object (the ``trends`` endpoint's body for one ``feature``)."""
    feature = trend.name
    points = []
    represents = data.represents or [1] * len(data.results)
    for k, v, ex in zip(trend.index, trend.values, trend.exceeded, strict=False):
        t = data.times[k]
        points.append(
            {
                "recorded_at": None if t is None else t.isoformat(),
                "value": _finite(float(v)),
                "exceeded": bool(ex),
                "represents": represents[k],
            }
        )
    marks = [
        {"id": a.id, "since": a.since, "closed_at": a.closed_at, "cause": a.cause}
        for a in data.alarms
        if a.feature == feature
    ]
    forecast = next((dict(f) for f in data.forecasts if f["feature"] == feature), None)
    return {
        "conveyor": conveyor_id,
        "feature": feature,
        "cause": trend.cause,
        "unit": trend.unit,
        "expected": trend.expected,
        "limit": trend.limit,
        "lower_limit": trend.lower,
        "points": points,
        "alarms": marks,
        "health_index": _finite(float(trend.health_index())),
        "forecast": forecast,
        "recordings": data.recordings,
        "max_points": max_points,
    }


@router.get("/conveyors/{conveyor_id:path}/trends")
def trends(
    request: Request,
    conveyor_id: str,
    feature: Annotated[list[str] | None, Query()] = None,
    max_points: Annotated[int, Query(ge=20, le=100_000)] = TREND_POINTS,
) -> dict[str, Any]:
    """Features' series with their baseline band and alarm markers.

    One ``feature``: that feature's trend object. Several (``feature=a&feature=b``)
    or none: ``{"conveyor", "trends": [...], "recordings", "max_points", "as_of"}``,
    ``trends`` holding the trend object of each feature asked (of every
    tracked feature without ``feature``), read in one pass over the results.
    At most ``max_points`` (20 to 100 000) results are read: the newest half in full, the
    older history thinned to one result per stretch of equal length (each
    point's ``represents`` says how many results it stands for: 1 for the
    newest), so the cost hardly grows with the history; ``recordings``
    counts them all (``represents`` counts refused results too). The alarm
    markers come from the alarms, whole; ``health_index`` is that of the
    newest results, as without a bound. Raise ``max_points`` to get every
    result of a long history. The forecasts are those computed after ingest
    (``as_of``: when, and how many recordings they are behind).
    """
    who(request, "viewer")
    data = _conveyor(request, conveyor_id, bands=True, max_points=max_points)
    by_name = {t.name: t for t in data.trends}
    asked = list(dict.fromkeys(feature)) if feature else list(by_name)
    unknown = [f for f in asked if f not in by_name]
    if unknown:
        names = ", ".join(by_name) or "none yet"
        raise ApiError(404, "not_found", f"no feature '{unknown[0]}' (tracked: {names})")
    if feature is not None and len(feature) == 1:
        return _trend(data, conveyor_id, by_name[asked[0]], max_points)
    return {
        "conveyor": conveyor_id,
        "trends": [_trend(data, conveyor_id, by_name[f], max_points) for f in asked],
        "recordings": data.recordings,
        "max_points": max_points,
        "as_of": data.summary.get("forecasts_as_of"),
    }


@router.get("/conveyors/{conveyor_id:path}/waterfall")
def spectrum_waterfall(
    request: Request,
    conveyor_id: str,
    kind: Literal["order", "frequency"] = "order",
    recordings: Annotated[int, Query(ge=1, le=100)] = 20,
) -> dict[str, Any]:
    """The torque spectra of the latest recordings on one axis (viewer), for a waterfall.

    Computed from the stored samples (order spectrum, or Welch at constant
    speed for ``kind=frequency``), each downsampled to 400 bins by the
    largest amplitude per bin; ``lines`` marks where the profile's
    speed-locked lines appear.
    """
    from chaintwin.web.waterfall import SpectrumCache, waterfall

    who(request, "viewer")
    web = _web(request)
    if web.store.profile(conveyor_id) is None:
        raise ApiError(404, "not_found", f"no conveyor '{conveyor_id}' in the store")
    cache = web.extra.setdefault("spectra", SpectrumCache())
    return waterfall(web.store, conveyor_id, cache, kind=kind, count=recordings)


@router.get("/conveyors/{conveyor_id:path}")
def conveyor(request: Request, conveyor_id: str) -> dict[str, Any]:
    """Profile, calibration summary, baselines and verdict of one conveyor.

    ``health``, ``health_since``, ``ne107``, ``ne107_since``, ``health_index``,
    ``deviation`` and ``worst_feature`` are those of ``/conveyors``;
    ``status`` is the latest result's status.
    """
    who(request, "viewer")
    data = _conveyor(request, conveyor_id)
    cal = data.calibration
    calibration = None
    if cal is not None:
        calibration = {
            "case": cal.case,
            "created_at": cal.created_at,
            "mu": cal.parameters["mu"],
            "mu_stderr": cal.parameters.stderr("mu"),
            "payload_sensitivity_rel_uncertainty": cal.sensitivity_rel_uncertainty,
            "recommendation": cal.recommendation(),
            "directions": sorted(cal.directions),
            # what the calibration found weak (friction_unchecked, stick_slip, ...)
            "warnings": [w.to_dict() for w in cal.warnings],
        }
    return {
        "id": conveyor_id,
        "profile": data.profile.model_dump(mode="json"),
        "calibration": calibration,
        "baseline_since": data.baseline_since,
        "summary": data.summary,
        "forecasts": data.forecasts,
        **data.verdict.to_dict(),
        "status": _latest_status(data.results),
        "features": [t.name for t in data.trends],
        "open_alarms": [a.to_dict() for a in data.open_alarms()],
        "recordings": data.recordings,
        "notes": data.notes,
    }


def _latest_status(results: list[dict[str, Any]]) -> str | None:
    """The latest (not refused) result's ``status``, as ``/conveyors`` gives it; None: none."""
    for r in reversed(results):
        if r.get("status") not in (None, "refused"):
            return str(r["status"])
    return None


@router.get("/alarms")
def alarms(
    request: Request,
    state: Literal["open", "closed"] | None = None,
    acknowledged: bool | None = None,
    lifecycle: Literal[LIFECYCLES] | None = None,  # type: ignore[valid-type]
) -> list[dict[str, Any]]:
    """Alarms of every conveyor, oldest first, optionally filtered (``state=open``: not closed;
    ``lifecycle``: unacknowledged, acknowledged, returned_unacknowledged, shelved,
    out_of_service or closed)."""
    who(request, "viewer")
    out = []
    for a in _web(request).store.alarms():
        if state is not None and (a.is_open != (state == "open")):
            continue
        if acknowledged is not None and ((a.acknowledged is not None) != acknowledged):
            continue
        if lifecycle is not None and a.lifecycle() != lifecycle:
            continue
        out.append(a.to_dict())
    return out


@router.get("/recordings/{recording_id}")
def recording(request: Request, recording_id: str) -> dict[str, Any]:
    """A stored result with its measured and model torque and speed, thinned for plotting."""
    who(request, "viewer")
    if not re.fullmatch(r"[0-9a-f]{64}", recording_id):
        raise ApiError(404, "not_found", f"no recording '{recording_id[:80]}'")
    store = _web(request).store
    found = recording_by_hash(store, recording_id)
    if found is None:
        raise ApiError(404, "not_found", f"no recording '{recording_id}'")
    result, rec = found
    step = max(1, math.ceil(rec.samples / PLOT_POINTS))
    series: dict[str, Any] = {
        "time_s": rec.time[::step].tolist(),
        "speed_rpm": (rec.speed[::step] * 60.0 / (2.0 * math.pi)).tolist(),
        "torque_nm": rec.torque[::step].tolist(),
        "model_torque_nm": None,
    }
    cal = store.calibration(result["conveyor"])
    payload = result.get("payload_kg")
    if cal is not None and payload is not None:
        from chaintwin.model.rigid import model_torque

        model = model_torque(rec, cal.id_profile, cal.parameters, float(payload))
        series["model_torque_nm"] = np.asarray(model)[::step].tolist()
    return {"result": result, "series": series}


# ------------------------------------------------------------------ changes
@router.post("/alarms/{alarm_id}/acknowledge")
def acknowledge(request: Request, alarm_id: str, body: AcknowledgeBody) -> dict[str, Any]:
    """Acknowledge an open alarm (maintainer): it stays open, no longer fails scripts."""
    p = who(request, "maintainer", changes=True)
    out: dict[str, Any] = acknowledge_as(_web(request).store, p.name, alarm_id, body.why).to_dict()
    return out


def acknowledge_as(store: Any, name: str, alarm_id: str, why: str) -> Any:
    """Acknowledge an alarm for the token ``name`` and audit it (API and form alike)."""
    try:
        conveyor_id = store.alarm_conveyor(alarm_id)
    except StoreError as exc:
        raise ApiError(404, "not_found", str(exc)) from None
    alarm = store.edit_state(conveyor_id, lambda d: acknowledge_alarm(d, alarm_id, name, why))
    audit(store, name, "acknowledge", {"alarm": alarm_id, "why": why})
    return alarm


def maintenance_as(
    store: Any, name: str, conveyor_id: str, kind: str, why: str, at: datetime | None
) -> Any:
    """Record maintenance for the token ``name`` and audit it (API and form alike)."""
    if store.profile(conveyor_id) is None:
        raise ApiError(404, "not_found", f"no conveyor '{conveyor_id}' in the store")
    event = store.edit_state(
        conveyor_id, lambda d: add_maintenance(d, conveyor_id, kind, name, why, at)
    )
    audit(store, name, "maintenance", {"conveyor": conveyor_id, "kind": kind})
    return event


@router.post("/conveyors/{conveyor_id:path}/maintenance")
def maintenance(request: Request, conveyor_id: str, body: MaintenanceBody) -> dict[str, Any]:
    """Record a maintenance event (maintainer): the baseline restarts after it."""
    p = who(request, "maintainer", changes=True)
    event = maintenance_as(_web(request).store, p.name, conveyor_id, body.kind, body.why, body.at)
    out: dict[str, Any] = event.to_dict()
    return out


_SAFE_NAME = re.compile(r"[^A-Za-z0-9._-]+")


def ingest_uploads(web: Any, staged: list[Staged], who_name: str) -> list[UploadedFile]:
    """Store staged uploads exactly as ``chaintwin ingest`` would; what became of each."""
    from chaintwin.ingest.pipeline import ingest

    profiles = {cid: p for cid in web.store.conveyors() if (p := web.store.profile(cid))}
    live = web.extra.get("live")
    # the live service follows --profiles and reads a changed folder again
    profiles |= live.profiles_now if live is not None else web.profiles
    out: list[UploadedFile] = []
    with _upload_lock:
        known = web.store.known(f.sha256 for f in staged)
        summary = ingest([f.path for f in staged], profiles, web.store, workers=1)
    refused = {r["file"]: r["error"] for r in summary.refusals}
    for f in staged:
        if f.path in refused:
            reason = refused[f.path].replace(f.path, f.name)
            out.append(
                UploadedFile(file=f.name, status="refused", reason=reason, recording_id=None)
            )
        else:
            status: Literal["stored", "already_stored"] = (
                "already_stored" if f.sha256 in known else "stored"
            )
            out.append(UploadedFile(file=f.name, status=status, reason=None, recording_id=f.sha256))
    audit(
        web.store,
        who_name,
        "upload",
        {"files": [f.file for f in out], "stored": sum(f.status == "stored" for f in out)},
    )
    return out


@dataclass(frozen=True, slots=True)
class Staged:
    """An uploaded file copied to the upload's folder: its name as sent, path and SHA-256."""

    name: str
    path: str
    sha256: str


_COPY_CHUNK = 1024 * 1024
"""Bytes copied at a time from an upload to its file (never a whole file in memory)."""


def stage_uploads(web: Any, files: list[UploadFile], folder: Path) -> list[Staged]:
    """Copy the uploaded files into ``folder`` chunk by chunk; ApiError 413 beyond the limit.

    The files arrive spooled by the multipart parser (in memory up to 1 MB,
    then in a temporary file), their total already bounded by the guard
    (:mod:`chaintwin.web.guard`); this copies them under their own names for
    ingest, hashing as it goes.
    """
    staged: list[Staged] = []
    total = 0
    for k, f in enumerate(files):
        name = f.filename or "upload.csv"
        base = _SAFE_NAME.sub("_", Path(name).name)[-120:] or "upload.csv"
        path = folder / f"{k:03d}-{base}"
        digest = hashlib.sha256()
        f.file.seek(0)
        with path.open("xb") as out:
            while chunk := f.file.read(_COPY_CHUNK):
                total += len(chunk)
                if total > web.max_upload_bytes:
                    raise ApiError(
                        413,
                        "too_large",
                        f"the upload is larger than {web.max_upload_bytes / (1024 * 1024):g} "
                        "MB; send fewer files at once",
                    )
                digest.update(chunk)
                out.write(chunk)
        staged.append(Staged(name, str(path), digest.hexdigest()))
    return staged


async def take_uploads(
    request: Request, files: list[UploadFile], who_name: str, fields: frozenset[str]
) -> list[UploadedFile]:
    """Check an upload's parts, copy its files aside, ingest them; what became of each.

    Every part must be a file named ``files``, or one of ``fields`` (the
    page's ``csrf``): anything else is refused (422) before a byte is stored.
    """
    web = _web(request)
    form = await request.form()  # parsed already for the handler's parameters
    for key, value in form.multi_items():
        if key == "files" and isinstance(value, str):
            raise ApiError(
                422, "invalid", "files: a part named 'files' is not a file; send files only"
            )
        if key != "files" and key not in fields:
            raise ApiError(
                422,
                "invalid",
                f"{key[:80]}: not a part of an upload; send the files as 'files' only",
            )
    with tempfile.TemporaryDirectory(prefix="chaintwin-upload-") as folder:
        staged = await run_in_threadpool(stage_uploads, web, files, Path(folder))
        done: list[UploadedFile] = await run_in_threadpool(ingest_uploads, web, staged, who_name)
    return done


@router.post("/recordings", response_model=UploadResult)
async def upload(
    request: Request, form: Annotated[UploadForm, Form(media_type="multipart/form-data")]
) -> dict[str, Any]:
    """Upload recordings (maintainer), ingested as ``chaintwin ingest`` would.

    Each file's answer says whether it was ``stored``, ``already_stored`` or
    ``refused``, with its ``recording_id`` (null when refused) and the
    ``reason`` of a refusal. A request without a valid token is refused
    before its body is read; one larger than the upload limit as soon as it
    passes it (413), whether it declared its length or not; a part that is
    not a file named ``files`` 422.
    """
    p = who(request, "maintainer", changes=True)
    done = await take_uploads(request, form.files, p.name, frozenset())
    return {"files": [f.model_dump() for f in done]}


# ------------------------------------------------------------------ admin
@router.get("/tokens")
def tokens(request: Request) -> list[dict[str, Any]]:
    """Every token (names, roles, lifetimes; never the tokens), admin."""
    who(request, "admin")
    return [t.to_dict() for t in list_tokens(_web(request).store)]


@router.post("/tokens")
def new_token(request: Request, body: TokenBody) -> dict[str, Any]:
    """Create a token (admin); the response is the only time it is shown."""
    p = who(request, "admin", changes=True)
    store = _web(request).store
    try:
        token = create_token(store, body.name, body.role, body.expires_days)
    except ChaintwinError as exc:
        raise ApiError(409, "conflict", str(exc)) from None
    audit(store, p.name, "token_create", {"name": body.name, "role": body.role})
    return {"token": token, "name": body.name, "role": body.role}


@router.post("/tokens/{name}/revoke")
def revoke(request: Request, name: str) -> dict[str, Any]:
    """Revoke a token by name (admin); its sessions end at once."""
    p = who(request, "admin", changes=True)
    store = _web(request).store
    try:
        info = revoke_token(store, name)
    except StoreError as exc:
        raise ApiError(404, "not_found", str(exc)) from None
    audit(store, p.name, "token_revoke", {"name": name})
    return info.to_dict()


@router.get("/audit")
def audit_log(
    request: Request, limit: Annotated[int, Query(ge=1, le=5000)] = 500
) -> list[dict[str, Any]]:
    """The audit log, newest first (admin)."""
    who(request, "admin")
    return audit_entries(_web(request).store, limit)
