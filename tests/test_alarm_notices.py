"""Alarm notifications in the outbox: one per alarm and change; escalation."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta
from pathlib import Path

from sqlalchemy import select
from sqlalchemy.orm import Session

from chaintwin.diagnose.records import Acknowledgement, Alarm, Evidence, Shelving
from chaintwin.live.escalation import escalate_due
from chaintwin.live.shelves import unshelve_due
from chaintwin.store.rows import put_alarms_events
from chaintwin.store.schema import ConveyorRow, OutboxRow
from chaintwin.store.store import Store

T0 = datetime(2026, 4, 1, 6, 0, tzinfo=UTC)
_LATER = datetime.now(UTC) + timedelta(days=20)
"""A shelf's end that the clock does not reach while the tests run."""


def _alarm(aid: str, cause: str) -> Alarm:
    return Alarm(
        id=aid,
        conveyor="c1",
        feature="impact_energy_max",
        cause=cause,
        change=None,
        since=T0.isoformat(),
        opened_at=T0.isoformat(),
        last_seen=T0.isoformat(),
        evidence=[Evidence("impact_energy_max"), Evidence("crest_factor")],
    )


def _outbox(store: Store) -> list[tuple[str, str, str | None]]:
    with Session(store.engine) as s:
        rows = s.scalars(select(OutboxRow).order_by(OutboxRow.created_at, OutboxRow.id))
        return [(r.alarm_id, r.event, r.at) for r in rows]


def _put(store: Store, alarms: list[Alarm]) -> None:
    with Session(store.engine) as s, s.begin():
        put_alarms_events(s, "c1", alarms, [])


def test_one_notification_per_alarm_and_change(tmp_path: Path) -> None:
    store = Store(f"sqlite:///{tmp_path / 'plant.db'}")
    with Session(store.engine) as s, s.begin():
        s.add(ConveyorRow(id="c1", profile={}, profile_sha256="0" * 64))
    a = _alarm("a1", "obstruction")
    _put(store, [a])
    _put(store, [a])  # nothing changed: nothing more to tell
    assert _outbox(store) == [("a1", "opened", T0.isoformat())]
    acked = (T0 + timedelta(minutes=5)).isoformat()
    a.acknowledged = Acknowledgement("ann", "seen", acked)
    shelf = (T0 + timedelta(minutes=6)).isoformat()
    a.shelved = Shelving("ann", "parts", shelf, _LATER.isoformat())  # still shelved
    _put(store, [a])
    _put(store, [a])
    a.close((T0 + timedelta(hours=3)).isoformat(), "quiet")
    _put(store, [a])
    events = [(e, at) for _, e, at in _outbox(store)]
    assert sorted(events) == sorted(
        [
            ("opened", T0.isoformat()),
            ("acknowledged", acked),
            ("shelved", shelf),
            ("closed", (T0 + timedelta(hours=3)).isoformat()),
        ]
    )
    store.close()


def test_escalation_tells_once_of_an_alarm_left_unacknowledged(tmp_path: Path) -> None:
    store = Store(f"sqlite:///{tmp_path / 'plant.db'}")
    with Session(store.engine) as s, s.begin():
        s.add(ConveyorRow(id="c1", profile={}, profile_sha256="0" * 64))
    waiting, seen, shelved = _alarm("a1", "gear"), _alarm("a2", "bearing"), _alarm("a3", "friction")
    seen.acknowledged = Acknowledgement("ann", "seen", T0.isoformat())
    shelved.shelved = Shelving("ann", "x", T0.isoformat(), (T0 + timedelta(days=1)).isoformat())
    _put(store, [waiting, seen, shelved])
    assert escalate_due(store, 30, T0 + timedelta(minutes=29)) == []
    assert escalate_due(store, 30, T0 + timedelta(minutes=30)) == ["a1"]
    assert escalate_due(store, 30, T0 + timedelta(minutes=90)) == []  # told once
    escalated = [r for r in _outbox(store) if r[1] == "escalated"]
    assert escalated == [("a1", "escalated", (T0 + timedelta(minutes=30)).isoformat())]
    store.close()


def _store(tmp_path: Path) -> Store:
    store = Store(f"sqlite:///{tmp_path / 'plant.db'}")
    with Session(store.engine) as s, s.begin():
        s.add(ConveyorRow(id="c1", profile={}, profile_sha256="0" * 64))
    return store


def test_a_shelf_that_ends_by_itself_is_told_once_at_its_end(tmp_path: Path) -> None:
    store = _store(tmp_path)
    a, b = _alarm("a1", "gear"), _alarm("a2", "bearing")
    now = datetime.now(UTC)
    end = now + timedelta(hours=1)
    a.shelved = Shelving("ann", "parts", now.isoformat(), end.isoformat())
    b.shelved = Shelving("ann", "parts", now.isoformat(), (now + timedelta(hours=5)).isoformat())
    _put(store, [a, b])
    assert unshelve_due(store, end - timedelta(seconds=1)) == []  # both still shelved
    assert unshelve_due(store, end) == ["a1"]
    assert unshelve_due(store, end + timedelta(minutes=5)) == []  # told once
    told = [r for r in _outbox(store) if r[1] == "unshelved"]
    assert told == [("a1", "unshelved", end.isoformat())]
    # shelved again: the new shelf ends and is told too
    again = end + timedelta(hours=5)  # after b's shelf too
    a.shelved = Shelving("bob", "again", end.isoformat(), again.isoformat())
    _put(store, [a])
    assert unshelve_due(store, again) == ["a1", "a2"]
    assert [r[2] for r in _outbox(store) if r[1] == "unshelved" and r[0] == "a1"] == [
        end.isoformat(),
        again.isoformat(),
    ]
    store.close()


def test_an_ended_shelf_is_told_when_the_alarm_is_next_stored(tmp_path: Path) -> None:
    store = _store(tmp_path)
    a = _alarm("a1", "gear")
    ended = T0 + timedelta(hours=1)  # in the past: the shelf has ended
    a.shelved = Shelving("ann", "parts", T0.isoformat(), ended.isoformat())
    _put(store, [a])
    _put(store, [a])
    assert [r for r in _outbox(store) if r[1] == "unshelved"] == [
        ("a1", "unshelved", ended.isoformat())
    ]
    assert unshelve_due(store) == []  # already told
    store.close()


def test_unshelving_by_hand_is_told_once_and_a_closed_alarm_is_not(tmp_path: Path) -> None:
    store = _store(tmp_path)
    a, b = _alarm("a1", "gear"), _alarm("a2", "bearing")
    now = datetime.now(UTC)
    for x in (a, b):
        x.shelved = Shelving("ann", "parts", now.isoformat(), _LATER.isoformat())
    _put(store, [a, b])
    a.shelved = None  # unshelved by someone
    b.shelved = None
    b.close(now.isoformat(), "quiet")  # closed: nothing to return to
    _put(store, [a, b])
    _put(store, [a, b])
    told = [r for r in _outbox(store) if r[1] == "unshelved"]
    assert [r[0] for r in told] == ["a1"]
    assert told[0][2] is not None and told[0][2] < _LATER.isoformat()
    store.close()
