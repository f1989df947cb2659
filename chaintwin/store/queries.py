"""Read queries the web service needs beyond :class:`~chaintwin.store.store.Store`'s.

Paged results newest first (a cursor of the last row's recording time and
id), a recording and its result by content hash, and a light per-conveyor
summary for the fleet overview (one query per table, not one per conveyor).
"""

from __future__ import annotations

import base64
import json
from dataclasses import dataclass
from typing import Any

from sqlalchemy import and_, func, or_, select, text
from sqlalchemy.orm import Session

from chaintwin.diagnose.records import Alarm
from chaintwin.errors import StoreError
from chaintwin.read.recording import Recording
from chaintwin.store.schema import (
    AlarmRow,
    ConveyorRow,
    DerivedHealthRow,
    MonitorStateRow,
    RecordingRow,
    ResultRow,
)
from chaintwin.store.store import Store
from chaintwin.store.supersede import STANDING, STANDING_RESULT

__all__ = [
    "TREND_POINTS",
    "Page",
    "Signature",
    "TrendRows",
    "fleet_rows",
    "health_version",
    "read_version",
    "recording_by_hash",
    "results_page",
    "signature_columns",
    "store_signature",
    "trend_rows",
]

TREND_POINTS = 1000
"""Default ``max_points`` of a trend: the newest 500 results in full, the older history
thinned to 500 (:func:`trend_rows`); the trends stored after ingest are built at this
bound (:mod:`chaintwin.report.trend_series`)."""

_NULL_TIME = ""
"""Sort key of a recording without a time (oldest)."""


@dataclass(frozen=True, slots=True)
class Page:
    """One page of results, newest first, and the cursor of the next (None: no more)."""

    items: list[dict[str, Any]]
    next_cursor: str | None


def _cursor(recorded_at: str | None, row_id: int) -> str:
    raw = json.dumps([recorded_at or _NULL_TIME, row_id]).encode()
    return base64.urlsafe_b64encode(raw).decode().rstrip("=")


def _uncursor(cursor: str) -> tuple[str, int]:
    try:
        raw = base64.urlsafe_b64decode(cursor + "=" * (-len(cursor) % 4))
        at, row_id = json.loads(raw)
        return str(at), int(row_id)
    except (ValueError, TypeError) as exc:
        raise StoreError(
            f"cursor '{cursor[:40]}' is not one this service gave ({exc.__class__.__name__}); "
            "start again without a cursor",
            field="cursor",
        ) from None


def results_page(
    store: Store,
    conveyor: str,
    *,
    since: str | None = None,
    until: str | None = None,
    limit: int = 100,
    cursor: str | None = None,
) -> Page:
    """A conveyor's stored results, newest first by recording time.

    Each item is the stored result (the ``export --format json`` object) with
    ``recording_id`` (the recording's content SHA-256) and ``stored_at``.
    ``since``/``until`` bound ``recorded_at`` (ISO 8601, inclusive);
    recordings without a time sort as the oldest.
    """
    base = (
        select(ResultRow, RecordingRow.sha256)
        .join(RecordingRow, RecordingRow.id == ResultRow.recording_id)
        .where(ResultRow.conveyor_id == conveyor, STANDING)
    )
    at, row_id = _uncursor(cursor) if cursor is not None else (None, None)
    # the timed results by the (conveyor_id, recorded_at) index, newest first;
    # then those without a time (the oldest), by id
    timed = base.where(ResultRow.recorded_at.is_not(None))
    if since is not None:
        timed = timed.where(ResultRow.recorded_at >= since)
    if until is not None:
        timed = timed.where(ResultRow.recorded_at <= until)
    if at:
        timed = timed.where(
            or_(
                ResultRow.recorded_at < at,
                and_(ResultRow.recorded_at == at, ResultRow.id < row_id),
            )
        )
    with store.session() as s:
        rows = []
        if at != _NULL_TIME:
            q = timed.order_by(ResultRow.recorded_at.desc(), ResultRow.id.desc())
            rows = list(s.execute(q.limit(limit + 1)))
        if len(rows) <= limit and since is None and until is None:
            untimed = base.where(ResultRow.recorded_at.is_(None))
            if at == _NULL_TIME and row_id is not None:
                untimed = untimed.where(ResultRow.id < row_id)
            q = untimed.order_by(ResultRow.id.desc()).limit(limit + 1 - len(rows))
            rows += list(s.execute(q))
    items = []
    for row, sha in rows[:limit]:
        items.append(
            dict(row.content)
            | {"conveyor": conveyor, "recording_id": sha, "stored_at": row.stored_at}
        )
    more = len(rows) > limit
    last = rows[limit - 1][0] if more else None
    return Page(items, _cursor(last.recorded_at, last.id) if last is not None else None)


