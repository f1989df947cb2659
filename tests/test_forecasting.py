"""Forecasts with prediction intervals, model choice by backtest and remaining life."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

import numpy as np
import pytest

from chaintwin.diagnose.forecasting import (
    MODELS,
    WINDOW,
    backtest_errors,
    forecast_feature,
    line_slope,
    predict,
    resample_even,
)

T0 = datetime(2026, 1, 1, tzinfo=UTC)


def _times(n: int, step_days: float = 0.5) -> list[datetime]:
    return [T0 + timedelta(days=step_days * k) for k in range(n)]


def test_resample_even_means_per_step_and_fills_gaps() -> None:
    t = np.array([0.0, 0.4, 1.0, 1.2, 3.1])
    v = np.array([1.0, 3.0, 4.0, 6.0, 10.0])
    grid, series, step = resample_even(t, v, 1.0)
    assert step == 1.0
    np.testing.assert_allclose(grid, [0.5, 1.5, 2.5, 3.5])
    # step 2 is empty: interpolated between its neighbours' means (5 and 10)
    np.testing.assert_allclose(series, [2.0, 5.0, 7.5, 10.0])


def test_line_interval_is_a_prediction_interval() -> None:
    # 300 series of a line with white noise: the 90 % interval covers ~90 % of the
    # next values (the mean's confidence band would cover far fewer)
    rng = np.random.default_rng(0)
    inside = total = 0
    for _ in range(300):
        y = 1.0 + 0.01 * np.arange(40) + rng.normal(0.0, 0.05, 40)
        _mean, lower, upper = predict("line", y[:30], 10)
        inside += int(np.count_nonzero((y[30:] >= lower) & (y[30:] <= upper)))
        total += 10
    assert 0.86 <= inside / total <= 0.94


def test_a_linear_rise_is_forecast_with_its_crossing_inside_the_band() -> None:
    rng = np.random.default_rng(1)
    n = 60
    values = 1.0 + 0.01 * 0.5 * np.arange(n) + rng.normal(0.0, 0.02, n)
    fc = forecast_feature("friction", _times(n), values, 1.5)
    assert fc is not None
    truth = T0 + timedelta(days=50.0)  # 1 + 0.01·d = 1.5
    assert fc.latest is not None
    assert fc.earliest <= truth <= fc.latest
    assert abs((fc.crosses_at - truth).total_seconds()) < 5 * 86400
    assert fc.model in MODELS
    d = fc.to_dict()
    assert {"crosses_at", "earliest", "latest", "model"} <= set(d)
    life = d["remaining_life_days"]
    assert life["earliest"] <= life["expected"] <= life["latest"]
    # counted from the last value (day 29.5)
    assert life["expected"] == pytest.approx((fc.crosses_at - T0).days - 29.5, abs=1.0)


def test_the_backtest_picks_the_model_and_a_random_walk_is_not_a_line() -> None:
    rng = np.random.default_rng(1)
    n = 60
    _ = rng.normal(0.0, 0.02, n)  # the same draws as above, then the walk
    walk = 1.0 + np.cumsum(0.005 + rng.normal(0.0, 0.02, n))
    errors = backtest_errors(walk[-WINDOW:])  # the models see the last WINDOW steps
    assert set(errors) == set(MODELS)
    assert min(errors["ets"], errors["arima"]) < errors["line"]
    fc = forecast_feature("friction", _times(n), walk, float(walk[-1]) + 0.3)
    assert fc is not None
    assert fc.model == min(MODELS, key=lambda m: errors[m])
    assert fc.backtest_mae == pytest.approx(errors[fc.model])


def test_no_rising_trend_no_forecast() -> None:
    rng = np.random.default_rng(2)
    flat = 1.0 + rng.normal(0.0, 0.02, 60)
    assert forecast_feature("friction", _times(60), flat, 1.5) is None
    assert forecast_feature("friction", _times(8), flat[:8], 1.5) is None


def test_a_forecast_carries_its_band_for_plotting_beside_its_crossings() -> None:
    rng = np.random.default_rng(1)
    n = 60
    values = 1.0 + 0.01 * 0.5 * np.arange(n) + rng.normal(0.0, 0.02, n)
    fc = forecast_feature("friction", _times(n), values, 1.5)
    assert fc is not None and fc.band is not None and fc.latest is not None
    band = fc.band
    assert band.level == pytest.approx(0.9)
    assert 2 < len(band.at) <= 120
    assert list(band.at) == sorted(band.at) and band.at[0] <= _times(n)[-1] + timedelta(days=1)
    lo, mid, hi = (np.array(x) for x in (band.lower, band.mean, band.upper))
    assert np.all(lo <= mid + 1e-12) and np.all(mid <= hi + 1e-12)
    assert np.all(np.diff(hi - lo)[1:] >= -1e-9)  # the interval widens ahead
    # the band reaches its crossings: the mean at crosses_at, the upper end at earliest,
    # and it ends where its lower end reaches the limit (latest)
    at = np.array([(t - T0).total_seconds() for t in band.at])

    def when(series: np.ndarray) -> float:
        return float(at[np.flatnonzero(series >= 1.5)[0]])

    thin = float(np.max(np.diff(at)))
    for series, crossing in ((mid, fc.crosses_at), (hi, fc.earliest), (lo, fc.latest)):
        assert abs(when(series) - (crossing - T0).total_seconds()) <= thin + 1.0
    assert "band" not in fc.to_dict()  # the monitor's JSON is unchanged


def test_a_limit_crossed_says_since_when_rising_or_levelled_off() -> None:
    # flat at 1.0 for 20 days, a step to 1.3 at day 20 (recording 40), then 1.3 on:
    # levelled off, no rising trend over the last steps, yet above the 1.2 limit
    rng = np.random.default_rng(4)
    n = 70
    values = np.where(np.arange(n) < 40, 1.0, 1.3) + rng.normal(0.0, 0.01, n)
    times = _times(n)
    fc = forecast_feature("friction", times, values, 1.2)
    assert fc is not None and fc.crossed
    # when it went above to stay: the first recording above, day 20 (recording 40)
    assert fc.crosses_at == fc.earliest == fc.latest == times[40]
    assert fc.band is None
    d = fc.to_dict()
    assert d["crossed"] is True
    assert d["remaining_life_days"] == {"earliest": 0.0, "expected": 0.0, "latest": 0.0}
    # rising through the limit: crossed since the first recording of the run above it
    rise = 1.0 + 0.01 * np.arange(n)  # 1.0 + 0.01·k reaches 1.5 at recording 50
    fc = forecast_feature("friction", times, rise, 1.5)
    assert fc is not None and fc.crossed and fc.crosses_at == times[50]
    # one value above among values below is no crossing (and no trend: no forecast)
    blip = 1.0 + rng.normal(0.0, 0.01, n)
    blip[-1] = 1.3
    assert forecast_feature("friction", times, blip, 1.2) is None


def test_the_gate_s_slope_and_p_value_agree_with_statsmodels_ols() -> None:
    """The gate's least-squares line in numpy gives statsmodels' slope and p-value."""
    import statsmodels.api as sm

    rng = np.random.default_rng(7)
    for n, rise, noise in ((12, 0.02, 0.05), (30, 0.0, 0.1), (30, 0.05, 0.5), (5, -0.3, 0.2)):
        x = np.sort(rng.uniform(0.0, 20.0, n))
        y = 1.0 + rise * x + rng.normal(0.0, noise, n)
        fit = sm.OLS(y, sm.add_constant(x)).fit()
        slope, p_value = line_slope(x, y)
        assert slope == pytest.approx(float(fit.params[1]), rel=1e-9, abs=1e-12)
        assert p_value == pytest.approx(float(fit.pvalues[1]), rel=1e-7, abs=1e-12)
    # a line without noise: the slope is certain (p = 0, as statsmodels' t is infinite)
    x = np.arange(10.0)
    assert line_slope(x, 2.0 + 0.5 * x) == pytest.approx((0.5, 0.0), abs=1e-12)
    # too few points or no spread in time: no slope
    assert all(np.isnan(line_slope(np.array([1.0, 2.0]), np.array([1.0, 3.0]))))
    assert all(np.isnan(line_slope(np.full(5, 3.0), np.arange(5.0))))
