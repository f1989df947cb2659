"""What the store takes besides the health model: recordings to store, alarm and event rows."""

from __future__ import annotations

import functools
import hashlib
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

from sqlalchemy import select
from sqlalchemy.orm import Session

from chaintwin.diagnose.monitor_state import MonitorState
from chaintwin.diagnose.records import Alarm, Event, RecordingResult, parse_time
from chaintwin.diagnose.state import json_ready
from chaintwin.diagnose.verdict import Verdict, verdict
from chaintwin.read.recording import Recording

from .schema import AlarmAliasRow, AlarmRow, EventRow, OutboxRow

__all__ = ["Finished", "Waiting", "notify_alarm", "put_alarms_events"]


@dataclass(frozen=True, slots=True)
class Waiting:
    """A recording the health model holds back until it has learned a calibration."""

    recording: Recording
    sha256: str
    samples: bytes | None = None


@dataclass(frozen=True, slots=True)
class Finished:
    """A recording that monitoring has taken, ready to be stored."""

    recording: Recording
    sha256: str
    result: RecordingResult
    samples: bytes | None = None
    """The compressed channels (:func:`~.samples.pack_samples`), if a worker packed them."""
    stored: bool = False
    """Stored already (while it waited for a learned calibration): only its result is new."""


def notify_alarm(
    s: Session,
    conveyor: str,
    alarm: Alarm,
    event: str,
    at: str | None = None,
    verdict: Callable[[], Verdict] | None = None,
    shelf_at: str | None = None,
) -> bool:
    """Put a notification of an alarm's change in the outbox (once per alarm and event).

    ``event`` is ``opened``, ``acknowledged``, ``shelved``, ``unshelved``,
    ``closed`` or ``escalated``; ``at`` is when it happened (default: when it
    opened or closed). A shelving and the end of a shelf are told once per
    shelf (its start in the id: ``shelf_at``, default the alarm's shelf).
    ``verdict`` gives the conveyor's verdict as the change leaves it (its
    ``health`` and ``ne107`` go with the notification), called only when a
    notification is written.
    Written in the transaction that changes the alarm's row: a notification
    exists exactly when its change was stored (the live service sends it).
    Returns whether it was written (False: told before).
    """
    key = f"{alarm.id}-{event}"
    if shelf_at is None and alarm.shelved is not None:
        shelf_at = alarm.shelved.at
    if event in ("shelved", "unshelved") and shelf_at is not None:
        key += "-" + hashlib.sha256(shelf_at.encode()).hexdigest()[:8]
    if s.get(OutboxRow, key) is not None:
        return False
    if at is None:
        at = alarm.closed_at if event == "closed" else (alarm.opened_at or alarm.since)
    told = None if verdict is None else verdict()
    s.add(
        OutboxRow(
            id=key,
            event=event,
            alarm_id=alarm.id,
            conveyor_id=conveyor,
            feature=alarm.feature,
            cause=alarm.cause,
            at=at,
            created_at=datetime.now(UTC).isoformat(),
            health=None if told is None else told.health,
            ne107=None if told is None else told.ne107,
        )
    )
    return True


def _notify_changes(
    s: Session,
    conveyor: str,
    alarm: Alarm,
    before: AlarmRow | None,
    verdict: Callable[[], Verdict] | None,
) -> None:
    """The notifications of an alarm's changes since its stored row ``before``."""
    if before is None:
        notify_alarm(s, conveyor, alarm, "opened", verdict=verdict)
    was: dict[str, Any] = dict(before.content) if before is not None else {}
    if alarm.acknowledged is not None and not was.get("acknowledged"):
        notify_alarm(s, conveyor, alarm, "acknowledged", alarm.acknowledged.at, verdict)
    shelf = alarm.shelved
    old = was.get("shelved") or {}
    if shelf is not None and old.get("at") != shelf.at:
        notify_alarm(s, conveyor, alarm, "shelved", shelf.at, verdict)
    if alarm.is_open:
        now = datetime.now(UTC)
        if old.get("at") and (shelf is None or shelf.at != old["at"]):  # unshelved, or shelved anew
            until = parse_time(old.get("until"))
            if until is not None and until.tzinfo is None:
                until = until.replace(tzinfo=UTC)
            ended = old["until"] if until is not None and until < now else now.isoformat()
            notify_alarm(s, conveyor, alarm, "unshelved", ended, verdict, shelf_at=old["at"])
        if shelf is not None and not alarm.is_shelved(now):  # the shelf ended by itself
            notify_alarm(s, conveyor, alarm, "unshelved", shelf.until, verdict)
    if alarm.status == "closed" and (before is None or before.status != "closed"):
        notify_alarm(s, conveyor, alarm, "closed", verdict=verdict)


def put_alarms_events(
    s: Session,
    conveyor: str,
    alarms: list[Alarm],
    events: list[Event],
    state: Callable[[], MonitorState] | None = None,
) -> None:
    """Bring the alarm and event rows of a conveyor up to its health model.

    ``state`` gives that health model: the notifications carry its verdict
    (worked out once, and only when a notification is written).

    An alarm that opens, is acknowledged, shelved or unshelved (by someone,
    or its shelf ended), or closes puts a notification in the outbox
    (:func:`notify_alarm`). An alarm grouped into another (its id in the
    other's ``merged``) leaves the table; its id stays an alias of the other.
    """
    told = None if state is None else functools.cache(lambda: verdict(state()))
    rows = {r.id: r for r in s.scalars(select(AlarmRow).where(AlarmRow.conveyor_id == conveyor))}
    for alarm in alarms:
        for old in alarm.merged:
            gone = rows.pop(old, None)
            if gone is not None:
                s.delete(gone)
            if s.get(AlarmAliasRow, old) is None:
                s.add(AlarmAliasRow(old_id=old, alarm_id=alarm.id))
    for alarm in alarms:
        _notify_changes(s, conveyor, alarm, rows.get(alarm.id), told)
        values = {
            "conveyor_id": conveyor,
            "feature": alarm.feature,
            "cause": alarm.cause,
            "status": alarm.status,
            "since": alarm.since,
            "content": json_ready(alarm.to_dict()),
        }
        row = rows.get(alarm.id)
        if row is None:
            s.add(AlarmRow(id=alarm.id, **values))
        elif row.content != values["content"] or row.status != values["status"]:
            for k, v in values.items():
                setattr(row, k, v)
    known = set(s.scalars(select(EventRow.id).where(EventRow.conveyor_id == conveyor)))
    for ev in events:
        if ev.id not in known:
            s.add(
                EventRow(
                    id=ev.id,
                    conveyor_id=conveyor,
                    kind=ev.kind,
                    at=ev.at,
                    content=json_ready(ev.to_dict()),
                )
            )