def recording_by_hash(store: Store, sha256: str) -> tuple[dict[str, Any], Recording] | None:
    """A stored recording's result (with ``recording_id``, ``stored_at``) and samples, or None."""
    with store.session() as s:
        found = s.execute(
            select(ResultRow, RecordingRow.id)
            .join(RecordingRow, RecordingRow.id == ResultRow.recording_id)
            .where(RecordingRow.sha256 == sha256)
        ).first()
    if found is None:
        return None
    row, rec_id = found
    result = dict(row.content) | {
        "conveyor": row.conveyor_id,
        "recording_id": sha256,
        "stored_at": row.stored_at,
    }
    return result, store.recording(int(rec_id))


def _lifecycle(content: Any) -> str | None:
    """A stored alarm's lifecycle now (None when its record is damaged)."""
    try:
        return Alarm.from_dict(dict(content)).lifecycle()
    except (KeyError, TypeError, ValueError):
        return None


def fleet_rows(store: Store) -> list[dict[str, Any]]:
    """Per conveyor: its latest result's numbers and its open alarms.

    The latest result is the conveyor's last one monitored (the highest id:
    ingest monitors in recorded order), found by an index seek per conveyor
    (``ix_results_conveyor_id_id``), so the cost grows with the number of
    conveyors, not of results.
    """
    latest_id = (
        select(ResultRow.id)
        .where(
            ResultRow.conveyor_id == ConveyorRow.id,
            ResultRow.status != "refused",
            STANDING_RESULT,
        )
        .order_by(ResultRow.id.desc())
        .limit(1)
        .correlate(ConveyorRow)
        .scalar_subquery()
    )
    with store.session() as s:
        pairs = s.execute(select(ConveyorRow.id, latest_id).order_by(ConveyorRow.id)).all()
        wanted = [int(rid) for _cid, rid in pairs if rid is not None]
        columns = (
            ResultRow.conveyor_id,
            ResultRow.recorded_at,
            ResultRow.payload_kg,
            ResultRow.tlf,
            ResultRow.status,
            ResultRow.alarm,
        )
        latest = {
            str(r.conveyor_id): r
            for r in s.execute(select(*columns).where(ResultRow.id.in_(wanted)))
        }
        open_alarms: dict[str, list[dict[str, Any]]] = {}
        for a in s.scalars(select(AlarmRow).where(AlarmRow.status != "closed")):
            open_alarms.setdefault(str(a.conveyor_id), []).append(
                {
                    "id": a.id,
                    "feature": a.feature,
                    "cause": a.cause,
                    "since": a.since,
                    "lifecycle": _lifecycle(a.content),
                }
            )
    out = []
    for cid, _rid in pairs:
        row = latest.get(str(cid))
        out.append(
            {
                "id": str(cid),
                "last_recorded_at": row.recorded_at if row is not None else None,
                "payload_kg": row.payload_kg if row is not None else None,
                "tlf": row.tlf if row is not None else None,
                "status": row.status if row is not None else None,
                "alarm": bool(row.alarm) if row is not None else False,
                "open_alarms": open_alarms.get(str(cid), []),
            }
        )
    return out


@dataclass(frozen=True, slots=True)
class Signature:
    """What the fleet's pages show has changed exactly when this has.

    Every stored result raises ``results`` (the highest result id); every
    stored result, acknowledgement and maintenance event raises ``states``
    (the sum of the health models' versions, each raised by every write of
    its model); ``conveyors`` and ``open_alarms`` count.
    """

    results: int
    states: int
    conveyors: int
    open_alarms: int

    @property
    def id(self) -> str:
        """A short text of the four numbers (an SSE event id, an ETag)."""
        return f"{self.results}.{self.states}.{self.conveyors}.{self.open_alarms}"

    def changes(self, before: Signature | None) -> list[str]:
        """What changed since ``before``: ``results``, ``alarms``, ``conveyors``."""
        if before is None:
            return []
        out = []
        if self.results != before.results:
            out.append("results")
        if self.states != before.states or self.open_alarms != before.open_alarms:
            out.append("alarms")
        if self.conveyors != before.conveyors:
            out.append("conveyors")
        return out


