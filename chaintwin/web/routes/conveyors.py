"""Conveyors: the fleet, one conveyor, its results, trends and waterfall; maintenance
and out-of-service windows.

The fleet, a conveyor, its page of results, trends and waterfall are
answered encoded by orjson at once (they are polled or large), their models
declared for the document; the conveyor's verdict comes from the process's
:class:`~chaintwin.store.verdicts.VerdictCache` (worked out once per version of
its health model), the same the fleet shows.
"""

from __future__ import annotations

from datetime import datetime
from typing import Annotated, Any, Literal

from fastapi import Depends, Header, Query, Request, Response

from chaintwin import __version__
from chaintwin.diagnose.alarm_actions import clear_out_of_service, set_out_of_service
from chaintwin.diagnose.state import add_maintenance
from chaintwin.errors import StoreError
from chaintwin.store.queries import TREND_POINTS, results_page, store_signature
from chaintwin.web.access import audit
from chaintwin.web.deps import require_role, web_of
from chaintwin.web.models import (
    ConveyorDetail,
    ConveyorRow,
    MaintenanceBody,
    MaintenanceEvent,
    OutOfServiceBody,
    OutOfServiceWindow,
    ResultsPage,
    Trend,
    Trends,
    Waterfall,
)
from chaintwin.web.security import ApiError, Principal

from .common import fast_json, make_router

__all__ = [
    "PAGE_POINTS",
    "TREND_POINTS",
    "conveyor_data_of",
    "fleet_etag",
    "fleet_health",
    "maintenance_as",
    "out_of_service_as",
    "router",
]

router = make_router("conveyors")

Viewer = Annotated[Principal, Depends(require_role("viewer"))]
Maintainer = Annotated[Principal, Depends(require_role("maintainer", changes=True))]


PAGE_POINTS = 200
"""Results a conveyor's page and ``GET /api/v1/conveyors/{id}`` read (status, health
index, features): the newest 100 and 100 of the older history."""


def fleet_etag(store: Any) -> str:
    """The fleet's ETag: its store signature (and this version's way of computing it)."""
    return f'W/"{__version__}-{store_signature(store).id}"'


def _matches(if_none_match: str | None, etag: str) -> bool:
    if if_none_match is None:
        return False
    tags = [t.strip() for t in if_none_match.split(",")]
    return "*" in tags or etag in tags or etag.removeprefix("W/") in tags


def fleet_health(web: Any) -> Any:
    """The process's :class:`~chaintwin.web.fleet.FleetHealth`."""
    from chaintwin.web.fleet import FleetHealth

    return web.extra.setdefault("fleet_health", FleetHealth())


def conveyor_data_of(
    web: Any,
    conveyor_id: str,
    *,
    bands: bool = False,
    max_points: int | None = None,
    trends: bool = True,
) -> Any:
    """A conveyor's :class:`~chaintwin.report.data.ConveyorData` for the pages and the API:
    bounded, forecasts as stored, the verdict from the process's cache (404: no conveyor).

    ``trends``: build the trends (False: only name them, ``feature_names``: the
    conveyor's page and detail, which show no series).

    Every read shares one database session (:meth:`~chaintwin.store.store.Store.session`):
    one connection checkout per request rather than one per read."""
    from chaintwin.report.data import conveyor_data

    store = web.store
    with store.session():
        try:
            return conveyor_data(
                store,
                conveyor_id,
                waterfall=0,
                forecast_bands=bands,
                max_points=PAGE_POINTS if max_points is None else max_points,
                latest=False,
                stored_forecasts=True,
                known_verdict=fleet_health(web).verdict(store, conveyor_id),
                trends=trends,
            )
        except StoreError:
            # the profile is read once, by conveyor_data (a round trip less on PostgreSQL)
            if store.profile(conveyor_id) is None:
                raise ApiError(
                    404, "not_found", f"no conveyor '{conveyor_id}' in the store"
                ) from None
            raise


