"""Alarms of a conveyor's health model: opened by the X-of-Y rule, closed when quiet.

Alarms are :class:`~chaintwin.diagnose.records.Alarm` records.
"""

from __future__ import annotations

import math
import uuid
from datetime import datetime

from .baseline import regressor_of
from .features import DRIFT_OF, feature_spec
from .health import FeatureBaseline
from .records import Alarm, MonitorSettings, iso_utc

__all__ = ["LIMIT_PREFIX", "close_quiet_alarms", "judge", "open_alarm", "window_key"]

LIMIT_PREFIX = "limit:"
"""Prefix of the exceedance windows of absolute limits (``limit:<feature>``)."""


def window_key(feature: str, kind: str = "statistical") -> str:
    """The key of a feature's exceedance window: its name, or ``limit:<name>`` for a limit."""
    return f"{LIMIT_PREFIX}{feature}" if kind == "limit" else feature


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
) -> Alarm:
    """The open alarm of a feature, opened now if there is none.

    Its cause and change are the latest known (a recording that cannot tell
    keeps the last change); a new alarm dates from the first exceedance in
    the feature's window. A feature has at most one open alarm per ``kind``
    (``statistical`` or ``limit``); ``rule`` says what raised it.
    """
    for alarm in alarms:
        if alarm.is_open and alarm.feature == feature and alarm.kind == kind:
            alarm.cause = cause
            if change is not None:
                alarm.change = change
            alarm.last_seen = iso_utc(when)
            return alarm
    since = next((t for t, f in zip(window_times, window, strict=True) if f), iso_utc(when))
    alarm = Alarm(
        id=uuid.uuid4().hex[:8],
        conveyor=conveyor,
        feature=feature,
        cause=cause,
        change=change,
        since=since,
        opened_at=iso_utc(when),
        last_seen=iso_utc(when),
        rule=rule,
        kind=kind,
        limit=limit,
    )
    alarms.append(alarm)
    return alarm


def close_quiet_alarms(
    alarms: list[Alarm],
    windows: dict[str, list[bool]],
    y: int,
    when: datetime | None,
) -> None:
    """Close every open alarm whose feature has not exceeded in its last ``y`` recordings."""
    for alarm in alarms:
        if not alarm.is_open:
            continue
        win = windows.get(window_key(alarm.feature, alarm.kind), [])
        if len(win) >= y and not any(win):
            alarm.close(iso_utc(when), f"no exceedance in the last {y} recordings")


def judge(
    baselines: dict[str, FeatureBaseline],
    values: dict[str, float],
    windows: dict[str, list[bool]],
    window_times: dict[str, list[str | None]],
    settings: MonitorSettings,
    when: datetime | None,
) -> tuple[list[str], dict[str, float], list[str]]:
    """Check a recording's features against their baselines and apply the X-of-Y rule.

    Each tracked feature's window (the last Y exceedances, with their times)
    is updated in place.

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
        regressor = regressor_of(name, fb)
        load = values.get(regressor, float("nan"))
        drift = values.get(DRIFT_OF.get(regressor, ""), 0.0)
        allowance = values.get(spec.drift, 0.0) if spec.drift else 0.0
        ex = fb.check(value, load, settings.z_limit, spec.min_rel, spec.two_sided, drift, allowance)
        win = windows.setdefault(name, [])
        times = window_times.setdefault(name, [])
        win.append(ex.exceeded)
        times.append(at)
        del win[: -settings.y]
        del times[: -settings.y]
        if ex.exceeded:
            exceeded.append(name)
        if math.isfinite(ex.change):
            change[name] = ex.change
        # the X-of-Y rule at this recording (x_of_y(win, x, y)[-1]): the window
        # holds the last y exceedances
        if sum(win) >= settings.x:
            met.append(name)
    return met, change, exceeded
