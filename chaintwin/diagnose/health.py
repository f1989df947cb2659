"""Baselines, control limits, the X-of-Y rule and trend forecasts.

A conveyor's baseline is learned from its first N recordings (after
calibration, and again after each maintenance event). For every feature it
is a robust line ``value = a + b·payload`` (``b`` only for features that
depend on the load, such as the tooth-pass ripple, only when the baseline's
payloads spread over at least :data:`MIN_PAYLOAD_SPREAD_KG` and only when the
slope stands :data:`MIN_SLOPE_T` standard errors out of zero; else the
median) with a robust scale ``s`` of what the line leaves (:func:`robust_scale`:
the larger of ``1.4826·MAD`` and ``IQR/1.349``, equal for a normal spread).
The baseline is checked for outliers: values more than :data:`OUTLIER_Z`
scales off are left out and the line fitted again.

A spectral line's amplitude need not follow a line: a belt mode that the
payload tunes through the line makes a hump (on the demo's short-fast-03 the
sprocket comb is 0.12 Nm at 23-26 kg and 0.05 Nm at 14 and at 40 kg). Where
the features allow it (``curve=True`` in :func:`fit_baseline`) and a curve
through the baseline's running medians over the payload predicts each
baseline value from the others at least twice as well as the line
(:data:`CURVE_GAIN`, leave-one-out), the baseline is that curve instead
(:attr:`FeatureBaseline.curve`), with the scale of its leave-one-out
residuals.

A recording *exceeds* on a feature when its value is above the baseline
line at its payload by more than ``z_limit·s`` **and** by more than the
feature's smallest relative change (:class:`~chaintwin.diagnose.features.FeatureSpec`
``min_rel``: the allowance for slow temperature drift and the payload's
estimation error) **and** by more than the baseline's own second-largest
rise above its line (a value the healthy conveyor itself showed in two of its
baseline recordings is no change: a line sum that sits at one of two levels
from scope to scope, the higher in a fifth of them, alarmed on healthy
conveyors otherwise). Only rises count, except for a two-sided feature
(:class:`~chaintwin.diagnose.features.FeatureSpec` ``two_sided``: a line the
fault adds to one the healthy conveyor has may first cancel part of it),
whose falls are judged the same way against the second-largest fall when its
baseline is flat.

An *alarm* needs X exceedances of one feature in the last Y recordings
(default 3 of 10, :func:`x_of_y`), so one odd scope pages no one.

Forecasts (:class:`Forecast`) say when a feature's alarm opens
(:mod:`chaintwin.diagnose.prognosis`, the monitor's) or when its values
reach a limit (:mod:`chaintwin.diagnose.forecasting`), with a 90 % band.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from datetime import datetime
from typing import Any

import numpy as np

from chaintwin._types import FloatArray

__all__ = [
    "EXTRAPOLATION",
    "MIN_PAYLOAD_SPREAD_KG",
    "OUTLIER_Z",
    "Exceedance",
    "FeatureBaseline",
    "Forecast",
    "ForecastBand",
    "fit_baseline",
    "in_days",
    "robust_scale",
    "x_of_y",
]

MIN_PAYLOAD_SPREAD_KG = 5.0
"""The baseline's payloads must spread this much to fit a payload slope, kg."""

OUTLIER_Z = 5.0
"""Baseline values this many robust scales off the line are left out."""

MIN_BASELINE = 5
"""Fewest finite values a feature's baseline needs."""

MIN_SLOPE_T = 3.0
"""A baseline's payload slope is kept when it is this many standard errors from zero."""

CURVE_MIN_ROWS = 10
"""Fewest baseline values a payload curve (:attr:`FeatureBaseline.curve`) is fitted from."""

CURVE_GAIN = 0.5
"""A payload curve replaces the line when the robust scale of its leave-one-out
residuals is at most this share of the line's."""


@dataclass(frozen=True, slots=True)
class Exceedance:
    """A feature's value against its baseline at one recording."""

    expected: float
    deviation: float
    z: float
    change: float
    """Relative change against the expected value (0.2 = 20 % above)."""
    exceeded: bool


