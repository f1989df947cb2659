"""Alarms of a conveyor's health model: opened by the X-of-Y rule, closed when quiet.

One alarm per probable cause: the features that exceed with a cause are its evidence.

Alarms are :class:`~chaintwin.diagnose.records.Alarm` records.
"""

from __future__ import annotations

import math
import uuid
from datetime import datetime

from .baseline import judge_inputs
from .confirmation import count_exceedance
from .features import feature_spec
from .health import FeatureBaseline
from .records import Alarm, Evidence, MonitorSettings, iso_utc

__all__ = [
    "CAUGHT_PREFIX",
    "LIMIT_PREFIX",
    "UNCONFIRMED_PREFIX",
    "close_quiet_alarms",
    "group_by_cause",
    "judge",
    "open_alarm",
    "window_key",
]

LIMIT_PREFIX = "limit:"
"""Prefix of the exceedance windows of absolute limits (``limit:<feature>``)."""


UNCONFIRMED_PREFIX = "unconfirmed:"
"""Prefix of the windows that hold whether a feature's last exceedance awaits its
confirmation (``unconfirmed:<feature>``, :func:`judge` with ``confirm``)."""


CAUGHT_PREFIX = "caught:"
"""Prefix of the windows that hold whether the recording a feature was last
judged on was caught (``caught:<feature>``, :func:`judge` with ``caught``)."""


def window_key(feature: str, kind: str = "statistical") -> str:
    """The key of a feature's exceedance window: its name, or ``limit:<name>`` for a limit."""
    return f"{LIMIT_PREFIX}{feature}" if kind == "limit" else feature


def _window_since(window: list[bool], window_times: list[str | None], at: str | None) -> str | None:
    """Time of the first exceedance in a window (``at`` when it holds none)."""
    return next((t for t, f in zip(window_times, window, strict=True) if f), at)


def open_alarm(
    alarms: list[Alarm],
    *,
    conveyor: str,
    feature: str,
    cause: str,
    change: float | None,
    when: datetime | None,
    window: list[bool],
    window_times: list[str | None],
    rule: str = "x_of_y",
    kind: str = "statistical",
    limit: float | None = None,
    value: float | None = None,
    z: float | None = None,
) -> Alarm:
    """The open alarm of a probable cause, opened now if there is none.

    A conveyor has at most one open alarm per cause: a feature whose rule is
    met with that cause joins the open one as evidence (or refreshes its
    evidence), a second cause opens a second alarm. The alarm's lead fields
    (``feature``, ``kind``, ``limit``, ``rule``, ``change``) describe the
    feature that opened it; a lead feature whose cause now reads otherwise,
    with no alarm of that cause open, carries its alarm over to the new cause
    (the latest known). A new alarm dates from the first exceedance in the
    feature's window.

    Parameters
    ----------
    value : float or None
        The feature's value at this recording (feature units).
    z : float or None
        Its distance from the baseline, robust baseline scales (None for a limit).
    """
    at = iso_utc(when)
    value = value if value is None or math.isfinite(value) else None
    z = z if z is None or math.isfinite(z) else None
    alarm = next((a for a in alarms if a.is_open and a.cause == cause), None)
    former = next(
        (
            a
            for a in alarms
            if a.is_open and a.cause != cause and any(_is(e, feature, kind) for e in a.evidence)
        ),
        None,
    )
    if former is not None:  # the feature's probable cause now reads otherwise
        if alarm is None:
            former.cause = cause  # the latest known
            alarm = former
        else:  # the fault of the other alarm: one alarm
            _merge(alarm, former)
            alarms.remove(former)
    if alarm is not None:
        if alarm.feature == feature and alarm.kind == kind and change is not None:
            alarm.change = change
        alarm.last_seen = at
        alarm.active = True
        ev = next((e for e in alarm.evidence if _is(e, feature, kind)), None)
        if ev is None:
            alarm.evidence.append(
                Evidence(feature, kind, value, z, _window_since(window, window_times, at))
            )
        else:
            ev.value, ev.z = value, z
        return alarm
    alarm = Alarm(
        id=uuid.uuid4().hex[:8],
        conveyor=conveyor,
        feature=feature,
        cause=cause,
        change=change,
        since=_window_since(window, window_times, at),
        opened_at=at,
        last_seen=at,
        rule=rule,
        kind=kind,
        limit=limit,
    )
    alarm.evidence.append(Evidence(feature, kind, value, z, alarm.since))
    alarms.append(alarm)
    return alarm


def _is(e: Evidence, feature: str, kind: str) -> bool:
    return e.feature == feature and e.kind == kind


def _merge(into: Alarm, alarm: Alarm) -> None:
    """Put ``alarm`` into ``into``: its evidence, comments and ids; the earliest since,
    the latest last_seen; an acknowledgement of either carries over (the earliest)."""
    known = {(e.feature, e.kind) for e in into.evidence}
    into.evidence += [e for e in alarm.evidence if (e.feature, e.kind) not in known]
    into.comments = sorted(into.comments + alarm.comments, key=lambda c: c.at)
    into.merged += [alarm.id, *alarm.merged]
    if alarm.since is not None and (into.since is None or alarm.since < into.since):
        into.since = alarm.since
    if alarm.last_seen is not None and (into.last_seen or "") < alarm.last_seen:
        into.last_seen = alarm.last_seen
    into.active = into.active or alarm.active
    acks = [a for a in (into.acknowledged, alarm.acknowledged) if a is not None]
    into.acknowledged = min(acks, key=lambda a: a.at) if acks else None
    if alarm.shelved is not None and into.shelved is None:
        into.shelved = alarm.shelved


