"""Forecasts of a rising feature with prediction intervals and a remaining-life band.

A straight line with the confidence band of its *mean* says where the trend
is, not where the next values will be. :func:`forecast_feature`, the one
forecasting path (the monitor's, the library's), forecasts the values:

1. **Gate**: a forecast is made only for a rising trend, the straight line's
   slope positive with p < 0.01 (as before), so noise is not extrapolated.
2. **Even time step**: the feature is resampled to an even step (the mean
   spacing of its recordings; the mean of the values in each step, empty
   steps interpolated), which ARIMA and ETS need.
3. **Models**: ``line`` (ordinary least squares on time, its prediction
   interval), ``ets`` (additive-error, additive-trend exponential smoothing,
   statsmodels ``ETSModel``) and ``arima`` (ARIMA(0,1,1) with drift).
4. **Choice by backtest**: each model is refitted at :data:`BACKTEST_ORIGINS`
   earlier origins and forecasts :data:`BACKTEST_STEPS` steps ahead; the model
   with the smallest mean absolute error of those forecasts is used (not an
   information criterion, which cannot compare models with different
   differencing).
5. **Crossing and remaining life**: ``crosses_at`` is where the forecast mean
   reaches the limit, ``earliest`` where the upper end of the 90 % prediction
   interval does, ``latest`` where its lower end does (None when it does not
   within the horizon). The remaining useful life is the band from the last
   value to ``earliest`` .. ``latest``.
6. **Crossed**: once the values are above the limit (the alarm open), the
   forecast says so, with when they went above it to stay, instead of a
   crossing time ahead; it stays while they are above, whether still rising
   or levelled off.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from datetime import datetime, timedelta
from typing import Literal

import numpy as np

from chaintwin._types import FloatArray

from .health import Forecast, ForecastBand, in_days

__all__ = [
    "BACKTEST_ORIGINS",
    "BACKTEST_STEPS",
    "MODELS",
    "WINDOW",
    "ModelName",
    "backtest_errors",
    "forecast_feature",
    "forecast_path",
    "line_slope",
    "predict",
    "resample_even",
]

ModelName = Literal["line", "ets", "arima"]
MODELS: tuple[ModelName, ...] = ("line", "ets", "arima")
"""The forecasting models, in the order ties are broken."""

BACKTEST_ORIGINS = 4
"""How many earlier origins the models are backtested from."""

BACKTEST_STEPS = 5
"""How many steps ahead each backtest forecasts."""

MIN_POINTS = 12
"""Fewest even-step values a model is fitted to."""

MAX_P_VALUE = 0.05
"""Largest p-value of the straight line's slope that counts as a rising trend."""

WINDOW = 30
"""The models see the last this many even steps (a fault's rise, not the years before it)."""

BAND_POINTS = 120
"""Most points of a forecast's band kept for plotting."""


def resample_even(
    t_days: FloatArray, values: FloatArray, step_days: float | None = None
) -> tuple[FloatArray, FloatArray, float]:
    """A feature at an even time step: the mean per step, empty steps interpolated.

    Parameters
    ----------
    t_days : FloatArray
        Times, days, ascending.
    values : FloatArray
        Finite values, feature units.
    step_days : float, optional
        The step; default the mean spacing of the times (their span over the
        number of gaps), so that recordings bunched in working hours do not
        leave most steps empty.

    Returns
    -------
    grid : FloatArray
        Step centres, days.
    series : FloatArray
        The values at the even step.
    step : float
        The step used, days.
    """
    t = np.asarray(t_days, dtype=np.float64)
    v = np.asarray(values, dtype=np.float64)
    if step_days is None:
        # the mean spacing: recordings bunched in working hours leave few empty steps
        span = float(t[-1] - t[0])
        step_days = span / (t.shape[0] - 1) if t.shape[0] > 1 and span > 0.0 else 1.0
    step = float(step_days)
    idx = np.floor((t - t[0]) / step + 1e-9).astype(np.int64)
    n = int(idx[-1]) + 1
    sums = np.bincount(idx, weights=v, minlength=n)
    counts = np.bincount(idx, minlength=n)
    grid = t[0] + (np.arange(n) + 0.5) * step
    have = counts > 0
    series = np.interp(grid, grid[have], sums[have] / counts[have])
    return grid, series, step


