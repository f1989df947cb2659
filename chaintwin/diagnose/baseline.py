"""Baselines of a conveyor's features: fitted from healthy recordings, and the trend
forecasts against their limits."""

from __future__ import annotations

import dataclasses
import math
from collections import Counter
from collections.abc import Iterable, Mapping, Sequence
from datetime import datetime
from typing import Any, Literal

import numpy as np

from .causes import NOTE_CAUSES
from .confirmation import needs_confirmation
from .features import DRIFT_OF, feature_spec, is_tracked
from .forecasting import forecast_feature
from .health import FeatureBaseline, fit_baseline, robust_scale
from .prognosis import RECENT, forecast_alarm
from .records import as_number

__all__ = [
    "ALTERNATIVE_SHARE",
    "NO_FORECAST",
    "WEIGHED_SOURCES",
    "alarm_margins",
    "at_mean_payload",
    "confirmations",
    "fit_features",
    "forecasts",
    "judge_inputs",
    "payload_of",
    "regressor_of",
    "values_at_mean_payload",
]

ALTERNATIVE_SHARE = 0.5
"""A feature's baseline regresses on its alternative payload estimate when the
usual one's line explains less than this share of what the alternative's
explains (robust R², :func:`_explained`): only when the usual estimate
fails. On a 1 ms scope the inertia payload explained 15 % of the residual's
spread and the weighed one 72 %; where both explain most (87 % and 99 %) the
usual one stays, since the weighed payload drifts with the gear losses and a
baseline through it raised tooth-pass alarms on a healthy 12 ms conveyor."""


def _explained(fb: FeatureBaseline, spread: float) -> float:
    """Share of the values' robust variance the baseline's line explains (robust R²)."""
    if not spread > 0.0:
        return 0.0
    return max(0.0, 1.0 - (fb.scale / spread) ** 2)


NO_FORECAST: tuple[str, ...] = ("belt_bump",)
"""Features without a trend forecast: the belt map carries each place's value
from recording to recording, so its points are not independent (and an
obstruction does not grow steadily)."""


def fit_features(
    rows: Sequence[dict[str, Any]],
    names: Iterable[str] | None = None,
    *,
    min_rows: int = 0,
) -> dict[str, FeatureBaseline]:
    """A baseline per tracked feature from the rows (one per recording) that hold it.

    Parameters
    ----------
    rows : sequence of dict
        Feature values per recording (None or NaN: unknown).
    names : iterable of str, optional
        The features to fit; default every tracked feature in the rows.
    min_rows : int
        Fewest finite values a feature needs for a baseline.
    """
    if names is None:
        names = sorted({k for r in rows for k in r})
    out: dict[str, FeatureBaseline] = {}
    for name in names:
        if not is_tracked(name):
            continue
        column = [as_number(r.get(name)) for r in rows]
        if min_rows and sum(np.isfinite(column)) < min_rows:
            continue
        spec = feature_spec(name)
        fb = fit_baseline(
            column,
            [as_number(r.get(spec.regressor)) for r in rows],
            payload_dependent=spec.payload_dependent,
            min_scale=spec.min_scale,
            curve=spec.payload_curve,
        )
        if fb is not None and spec.alternative is not None:
            alt = fit_baseline(
                column,
                [as_number(r.get(spec.alternative)) for r in rows],
                payload_dependent=spec.payload_dependent,
                min_scale=spec.min_scale,
                curve=spec.payload_curve,
            )
            if alt is not None and (alt.slope != 0.0 or alt.curve is not None):
                spread = robust_scale(np.asarray([v for v in column if np.isfinite(v)]))
                if _explained(fb, spread) < ALTERNATIVE_SHARE * _explained(alt, spread):
                    fb = dataclasses.replace(alt, regressor=spec.alternative)
        if fb is not None:
            out[name] = fb
    return out


def regressor_of(name: str, fb: FeatureBaseline) -> str:
    """The feature a baseline's line regresses on (the spec's, unless the baseline chose)."""
    return fb.regressor or feature_spec(name).regressor


def judge_inputs(
    name: str, fb: FeatureBaseline, values: Mapping[str, float | None]
) -> tuple[float, float, float]:
    """What a recording's value of a feature is judged with besides the value itself.

    The one source of :meth:`~chaintwin.diagnose.health.FeatureBaseline.check`'s
    inputs for the alarm rule and for the forecasts of when it alarms.

    Parameters
    ----------
    name : str
        The feature.
    fb : FeatureBaseline
        Its baseline.
    values : Mapping
        The recording's features (None or NaN: unknown).

    Returns
    -------
    load : float
        The baseline's regressor, kg (NaN: unknown, judged at the mean payload).
    payload_sigma : float
        How far a loss drift may have moved that payload estimate, kg.
    allowance : float
        How far a loss drift may have moved the feature, feature units.
    """
    spec = feature_spec(name)
    regressor = regressor_of(name, fb)
    load = as_number(values.get(regressor))
    drift = values.get(DRIFT_OF.get(regressor, ""), 0.0)
    allowance = values.get(spec.drift, 0.0) if spec.drift else 0.0
    return load, as_number(drift), as_number(allowance)


