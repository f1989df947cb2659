"""Trends computed once: a conveyor's trends built after ingest, stored pre-serialised.

The trends endpoint's answer is mostly each feature's points (1000 a
feature at the default ``max_points``, 18 features: 1.7 MB of JSON), which
change only with a new result or a new health model. They are built after
ingest, after the forecasts (:func:`refit_with_trends`, called by ingest; in
the live service at most
:data:`~chaintwin.live.refit.REFIT_EVERY_S` behind), and kept in
``trend_series``: each feature's points as one JSON array (one after the
other in ``points``) and its fixed fields (cause, unit, baseline level,
limits, health index) in ``header``, with :func:`built_from`, the
fingerprint of what they were built from (the conveyor's newest result and
number of results, its health model's inputs, its profile, ``max_points``).

The endpoint (:meth:`TrendSeries.answer`) takes the stored points as they
are (``orjson.Fragment``) and adds what changes without a new result: the
alarm markers, the stored forecasts and ``as_of``. The answer is byte for
byte the one built from the results (:func:`trend_object`). The stored
trends are used only while their fingerprint is the current one: a result
stored since (the refit not yet run) makes the endpoint build the trends
from the results, as without them, so the points are never behind the
newest result (the forecasts are, as always, by what the refit has not yet
reached: ``as_of``).
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import threading
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

import orjson
from sqlalchemy import func, select
from sqlalchemy.exc import SQLAlchemyError

from chaintwin.diagnose.monitor_state import MonitorState, derived_inputs
from chaintwin.diagnose.records import Alarm
from chaintwin.errors import StoreError
from chaintwin.read.profile import ConveyorProfile
from chaintwin.store.derived import Derived
from chaintwin.store.queries import TREND_POINTS, read_version
from chaintwin.store.schema import RecordingRow, ResultRow, TrendSeriesRow
from chaintwin.store.store import Store
from chaintwin.store.upsert import upsert_conveyor_row

from .data import ConveyorData, FeatureTrend, conveyor_data

__all__ = [
    "TREND_POINTS",
    "TrendSeries",
    "alarm_marks",
    "answer_of",
    "build_and_store",
    "built_from",
    "current_series",
    "forecast_of",
    "iso_times",
    "read_series",
    "refit_trends",
    "refit_with_trends",
    "series_of",
    "store_series",
    "stored_from",
    "trend_object",
]

log = logging.getLogger(__name__)

FORMAT = 1
"""Version of the stored layout (a new one makes every stored series stale)."""

_OPTIONS = orjson.OPT_SERIALIZE_NUMPY
"""orjson's options, as the web answers use them."""


def _finite(x: Any) -> Any:
    return None if isinstance(x, float) and not math.isfinite(x) else x


def iso_times(data: ConveyorData) -> list[str | None]:
    """Each result's recording time in ISO 8601 (None: unknown), written once for
    all the trends of an answer."""
    return [None if t is None else t.isoformat() for t in data.times]


def alarm_marks(alarms: list[Alarm], feature: str) -> list[dict[str, Any]]:
    """A feature's alarm markers: every alarm of the feature, whole."""
    return [
        {"id": a.id, "since": a.since, "closed_at": a.closed_at, "cause": a.cause}
        for a in alarms
        if a.feature == feature
    ]


def forecast_of(forecasts: list[dict[str, Any]], feature: str) -> dict[str, Any] | None:
    """A feature's forecast among the conveyor's (None: none)."""
    return next((dict(f) for f in forecasts if f["feature"] == feature), None)


def _fixed(trend: FeatureTrend) -> dict[str, Any]:
    """A trend's fields that change only with its results or its health model."""

    def num(x: float | None) -> float | None:
        return None if x is None else _finite(float(x))

    return {
        "feature": trend.name,
        "cause": trend.cause,
        "unit": trend.unit,
        "expected": num(trend.expected),
        "limit": num(trend.limit),
        "lower_limit": num(trend.lower),
        "health_index": _finite(float(trend.health_index())),
    }


