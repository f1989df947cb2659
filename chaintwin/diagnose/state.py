"""The monitoring state file: what ``monitor --state FILE`` carries between runs.

One JSON object::

    {"format": "chaintwin.monitor-state", "format_version": 2,
     "conveyors": {"<id>": <MonitorState.to_dict()>, ...}}

Version 2 adds each conveyor's ``zero_tracking`` (the loss-drift allowance
tracked from known runs, :mod:`chaintwin.weigh.zero_tracking`); a version 1
file still loads (its conveyors start with nothing tracked) and is written
back as version 2.

Unknown numbers (NaN) are written as null. It is written atomically (a
temporary file, then a rename), so a run that fails or is killed leaves the
previous state intact. Maintenance events and
alarm acknowledgements are added to it by ``chaintwin maintenance`` and
``chaintwin acknowledge`` (:func:`add_maintenance`, :func:`acknowledge_alarm`)
with who, when and why; the next ``monitor`` run applies them.
"""

from __future__ import annotations

import json
import math
import uuid
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from chaintwin.errors import StoreError
from chaintwin.read.files import read_limited, write_atomic
from chaintwin.read.integers import json_loads, refuse_huge_integers

from .alarm_actions import edit_alarm
from .records import Acknowledgement, Alarm, Event, date_out_of_span, parse_time

__all__ = [
    "MAINTENANCE_KINDS",
    "READABLE_VERSIONS",
    "STATE_FORMAT",
    "STATE_VERSION",
    "acknowledge_alarm",
    "add_maintenance",
    "close_alarms",
    "empty_state",
    "json_ready",
    "load_state",
    "new_event",
    "save_state",
]

STATE_FORMAT = "chaintwin.monitor-state"
STATE_VERSION = 2
READABLE_VERSIONS: tuple[int, ...] = (1, STATE_VERSION)
"""State format versions this chaintwin reads (1: before zero tracking)."""

MAINTENANCE_KINDS: tuple[str, ...] = (
    "repair",
    "lubrication",
    "belt_change",
    "chain_change",
    "cleaning",
    "other",
)
"""Kinds of maintenance event."""


def empty_state() -> dict[str, Any]:
    """A state with no conveyor."""
    return {"format": STATE_FORMAT, "format_version": STATE_VERSION, "conveyors": {}}


def load_state(path: str | Path, *, missing_ok: bool = True) -> dict[str, Any]:
    """Read a state file (an empty state when it does not exist yet and ``missing_ok``).

    Raises
    ------
    StoreError
        When it cannot be read or is not a chaintwin monitoring state.
    """
    p = Path(path)
    if not p.exists():
        if missing_ok:
            return empty_state()
        raise StoreError(f"{p}: no such state file; run `chaintwin monitor --state {p}` first")
    raw = read_limited(p, what="state", error=lambda src, msg: StoreError(f"{src}: {msg}"))
    try:
        data = json_loads(raw.decode("utf-8"))
    except UnicodeDecodeError as exc:
        raise StoreError(f"{p}: cannot read the state ({exc})") from None
    except json.JSONDecodeError as exc:
        raise StoreError(
            f"{p}, line {exc.lineno}: the state is not valid JSON; restore it from a backup "
            "or start a new state file"
        ) from None
    except RecursionError:
        raise StoreError(f"{p}: nested too deeply to be a monitoring state") from None
    refuse_huge_integers(data, str(p), StoreError, "monitoring state")
    if not isinstance(data, dict) or data.get("format") != STATE_FORMAT:
        raise StoreError(f"{p}: not a chaintwin monitoring state (no 'format: {STATE_FORMAT}')")
    version = data.get("format_version")
    if isinstance(version, bool) or version not in READABLE_VERSIONS:
        raise StoreError(
            f"{p}: state format version {version!r} is not supported "
            f"(this chaintwin reads versions {', '.join(map(str, READABLE_VERSIONS))})"
        )
    data["format_version"] = STATE_VERSION
    if not isinstance(data.get("conveyors"), dict):
        raise StoreError(f"{p}: the state has no 'conveyors' object; start a new state file")
    return data


