"""What people do to alarms besides acknowledging: shelve, unshelve, comment, out of service.

Each function changes a state in the layout of a state file
(``{"conveyors": {id: state}}``) in place, as
:func:`~chaintwin.diagnose.state.acknowledge_alarm` does, so that it applies
to a state file and, through :meth:`~chaintwin.store.store.Store.edit_state`,
to a results store alike. Times are ISO 8601 in UTC.

A conveyor out of service keeps ``out_of_service`` (who, why, from, until)
in its state: its recordings in that window are stored and shown but not
judged and do not feed the baseline (:func:`out_of_service_at`), and its
open alarms read ``out_of_service``.
"""

from __future__ import annotations

from collections.abc import Callable
from datetime import UTC, datetime, timedelta
from typing import Any

from chaintwin.errors import StoreError

from .records import Alarm, Comment, Shelving, iso_utc, parse_time

__all__ = [
    "MAX_SHELVE_MINUTES",
    "clear_out_of_service",
    "comment_alarm",
    "edit_alarm",
    "out_of_service_at",
    "set_out_of_service",
    "shelve_alarm",
    "unshelve_alarm",
]

MAX_SHELVE_MINUTES = 30 * 24 * 60
"""The longest shelf: 30 days (a longer one is a conveyor out of service)."""


def _now(at: datetime | None) -> datetime:
    when = at or datetime.now(UTC)
    return when.replace(tzinfo=UTC) if when.tzinfo is None else when.astimezone(UTC)


def _who(by: str, what: str) -> None:
    if not by.strip():
        raise StoreError(f"say who {what} (by)", field="by")


def edit_alarm(data: dict[str, Any], alarm_id: str, change: Callable[[Alarm], None]) -> Alarm:
    """Find an alarm by id (or a grouped id) in any conveyor, ``change`` it, write it back.

    Raises
    ------
    StoreError
        When no alarm has that id, the state is damaged, or from ``change``.
    """
    ids: list[str] = []
    for conveyor, state in data["conveyors"].items():
        try:
            alarms = [Alarm.from_dict(a) for a in state["alarms"]]
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise StoreError(
                f"the state of '{conveyor}' is damaged ({exc!r}); start a new one"
            ) from None
        for k, alarm in enumerate(alarms):
            if alarm.answers_to(alarm_id):
                change(alarm)
                state["alarms"][k] = alarm.to_dict()
                return alarm
            if alarm.is_open:
                ids.append(alarm.id)
    raise StoreError(
        f"no alarm '{alarm_id}' in the state (open alarms: {', '.join(ids) or 'none'})"
    )


def _open(alarm: Alarm, alarm_id: str, what: str) -> None:
    if not alarm.is_open:
        raise StoreError(
            f"alarm '{alarm_id}' is closed ({alarm.closed_by or 'closed'}); only open alarms "
            f"are {what}"
        )


def shelve_alarm(
    data: dict[str, Any],
    alarm_id: str,
    by: str,
    why: str,
    minutes: float,
    at: datetime | None = None,
) -> Alarm:
    """Shelve an open alarm for ``minutes`` (1 to :data:`MAX_SHELVE_MINUTES`) with a reason.

    It neither counts (``--fail-on-alarm``, the health index) nor notifies
    while shelved, and returns to its state by itself when the shelf ends.

    Raises
    ------
    StoreError
        When the alarm is unknown or closed, ``by`` or ``why`` is empty, or
        ``minutes`` is out of range.
    """
    _who(by, "shelves the alarm")
    if not why.strip():
        raise StoreError("say why the alarm is shelved (why)", field="why")
    if not 1 <= minutes <= MAX_SHELVE_MINUTES:
        raise StoreError(
            f"minutes {minutes:g} must be from 1 to {MAX_SHELVE_MINUTES} (30 days); take the "
            "conveyor out of service for longer work",
            field="minutes",
        )
    now = _now(at)

    def shelve(alarm: Alarm) -> None:
        _open(alarm, alarm_id, "shelved")
        until = (now + timedelta(minutes=minutes)).isoformat()
        alarm.shelved = Shelving(by=by, why=why, at=now.isoformat(), until=until)

    return edit_alarm(data, alarm_id, shelve)