WEIGHED_SOURCES: tuple[str, str] = ("weighed_by_inertia", "weighed")
"""The sources (:func:`payload_of`) besides the regressor's name: the recording's
payload weighed by the inertia signature alone (the monitor's reading while the
friction is suspect), or as weighed."""


def payload_of(name: str, fb: FeatureBaseline, result: Mapping[str, Any]) -> tuple[float, str]:
    """The load a feature's value is moved to the mean payload from, and which it is.

    The baseline's regressor where the recording holds it; else the payload
    the weighing gave the recording (``payload_kg``): a recording whose
    signatures disagree (a friction rise) has no ``payload_inertia_kg``
    feature, but the monitor weighs it by the inertia signature alone.

    Parameters
    ----------
    name : str
        The feature.
    fb : FeatureBaseline
        Its baseline.
    result : Mapping
        A recording's result (``RecordingResult.to_dict()``): ``features``,
        ``payload_kg`` and ``warnings``.

    Returns
    -------
    load : float
        kg; NaN when neither is known.
    source : str
        The regressor's name (also when neither is known), one of
        :data:`WEIGHED_SOURCES`, or ``none`` when the baseline does not depend
        on the payload.
    """
    if fb.slope == 0.0 and fb.curve is None:
        return math.nan, "none"
    regressor = regressor_of(name, fb)
    load = as_number((result.get("features") or {}).get(regressor))
    if math.isfinite(load):
        return load, regressor
    weighed = as_number(result.get("payload_kg"))
    if not math.isfinite(weighed):
        return math.nan, regressor
    codes = {w.get("code") for w in result.get("warnings") or () if isinstance(w, Mapping)}
    return weighed, WEIGHED_SOURCES[0] if "weighed_by_inertia" in codes else WEIGHED_SOURCES[1]


def at_mean_payload(
    name: str, fb: FeatureBaseline, features: Mapping[str, Any], load_kg: float | None = None
) -> float:
    """A feature's value with the load's part taken out: as at the baseline's mean payload.

    What the forecasts and the wear rates fit over time (NaN when unknown).

    Parameters
    ----------
    name : str
        The feature.
    fb : FeatureBaseline
        Its baseline.
    features : Mapping
        The recording's features.
    load_kg : float, optional
        The load to take out, kg (:func:`payload_of`); default the
        baseline's regressor among ``features``.
    """
    value = as_number(features.get(name))
    if fb.slope == 0.0 and fb.curve is None:
        return value  # no load part
    load = as_number(features.get(regressor_of(name, fb))) if load_kg is None else load_kg
    if not math.isfinite(load):
        return math.nan
    if fb.curve is not None:
        return value - (fb.expected(load) - fb.expected(fb.mean_payload_kg))
    return value - fb.slope * (load - fb.mean_payload_kg)


def values_at_mean_payload(
    name: str, fb: FeatureBaseline, rows: Sequence[Mapping[str, Any]]
) -> tuple[list[float], list[str]]:
    """A feature's values over results as at the baseline's mean payload, and their loads' sources.

    Each :func:`at_mean_payload` at the load :func:`payload_of` gives (NaN: unknown).
    """
    vals, sources = [], []
    for h in rows:
        load, source = payload_of(name, fb, h)
        vals.append(at_mean_payload(name, fb, h["features"], load))
        sources.append(source)
    return vals, sources


def alarm_margins(
    name: str, fb: FeatureBaseline, rows: Sequence[Mapping[str, Any]], z_limit: float
) -> tuple[list[float], list[bool]]:
    """The alarm rule's margin at each result, and whether the result exceeded on the feature.

    The margin is how far above the baseline's value a recording's value had
    to lie to exceed (:meth:`~chaintwin.diagnose.health.FeatureBaseline.rise_margin`
    with :func:`judge_inputs`, feature units); the exceedances are the
    monitor's own (each result's ``exceeded``).
    """
    spec = feature_spec(name)
    margins = []
    for h in rows:
        load, sigma, allowance = judge_inputs(name, fb, h["features"])
        margins.append(fb.rise_margin(load, z_limit, spec.min_rel, sigma, allowance))
    return margins, [name in (h.get("exceeded") or ()) for h in rows]