def _points(data: ConveyorData, trend: FeatureTrend, times: list[str | None]) -> list[Any]:
    """A trend's points: time, value (null: unknown), exceeded, how many results each
    stands for."""
    represents = data.represents or [1] * len(data.results)
    finite = math.isfinite
    # the values are floats (NaN where unknown: null) and the flags bools already
    return [
        {
            "recorded_at": times[k],
            "value": v if finite(v) else None,
            "exceeded": ex,
            "represents": represents[k],
        }
        for k, v, ex in zip(trend.index, trend.values, trend.exceeded, strict=False)
    ]


def _object(
    conveyor: str,
    fixed: dict[str, Any],
    points: Any,
    marks: list[dict[str, Any]],
    forecast: dict[str, Any] | None,
    recordings: int,
    max_points: int,
) -> dict[str, Any]:
    """One feature's trend object, its fields in their order (built or stored alike)."""
    return {
        "conveyor": conveyor,
        "feature": fixed["feature"],
        "cause": fixed["cause"],
        "unit": fixed["unit"],
        "expected": fixed["expected"],
        "limit": fixed["limit"],
        "lower_limit": fixed["lower_limit"],
        "points": points,
        "alarms": marks,
        "health_index": fixed["health_index"],
        "forecast": forecast,
        "recordings": recordings,
        "max_points": max_points,
    }


def trend_object(
    data: ConveyorData,
    conveyor: str,
    trend: FeatureTrend,
    max_points: int,
    times: list[str | None],
) -> dict[str, Any]:
    """One feature's trend object built from the results (the trends endpoint's body
    for one ``feature``). ``times``: :func:`iso_times`."""
    return _object(
        conveyor,
        _fixed(trend),
        _points(data, trend, times),
        alarm_marks(data.alarms, trend.name),
        forecast_of(data.forecasts, trend.name),
        data.recordings,
        max_points,
    )


def answer_of(
    conveyor: str,
    feature: list[str] | None,
    objects: dict[str, Any],
    recordings: int,
    max_points: int,
    as_of: Any,
) -> dict[str, Any]:
    """The trends endpoint's body: one ``feature``'s trend object, or several (none:
    every feature's) in ``trends``. ``objects``: feature → a function giving its object."""
    if feature is not None and len(feature) == 1:
        return dict(objects[feature[0]]())
    asked = list(dict.fromkeys(feature)) if feature else list(objects)
    return {
        "conveyor": conveyor,
        "trends": [objects[f]() for f in asked],
        "recordings": recordings,
        "max_points": max_points,
        "as_of": as_of,
    }


@dataclass(frozen=True)
class TrendSeries:
    """A conveyor's trends as stored (:func:`series_of`).

    Attributes
    ----------
    built_from : str
        :func:`built_from` of what they were built from.
    header : dict
        ``recordings``, ``max_points`` and ``features``: per feature its fixed
        fields and where its points lie in ``points`` (``start``, ``end``, bytes).
    points : bytes
        Every feature's points, one JSON array after another.
    computed_at : str
        When they were built (UTC, ISO 8601).
    """

    built_from: str
    header: dict[str, Any]
    points: bytes
    computed_at: str

    @property
    def names(self) -> list[str]:
        """The features, in the order of the trends."""
        return [str(f["feature"]) for f in self.header["features"]]

    def answer(
        self,
        conveyor: str,
        feature: list[str] | None,
        alarms: list[Alarm],
        forecasts: list[dict[str, Any]],
        as_of: Any,
    ) -> bytes:
        """The trends endpoint's body (JSON): the stored points and fixed fields, with
        the alarm markers, forecasts and ``as_of`` given. ``feature``: known names."""
        recordings = int(self.header["recordings"])
        max_points = int(self.header["max_points"])
        points = memoryview(self.points)
        by_name = {f["feature"]: f for f in self.header["features"]}

        def one(name: str) -> Any:
            def build() -> dict[str, Any]:
                fixed = by_name[name]
                raw = bytes(points[int(fixed["start"]) : int(fixed["end"])])
                return _object(
                    conveyor,
                    fixed,
                    orjson.Fragment(raw),
                    alarm_marks(alarms, name),
                    forecast_of(forecasts, name),
                    recordings,
                    max_points,
                )

            return build

        body = answer_of(
            conveyor, feature, {n: one(n) for n in by_name}, recordings, max_points, as_of
        )
        return orjson.dumps(body, option=_OPTIONS)


