"""A conveyor's verdict: one ``health`` value and its NAMUR NE 107 category.

Every view (fleet page, conveyor page, API, ``monitor`` output, reports,
notifications, ``/metrics``) takes its verdict from :func:`verdict`, worked
out from the conveyor's stored health model alone, so that they agree.

``health`` is the first that holds of:

==================  ==========================================  ==================
health              when                                        ``ne107``
==================  ==========================================  ==================
``no_data``         no health model, or no recording yet        ``check_function``
``out_of_service``  the conveyor is out of service now          ``check_function``
``alarm``           a standing alarm (open, neither shelved     ``failure``
                    nor out of service) is not acknowledged
``acknowledged``    standing alarms, all acknowledged           ``failure``
``relearning``      maintenance was recorded and the baseline   ``check_function``
                    after it is not complete yet (from the
                    moment it is recorded, not from the next
                    recording)
``learning``        the first baseline is not complete yet      ``check_function``
``shelved``         open alarms, all shelved                    ``off_spec``
``watch``           the health index is at least                ``maintenance_required``
                    :data:`WATCH_INDEX` (0 = baseline, 1 =
                    alarm limit)
``ok``              none of the above                           ``normal``
==================  ==========================================  ==================

``health_since`` is when the current ``health`` began: the first standing
alarm's opening (``alarm``), the latest acknowledgement (``acknowledged``),
the latest shelving (``shelved``), the out-of-service window's start, the
latest maintenance (``relearning``), the first recording (``learning``) and,
for ``watch`` and ``ok``, the recording from which the health index has
stayed on the same side of :data:`WATCH_INDEX` (no earlier than the end of
whatever came before: the baseline's completion, the latest alarm closed,
the latest return to service). ``ne107_since`` is the same except that
``alarm`` and ``acknowledged`` (both ``failure``) date from the first
standing alarm's opening. None where no time is known (``no_data``).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

import numpy as np

from chaintwin._types import FloatArray

from .features import feature_spec
from .monitor_state import HEALTH_RECENT, MonitorState
from .records import as_number

__all__ = [
    "HEALTH",
    "NE107",
    "NE107_OF",
    "WATCH_INDEX",
    "DeviationSeries",
    "Verdict",
    "deviation_series",
    "verdict",
]

HEALTH: tuple[str, ...] = (
    "alarm",
    "acknowledged",
    "shelved",
    "watch",
    "relearning",
    "out_of_service",
    "learning",
    "no_data",
    "ok",
)
"""The values of ``health``, worst first (the fleet's ranking)."""

NE107: tuple[str, ...] = (
    "failure",
    "check_function",
    "off_spec",
    "maintenance_required",
    "normal",
)
"""The NAMUR NE 107 categories, in NE 107's order of precedence."""

NE107_OF: dict[str, str] = {
    "alarm": "failure",
    "acknowledged": "failure",
    "shelved": "off_spec",
    "watch": "maintenance_required",
    "relearning": "check_function",
    "out_of_service": "check_function",
    "learning": "check_function",
    "no_data": "check_function",
    "ok": "normal",
}
"""Each ``health`` value's NE 107 category."""

WATCH_INDEX = 0.7
"""A health index from here (0 = baseline, 1 = alarm limit) puts a conveyor on watch."""


@dataclass(frozen=True, slots=True)
class Verdict:
    """A conveyor's verdict at one time.

    Attributes
    ----------
    health : str
        One of :data:`HEALTH`.
    health_since : str or None
        ISO time the current ``health`` began (None: unknown, ``no_data``).
    ne107 : str
        Its NE 107 category (:data:`NE107_OF`).
    ne107_since : str or None
        ISO time the current ``ne107`` began.
    health_index : float or None
        Its largest normalised deviation (``deviation``), at least 1 with a
        standing alarm; None while no baseline judges its recordings
        (``no_data``, ``learning``, ``relearning``, ``out_of_service``).
    deviation : float or None
        The largest normalised deviation of its features from their
        baseline (0 at the baseline, 1 at the alarm limit); None as above.
    worst_feature : str or None
        The feature of ``deviation``.
    """

    health: str
    health_since: str | None
    ne107: str
    ne107_since: str | None
    health_index: float | None
    deviation: float | None
    worst_feature: str | None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (the fields of the API's conveyor rows)."""
        return {
            "health": self.health,
            "health_since": self.health_since,
            "ne107": self.ne107,
            "ne107_since": self.ne107_since,
            "health_index": self.health_index,
            "deviation": self.deviation,
            "worst_feature": self.worst_feature,
        }


def _make(
    health: str,
    since: str | None,
    ne107_since: str | None = None,
    index: float | None = None,
    deviation: float | None = None,
    worst: str | None = None,
) -> Verdict:
    return Verdict(
        health=health,
        health_since=since,
        ne107=NE107_OF[health],
        ne107_since=since if ne107_since is None else ne107_since,
        health_index=index,
        deviation=deviation,
        worst_feature=worst,
    )


def _parse(text: str | None) -> datetime | None:
    if not text:
        return None
    try:
        out = datetime.fromisoformat(text)
    except ValueError:
        return None
    return out if out.tzinfo is not None else out.replace(tzinfo=UTC)


def _latest(times: list[str | None]) -> str | None:
    parsed = [(t, p) for t in times if (p := _parse(t)) is not None]
    return max(parsed, key=lambda tp: tp[1])[0] if parsed else None


def _earliest(times: list[str | None]) -> str | None:
    parsed = [(t, p) for t in times if (p := _parse(t)) is not None]
    return min(parsed, key=lambda tp: tp[1])[0] if parsed else None


@dataclass(frozen=True, slots=True)
class DeviationSeries:
    """Each feature's normalised deviation at every recording judged against the current baseline.

    Attributes
    ----------
    times : list of str or None
        The recordings' times (ISO), oldest first.
    names : list of str
        The monitored features (a baseline and a probable cause).
    values : ndarray, shape (len(times), len(names))
        At each recording, each feature's median over the latest ``recent``
        recordings up to it of ``(value − e(p)) / (L(p) − e(p))``
        (dimensionless: 0 at the baseline, 1 at the alarm limit; NaN where
        none is known yet).
    """

    times: list[str | None]
    names: list[str]
    values: FloatArray

    def latest(self) -> dict[str, float]:
        """Each feature's deviation at the latest recording (features without one left out)."""
        if not self.times:
            return {}
        row = self.values[-1]
        return {n: float(v) for n, v in zip(self.names, row, strict=True) if math.isfinite(v)}

    def worst(self) -> FloatArray:
        """The largest deviation at each recording (NaN where no feature has one)."""
        if not self.names or not self.times:
            return np.full(len(self.times), np.nan)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN rows: NaN
            return np.asarray(np.nanmax(self.values, axis=1), dtype=float)


def _nanmedian_rows(windows: FloatArray) -> FloatArray:
    """The median of each row's finite values (NaN for a row without one)."""
    ordered = np.sort(windows, axis=1)  # NaN last
    count = np.isfinite(ordered).sum(axis=1)
    lo = np.clip((count - 1) // 2, 0, None)
    hi = np.clip(count // 2, 0, None)
    a = np.take_along_axis(ordered, lo[:, None], axis=1)[:, 0]
    b = np.take_along_axis(ordered, np.minimum(hi, windows.shape[1] - 1)[:, None], axis=1)[:, 0]
    return np.where(count > 0, (a + b) / 2.0, np.nan)


def deviation_series(state: MonitorState, recent: int = HEALTH_RECENT) -> DeviationSeries:
    """Each monitored feature's normalised deviation at every recording since the baseline.

    For each feature with a baseline and a probable cause, at each recording
    judged against the current baseline (status ``monitored``, recorded from
    the baseline on): the median over the latest ``recent`` such recordings
    that hold the feature (non-finite values left out of the median) of
    ``(value − e(p)) / (L(p) − e(p))``, with ``e(p)`` the baseline's line and
    ``L(p)`` the alarm limit at the recording's payload ``p``. The last row
    is the conveyor's current deviation per feature, the same number as the
    report's feature health index.
    """
    if not state.baselines:
        return DeviationSeries([], [], np.empty((0, 0)))
    since = state.baseline_since or ""
    rows = [
        h
        for h in state.history
        if h.get("status") == "monitored" and (h.get("recorded_at") or "") >= since
    ]
    z_limit = state.settings.z_limit
    feats = [h.get("features") or {} for h in rows]
    names: list[str] = []
    columns: list[FloatArray] = []
    for name, fb in state.baselines.items():
        spec = feature_spec(name)
        if spec.cause is None:
            continue
        present = np.asarray([name in f for f in feats], dtype=bool)
        held = [f for f in feats if name in f]
        v = np.asarray([as_number(f[name]) for f in held], dtype=float)
        p = np.asarray([as_number(f.get(spec.regressor)) for f in held], dtype=float)
        e = fb.expected_at(p)  # NaN p: the mean payload
        span = fb.margin_at(e, z_limit, spec.min_rel)
        with np.errstate(invalid="ignore", divide="ignore"):
            vals = np.where(span > 0.0, (v - e) / span, np.nan)
        column = np.full(len(rows), np.nan)
        if vals.size:
            padded = np.concatenate([np.full(recent - 1, np.nan), vals])
            windows = np.lib.stride_tricks.sliding_window_view(padded, recent)
            medians = _nanmedian_rows(windows)
            upto = np.cumsum(present)  # present values up to each recording
            have = upto > 0
            column[have] = medians[upto[have] - 1]
        names.append(name)
        columns.append(column)
    values = np.column_stack(columns) if columns else np.empty((len(rows), 0))
    return DeviationSeries([h.get("recorded_at") for h in rows], names, values)


def _worst(devs: dict[str, float]) -> tuple[float | None, str | None]:
    if not devs:
        return None, None
    name = max(devs, key=lambda k: devs[k])
    return devs[name], name


def verdict(
    state: MonitorState | None,
    now: datetime | None = None,
    series: DeviationSeries | None = None,
) -> Verdict:
    """The conveyor's verdict from its stored health model (see the module notes).

    Parameters
    ----------
    state : MonitorState or None
        Its health model (None: none stored, ``no_data``).
    now : datetime, optional
        The time to judge at (shelving and out-of-service windows end by
        themselves); default: the clock.
    series : DeviationSeries, optional
        ``deviation_series(state)`` when the caller has it already (worked
        out here when None).

    Returns
    -------
    Verdict
        ``health``, ``ne107``, their ``since`` times and the health index.
    """
    from .alarm_actions import out_of_service_at

    now = now or datetime.now(UTC)
    if state is None or not state.history:
        return _make("no_data", None)
    window = state.out_of_service
    if out_of_service_at(window, now):
        return _make("out_of_service", None if window is None else window.get("from"))
    lifecycles = [(a, a.lifecycle(now)) for a in state.alarms]
    standing = [a for a, life in lifecycles if life not in ("closed", "shelved", "out_of_service")]
    series = deviation_series(state) if series is None else series
    deviation, worst = _worst(series.latest())
    if standing:
        first = _earliest([a.since for a in standing])
        index = max(1.0, deviation) if deviation is not None else 1.0
        if any(a.acknowledged is None for a in standing):
            return _make("alarm", first, first, index, deviation, worst)
        acked = _latest([a.acknowledged.at for a in standing if a.acknowledged is not None])
        return _make("acknowledged", acked, first, index, deviation, worst)
    pending = [e for e in state.events if not e.applied]
    if pending or (state.events and state.baselines is None):
        return _make("relearning", _latest([e.at for e in state.events]))
    if state.baselines is None:
        return _make("learning", _earliest([h.get("recorded_at") for h in state.history]))
    # judged against a complete baseline from here on
    floor = _latest(
        [
            series.times[0] if series.times else None,
            *[a.closed_at for a in state.alarms],
            *[e.at for e in state.events],
            None if window is None else window.get("until"),
        ]
    )
    shelved = [a for a, life in lifecycles if life == "shelved"]
    if shelved:
        since = _latest([a.shelved.at for a in shelved if a.shelved is not None])
        return _make("shelved", since, None, deviation, deviation, worst)
    watch = deviation is not None and deviation >= WATCH_INDEX
    worst_at = series.worst()
    watching = np.where(np.isfinite(worst_at), worst_at >= WATCH_INDEX, False)
    changed = np.flatnonzero(watching != watch)
    start: str | None = None
    if series.times:
        run = int(changed[-1]) + 1 if changed.size else 0  # where the current run began
        start = series.times[run] if run < len(series.times) else None
    since = _latest([start, floor])
    return _make("watch" if watch else "ok", since, None, deviation, deviation, worst)