def confirmations(
    rows: Sequence[Mapping[str, Any]], baselines: Mapping[str, FeatureBaseline]
) -> tuple[list[bool], list[bool]]:
    """Whether each result's exceedances needed a neighbour's confirmation, and was caught.

    :func:`~chaintwin.diagnose.confirmation.needs_confirmation` of each
    result's ``features``, with the ``residual_step`` baseline of
    ``baselines`` (the monitor's judgement of each recording, redone).
    """
    step = baselines.get("residual_step")
    confirm: list[bool] = []
    caught: list[bool] = []
    for h in rows:
        feats = {
            k: math.nan if v is None else float(v) for k, v in (h.get("features") or {}).items()
        }
        c, k = needs_confirmation(feats, step)
        confirm.append(c)
        caught.append(k)
    return confirm, caught


def noted_events(name: str, rows: Sequence[Mapping[str, Any]]) -> list[bool]:
    """Whether the monitor noted an event of operation on the feature at each result.

    An item caught, an impulsive residual (:data:`~chaintwin.diagnose.causes.
    NOTE_CAUSES`): the feature's rule was met there, and no alarm opened.
    """
    return [
        any(
            c.get("feature") == name and c.get("cause") in NOTE_CAUSES
            for c in (h.get("causes") or ())
        )
        for h in rows
    ]


def forecasts(
    baselines: dict[str, FeatureBaseline],
    history: Sequence[dict[str, Any]],
    since: str,
    z_limit: float,
    *,
    bands: bool = False,
    x: int = 3,
    y: int = 10,
    method: Literal["alarm", "window"] = "alarm",
) -> list[dict[str, Any]]:
    """When each tracked feature's alarm opens (or its trend crosses its limit; rising ones only).

    Parameters
    ----------
    baselines : dict
        The features' baselines.
    history : sequence of dict
        Recent results (``RecordingResult.to_dict()``), oldest first.
    since : str
        ISO time the baseline dates from; earlier results are left out.
    z_limit : float
        The monitor's z limit.
    bands : bool
        Add each forecast's ``band`` (its path and 90 % interval ahead,
        :class:`~chaintwin.diagnose.health.ForecastBand`; None when crossed).
    x, y : int
        The monitor's X-of-Y rule.
    method : {"alarm", "window"}
        ``alarm``: when the alarm rule opens the feature's alarm, from the
        rise after its change point (:func:`~chaintwin.diagnose.prognosis.
        forecast_alarm`); ``window``: where the model its backtest picks over
        the last steps crosses the baseline's limit at its mean payload
        (:func:`~chaintwin.diagnose.forecasting.forecast_feature`, the
        forecasts before the alarm's opening was predicted).

    Returns
    -------
    list of dict
        :meth:`~chaintwin.diagnose.health.Forecast.to_dict` with the feature's
        ``cause``, ``payload_source`` (what the latest value's load part was
        taken out at, :func:`payload_of`: on a friction rise the regressor
        ``payload_inertia_kg`` until the signatures disagree, then
        ``weighed_by_inertia``) and ``payload_sources`` (how many of the
        values stand on each).
    """
    out = []
    rows = [
        h
        for h in history
        if h.get("status") == "monitored" and h.get("recorded_at") and h["recorded_at"] >= since
    ]
    if len(rows) < 8:
        return []
    times = [datetime.fromisoformat(h["recorded_at"]) for h in rows]
    confirm, caught = confirmations(rows, baselines) if method == "alarm" else ([], [])
    for name, fb in baselines.items():
        spec = feature_spec(name)
        if spec.cause is None or name in NO_FORECAST:
            continue
        vals, sources = values_at_mean_payload(name, fb, rows)
        if method == "window":
            fc = forecast_feature(name, times, vals, fb.limit(z_limit, spec.min_rel))
        else:
            # the margins of the last recordings stand for those ahead
            margins, _ = alarm_margins(name, fb, rows[-RECENT:], z_limit)
            exceeded = [name in (h.get("exceeded") or ()) for h in rows]
            noted = noted_events(name, rows)
            healthy = fb.expected(fb.mean_payload_kg)
            limit = fb.limit(z_limit, spec.min_rel)
            fc = forecast_alarm(
                name,
                times,
                vals,
                margins,
                exceeded,
                healthy,
                x=x,
                y=y,
                limit=limit,
                confirm=confirm,
                caught=caught,
                noted=noted,
            )
        if fc is not None:
            used = [src for src, v in zip(sources, vals, strict=True) if math.isfinite(v)]
            extra: dict[str, Any] = {
                "cause": spec.cause,
                "payload_source": used[-1],
                "payload_sources": dict(sorted(Counter(used).items())),
            }
            if bands:
                extra["band"] = None if fc.band is None else fc.band.to_dict()
            out.append(fc.to_dict() | extra)
    return out