@dataclass(frozen=True, slots=True)
class FeatureBaseline:
    """A feature's healthy level: ``intercept + slope·payload`` ± ``scale``.

    Attributes
    ----------
    intercept : float
        Value at zero payload (feature units).
    slope : float
        Per kg of payload (0 when not payload dependent).
    scale : float
        Robust standard deviation about the line (:func:`robust_scale`).
    count : int
        Baseline values used.
    outliers : int
        Baseline values left out as outliers.
    mean_payload_kg : float
        Mean payload of the baseline recordings, kg.
    regressor : str or None
        The feature the line regresses on when it is not the feature's
        usual one (:func:`chaintwin.diagnose.baseline.fit_features` picks
        the payload estimate that explains the baseline better); None: the
        usual one.
    top_residual : float or None
        The baseline's second-largest value above its line (feature units;
        outliers included): what healthy recordings themselves reached, which
        no exceedance lies below (:meth:`check`); None for baselines stored
        before it was kept.
    bottom_residual : float or None
        The baseline's second-largest value below its line (negative, feature
        units): the same guard for the falls of a two-sided feature.
    payload_range_kg : (float, float)
        Payloads the line holds for, kg: the baseline's, widened by half
        their spread each way (:data:`EXTRAPOLATION`); :meth:`expected`
        holds the line's value at the nearer end beyond them. None: unbounded
        (a flat line, or a baseline stored before it was kept).
    curve : ((float, ...), (float, ...)) or None
        Payloads (kg, increasing) and the healthy values there (feature
        units), when the feature follows the payload in a way a line does
        not (see the module notes): :meth:`expected` interpolates between
        them, holding the end values beyond. ``intercept`` and ``slope`` are
        then the line's, for the trend forecasts. None: the line.
    """

    intercept: float
    slope: float
    scale: float
    count: int
    outliers: int
    mean_payload_kg: float
    regressor: str | None = None
    top_residual: float | None = None
    bottom_residual: float | None = None
    payload_range_kg: tuple[float, float] | None = None
    curve: tuple[tuple[float, ...], tuple[float, ...]] | None = None

    def expected(self, payload_kg: float) -> float:
        """The healthy value at a payload (feature units; NaN payload: the mean payload)."""
        return float(self.expected_at(np.asarray([payload_kg], dtype=float))[0])

    def expected_at(self, payloads_kg: FloatArray) -> FloatArray:
        """:meth:`expected` at each of many payloads (kg; NaN: the mean payload)."""
        p = np.where(np.isfinite(payloads_kg), payloads_kg, self.mean_payload_kg)
        if self.curve is not None:
            return np.asarray(np.interp(p, self.curve[0], self.curve[1]), dtype=float)
        if self.payload_range_kg is not None:
            lo, hi = self.payload_range_kg
            p = np.minimum(np.maximum(p, lo), hi)
        return np.asarray(self.intercept + self.slope * p, dtype=float)

    def margin_at(self, expected: FloatArray, z_limit: float, min_rel: float) -> FloatArray:
        """How far above each expected value the limit lies (feature units): :meth:`limit` less
        :meth:`expected`."""
        top = -math.inf if self.top_residual is None else self.top_residual
        out = np.maximum(np.maximum(z_limit * self.scale, min_rel * np.abs(expected)), top)
        return np.asarray(out, dtype=float)

    def limit(self, z_limit: float, min_rel: float, payload_kg: float | None = None) -> float:
        """The value above which a recording exceeds (at the mean payload by default)."""
        e = self.expected(self.mean_payload_kg if payload_kg is None else payload_kg)
        return e + float(self.margin_at(np.asarray([e]), z_limit, min_rel)[0])

    def lower_limit(self, z_limit: float, min_rel: float, payload_kg: float | None = None) -> float:
        """The value below which a two-sided feature exceeds (at the mean payload by default)."""
        e = self.expected(self.mean_payload_kg if payload_kg is None else payload_kg)
        bottom = -math.inf if self.bottom_residual is None else -self.bottom_residual
        return e - max(z_limit * self.scale, min_rel * abs(e), bottom)

    def _scale_at(self, payload_kg: float, payload_sigma_kg: float) -> float:
        """The scale a value at this payload is judged with: widened for the payload's drift."""
        scale = self.scale
        uncertain = math.isfinite(payload_sigma_kg) and payload_sigma_kg > 0.0
        if self.curve is not None and uncertain:
            # half the curve's spread over the payload's band
            p = payload_kg if math.isfinite(payload_kg) else self.mean_payload_kg
            band = [
                self.expected(q) for q in np.linspace(p - payload_sigma_kg, p + payload_sigma_kg, 9)
            ]
            scale = math.hypot(scale, 0.5 * (max(band) - min(band)))
        elif self.slope != 0.0 and uncertain:
            scale = math.hypot(scale, self.slope * payload_sigma_kg)
        return scale

    def rise_margin(
        self,
        payload_kg: float,
        z_limit: float,
        min_rel: float,
        payload_sigma_kg: float = 0.0,
        drift_allowance: float = 0.0,
    ) -> float:
        """How far above the healthy value a value must lie to exceed (feature units).

        The alarm rule's threshold (:meth:`check`, whose arguments these are),
        written once for the rule and for the forecasts of when it alarms
        (:mod:`chaintwin.diagnose.prognosis`): the larger of ``z_limit``
        scales (widened for the payload's drift) plus the loss-drift
        allowance, the smallest relative change of the healthy value, and the
        baseline's second-largest rise.
        """
        e = self.expected(payload_kg)
        scale = self._scale_at(payload_kg, payload_sigma_kg)
        return self._margin(e, scale, z_limit, min_rel, drift_allowance)

    def _margin(
        self, e: float, scale: float, z_limit: float, min_rel: float, drift_allowance: float
    ) -> float:
        """:meth:`rise_margin` from the healthy value and the scale at the payload."""
        allowance = drift_allowance if math.isfinite(drift_allowance) else 0.0
        top = -math.inf if self.top_residual is None else self.top_residual
        return max(z_limit * scale + allowance, min_rel * abs(e), top)

    def check(
        self,
        value: float,
        payload_kg: float,
        z_limit: float,
        min_rel: float,
        two_sided: bool = False,
        payload_sigma_kg: float = 0.0,
        drift_allowance: float = 0.0,
    ) -> Exceedance:
        """Compare a value with the baseline: rises only, or falls too when ``two_sided``.

        ``payload_sigma_kg`` is how far the payload estimate may be off for a
        reason the baseline's scatter does not hold (a gear-loss drift since
        the baseline moves the weighed payload): the expected value is then
        uncertain by ``slope·payload_sigma_kg`` too, and the z-score is taken
        against both (errors in the regressor). On one drawn conveyor the
        weighed payload drifted 12 kg below the baseline's with the losses
        while the load stayed, and a tooth-pass line with a real payload
        slope alarmed on 19 healthy recordings.

        ``drift_allowance`` is how far a drift of the gear losses within its
        range may have moved the value since the baseline (feature units,
        :class:`~chaintwin.diagnose.features.FeatureSpec` ``drift``): a bounded
        bias, not a random error, so a rise or fall counts only when what is
        left of it beyond the allowance is ``z_limit`` scales out (the reported
        ``z`` is the whole deviation's). It is the recording's own, not the
        baseline's, since how well a recording tells a loss change from a
        payload depends on its ramps.

        Falls count only on a flat baseline (no payload slope): a sloped line's
        expected value follows a payload estimate that a loss drift moves both
        ways, and a healthy conveyor's tooth-pass lines, regressed on a
        weighed payload drifting upwards, fell below it on 95 recordings.
        """
        e = self.expected(payload_kg)
        dev = value - e
        scale = self._scale_at(payload_kg, payload_sigma_kg)
        z = dev / scale
        change = dev / abs(e) if e != 0.0 else math.copysign(math.inf, dev)
        allowance = drift_allowance if math.isfinite(drift_allowance) else 0.0
        rose = dev > self._margin(e, scale, z_limit, min_rel, allowance)
        fell = (
            two_sided
            and self.slope == 0.0
            and self.curve is None
            and (-dev - allowance) / scale > z_limit
            and -dev > min_rel * abs(e)
            and (self.bottom_residual is None or dev < self.bottom_residual)
        )
        return Exceedance(e, dev, z, change, bool(math.isfinite(value) and (rose or fell)))

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (the payload range as a list, as JSON reads it back)."""
        out = asdict(self)
        if self.payload_range_kg is not None:
            out["payload_range_kg"] = list(self.payload_range_kg)
        if self.curve is None:
            del out["curve"]  # as stored before curves existed
        else:
            out["curve"] = [list(self.curve[0]), list(self.curve[1])]
        return out

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> FeatureBaseline:
        """Inverse of :meth:`to_dict`."""
        rng = data.get("payload_range_kg")
        knots = data.get("curve")
        return cls(
            **(
                data
                | {
                    "payload_range_kg": None if rng is None else tuple(rng),
                    "curve": None
                    if knots is None
                    else (tuple(float(x) for x in knots[0]), tuple(float(y) for y in knots[1])),
                }
            )
        )


EXTRAPOLATION = 0.5
"""How far beyond the baseline's payloads a line is extended, as a share of their spread."""