def group_by_cause(alarms: list[Alarm]) -> dict[str, str]:
    """Group the open alarms of one cause into the oldest (alarms kept before grouping).

    The later ones' evidence, comments and ids (``merged``) join the oldest,
    which keeps the earliest ``since`` and the latest ``last_seen``; an
    acknowledgement of any of them carries over (the earliest). The grouped
    ones leave ``alarms``.

    Returns
    -------
    dict of str to str
        Each grouped alarm's id and the id of the alarm it joined.
    """
    keeper: dict[str, Alarm] = {}
    moved: dict[str, str] = {}
    for alarm in list(alarms):
        if not alarm.is_open:
            continue
        into = keeper.setdefault(alarm.cause, alarm)
        if into is alarm:
            continue
        _merge(into, alarm)
        moved[alarm.id] = into.id
        moved.update({m: into.id for m in alarm.merged})
        alarms.remove(alarm)
    return moved


def close_quiet_alarms(
    alarms: list[Alarm],
    windows: dict[str, list[bool]],
    y: int,
    when: datetime | None,
) -> None:
    """Close every open alarm none of whose features exceeded in its last ``y`` recordings.

    An open alarm not seen at this recording (``when``) is marked inactive:
    its features are back in band (ISA-18.2's "returned").
    """
    at = iso_utc(when)
    for alarm in alarms:
        if not alarm.is_open:
            continue
        alarm.active = alarm.last_seen == at
        keys = {window_key(e.feature, e.kind) for e in alarm.evidence}
        keys.add(window_key(alarm.feature, alarm.kind))
        wins = [windows.get(k, []) for k in keys]
        if all(len(w) >= y and not any(w) for w in wins):
            alarm.close(at, f"no exceedance in the last {y} recordings")


def judge(
    baselines: dict[str, FeatureBaseline],
    values: dict[str, float],
    windows: dict[str, list[bool]],
    window_times: dict[str, list[str | None]],
    settings: MonitorSettings,
    when: datetime | None,
    z_out: dict[str, float] | None = None,
    confirm: bool = False,
    caught: bool = False,
) -> tuple[list[str], dict[str, float], list[str]]:
    """Check a recording's features against their baselines and apply the X-of-Y rule.

    Each tracked feature's window (the last Y exceedances, with their times)
    is updated in place; ``z_out``, when given, receives each feature's
    distance from its baseline (robust baseline scales, where known).

    ``confirm``: this recording's torque shows an item caught (a drag the
    impact search found) or could not be searched for one (its
    constant-speed run too short for the impact search, as on a 1 ms
    scope); such an event moves the features of this recording alone
    (speed loss, residual, spectral lines). An exceedance of such a recording
    counts only when the feature exceeded at the recording before it or
    exceeds at the next one (which then counts both); until then it waits
    in ``unconfirmed:<feature>``. A fault that grows exceeds recording after
    recording and loses at most one recording; an event stays alone.

    ``caught``: this recording shows an item caught (a drag the impact
    search found, or where it could not look, a plateau whose level stepped:
    ``residual_step`` beyond its baseline); it implies ``confirm``. Events
    come one after another too (a 1 ms declined conveyor had items caught
    in four recordings in a row, which confirmed each other into an alarm),
    so a caught recording confirms no exceedance and is confirmed only by a
    neighbour that was not caught: the recording before it, which exceeded,
    or the next one, which exceeds.

    Returns
    -------
    (list of str, dict of str to float, list of str)
        Features whose rule is met, each feature's relative change (where
        known), and the features this recording exceeded.
    """
    met: list[str] = []
    change: dict[str, float] = {}
    exceeded: list[str] = []
    at = iso_utc(when)
    if not 1 <= settings.x <= settings.y:
        raise ValueError(f"X-of-Y needs 1 <= X <= Y, got {settings.x} of {settings.y}")
    for name, fb in baselines.items():
        spec = feature_spec(name)
        if spec.cause is None:
            continue
        value = values.get(name, float("nan"))
        load, drift, allowance = judge_inputs(name, fb, values)
        ex = fb.check(value, load, settings.z_limit, spec.min_rel, spec.two_sided, drift, allowance)
        win = windows.setdefault(name, [])
        times = window_times.setdefault(name, [])
        waiting = windows.setdefault(UNCONFIRMED_PREFIX + name, [])
        waiting_at = window_times.setdefault(UNCONFIRMED_PREFIX + name, [])
        was_caught = windows.setdefault(CAUGHT_PREFIX + name, [])
        caught_at = window_times.setdefault(CAUGHT_PREFIX + name, [])
        count_exceedance(win, waiting, was_caught, ex.exceeded, confirm=confirm, caught=caught)
        times.append(at)
        waiting_at[:] = [at]
        caught_at[:] = [at]
        del win[: -settings.y]
        del times[: -settings.y]
        if ex.exceeded:
            exceeded.append(name)
        if math.isfinite(ex.change):
            change[name] = ex.change
        if z_out is not None and math.isfinite(ex.z):
            z_out[name] = ex.z
        # the X-of-Y rule at this recording (x_of_y(win, x, y)[-1]): the window
        # holds the last y exceedances
        if sum(win) >= settings.x:
            met.append(name)
    return met, change, exceeded
