"""Which exceedances count: the monitor's confirmation of a recording's exceedance by a neighbour.

An item caught moves the features of its recording alone, so where the
impact search found a drag, or could not look (a constant-speed run too
short for it, as on a 1 ms scope), a recording's exceedance counts only
beside another (:func:`count_exceedance`, used by
:func:`chaintwin.diagnose.alarms.judge` and by the remaining-life forecast,
:func:`chaintwin.diagnose.prognosis.forecast_alarm`, for the recordings ahead).
"""

from __future__ import annotations

import math
from collections.abc import Mapping

from .features import CAUGHT_Z, feature_spec
from .health import FeatureBaseline

__all__ = ["count_exceedance", "needs_confirmation"]


def needs_confirmation(
    values: Mapping[str, float], step_baseline: FeatureBaseline | None
) -> tuple[bool, bool]:
    """Whether a recording's exceedances need a neighbour's confirmation, and whether it was caught.

    Parameters
    ----------
    values : mapping of str to float
        The recording's features (``belt_travel_m`` in m: the run the impact
        search looked at, 0 when it could not look; ``impact_drags``: the
        drags it found; ``residual_step`` in N m).
    step_baseline : FeatureBaseline or None
        The baseline of ``residual_step`` (None: not known).

    Returns
    -------
    (bool, bool)
        ``confirm`` and ``caught`` as :func:`count_exceedance` takes them:
        caught where the impact search found a drag or, where it could not
        look, the plateau's level stepped beyond :data:`~chaintwin.diagnose.
        features.CAUGHT_Z` scales of its baseline; confirm where caught or
        not searched.
    """
    travel = values.get("belt_travel_m")
    searched = travel is not None and math.isfinite(travel) and travel > 0.0
    drags = values.get("impact_drags")
    stepped = False
    if not searched and step_baseline is not None:
        step = values.get("residual_step", math.nan)
        if step is not None and math.isfinite(step):
            spec = feature_spec("residual_step")
            stepped = step_baseline.check(step, math.nan, CAUGHT_Z, spec.min_rel).exceeded
    caught = (drags is not None and math.isfinite(drags) and drags > 0.0) or stepped
    return caught or not searched, caught


def count_exceedance(
    window: list[bool],
    waiting: list[bool],
    was_caught: list[bool],
    exceeded: bool,
    *,
    confirm: bool = False,
    caught: bool = False,
) -> bool:
    """Append whether a recording's exceedance counts to its feature's window (in place).

    ``confirm``: the exceedance counts only when the feature exceeded at the
    recording before it or exceeds at the next one (which then counts both:
    the window's last entry turns True); until then it waits (``waiting``
    holds whether the last exceedance waits). ``caught`` implies ``confirm``;
    a caught recording confirms no exceedance and is confirmed only by a
    neighbour that was not caught (``was_caught`` holds whether the last
    recording was caught).

    Parameters
    ----------
    window, waiting, was_caught : list of bool
        The feature's window of counted exceedances and the one-entry lists
        of its last recording's state; updated in place.
    exceeded : bool
        Whether this recording exceeded.
    confirm, caught : bool
        As :func:`needs_confirmation` returns them.

    Returns
    -------
    bool
        Whether this recording's exceedance counts now.
    """
    held = bool(was_caught and was_caught[-1])
    # the recording before exceeded (counted, or waiting for this one)
    before = bool(window and window[-1]) or bool(waiting and waiting[-1] and window)
    if exceeded and not caught and waiting and waiting[-1] and window:
        window[-1] = True  # the exceedance before, confirmed now
    counted = exceeded and (not (confirm or caught) or (before and not held))
    window.append(counted)
    waiting[:] = [exceeded and not counted]
    was_caught[:] = [caught]
    return counted