def _held_range(payloads: FloatArray) -> tuple[float, float]:
    """The payloads a baseline's line holds for (see :class:`FeatureBaseline`).

    Beyond them the line is not extended: a weighed payload that a loss
    drift moved 10 kg below every baseline payload took the tooth-pass
    line's expected value down with it, and a healthy conveyor's tooth-pass
    lines exceeded on 19 recordings.
    """
    lo, hi = float(np.min(payloads)), float(np.max(payloads))
    margin = EXTRAPOLATION * (hi - lo)
    return (lo - margin, hi + margin)


def robust_scale(r: FloatArray) -> float:
    """The larger of ``1.4826·MAD`` and ``IQR/1.349`` of ``r`` (both σ for a normal spread).

    The MAD alone sees only the larger mode of a two-valued feature: a line
    sum that sits at 0.0038 Nm in 14 baseline scopes and 0.0085 Nm in 6
    (a line falling on or beside a bin, scope to scope) got a scale of the
    low mode, the high scopes were left out as outliers, and every later
    high scope exceeded on a healthy conveyor. The interquartile range spans
    both modes.
    """
    mad = 1.4826 * float(np.median(np.abs(r - np.median(r))))
    q25, q75 = np.percentile(r, [25.0, 75.0])
    return max(mad, float(q75 - q25) / 1.349)