def signature_columns() -> tuple[Any, ...]:
    """The scalar subqueries of :func:`store_signature`: the highest result id, the sum
    of the health models' versions, the number of conveyors and of open alarms (others
    may select more beside them in the same round trip)."""
    return (
        select(func.max(ResultRow.id)).scalar_subquery(),
        select(func.coalesce(func.sum(MonitorStateRow.version), 0)).scalar_subquery(),
        select(func.count()).select_from(ConveyorRow).scalar_subquery(),
        select(func.count())
        .select_from(AlarmRow)
        .where(AlarmRow.status != "closed")
        .scalar_subquery(),
    )


def store_signature(store: Store) -> Signature:
    """The store's :class:`Signature` in one round trip.

    Cheap at any size: the highest result id is a primary-key seek; the
    health models, conveyors and alarms are a row per conveyor or alarm.
    """
    with store.engine.connect() as c:
        results, states, conveyors, open_alarms = c.execute(select(*signature_columns())).one()
    return Signature(int(results or 0), int(states or 0), int(conveyors), int(open_alarms))


@dataclass(frozen=True, slots=True)
class TrendRows:
    """A conveyor's results for its trends, bounded (:func:`trend_rows`).

    ``results`` are in the order monitored, as :meth:`Store.results` gives
    them, refused ones left out; ``represents[k]`` is how many stored results
    ``results[k]`` stands for (1 for each of the newest, which are all there;
    more for an older one standing for its stretch of the history, refused
    results counted too: telling them apart would read every row);
    ``total`` counts the conveyor's results that were not refused.
    """

    results: list[dict[str, Any]]
    represents: list[int]
    total: int


_TOTALS: dict[tuple[tuple[str, int], str], tuple[int, int, int]] = {}
"""Per (store URL, conveyor): (its results, highest result id, those not refused)."""

_TOTALS_KEPT = 1000


def _not_refused(s: Session, store: Store, conveyor: str, newest_id: int) -> int:
    """How many of a conveyor's results were not refused.

    Telling refused ones apart reads every row (``status`` is in no index):
    2 ms per 10 000 on SQLite. Results are only ever added, so the count is
    kept per process and read again only when the conveyor's number of
    results (a count of the ``(conveyor_id, id)`` index alone, 5 times
    cheaper) or its newest id changes.
    """
    mine = ResultRow.conveyor_id == conveyor
    every = int(s.scalar(select(func.count()).select_from(ResultRow).where(mine)) or 0)
    key = (store.cache_key, conveyor)
    known = _TOTALS.get(key)
    if known is not None and known[:2] == (every, newest_id):
        return known[2]
    total = int(
        s.scalar(
            select(func.count())
            .select_from(ResultRow)
            .where(mine, ResultRow.status != "refused", STANDING_RESULT)
        )
        or 0
    )
    if len(_TOTALS) >= _TOTALS_KEPT:
        _TOTALS.clear()
    _TOTALS[key] = (every, newest_id, total)
    return total


def read_version(store: Store, conveyor: str) -> tuple[int | None, int, int | None]:
    """What changes whenever a conveyor's bounded results or its health model do, in one
    round trip: its newest result id, its number of results (a seek and a count of the
    ``(conveyor_id, id)`` index) and its health model's version (raised by every write
    of the model; None: none)."""
    mine = ResultRow.conveyor_id == conveyor
    version = (
        select(MonitorStateRow.version)
        .where(MonitorStateRow.conveyor_id == conveyor)
        .scalar_subquery()
    )
    with store.session() as s:
        newest, count, model = s.execute(
            select(func.max(ResultRow.id), func.count(), version).where(mine)
        ).one()
    return (
        None if newest is None else int(newest),
        int(count),
        None if model is None else int(model),
    )