@router.get(
    "/conveyors",
    response_model=list[ConveyorRow],
    responses={304: {"description": "Not modified: If-None-Match holds the current ETag"}},
)
def conveyors(
    request: Request,
    _who: Viewer,
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
    web = web_of(request)
    store = web.store
    # the signature first: a change while the rows are read makes the next poll read again
    etag = fleet_etag(store)
    headers = {"ETag": etag, "Cache-Control": "no-cache"}
    if _matches(if_none_match, etag):
        return Response(status_code=304, headers=headers)
    _rows, body = fleet_health(web).snapshot(store, etag)
    return Response(body, media_type="application/json", headers=headers)


@router.get("/conveyors/{conveyor_id:path}/recordings", response_model=ResultsPage)
def recordings(
    request: Request,
    conveyor_id: str,
    _who: Viewer,
    since: str | None = None,
    until: str | None = None,
    limit: Annotated[int, Query(ge=1, le=1000)] = 100,
    cursor: Annotated[
        str | None,
        Query(
            description="The `next_cursor` of the page before (opaque: only one this "
            "service gave is accepted)"
        ),
    ] = None,
) -> Response:
    """Stored results, newest first by recording time, cursor-paginated."""
    store = web_of(request).store
    if store.profile(conveyor_id) is None:
        raise ApiError(404, "not_found", f"no conveyor '{conveyor_id}' in the store")
    page = results_page(store, conveyor_id, since=since, until=until, limit=limit, cursor=cursor)
    return fast_json({"items": page.items, "next_cursor": page.next_cursor})


def _asked(names: list[str], feature: list[str] | None) -> None:
    """404 for a feature asked that the conveyor does not track."""
    unknown = [f for f in dict.fromkeys(feature or []) if f not in names]
    if unknown:
        tracked = ", ".join(names) or "none yet"
        raise ApiError(404, "not_found", f"no feature '{unknown[0]}' (tracked: {tracked})")


@router.get("/conveyors/{conveyor_id:path}/trends", response_model=Trend | Trends)
def trends(
    request: Request,
    conveyor_id: str,
    _who: Viewer,
    feature: Annotated[list[str] | None, Query()] = None,
    max_points: Annotated[int, Query(ge=20, le=100_000)] = TREND_POINTS,
) -> Response:
    """Features' series with their baseline band and alarm markers.

    One ``feature``: that feature's trend object. Several (``feature=a&feature=b``)
    or none: ``{"conveyor", "trends": [...], "recordings", "max_points", "as_of"}``,
    ``trends`` holding the trend object of each feature asked (of every
    tracked feature without ``feature``), read in one pass over the results.
    At most ``max_points`` (20 to 100 000) results are read: the newest half in full, the
    older history thinned evenly (each point's ``represents`` says how many
    results it stands for; ``recordings`` counts them all). The alarm
    markers are every alarm's of the feature, whole; ``health_index`` is that of the
    newest results, as without a bound. Raise ``max_points`` to get every
    result of a long history. The forecasts are those computed after ingest
    (``as_of``: when, and how many recordings they are behind).

    At the default ``max_points`` the series are those built after ingest
    (:mod:`chaintwin.report.trend_series`), used only while no result or
    health model came since they were built; else (the refit not yet run,
    at most one refit round behind the newest recording) they are built
    from the results here: the points are never behind the newest result.
    The answer is the same either way, byte for byte.
    """
    from chaintwin.report.data import health_part
    from chaintwin.report.trend_series import (
        answer_of,
        build_and_store,
        built_from,
        current_series,
        iso_times,
        stored_from,
        trend_object,
    )

    web = web_of(request)
    store = web.store

    def build() -> Any:
        return conveyor_data_of(web, conveyor_id, bands=True, max_points=max_points)

    with store.session():  # one connection checkout for every read
        profile = store.profile(conveyor_id)
        if profile is None:
            raise ApiError(404, "not_found", f"no conveyor '{conveyor_id}' in the store")
        if max_points != TREND_POINTS:
            data = build()
        else:
            state, health = health_part(
                store, conveyor_id, profile, stored_forecasts=True, forecast_bands=True
            )
            current = built_from(store, conveyor_id, profile, state, inputs=health.inputs)
            series = current_series(store, conveyor_id, current)
            if series is not None:  # built from these very results and health model
                _asked(series.names, feature)
                body = series.answer(
                    conveyor_id,
                    feature,
                    store.alarms(conveyor_id),
                    health.forecasts,
                    health.summary.get("forecasts_as_of"),
                )
                return Response(body, media_type="application/json")
            if stored_from(store, conveyor_id) is None:
                # none stored yet (a store written before them): built once here and stored
                data = build_and_store(store, conveyor_id, profile, build, replace=False)[0]
            else:  # behind the newest result or health model: built, never stale points
                data = build()
    _asked([t.name for t in data.trends], feature)
    times = iso_times(data)
    objects = {
        t.name: (lambda t=t: trend_object(data, conveyor_id, t, max_points, times))
        for t in data.trends
    }
    return fast_json(
        answer_of(
            conveyor_id,
            feature,
            objects,
            data.recordings,
            max_points,
            data.summary.get("forecasts_as_of"),
        )
    )


@router.get("/conveyors/{conveyor_id:path}/waterfall", response_model=Waterfall)
def spectrum_waterfall(
    request: Request,
    conveyor_id: str,
    _who: Viewer,
    kind: Literal["order", "frequency"] = "order",
    recordings: Annotated[int, Query(ge=1, le=100)] = 20,
) -> Response:
    """The torque spectra of the latest recordings on one axis (viewer), for a waterfall.

    Computed from the stored samples (order spectrum, or Welch at constant
    speed for ``kind=frequency``), each downsampled to 400 bins by the
    largest amplitude per bin; ``lines`` marks where the profile's
    speed-locked lines appear.
    """
    from chaintwin.web.waterfall import SpectrumCache, waterfall

    web = web_of(request)
    if web.store.profile(conveyor_id) is None:
        raise ApiError(404, "not_found", f"no conveyor '{conveyor_id}' in the store")
    cache = web.extra.setdefault("spectra", SpectrumCache())
    return fast_json(waterfall(web.store, conveyor_id, cache, kind=kind, count=recordings))


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


@router.post("/conveyors/{conveyor_id:path}/maintenance", response_model=MaintenanceEvent)
def maintenance(
    request: Request, conveyor_id: str, body: MaintenanceBody, who: Maintainer
) -> dict[str, Any]:
    """Record a maintenance event (maintainer): the baseline restarts after it."""
    store = web_of(request).store
    event = maintenance_as(store, who.name, conveyor_id, body.kind, body.why, body.at)
    out: dict[str, Any] = event.to_dict()
    return out


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


@router.post("/conveyors/{conveyor_id:path}/out-of-service", response_model=OutOfServiceWindow)
def out_of_service(
    request: Request, conveyor_id: str, body: OutOfServiceBody, who: Maintainer
) -> dict[str, Any]:
    """Take a conveyor out of service until ``until`` (maintainer): its recordings are
    stored and shown, neither judged nor learned."""
    store = web_of(request).store
    return out_of_service_as(store, who.name, conveyor_id, body.why, body.until, end=False)


@router.delete("/conveyors/{conveyor_id:path}/out-of-service", response_model=OutOfServiceWindow)
def back_in_service(request: Request, conveyor_id: str, who: Maintainer) -> dict[str, Any]:
    """Put a conveyor back in service now (maintainer)."""
    store = web_of(request).store
    return out_of_service_as(store, who.name, conveyor_id, None, None, end=True)


def _latest_status(results: list[dict[str, Any]]) -> str | None:
    """The latest (not refused) result's ``status``, as ``/conveyors`` gives it; None: none."""
    for r in reversed(results):
        if r.get("status") not in (None, "refused"):
            return str(r["status"])
    return None


# last: its {conveyor_id:path} would take the routes above for a conveyor's id
@router.get("/conveyors/{conveyor_id:path}", response_model=ConveyorDetail)
def conveyor(request: Request, conveyor_id: str, _who: Viewer) -> Response:
    """Profile, calibration summary, baselines and verdict of one conveyor.

    ``health``, ``health_since``, ``ne107``, ``ne107_since``, ``health_index``,
    ``deviation`` and ``worst_feature`` are those of ``/conveyors``;
    ``status`` is the latest result's status.
    """
    data = conveyor_data_of(web_of(request), conveyor_id, trends=False)
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
    return fast_json(
        {
            "id": conveyor_id,
            "profile": data.profile.model_dump(mode="json"),
            "calibration": calibration,
            "baseline_since": data.baseline_since,
            "summary": data.summary,
            "forecasts": data.forecasts,
            **data.verdict.to_dict(),
            "status": _latest_status(data.results),
            "features": data.feature_names,
            "open_alarms": [a.to_dict() for a in data.open_alarms()],
            "recordings": data.recordings,
            "notes": data.notes,
        }
    )
