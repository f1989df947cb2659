"""Alarm KPIs (EEMUA 191, ISA-18.2) on hand-made alarm histories: known answers."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

import pytest

from chaintwin.diagnose.alarm_kpis import alarm_kpis, flood_periods
from chaintwin.diagnose.records import Acknowledgement, Alarm, Shelving

T0 = datetime(2026, 3, 1, tzinfo=UTC)


def _h(hours: float) -> str:
    return (T0 + timedelta(hours=hours)).isoformat()


def _alarm(
    conveyor: str, cause: str, opened: float, closed: float | None = None, **kw: object
) -> Alarm:
    a = Alarm(
        id=f"{conveyor}-{cause}-{opened}",
        conveyor=conveyor,
        feature="f",
        cause=cause,
        change=None,
        since=_h(opened),
        opened_at=_h(opened),
        last_seen=_h(opened),
        **kw,  # type: ignore[arg-type]
    )
    if closed is not None:
        a.close(_h(closed), "quiet")
    return a


def _history() -> list[Alarm]:
    ack = Acknowledgement
    return [
        _alarm("c1", "friction", -5, 1),  # before the period: neither counted nor standing
        _alarm("c1", "friction", 0, 2),
        _alarm("c1", "friction", 5, 6),
        _alarm("c1", "friction", 20),  # the third in 24 h (chatters), open 28 h: stale
        _alarm("c1", "gear", 30, acknowledged=ack("ann", "seen", _h(30 + 600 / 3600))),
        *[_alarm("c2", f"x{k}", 40 + k * 30 / 3600, 41) for k in range(11)],  # a flood
        _alarm(
            "c2",
            "y",
            45,
            acknowledged=ack("bob", "seen", _h(45.5)),
            shelved=Shelving("bob", "parts", _h(45.5), _h(50)),
        ),
        _alarm("c3", "bearing", 10, out_of_service=True),
    ]


def test_fleet_and_conveyor_kpis_of_a_known_history() -> None:
    k = alarm_kpis(_history(), T0, T0 + timedelta(hours=48))
    assert k["days"] == 2.0
    fleet = k["fleet"]
    assert fleet["alarms"] == 17
    assert fleet["alarms_per_day"] == 8.5
    assert fleet["standing"] == 4
    assert fleet["stale"] == 2
    assert fleet["chattering"] == 1 and fleet["chattering_causes"] == ["c1:friction"]
    assert fleet["flood_periods"] == 1
    assert fleet["median_time_to_acknowledge_s"] == pytest.approx(1200.0)
    assert fleet["shelved"] == 1
    assert fleet["out_of_service"] == 1
    c1, c2, c3 = (k["conveyors"][c] for c in ("c1", "c2", "c3"))
    assert (c1["alarms"], c1["standing"], c1["stale"], c1["chattering"]) == (4, 2, 1, 1)
    assert c1["median_time_to_acknowledge_s"] == pytest.approx(600.0)
    assert (c2["alarms"], c2["flood_periods"], c2["shelved"], c2["standing"]) == (12, 1, 1, 1)
    assert (c3["alarms"], c3["out_of_service"], c3["stale"]) == (1, 1, 1)
    assert c3["median_time_to_acknowledge_s"] is None


def test_a_period_before_the_flood_and_after_the_shelf() -> None:
    early = alarm_kpis(_history(), T0, T0 + timedelta(hours=12))
    # at 12 h: friction opened at 0 and 5 closed, c3's bearing open (2 h: not stale)
    assert early["fleet"]["alarms"] == 3
    assert early["fleet"]["standing"] == 1 and early["fleet"]["stale"] == 0
    assert early["fleet"]["flood_periods"] == 0 and early["fleet"]["chattering"] == 0
    late = alarm_kpis(_history(), T0, T0 + timedelta(hours=60))
    assert late["fleet"]["shelved"] == 0  # the shelf ended at 50 h


def test_flood_periods_merge_and_need_more_than_ten() -> None:
    ten = [T0 + timedelta(seconds=30 * k) for k in range(10)]
    assert flood_periods(ten) == []
    eleven = [*ten, T0 + timedelta(seconds=300)]
    assert flood_periods(eleven) == [(T0, T0 + timedelta(minutes=10))]
    # a second burst overlapping the first window's end is the same flood
    more = [*eleven, *(T0 + timedelta(minutes=9, seconds=5 * k) for k in range(11))]
    (span,) = flood_periods(more)
    assert span[0] == T0 and span[1] > T0 + timedelta(minutes=10)


def test_an_empty_period_is_refused() -> None:
    with pytest.raises(ValueError, match="is not after since"):
        alarm_kpis([], T0, T0)