def series_of(data: ConveyorData, built: str, max_points: int = TREND_POINTS) -> TrendSeries:
    """A conveyor's trends to store, from its :class:`ConveyorData` (read with
    ``max_points``). ``built``: :func:`built_from` of what ``data`` was read from."""
    times = iso_times(data)
    chunks: list[bytes] = []
    features = []
    at = 0
    for trend in data.trends:
        raw = orjson.dumps(_points(data, trend, times), option=_OPTIONS)
        features.append(_fixed(trend) | {"start": at, "end": at + len(raw)})
        chunks.append(raw)
        at += len(raw)
    header = {
        "format": FORMAT,
        "recordings": data.recordings,
        "max_points": max_points,
        "features": features,
    }
    return TrendSeries(built, header, b"".join(chunks), datetime.now(UTC).isoformat())


def built_from(
    store: Store,
    conveyor: str,
    profile: ConveyorProfile,
    state: MonitorState | None,
    max_points: int = TREND_POINTS,
    inputs: str | None = None,
) -> str:
    """SHA-256 of what a conveyor's trends are built from: its newest result and number
    of results (one seek and one count of the ``(conveyor_id, id)`` index), the number
    of its recordings superseded (partial ones replaced by complete ones), its health
    model's inputs (:func:`~chaintwin.diagnose.monitor_state.derived_inputs`: the
    baselines, their start, the z limit, the model's newest result), its profile and
    ``max_points``. ``inputs``: ``derived_inputs(state)`` when the caller has it.

    Raises
    ------
    StoreError
        When the database fails.
    """
    with store.reading(f"the results of '{conveyor}'") as s:
        newest, count = s.execute(
            select(func.max(ResultRow.id), func.count()).where(ResultRow.conveyor_id == conveyor)
        ).one()
        # a partial recording superseded by a complete one still waiting for its
        # result leaves the trends (counted from ix_recordings_conveyor_superseded alone)
        superseded = s.scalar(
            select(func.count()).where(
                RecordingRow.superseded_by.is_not(None),
                RecordingRow.conveyor_id == conveyor,
            )
        )
    if state is not None and inputs is None:
        inputs = derived_inputs(state)
    model = None if state is None else [state.profile_sha256, inputs]
    parts = [
        FORMAT,
        max_points,
        newest,
        int(count),
        int(superseded or 0),
        profile.content_hash(),
        model,
    ]
    return hashlib.sha256(json.dumps(parts).encode()).hexdigest()


_KEPT: dict[tuple[tuple[str, int], str], TrendSeries] = {}
"""Per (store URL, conveyor): its stored trends as last read (each some MB)."""

_KEPT_MOST = 8
"""Conveyors whose stored trends are kept in the process (the first kept goes first)."""

_KEPT_LOCK = threading.Lock()


def current_series(store: Store, conveyor: str, built: str) -> TrendSeries | None:
    """A conveyor's stored trends when built from ``built`` (None: none, or built from
    something else). Those last read are kept in the process while their fingerprint
    stays the stored one: only the fingerprint is read then.

    Raises
    ------
    StoreError
        When the database fails.
    """
    if stored_from(store, conveyor) != built:
        return None
    key = (store.cache_key, conveyor)
    kept = _KEPT.get(key)
    if kept is not None and kept.built_from == built:
        return kept
    found = read_series(store, conveyor, built)
    if found is not None:
        with _KEPT_LOCK:
            _KEPT.pop(key, None)
            if len(_KEPT) >= _KEPT_MOST:
                _KEPT.pop(next(iter(_KEPT)))
            _KEPT[key] = found
    return found


def read_series(store: Store, conveyor: str, built: str | None = None) -> TrendSeries | None:
    """A conveyor's stored trends (None: none, or ``built`` given and they were built
    from something else: only the fingerprint is read then).

    Raises
    ------
    StoreError
        When the database fails.
    """
    with store.reading(f"the trends of '{conveyor}'") as s:
        q = select(TrendSeriesRow).where(TrendSeriesRow.conveyor_id == conveyor)
        if built is not None:
            q = q.where(TrendSeriesRow.built_from == built)
        row = s.scalars(q).one_or_none()
        if row is None:
            return None
        return TrendSeries(row.built_from, dict(row.header), bytes(row.points), row.computed_at)


