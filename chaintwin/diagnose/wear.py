"""Usage-based wear: what a conveyor carried, and each feature's change per unit of it.

A conveyor that carries more wears faster. Time alone cannot tell a heavily
loaded conveyor's expected wear from a fault; the transported work can:

* **usage per recording**: ``usage_kg_m = payload × belt travel`` over the
  recording (kg·m; the payload weighed, the travel ``∫|ω|·r/i dt``), a
  feature of every monitored result (NaN when the payload is unknown);
* **cumulative usage** per conveyor: the sum over its results, in t·km
  (10⁶ kg·m);
* **wear rate** per feature: the slope of the feature (at the baseline's mean
  payload, as the forecasts take it) against the cumulative usage since the
  baseline, per t·km, with its standard error, by ordinary least squares.

Two conveyors whose friction rises at the same rate per t·km wear alike, even
when one rises twice as fast per day because it carries twice as much.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from .baseline import at_mean_payload
from .features import feature_spec
from .health import FeatureBaseline
from .records import as_number

__all__ = ["KG_M_PER_T_KM", "MIN_ROWS", "known_usage", "usage_of", "usage_summary", "wear_rates"]

KG_M_PER_T_KM = 1.0e6
"""kg·m in one tonne-kilometre."""

MIN_ROWS = 8
"""Fewest monitored results with a usage a wear rate is fitted to."""


def known_usage(value: float) -> float:
    """A recording's usage as it counts, kg·m: 0 when unknown (NaN) or not positive."""
    return value if math.isfinite(value) and value > 0.0 else 0.0


def usage_of(row: Mapping[str, Any]) -> float:
    """A stored result's usage, kg·m (0 when unknown)."""
    return known_usage(as_number((row.get("features") or {}).get("usage_kg_m")))


def usage_summary(history: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """Cumulative usage of a conveyor's results: ``{"total_t_km", "recordings"}``.

    ``recordings`` counts the results with a known usage.
    """
    known = [usage_of(h) for h in history if h.get("status") in ("baseline", "monitored")]
    return {
        "total_t_km": sum(known) / KG_M_PER_T_KM,
        "recordings": sum(1 for u in known if u > 0.0),
    }


def wear_rates(
    baselines: Mapping[str, FeatureBaseline],
    history: Sequence[Mapping[str, Any]],
    since: str,
) -> list[dict[str, Any]]:
    """Each alarmed feature's change per t·km of usage since the baseline.

    Parameters
    ----------
    baselines : mapping
        The features' baselines.
    history : sequence of dict
        Results (``RecordingResult.to_dict()``), oldest first.
    since : str
        ISO time the baseline dates from.

    Returns
    -------
    list of dict
        ``{"feature", "rate_per_t_km", "rate_stderr", "usage_t_km", "recordings"}``
        per feature with at least :data:`MIN_ROWS` results and some usage;
        ``rate_per_t_km`` in the feature's units per t·km.
    """
    rows = [
        h
        for h in history
        if h.get("status") in ("baseline", "monitored")
        and h.get("recorded_at")
        and h["recorded_at"] >= since
    ]
    if len(rows) < MIN_ROWS:
        return []
    used = np.cumsum([usage_of(h) for h in rows]) / KG_M_PER_T_KM
    if float(used[-1]) <= 0.0:
        return []
    out = []
    for name, fb in baselines.items():
        spec = feature_spec(name)
        if spec.cause is None:
            continue
        vals = np.array([at_mean_payload(name, fb, h.get("features") or {}) for h in rows])
        ok = np.isfinite(vals)
        if ok.sum() < MIN_ROWS or float(np.ptp(used[ok])) <= 0.0:
            continue
        x, y = used[ok], vals[ok]
        a = np.column_stack((np.ones_like(x), x))
        coef, *_ = np.linalg.lstsq(a, y, rcond=None)
        resid = y - a @ coef
        dof = max(len(y) - 2, 1)
        cov = float(resid @ resid) / dof * np.linalg.inv(a.T @ a)
        out.append(
            {
                "feature": name,
                "rate_per_t_km": float(coef[1]),
                "rate_stderr": math.sqrt(max(float(cov[1, 1]), 0.0)),
                "usage_t_km": float(x[-1] - x[0]),
                "recordings": int(ok.sum()),
            }
        )
    return out