def unshelve_alarm(
    data: dict[str, Any], alarm_id: str, by: str, at: datetime | None = None
) -> Alarm:
    """End an alarm's shelf now: it returns to its state.

    Raises
    ------
    StoreError
        When the alarm is unknown, closed or not shelved, or ``by`` is empty.
    """
    _who(by, "unshelves the alarm")
    now = _now(at)

    def unshelve(alarm: Alarm) -> None:
        _open(alarm, alarm_id, "unshelved")
        if not alarm.is_shelved(now):
            raise StoreError(f"alarm '{alarm_id}' is not shelved")
        alarm.shelved = None

    return edit_alarm(data, alarm_id, unshelve)


def comment_alarm(
    data: dict[str, Any], alarm_id: str, by: str, text: str, at: datetime | None = None
) -> Alarm:
    """Add a comment (author, time, text) to an alarm, open or closed.

    Raises
    ------
    StoreError
        When the alarm is unknown, or ``by`` or ``text`` is empty.
    """
    _who(by, "comments")
    if not text.strip():
        raise StoreError("the comment is empty; give its text", field="text")
    comment = Comment(by=by, at=_now(at).isoformat(), text=text)
    return edit_alarm(data, alarm_id, lambda alarm: alarm.comments.append(comment))


def _conveyor_state(data: dict[str, Any], conveyor: str) -> dict[str, Any]:
    conveyors: dict[str, Any] = data["conveyors"]
    if conveyor not in conveyors:
        known = ", ".join(sorted(conveyors)) or "none yet"
        raise StoreError(f"the state holds no conveyor '{conveyor}' (it holds: {known})")
    state: dict[str, Any] = conveyors[conveyor]
    return state


def _mark(state: dict[str, Any], window: dict[str, Any] | None) -> None:
    """Mark a conveyor's open alarms out of service over ``window`` (None: back in service)."""
    out = []
    for raw in state.get("alarms", []):
        alarm = Alarm.from_dict(raw)
        if alarm.is_open:
            alarm.out_of_service = window is not None
            alarm.out_of_service_until = None if window is None else window["until"]
        out.append(alarm.to_dict())
    state["alarms"] = out


def set_out_of_service(
    data: dict[str, Any],
    conveyor: str,
    by: str,
    why: str,
    until: datetime | None,
    at: datetime | None = None,
) -> dict[str, Any]:
    """Take a conveyor out of service from now (``at``) until ``until`` (None: until put back).

    Returns
    -------
    dict
        The window: ``by``, ``why``, ``from``, ``until`` (ISO times).

    Raises
    ------
    StoreError
        When the conveyor is unknown, ``by`` or ``why`` is empty, or ``until``
        is not after now.
    """
    _who(by, "takes the conveyor out of service")
    if not why.strip():
        raise StoreError("say why the conveyor is out of service (why)", field="why")
    now = _now(at)
    end = None if until is None else _now(until)
    if end is not None and end <= now:
        raise StoreError(
            f"until {end.isoformat()} is not after now ({now.isoformat()}); give a later time",
            field="until",
        )
    state = _conveyor_state(data, conveyor)
    window = {"by": by, "why": why, "from": now.isoformat(), "until": iso_utc(end)}
    state["out_of_service"] = window
    _mark(state, window)
    return window


def clear_out_of_service(
    data: dict[str, Any], conveyor: str, by: str, at: datetime | None = None
) -> dict[str, Any]:
    """Put a conveyor back in service now: its recordings are judged again.

    Returns
    -------
    dict
        The window it was out of service, ending now.

    Raises
    ------
    StoreError
        When the conveyor is unknown, not out of service, or ``by`` is empty.
    """
    _who(by, "puts the conveyor back in service")
    state = _conveyor_state(data, conveyor)
    window = state.get("out_of_service")
    now = _now(at)
    if not isinstance(window, dict) or not _within(window, now):
        raise StoreError(f"conveyor '{conveyor}' is not out of service")
    state["out_of_service"] = None
    _mark(state, None)
    return dict(window, until=now.isoformat())


def _within(window: dict[str, Any], when: datetime) -> bool:
    start = parse_time(window.get("from"))
    end = parse_time(window.get("until"))
    if start is None:
        return False
    start = _now(start)
    return start <= when and (end is None or when < _now(end))


def out_of_service_at(window: dict[str, Any] | None, when: datetime | None) -> bool:
    """Whether a recording made at ``when`` falls in a conveyor's out-of-service window.

    An undated recording is judged as made now.
    """
    if window is None:
        return False
    return _within(window, _now(when))