def stored_from(store: Store, conveyor: str) -> str | None:
    """The fingerprint of a conveyor's stored trends (None: none stored).

    Raises
    ------
    StoreError
        When the database fails.
    """
    with store.reading(f"the trends of '{conveyor}'") as s:
        found = s.scalar(
            select(TrendSeriesRow.built_from).where(TrendSeriesRow.conveyor_id == conveyor)
        )
    return None if found is None else str(found)


def store_series(store: Store, conveyor: str, series: TrendSeries, *, replace: bool = True) -> None:
    """Store a conveyor's trends, replacing those stored (``replace`` False: only when
    none are stored: a reader storing what it built never replaces a refit's).

    Raises
    ------
    StoreError
        When the database fails.
    """
    values = {
        "built_from": series.built_from,
        "computed_at": series.computed_at,
        "header": series.header,
        "points": series.points,
    }
    upsert_conveyor_row(store, TrendSeriesRow, conveyor, values, what="the trends", replace=replace)


def _state(store: Store, conveyor: str) -> MonitorState | None:
    """The stored health model; None when damaged too (the trends are then built without it)."""
    try:
        return store.state(conveyor)
    except StoreError:
        return None


def build_and_store(
    store: Store,
    conveyor: str,
    profile: ConveyorProfile,
    build: Callable[[], ConveyorData],
    *,
    built: str | None = None,
    replace: bool = True,
) -> tuple[ConveyorData, TrendSeries | None]:
    """Build a conveyor's :class:`ConveyorData` with ``build()`` (read at
    :data:`TREND_POINTS`) and store its trends when nothing changed meanwhile
    (its newest result, number of results and health model version are the same
    before and after: :func:`~chaintwin.store.queries.read_version`; else nothing is
    stored). ``built``: :func:`built_from` now, when the caller has it.
    ``replace``: as :func:`store_series`.

    Raises
    ------
    StoreError
        When the database fails.
    """
    version = read_version(store, conveyor)
    before = built
    if before is None:
        before = built_from(store, conveyor, profile, _state(store, conveyor))
    data = build()
    if read_version(store, conveyor) != version:
        return data, None
    series = series_of(data, before)
    if replace:
        store_series(store, conveyor, series)
        return data, series
    # a reader's: what it built is its answer even when storing it fails (the store busy
    # for a moment, no connection free); the next refit stores them
    try:
        store_series(store, conveyor, series, replace=False)
    except (StoreError, SQLAlchemyError) as exc:
        log.warning("the trends of '%s' built but not stored: %s", conveyor, exc)
        return data, None
    return data, series


def refit_trends(store: Store, conveyor: str) -> bool:
    """Build and store a conveyor's trends unless those stored are current.

    Called by :func:`refit_with_trends` after the forecasts.
    Returns whether they were built and stored now (False: those stored are
    current, no such conveyor, or results came while building: the next
    refit stores them).

    Raises
    ------
    StoreError
        When the database fails.
    """
    profile = store.profile(conveyor)
    if profile is None:
        return False
    current = built_from(store, conveyor, profile, _state(store, conveyor))
    if stored_from(store, conveyor) == current:
        return False

    def build() -> ConveyorData:
        return conveyor_data(
            store,
            conveyor,
            waterfall=0,
            max_points=TREND_POINTS,
            latest=False,
            stored_forecasts=True,
        )

    return build_and_store(store, conveyor, profile, build, built=current)[1] is not None


def refit_with_trends(store: Store, conveyor: str) -> Derived | None:
    """After ingest: a conveyor's forecasts and wear rates
    (:func:`~chaintwin.store.derived.refit`), then its trends (:func:`refit_trends`);
    nothing is computed where the stored ones are current.

    Returns
    -------
    Derived or None
        The forecasts stored now; None when the conveyor has no health model (no
        trends are stored then either).

    Raises
    ------
    StoreError
        When the database fails or the stored model is damaged.
    """
    from chaintwin.store import derived

    found = derived.refit(store, conveyor)
    if found is not None:
        refit_trends(store, conveyor)
    return found
