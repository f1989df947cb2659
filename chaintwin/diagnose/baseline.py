"""Baselines of a conveyor's features: fitted from healthy recordings, and the trend
forecasts against their limits."""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from datetime import datetime
from typing import Any

import numpy as np

from .features import FEATURES, feature_spec
from .forecasting import forecast_feature
from .health import FeatureBaseline, fit_baseline
from .records import as_number

__all__ = ["NO_FORECAST", "fit_features", "forecasts"]

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
        if name not in FEATURES and not name.startswith("comb_"):
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
        )
        if fb is not None:
            out[name] = fb
    return out


def forecasts(
    baselines: dict[str, FeatureBaseline],
    history: Sequence[dict[str, Any]],
    since: str,
    z_limit: float,
    *,
    bands: bool = False,
) -> list[dict[str, Any]]:
    """When each tracked feature's trend crosses its limit (rising trends only).

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
    for name, fb in baselines.items():
        spec = feature_spec(name)
        if spec.cause is None or name in NO_FORECAST:
            continue
        # at the baseline's mean payload: the load's part of the value taken out
        vals = [
            as_number(h["features"].get(name))
            - fb.slope * (as_number(h["features"].get(spec.regressor)) - fb.mean_payload_kg)
            for h in rows
        ]
        fc = forecast_feature(name, times, vals, fb.limit(z_limit, spec.min_rel))
        if fc is not None:
            extra: dict[str, Any] = {"cause": spec.cause}
            if bands:
                extra["band"] = None if fc.band is None else fc.band.to_dict()
            out.append(fc.to_dict() | extra)
    return out
