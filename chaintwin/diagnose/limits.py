"""Absolute limits: engineer-set levels per feature, alarmed beside the statistical alarms.

A profile's ``limits:`` (:class:`~chaintwin.read.profile.LimitSpec`) gives a
feature a warning level, an alarm level, or both, in the feature's own units
(``friction`` is the friction relative to the calibration's, so 1.30 is 30 %
more). Unlike the statistical alarms they need no baseline: they are judged
from the first recording on.

* above ``warn`` (and not above ``alarm``): the warning ``limit_warn`` on the
  recording's result;
* above ``alarm``: an exceedance in the feature's limit window
  (``limit:<feature>``, beside its statistical window); rule ``immediate``
  opens an alarm at once, rule ``x_of_y`` when X of the last Y recordings
  exceeded (the monitor's X and Y). Until then the warning
  ``limit_exceeded`` says so.

A limit alarm has ``kind`` ``limit``, its ``rule`` and ``limit``; it closes
as the statistical ones do, after Y recordings without an exceedance.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

from chaintwin.errors import MonitorError
from chaintwin.read.profile import ConveyorProfile, LimitSpec

from .features import FEATURES, is_tracked
from .health import x_of_y
from .records import MonitorSettings

__all__ = ["LimitCheck", "check_limit_names", "judge_limits"]


@dataclass(frozen=True, slots=True)
class LimitCheck:
    """One feature's value against its absolute limit at one recording.

    Attributes
    ----------
    feature : str
        The feature.
    value : float
        Its value, feature units.
    limit : LimitSpec
        The limit.
    exceeded : bool
        Above ``alarm``.
    met : bool
        The rule is met: an alarm is (or stays) open.
    warning : dict of str to str or None
        ``limit_warn`` or ``limit_exceeded`` for the result, else None.
    """

    feature: str
    value: float
    limit: LimitSpec
    exceeded: bool
    met: bool
    warning: dict[str, str] | None


def check_limit_names(profile: ConveyorProfile) -> None:
    """Refuse limits and expected wear on features the monitor does not compute.

    Raises
    ------
    MonitorError
        Naming the profile field and the features there are.
    """
    for key, names in (("limits", profile.limits), ("expected_wear", profile.expected_wear)):
        for name in names or {}:
            if not is_tracked(name):
                shown = "".join(c if c.isprintable() else repr(c)[1:-1] for c in name)
                raise MonitorError(
                    f"profile '{profile.id}': {key}.{shown}: no such feature; {key} apply to "
                    f"{', '.join(sorted(FEATURES))}, comb_<shaft> and mode_<line>",
                    field=key,
                )


def judge_limits(
    limits: Mapping[str, LimitSpec],
    values: Mapping[str, float],
    windows: dict[str, list[bool]],
    window_times: dict[str, list[str | None]],
    settings: MonitorSettings,
    when: str | None,
) -> list[LimitCheck]:
    """Check a recording's features against their absolute limits.

    Each limited feature's window ``limit:<feature>`` (the last Y exceedances
    with their ISO times) is updated in place; a feature without a value
    counts as not exceeded.

    Parameters
    ----------
    limits : mapping of str to LimitSpec
        The profile's ``limits``.
    values : mapping of str to float
        The recording's features.
    windows, window_times : dict
        The monitor's exceedance windows and their times.
    settings : MonitorSettings
        X and Y of the ``x_of_y`` rule.
    when : str or None
        The recording's ISO time.
    """
    out: list[LimitCheck] = []
    for name, spec in limits.items():
        value = float(values.get(name, math.nan))
        finite = math.isfinite(value)
        exceeded = finite and spec.alarm is not None and value > spec.alarm
        key = f"limit:{name}"
        win = windows.setdefault(key, [])
        times = window_times.setdefault(key, [])
        win.append(exceeded)
        times.append(when)
        del win[: -settings.y]
        del times[: -settings.y]
        met = exceeded if spec.rule == "immediate" else x_of_y(win, settings.x, settings.y)[-1]
        warning: dict[str, str] | None = None
        if exceeded and not met:
            warning = {
                "code": "limit_exceeded",
                "message": f"{name} = {value:.4g} is above its alarm limit {spec.alarm:g} "
                f"(profile limits); it alarms at {settings.x} of {settings.y} recordings",
            }
        elif finite and not exceeded and spec.warn is not None and value > spec.warn:
            warning = {
                "code": "limit_warn",
                "message": f"{name} = {value:.4g} is above its warning limit {spec.warn:g} "
                "(profile limits)",
            }
        out.append(LimitCheck(name, value, spec, exceeded, met, warning))
    return out