def health_version(store: Store, conveyor: str) -> tuple[int | None, str | None, str | None]:
    """What changes whenever a conveyor's health model or stored forecasts do, in one
    round trip: the model's version (raised by every write of it; None: none) and the
    stored forecasts' ``computed_at`` and ``inputs`` (None: none stored)."""
    version = (
        select(MonitorStateRow.version)
        .where(MonitorStateRow.conveyor_id == conveyor)
        .scalar_subquery()
    )
    computed = (
        select(DerivedHealthRow.computed_at)
        .where(DerivedHealthRow.conveyor_id == conveyor)
        .scalar_subquery()
    )
    inputs = (
        select(DerivedHealthRow.inputs)
        .where(DerivedHealthRow.conveyor_id == conveyor)
        .scalar_subquery()
    )
    with store.session() as s:
        model, at, fingerprint = s.execute(select(version, computed, inputs)).one()
    return (
        None if model is None else int(model),
        None if at is None else str(at),
        None if fingerprint is None else str(fingerprint),
    )


_STRETCHES = text(
    """
    WITH RECURSIVE k(n) AS (SELECT 0 UNION ALL SELECT n + 1 FROM k WHERE n + 1 < :stretches)
    SELECT
      (SELECT min(r.id) FROM results r WHERE r.conveyor_id = :conveyor
        AND r.id >= :first + k.n * :width AND r.id < :first + (k.n + 1) * :width
        AND r.id < :lo),
      (SELECT count(*) FROM results r WHERE r.conveyor_id = :conveyor
        AND r.id >= :first + k.n * :width AND r.id < :first + (k.n + 1) * :width
        AND r.id < :lo)
    FROM k
    """
)
"""Per stretch of ids (``width`` each from ``first``, before ``lo``): its first
result's id (NULL when it has none) and how many results it holds (SQLite and
PostgreSQL alike: a recursive CTE of the stretch numbers)."""


def trend_rows(store: Store, conveyor: str, max_points: int) -> TrendRows:
    """At most ``max_points`` of a conveyor's results: the newest half in full, the
    older history thinned to one result per stretch.

    The older results (those before the newest ``max_points // 2``) are cut
    into at most ``max_points - max_points // 2`` stretches of equal id range
    (ids grow in the order monitored) and each stretch is shown by its first
    result. Only that many results' contents are read: each stretch's first
    result is an index seek on ``(conveyor_id, id)`` (``ix_results_conveyor_id_id``)
    and its count a range count of that index, so the cost hardly grows with
    the history (the count of all results is a scan of the index: about
    0.4 ms per 10 000 on SQLite). What was thinned is the
    values between the kept ones; alarms are in their own table and stay
    whole.
    """
    if max_points < 2:
        raise StoreError(f"max_points {max_points} must be at least 2", field="max_points")
    recent = max_points // 2
    buckets = max_points - recent
    mine = ResultRow.conveyor_id == conveyor
    with store.session() as s:
        newest = s.execute(
            select(ResultRow.id, ResultRow.content)
            .where(mine, STANDING_RESULT)
            .order_by(ResultRow.id.desc())
            .limit(recent)
        ).all()
        older: list[Any] = []
        counts: dict[int, int] = {}
        if len(newest) == recent:
            lo = int(newest[-1][0])
            first = s.scalar(select(func.min(ResultRow.id)).where(mine))
            if first is not None and int(first) < lo:
                # stretches of ``width`` ids: each one's first result and count by
                # seeks and range counts on the (conveyor_id, id) index, no sort
                width = -(-(lo - int(first)) // buckets)
                params = {
                    "conveyor": conveyor,
                    "first": int(first),
                    "width": width,
                    "lo": lo,
                    "stretches": -(-(lo - int(first)) // width),
                }
                counts = {int(i): int(n) for i, n in s.execute(_STRETCHES, params) if i is not None}
                older = list(
                    s.execute(
                        select(ResultRow.id, ResultRow.content)
                        .where(ResultRow.id.in_(list(counts)), STANDING_RESULT)
                        .order_by(ResultRow.id)
                    )
                )
            total = _not_refused(s, store, conveyor, int(newest[0][0]))
        else:
            total = sum("error" not in content for _i, content in newest)
    results, represents = [], []
    for row_id, content in [*older, *reversed(newest)]:
        if "error" in content:
            continue
        results.append(dict(content))
        represents.append(counts.get(int(row_id), 1))
    return TrendRows(results, represents, total)