def predict(
    model: ModelName, y: FloatArray, steps: int, alpha: float = 0.1
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Mean and (1 − alpha) prediction interval ``steps`` ahead of an even series.

    Returns
    -------
    mean, lower, upper : FloatArray
        One value per step ahead, feature units.
    """
    # imported here, and not statsmodels.api (half a second more): statsmodels
    # and pandas cost over a second to import, paid only by a refit with a
    # feature whose trend rises
    from statsmodels.regression.linear_model import OLS
    from statsmodels.tools.tools import add_constant

    y = np.asarray(y, dtype=np.float64)
    n = y.shape[0]
    with warnings.catch_warnings():
        # convergence and frequency chatter of statsmodels: the backtest judges the fit
        warnings.simplefilter("ignore")
        if model == "line":
            x = np.arange(n, dtype=np.float64)
            fit = OLS(y, add_constant(x)).fit()
            ahead = np.arange(n, n + steps, dtype=np.float64)
            frame = fit.get_prediction(add_constant(ahead, has_constant="add")).summary_frame(
                alpha=alpha
            )
            return (
                frame["mean"].to_numpy(),
                frame["obs_ci_lower"].to_numpy(),
                frame["obs_ci_upper"].to_numpy(),
            )
        if model == "ets":
            import pandas as pd
            from statsmodels.tsa.exponential_smoothing.ets import ETSModel

            res = ETSModel(pd.Series(y), error="add", trend="add").fit(disp=False)
            frame = res.get_prediction(start=n, end=n + steps - 1).summary_frame(alpha=alpha)
            return (
                frame["mean"].to_numpy(),
                frame["pi_lower"].to_numpy(),
                frame["pi_upper"].to_numpy(),
            )
        from statsmodels.tsa.arima.model import ARIMA

        arima = ARIMA(y, order=(0, 1, 1), trend="t").fit()
        fc = arima.get_forecast(steps)
        ci = np.asarray(fc.conf_int(alpha=alpha))
        return np.asarray(fc.predicted_mean), ci[:, 0], ci[:, 1]


def _backtest(y: FloatArray, model: ModelName, origins: int, steps: int) -> FloatArray:
    """Signed errors (forecast − actual) from earlier origins: origins × steps (NaN: failed)."""
    n = y.shape[0]
    ends = [n - steps * (k + 1) for k in range(origins)]
    ends = [e for e in ends if e >= MIN_POINTS]
    out = np.full((len(ends), steps), np.nan)
    for row, end in enumerate(ends):
        try:
            mean, _, _ = predict(model, y[:end], steps)
        except (ValueError, np.linalg.LinAlgError):
            continue
        out[row] = mean - y[end : end + steps]
    return out


def backtest_errors(
    y: FloatArray,
    models: Sequence[ModelName] = MODELS,
    *,
    origins: int = BACKTEST_ORIGINS,
    steps: int = BACKTEST_STEPS,
) -> dict[str, float]:
    """Mean absolute error of each model's forecasts from earlier origins.

    The origins are the last ``origins`` points that leave ``steps`` values
    after them (spaced by ``steps``); a model that fails to fit there gets an
    infinite error.
    """
    y = np.asarray(y, dtype=np.float64)
    out: dict[str, float] = {}
    for model in models:
        err = _backtest(y, model, origins, steps)
        out[model] = (
            float(np.mean(np.abs(err))) if err.size and np.all(np.isfinite(err)) else math.inf
        )
    return out


def forecast_path(
    series: FloatArray,
    steps: int,
    alpha: float = 0.1,
    models: Sequence[ModelName] = MODELS,
) -> tuple[ModelName, float, FloatArray, FloatArray, FloatArray]:
    """The backtest's model and its forecast of an even series, interval widened by the backtest.

    The series' last :data:`WINDOW` values are used. The model with the
    smallest backtest error forecasts ``steps`` ahead; its (1 − alpha)
    prediction interval is widened, where narrower, to the (1 − alpha)
    quantile of the backtest's absolute errors (scaled with the square root
    of the step ahead over the backtest's mean step): a model's own interval
    assumes its errors white, which a feature's daily temperature cycle and
    its steps are not.

    Returns
    -------
    model : str
    mae : float
        Its backtest mean absolute error.
    mean, lower, upper : FloatArray
        Per step ahead.

    Raises
    ------
    ValueError
        When no model fits.
    """
    y = np.asarray(series, dtype=np.float64)[-WINDOW:]
    errs = {m: _backtest(y, m, BACKTEST_ORIGINS, BACKTEST_STEPS) for m in models}
    mae = {
        m: float(np.mean(np.abs(e))) if e.size and np.all(np.isfinite(e)) else math.inf
        for m, e in errs.items()
    }
    model = min(models, key=lambda m: (mae[m], models.index(m)))
    mean, lower, upper = predict(model, y, steps, alpha)
    e = errs[model]
    if e.size and np.all(np.isfinite(e)):
        q = float(np.quantile(np.abs(e), 1.0 - alpha))
        h = np.arange(1, steps + 1, dtype=np.float64)
        half = q * np.sqrt(h / (0.5 * (BACKTEST_STEPS + 1)))
        lower = np.minimum(lower, mean - half)
        upper = np.maximum(upper, mean + half)
    return model, mae[model], mean, lower, upper


def line_slope(x: FloatArray, y: FloatArray) -> tuple[float, float]:
    """Slope of the least-squares straight line through (x, y) and its two-sided p-value.

    Ordinary least squares with an intercept, the p-value from Student's t
    with n − 2 degrees of freedom (as statsmodels' ``OLS(...).fit().pvalues``
    gives it), in numpy: the gate runs for every feature of every refit,
    and most features never reach a model, so statsmodels (over a second to
    import) is imported only when one does.

    Parameters
    ----------
    x : FloatArray
        Abscissae (days).
    y : FloatArray
        Ordinates (feature units).

    Returns
    -------
    slope : float
        y units per x unit (NaN with fewer than 3 points or no spread of x).
    p_value : float
        Of the slope being zero (NaN when the slope is).
    """
    from scipy.special import stdtr

    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    n = x.shape[0]
    if n < 3:
        return math.nan, math.nan
    dx = x - x.mean()
    sxx = float(dx @ dx)
    if not sxx > 0.0:
        return math.nan, math.nan
    slope = float(dx @ (y - y.mean())) / sxx
    resid = y - y.mean() - slope * dx
    se = math.sqrt(float(resid @ resid) / (n - 2) / sxx)
    with np.errstate(divide="ignore", invalid="ignore"):
        t_value = np.float64(abs(slope)) / np.float64(se)
    return slope, float(2.0 * stdtr(n - 2, -t_value))


def _first_cross(t: FloatArray, series: FloatArray, limit: float) -> float | None:
    hit = np.flatnonzero(series >= limit)
    return float(t[hit[0]]) if hit.size else None


def _since(above: np.ndarray) -> int:
    """Index of the first of the trailing run of True values (``above[-1]`` is True)."""
    below = np.flatnonzero(~above)
    return int(below[-1]) + 1 if below.size else 0


def forecast_feature(
    feature: str,
    times: Sequence[datetime],
    values: Sequence[float],
    limit: float,
    *,
    horizon_days: float = 365.0,
    alpha: float = 0.1,
    models: Sequence[ModelName] = MODELS,
) -> Forecast | None:
    """Forecast when a rising feature's values reach a limit, with the model its backtest picks.

    See the module notes. ``crosses_at``, ``earliest`` and ``latest`` are
    the crossings of the forecast mean and of the upper and lower end of the
    (1 − ``alpha``) prediction interval; ``model`` names the model chosen and
    ``backtest_mae`` its backtest error.

    Parameters
    ----------
    feature : str
        Name, for the result.
    times : sequence of datetime
        When each value was recorded, ascending.
    values : sequence of float
        The feature (NaN values are left out).
    limit : float
        The alarm limit, feature units.
    horizon_days : float
        How far ahead to look from the last value, days.
    alpha : float
        1 − the prediction interval's level.
    models : sequence of str
        Candidate models.

    Returns
    -------
    Forecast or None
        None without a significant rising trend, with too few values, or
        when the forecast mean does not reach the limit within the horizon.
        A limit already crossed (the last even step above it, and the trend
        rising or the last :data:`BACKTEST_STEPS` steps all above it) is a
        forecast with ``crossed`` True whose times are when the values went
        above the limit to stay (the first recording of the even step that
        began the run above it), ``model`` ``line`` (no model forecasts) and a
        remaining life of zero.
    """
    days = in_days(times, values, MIN_POINTS)
    if days is None:
        return None
    t0, t, v = days
    grid, series, step = resample_even(t, v)
    if series.shape[0] < MIN_POINTS:
        return None
    # the gate: a rising straight line over the values the models see
    recent = t >= grid[-WINDOW:][0] - 0.5 * step
    slope, p_value = line_slope(t[recent], v[recent])
    rising = slope > 0.0 and p_value < MAX_P_VALUE
    day = timedelta(days=1)
    above = series >= limit
    if above[-1] and (rising or bool(np.all(above[-BACKTEST_STEPS:]))):
        # already there (rising, or above for several steps however it got
        # there): since the start of the steps above the limit that reach the
        # last one; no model is needed
        start = float(grid[_since(above)]) - 0.5 * step
        at = t0 + float(t[np.searchsorted(t, start - 1e-9 * step)]) * day
        last = t0 + float(t[-1]) * day
        return Forecast(feature, limit, slope, at, at, at, True, "line", None, last)
    if not rising:
        return None
    steps = max(1, math.ceil(horizon_days / step))
    try:
        model, mae, mean, lower, upper = forecast_path(series, steps, alpha, models)
    except (ValueError, np.linalg.LinAlgError):
        return None
    ahead = grid[-1] + step * np.arange(1, steps + 1)
    cross = _first_cross(ahead, mean, limit)
    if cross is None:
        return None
    earliest = _first_cross(ahead, upper, limit)
    latest = _first_cross(ahead, lower, limit)
    # the band to where its lower end crosses too (or to twice the mean's crossing)
    stop = latest if latest is not None else grid[-1] + 2.0 * (cross - grid[-1])
    keep = ahead <= stop + step
    days_ahead = np.concatenate(([grid[-1]], ahead[keep]))
    paths = [np.concatenate(([series[-1]], p[keep])) for p in (mean, lower, upper)]
    n_band = days_ahead.shape[0]
    k = np.unique(np.linspace(0, n_band - 1, min(BAND_POINTS, n_band)).round()).astype(np.int64)
    band = ForecastBand(
        at=tuple(t0 + float(d) * day for d in days_ahead[k]),
        mean=tuple(float(v) for v in paths[0][k]),
        lower=tuple(float(v) for v in paths[1][k]),
        upper=tuple(float(v) for v in paths[2][k]),
        level=1.0 - alpha,
    )
    return Forecast(
        feature=feature,
        limit=limit,
        slope_per_day=slope,
        crosses_at=t0 + cross * day,
        earliest=t0 + (earliest if earliest is not None else cross) * day,
        latest=None if latest is None else t0 + latest * day,
        crossed=False,
        model=model,
        backtest_mae=mae,
        last=t0 + float(t[-1]) * day,
        band=band,
    )