def _line(values: FloatArray, payloads: FloatArray, with_slope: bool) -> tuple[float, float]:
    """Intercept and slope; the slope only when it stands out of its noise.

    A slope less than :data:`MIN_SLOPE_T` standard errors from zero is
    dropped (the median is used): a spurious slope would make the expected
    value follow a payload estimate that a friction or loss change moves.
    """
    if with_slope and values.shape[0] >= 4:
        x = np.column_stack([np.ones_like(payloads), payloads])
        sol, _res, _rank, _sv = np.linalg.lstsq(x, values, rcond=None)
        resid = values - x @ sol
        dof = values.shape[0] - 2
        s2 = float(resid @ resid) / dof
        sxx = float(np.sum((payloads - payloads.mean()) ** 2))
        se = math.sqrt(s2 / sxx) if sxx > 0 else math.inf
        if abs(float(sol[1])) > MIN_SLOPE_T * se:
            return float(sol[0]), float(sol[1])
    return float(np.median(values)), 0.0


def _curve_knots(p: FloatArray, v: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Knots of a payload curve: the values' running medians of three over the
    payload order (the ends: the two nearest), one knot per distinct payload."""
    order = np.argsort(p, kind="stable")
    ps, vs = p[order], v[order]
    n = ps.shape[0]
    smooth = np.array([float(np.median(vs[max(0, i - 1) : min(n, i + 2)])) for i in range(n)])
    knots, at = np.unique(ps, return_inverse=True)
    sums = np.bincount(at, weights=smooth)
    return knots, sums / np.bincount(at)


def _curve(
    v: FloatArray, p: FloatArray, line_scale: float, min_scale: float
) -> tuple[tuple[tuple[float, ...], tuple[float, ...]], float, FloatArray] | None:
    """A payload curve (knots, scale, leave-one-out residuals) when it predicts the
    baseline better than the line by :data:`CURVE_GAIN`, else None."""
    n = v.shape[0]
    if n < CURVE_MIN_ROWS:
        return None
    loo = np.empty(n)
    for i in range(n):
        rest = np.arange(n) != i
        kp, kv = _curve_knots(p[rest], v[rest])
        loo[i] = v[i] - float(np.interp(p[i], kp, kv))
    scale = robust_scale(loo)
    if not scale <= CURVE_GAIN * line_scale:
        return None
    kp, kv = _curve_knots(p, v)
    knots = (tuple(float(x) for x in kp), tuple(float(y) for y in kv))
    return knots, max(scale, min_scale, 1e-9 * max(float(np.max(np.abs(kv))), 1e-12)), loo


def fit_baseline(
    values: Sequence[float],
    payloads_kg: Sequence[float],
    *,
    payload_dependent: bool,
    min_scale: float = 0.0,
    curve: bool = False,
) -> FeatureBaseline | None:
    """Learn a feature's baseline from healthy recordings.

    Parameters
    ----------
    values : sequence of float
        The feature per baseline recording (NaN where unknown).
    payloads_kg : sequence of float
        The estimated payload per recording, kg.
    payload_dependent : bool
        Regress the value on the payload (when the payloads spread enough).
    min_scale : float
        Floor of the robust scale (feature units).
    curve : bool
        A payload curve may replace the line (see the module notes; only
        with ``payload_dependent``).

    Returns
    -------
    FeatureBaseline or None
        None when fewer than :data:`MIN_BASELINE` values are finite.
    """
    v = np.asarray(values, dtype=np.float64)
    p = np.asarray(payloads_kg, dtype=np.float64)
    ok = np.isfinite(v) & np.isfinite(p)
    if ok.sum() < MIN_BASELINE:
        return None
    v, p = v[ok], p[ok]
    with_slope = payload_dependent and float(np.ptp(p)) >= MIN_PAYLOAD_SPREAD_KG
    keep = np.ones(v.shape[0], dtype=bool)
    a, b = _line(v, p, with_slope)
    for _ in range(2):
        r = v - (a + b * p)
        scale = max(robust_scale(r[keep]), 1e-9 * max(abs(a), 1e-12))
        new_keep = np.abs(r - float(np.median(r[keep]))) <= OUTLIER_Z * scale
        if new_keep.sum() < MIN_BASELINE or np.array_equal(new_keep, keep):
            break
        keep = new_keep
        a, b = _line(v[keep], p[keep], with_slope)
    r = v[keep] - (a + b * p[keep])
    scale = max(robust_scale(r), min_scale, 1e-9 * max(abs(a), 1e-12))
    every = np.sort(v - (a + b * p))
    bent = (
        _curve(v, p, robust_scale(v - (a + b * p)), min_scale)
        if curve and payload_dependent and float(np.ptp(p)) >= MIN_PAYLOAD_SPREAD_KG
        else None
    )
    if bent is not None:
        knots, bent_scale, loo = bent
        ordered = np.sort(loo)
        return FeatureBaseline(
            intercept=a,
            slope=b,
            scale=bent_scale,
            count=int(v.shape[0]),
            outliers=0,
            mean_payload_kg=float(np.mean(p)),
            payload_range_kg=_held_range(p) if b != 0.0 else None,
            top_residual=float(ordered[-2]),
            bottom_residual=float(ordered[1]),
            curve=knots,
        )
    return FeatureBaseline(
        intercept=a,
        slope=b,
        scale=scale,
        count=int(keep.sum()),
        outliers=int((~keep).sum()),
        mean_payload_kg=float(np.mean(p[keep])),
        payload_range_kg=_held_range(p[keep]) if b != 0.0 else None,
        top_residual=float(every[-2]),
        bottom_residual=float(every[1]),
    )


def x_of_y(exceeded: Sequence[bool], x: int, y: int) -> list[bool]:
    """The X-of-Y rule along a sequence of exceedances.

    Parameters
    ----------
    exceeded : sequence of bool
        Whether each recording exceeded, in recorded order.
    x, y : int
        At least ``x`` exceedances among the last ``y`` recordings (the
        current one included), 1 ≤ x ≤ y.

    Returns
    -------
    list of bool
        Whether the rule is met at each recording.
    """
    if not 1 <= x <= y:
        raise ValueError(f"X-of-Y needs 1 <= X <= Y, got {x} of {y}")
    flags = np.asarray(exceeded, dtype=np.int64)
    csum = np.concatenate(([0], np.cumsum(flags)))
    idx = np.arange(1, flags.shape[0] + 1)
    counts = csum[idx] - csum[np.maximum(idx - y, 0)]
    return [bool(c >= x) for c in counts]


@dataclass(frozen=True, slots=True)
class ForecastBand:
    """A forecast's path: the mean and its prediction interval at times ahead.

    Attributes
    ----------
    at : tuple of datetime
        Times, from the last value of the even series on.
    mean, lower, upper : tuple of float
        The forecast mean and the interval's ends, feature units.
    level : float
        The interval's level (0.9: 90 %).
    """

    at: tuple[datetime, ...]
    mean: tuple[float, ...]
    lower: tuple[float, ...]
    upper: tuple[float, ...]
    level: float

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: ``at`` as ISO 8601 texts."""
        return {
            "at": [t.isoformat() for t in self.at],
            "mean": list(self.mean),
            "lower": list(self.lower),
            "upper": list(self.upper),
            "level": self.level,
        }


@dataclass(frozen=True, slots=True)
class Forecast:
    """When a feature's trend crosses its limit."""

    feature: str
    limit: float
    slope_per_day: float
    crosses_at: datetime
    earliest: datetime
    latest: datetime | None
    """None when the 90 % band does not cross within the horizon."""
    crossed: bool = False
    """Already there at the last value: the alarm open (:func:`chaintwin.diagnose.
    prognosis.forecast_alarm`) or the values above the limit (:func:`chaintwin.
    diagnose.forecasting.forecast_feature`)."""
    model: str = "line"
    """The trend model: ``line`` (the rise after its change point, or a line
    fitted over time), or ``ets`` or ``arima`` where
    :func:`chaintwin.diagnose.forecasting.forecast_feature`'s backtest chose it."""
    backtest_mae: float | None = None
    """The chosen model's backtest mean absolute error, feature units."""
    last: datetime | None = None
    """When the last value was recorded (the remaining life counts from there)."""
    band: ForecastBand | None = field(default=None, compare=False, repr=False)
    """The forecast's path with its interval, for plotting (:func:`~chaintwin.diagnose.
    forecasting.forecast_feature` only, not crossed yet); not part of :meth:`to_dict`."""
    trend_since: datetime | None = None
    """Where the rise the forecast follows began (its change point,
    :func:`chaintwin.diagnose.prognosis.forecast_alarm`); None: not found."""
    threshold: float | None = None
    """The alarm rule's threshold the forecast predicts the crossing of, at the
    baseline's mean payload (the median of the last recordings', feature units;
    :func:`chaintwin.diagnose.prognosis.forecast_alarm`); None: ``limit``."""

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready; with ``remaining_life_days`` (earliest, expected, latest) from ``last``."""
        out: dict[str, Any] = {
            "feature": self.feature,
            "limit": self.limit,
            "slope_per_day": self.slope_per_day,
            "crosses_at": self.crosses_at.isoformat(),
            "earliest": self.earliest.isoformat(),
            "latest": None if self.latest is None else self.latest.isoformat(),
            "crossed": self.crossed,
            "model": self.model,
        }
        if self.backtest_mae is not None:
            out["backtest_mae"] = self.backtest_mae
        if self.trend_since is not None:
            out["trend_since"] = self.trend_since.isoformat()
        if self.threshold is not None and math.isfinite(self.threshold):
            out["threshold"] = self.threshold
        last = self.last
        if last is not None:

            def days(at: datetime | None) -> float | None:
                return None if at is None else max(0.0, (at - last).total_seconds() / 86400.0)

            out["remaining_life_days"] = {
                "earliest": days(self.earliest),
                "expected": days(self.crosses_at),
                "latest": days(self.latest),
            }
        return out


def in_days(
    times: Sequence[datetime], values: Sequence[float], min_points: int
) -> tuple[datetime, FloatArray, FloatArray] | None:
    """A feature's finite values against days since its first time.

    Returns
    -------
    (datetime, FloatArray, FloatArray) or None
        The first time, the days of the finite values since it and those
        values; None with fewer than ``min_points`` of them or no time span.
    """
    v = np.asarray(values, dtype=np.float64)
    ok = np.isfinite(v)
    if ok.sum() < min_points:
        return None
    t0 = times[0]
    t = np.array([(ti - t0).total_seconds() / 86400.0 for ti in times])[ok]
    if float(np.ptp(t)) <= 0.0:
        return None
    return t0, t, v[ok]