def json_ready(value: Any) -> Any:
    """Non-finite floats become null (standard JSON); containers are copied."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {str(k): json_ready(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [json_ready(v) for v in value]
    return value


def save_state(path: str | Path, data: dict[str, Any]) -> Path:
    """Write a state file atomically.

    Raises
    ------
    StoreError
        When it cannot be written (the previous state is left as it was).
    """
    return write_atomic(
        path,
        json.dumps(json_ready(data), allow_nan=False) + "\n",
        what="state",
        error=lambda t, m: StoreError(f"{t}: {m}"),
    )


def _conveyor(data: dict[str, Any], conveyor: str) -> dict[str, Any]:
    conveyors: dict[str, Any] = data["conveyors"]
    if conveyor not in conveyors:
        known = ", ".join(sorted(conveyors)) or "none yet"
        raise StoreError(f"the state holds no conveyor '{conveyor}' (it holds: {known})")
    state: dict[str, Any] = conveyors[conveyor]
    return state


def new_event(kind: str, by: str, why: str, at: datetime | None = None) -> Event:
    """A maintenance event: id, kind, at, by, why, when it was recorded.

    Parameters
    ----------
    kind : str
        One of :data:`MAINTENANCE_KINDS`.
    by, why : str
        Who did it and why.
    at : datetime, optional
        When it was done (default now); recordings after it form the new baseline.

    Raises
    ------
    StoreError
        For an unknown kind or an empty ``by``.
    """
    if kind not in MAINTENANCE_KINDS:
        raise StoreError(f"maintenance kind '{kind}' must be one of {', '.join(MAINTENANCE_KINDS)}")
    if not by.strip():
        raise StoreError("say who did the maintenance (by)", field="by")
    when = at or datetime.now(UTC)
    refused = date_out_of_span(when)
    if refused is not None:
        raise StoreError(f"the maintenance time (at) {refused}", field="at")
    if when.tzinfo is None:
        when = when.replace(tzinfo=UTC)
    when = when.astimezone(UTC)
    return Event(
        id=uuid.uuid4().hex[:8],
        kind=kind,
        at=when.isoformat(),
        by=by,
        why=why,
        recorded=datetime.now(UTC).isoformat(),
    )


def add_maintenance(
    data: dict[str, Any],
    conveyor: str,
    kind: str,
    by: str,
    why: str,
    at: datetime | None = None,
) -> Event:
    """Record a maintenance event in a state; the conveyor's baseline restarts after it.

    Parameters
    ----------
    data : dict
        The state (changed in place).
    conveyor : str
        Conveyor id.
    kind, by, why, at
        As :func:`new_event`.

    Returns
    -------
    Event
        The event.

    Raises
    ------
    StoreError
        For an unknown conveyor or kind, or an empty ``by``.
    """
    state = _conveyor(data, conveyor)
    event = new_event(kind, by, why, at)
    try:
        events = [Event.from_dict(e) for e in state["events"]] + [event]
        alarms = [Alarm.from_dict(a) for a in state["alarms"]]
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise StoreError(
            f"the state of '{conveyor}' is damaged ({exc!r}); start a new one"
        ) from None
    events.sort(key=lambda e: e.at)
    close_alarms(alarms, event)
    state["events"] = [e.to_dict() for e in events]
    state["alarms"] = [a.to_dict() for a in alarms]
    return event


def close_alarms(alarms: list[Alarm], event: Event) -> None:
    """Close the open alarms of a conveyor for a maintenance event (who and what did it)."""
    for alarm in alarms:
        if alarm.is_open:
            alarm.close(event.at, f"maintenance {event.kind} ({event.by}: {event.why})")


def acknowledge_alarm(
    data: dict[str, Any], alarm_id: str, by: str, why: str, at: datetime | None = None
) -> Alarm:
    """Acknowledge an open alarm (any conveyor): it stays open but no longer fails scripts.

    Raises
    ------
    StoreError
        When no alarm has that id, ``by`` is empty, or the state is damaged.
    """
    if not by.strip():
        raise StoreError("say who acknowledges the alarm (by)", field="by")
    when = (at or datetime.now(UTC)).astimezone(UTC).isoformat()

    def acknowledge(alarm: Alarm) -> None:
        if not alarm.is_open:
            raise StoreError(
                f"alarm '{alarm_id}' is closed ({alarm.closed_by or 'closed'}); "
                "only open alarms are acknowledged"
            )
        done = alarm.acknowledged
        if done is not None:
            raise StoreError(
                f"alarm '{alarm_id}' was acknowledged by {done.by} at "
                f"{done.at} ({done.why}); it stays so"
            )
        alarm.acknowledged = Acknowledgement(by=by, why=why, at=when)

    return edit_alarm(data, alarm_id, acknowledge)


def apply_events(
    events: list[Event], alarms: list[Alarm], when: datetime | None
) -> list[dict[str, str]]:
    """Apply the maintenance events made up to a recording's time; a note for each.

    Each event not yet applied whose time is at or before ``when`` is marked
    applied and closes the open alarms; the caller restarts its baseline
    when any note comes back.
    """
    from chaintwin.read.recording import RecordingWarning  # NumPy: not for `--help`

    notes: list[dict[str, str]] = []
    if when is None:
        return notes
    for event in events:
        at = None if event.applied else parse_time(event.at)
        if at is None or at > when:
            continue
        event.applied = True
        close_alarms(alarms, event)
        notes.append(
            RecordingWarning(
                "baseline_restarted",
                f"maintenance '{event.kind}' on {event.at} by {event.by} "
                f"({event.why}): the baseline restarts from this recording",
            ).to_dict()
        )
    return notes
