"""How healthy the alarm system is (EEMUA 191, ISA-18.2): alarm KPIs over a period.

Per conveyor and for the fleet, over ``[since, until)``:

``alarms``
    Alarms opened in the period (by the recording time that opened them).
``alarms_per_day``
    ``alarms`` over the period's length in days.
``standing``
    Alarms open at ``until`` (opened before it, not closed by then).
``stale``
    Standing alarms opened more than 24 h before ``until``.
``chattering``
    Probable causes that opened at least 3 alarms within 24 h in the period
    (one conveyor's cause; the fleet's count sums the conveyors').
``flood_periods``
    Stretches in which more than 10 alarms opened within 10 minutes
    (overlapping 10-minute windows merged into one stretch).
``median_time_to_acknowledge_s``
    Median time from opening to acknowledgement of the alarms opened in the
    period and acknowledged (s; None when none was).
``shelved``, ``out_of_service``
    Alarms shelved, and alarms of a conveyor out of service, at ``until``.
"""

from __future__ import annotations

import statistics
from collections.abc import Iterable
from datetime import UTC, datetime, timedelta
from typing import Any

from .records import Alarm, parse_time

__all__ = [
    "CHATTER_OPENS",
    "CHATTER_WINDOW",
    "FLOOD_ALARMS",
    "FLOOD_WINDOW",
    "KPI_DAYS",
    "STALE_AFTER",
    "alarm_kpis",
    "flood_periods",
]

KPI_DAYS = 30
"""The period the dashboard and the reports show by default: the last 30 days."""
STALE_AFTER = timedelta(hours=24)
"""An alarm open longer than this is stale."""
CHATTER_OPENS = 3
"""Opens of one cause within :data:`CHATTER_WINDOW` that make it chatter."""
CHATTER_WINDOW = timedelta(hours=24)
FLOOD_ALARMS = 10
"""More alarms than this within :data:`FLOOD_WINDOW` make a flood."""
FLOOD_WINDOW = timedelta(minutes=10)


def _utc(text: str | None) -> datetime | None:
    t = parse_time(text)
    if t is None:
        return None
    return t.replace(tzinfo=UTC) if t.tzinfo is None else t.astimezone(UTC)


def _opened(a: Alarm) -> datetime | None:
    return _utc(a.opened_at or a.since)


def flood_periods(opens: Iterable[datetime]) -> list[tuple[datetime, datetime]]:
    """Stretches in which more than :data:`FLOOD_ALARMS` alarms opened within :data:`FLOOD_WINDOW`.

    Every window ``[t, t + 10 min)`` starting at an opening and holding more
    than 10 openings is a flood; overlapping ones merge into one stretch.
    """
    times = sorted(opens)
    spans: list[tuple[datetime, datetime]] = []
    j = 0
    for i, t in enumerate(times):
        j = max(j, i)
        while j < len(times) and times[j] < t + FLOOD_WINDOW:
            j += 1
        if j - i > FLOOD_ALARMS:
            end = t + FLOOD_WINDOW
            if spans and t <= spans[-1][1]:
                spans[-1] = (spans[-1][0], max(spans[-1][1], end))
            else:
                spans.append((t, end))
    return spans


def _chattering(alarms: list[Alarm]) -> list[str]:
    """Causes with at least :data:`CHATTER_OPENS` opens within :data:`CHATTER_WINDOW`."""
    by_cause: dict[str, list[datetime]] = {}
    for a in alarms:
        t = _opened(a)
        if t is not None:
            by_cause.setdefault(a.cause, []).append(t)
    out = []
    for cause, times in sorted(by_cause.items()):
        times.sort()
        n = CHATTER_OPENS
        if any(times[k + n - 1] - times[k] < CHATTER_WINDOW for k in range(len(times) - n + 1)):
            out.append(cause)
    return out


def _kpis(alarms: list[Alarm], since: datetime, until: datetime) -> dict[str, Any]:
    days = (until - since).total_seconds() / 86400.0
    opened = [a for a in alarms if (t := _opened(a)) is not None and since <= t < until]

    def open_at_end(a: Alarm) -> bool:
        t = _opened(a)
        if t is None or t >= until:
            return False
        closed = _utc(a.closed_at) if not a.is_open else None
        return a.is_open or (closed is not None and closed >= until)

    standing = [a for a in alarms if open_at_end(a)]
    waits = []
    for a in opened:
        t, ack = _opened(a), None if a.acknowledged is None else _utc(a.acknowledged.at)
        if t is not None and ack is not None:
            waits.append((ack - t).total_seconds())
    chatter = _chattering(opened)
    return {
        "alarms": len(opened),
        "alarms_per_day": len(opened) / days,
        "standing": len(standing),
        "stale": sum((until - t) > STALE_AFTER for a in standing if (t := _opened(a))),
        "chattering": len(chatter),
        "chattering_causes": chatter,
        "flood_periods": len(flood_periods(t for a in opened if (t := _opened(a)))),
        "median_time_to_acknowledge_s": statistics.median(waits) if waits else None,
        "acknowledged": len(waits),
        "shelved": sum(a.lifecycle(until) == "shelved" for a in standing),
        "out_of_service": sum(a.lifecycle(until) == "out_of_service" for a in standing),
    }


def alarm_kpis(alarms: list[Alarm], since: datetime, until: datetime) -> dict[str, Any]:
    """The alarm KPIs of the fleet and of each conveyor over ``[since, until)``.

    Parameters
    ----------
    alarms : list of Alarm
        Every alarm (open and closed) of the conveyors considered.
    since, until : datetime
        The period (UTC when naive); ``until`` after ``since``.

    Returns
    -------
    dict
        ``since``, ``until``, ``days``, ``fleet`` (the KPIs of every alarm;
        ``chattering`` sums the conveyors') and ``conveyors`` (id: KPIs).

    Raises
    ------
    ValueError
        When ``until`` is not after ``since``.
    """
    since = since.replace(tzinfo=UTC) if since.tzinfo is None else since.astimezone(UTC)
    until = until.replace(tzinfo=UTC) if until.tzinfo is None else until.astimezone(UTC)
    if until <= since:
        raise ValueError(f"until {until.isoformat()} is not after since {since.isoformat()}")
    by_conveyor: dict[str, list[Alarm]] = {}
    for a in alarms:
        by_conveyor.setdefault(a.conveyor, []).append(a)
    conveyors = {c: _kpis(group, since, until) for c, group in sorted(by_conveyor.items())}
    fleet = _kpis(alarms, since, until)
    fleet["chattering"] = sum(k["chattering"] for k in conveyors.values())
    fleet["chattering_causes"] = sorted(
        {f"{c}:{cause}" for c, k in conveyors.items() for cause in k["chattering_causes"]}
    )
    return {
        "since": since.isoformat(),
        "until": until.isoformat(),
        "days": (until - since).total_seconds() / 86400.0,
        "fleet": fleet,
        "conveyors": conveyors,
    }
