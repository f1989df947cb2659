"""What the store takes besides the health model: recordings to store, alarm and event rows."""

from __future__ import annotations

from dataclasses import dataclass
from datetime import UTC, datetime

from sqlalchemy import select
from sqlalchemy.orm import Session

from chaintwin.diagnose.records import Alarm, Event, RecordingResult
from chaintwin.diagnose.state import json_ready
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


def notify_alarm(s: Session, conveyor: str, alarm: Alarm, event: str) -> None:
    """Put a notification of an alarm opened or closed in the outbox (once per alarm and event).

    Written in the transaction that changes the alarm's row: a notification
    exists exactly when its change was stored (the live service sends it).
    """
    key = f"{alarm.id}-{event}"
    if s.get(OutboxRow, key) is not None:
        return
    s.add(
        OutboxRow(
            id=key,
            event=event,
            alarm_id=alarm.id,
            conveyor_id=conveyor,
            feature=alarm.feature,
            cause=alarm.cause,
            at=alarm.closed_at if event == "closed" else (alarm.opened_at or alarm.since),
            created_at=datetime.now(UTC).isoformat(),
        )
    )


def put_alarms_events(s: Session, conveyor: str, alarms: list[Alarm], events: list[Event]) -> None:
    """Bring the alarm and event rows of a conveyor up to its health model.

    An alarm that opens or closes puts a notification in the outbox
    (:func:`notify_alarm`). An alarm grouped into another (its id in the
    other's ``merged``) leaves the table; its id stays an alias of the other.
    """
    rows = {r.id: r for r in s.scalars(select(AlarmRow).where(AlarmRow.conveyor_id == conveyor))}
    for alarm in alarms:
        for old in alarm.merged:
            gone = rows.pop(old, None)
            if gone is not None:
                s.delete(gone)
            if s.get(AlarmAliasRow, old) is None:
                s.add(AlarmAliasRow(old_id=old, alarm_id=alarm.id))
    for alarm in alarms:
        row_before = rows.get(alarm.id)
        if row_before is None:
            notify_alarm(s, conveyor, alarm, "opened")
        if alarm.status == "closed" and (row_before is None or row_before.status != "closed"):
            notify_alarm(s, conveyor, alarm, "closed")
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
