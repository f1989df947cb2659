"""When a feature's alarm will open: the rise after its change point, and the alarm rule ahead.

The truth a remaining life is judged by is the recording at which the alarm
opens; :func:`forecast_alarm` predicts that event, with the alarm rule's own
threshold and confirmation, instead of where a trend meets a single limit:

1. **Threshold per recording**: a recording exceeds when its value lies more
   than its own margin above the healthy value
   (:meth:`~chaintwin.diagnose.health.FeatureBaseline.rise_margin`: the
   z limit's scales widened for the payload's drift plus the loss-drift
   allowance, the smallest relative change, the baseline's second-largest
   rise), the one the alarm rule applies. The margins of the last recordings
   stand for those ahead (their payloads and allowances vary).
2. **Change point**: a feature stays flat until a fault begins and then
   rises. A continuous two-segment line (flat, then rising from ``tau``) is
   fitted by least squares for every ``tau`` at a recording that leaves at
   least :data:`MIN_AFTER` recordings after it (``tau`` at the first: a
   straight line). The best one is a rise only when its slope is positive
   and its F statistic against a flat line is above :data:`MIN_F` (the
   largest over all ``tau`` of white noise exceeds it in about 2 % of
   series).
3. **Trend and its uncertainty**: the line after ``tau`` (intercept and slope
   by ordinary least squares over every recording, the flat part fixing the
   level), its covariance and the residuals' scatter.
4. **The alarm rule ahead**: :data:`PATHS` futures are drawn (the line's
   parameters from their covariance, the scatter from its chi-square
   distribution, each recording's noise and margin), one recording per mean
   spacing of the recent ones; a future's alarm opens at the first recording
   where X of the last Y exceeded (the window continues the recordings' own
   exceedances). ``crosses_at`` is the median opening, ``earliest`` and
   ``latest`` its 5 % and 95 % quantiles (the 90 % band; ``latest`` None when
   more than 5 % of the futures stay quiet for the horizon). None when the
   median future stays quiet.
5. **Crossed**: when the alarm rule holds the feature's alarm open at the
   last recording (opened by X of Y, not yet Y recordings without an
   exceedance), the forecast says so, dated from the first exceedance of the
   window that opened it (as the alarm's ``since``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import datetime, timedelta
from statistics import NormalDist

import numpy as np

from chaintwin._types import FloatArray

from .forecasting import line_slope
from .health import Forecast, ForecastBand

__all__ = [
    "MIN_AFTER",
    "MIN_F",
    "MIN_POINTS",
    "PATHS",
    "RECENT",
    "Rise",
    "alarm_open",
    "fit_rise",
    "forecast_alarm",
]

MIN_POINTS = 12
"""Fewest recordings a rise is fitted to."""

MIN_AFTER = 3
"""Fewest recordings after a change point."""

MIN_F = 7.0
"""Smallest F statistic of the two-segment line against a flat one that counts as a rise
(measured: its largest over the change points exceeds it in 1.6-2.5 % of white-noise
series of 20-200 recordings, about as often as the former straight line's p < 0.05 gate
let noise through)."""

PATHS = 400
"""Futures drawn to find the alarm's opening."""

RECENT = 30
"""The last this many recordings give the margins ahead and the spacing."""

FIT_POINTS = 250
"""The rise is fitted to the last this many values (the change point search costs their
square)."""

CHUNK = 32
"""Recordings ahead drawn first; each further draw twice as many (the drawing stops
once the band is known)."""

MAX_CHUNK = 2048
"""Most recordings ahead drawn at a time (memory: paths × this)."""

BAND_POINTS = 120
"""Most points of a forecast's band kept for plotting."""


@dataclass(frozen=True, slots=True)
class Rise:
    """A two-segment line: flat until ``tau``, then rising linearly.

    Attributes
    ----------
    tau : float
        The change point of the best fit, days (the abscissa's units).
    coef : FloatArray
        Its level before ``tau`` (feature units) and slope after it (per day).
    cov : FloatArray
        Their covariance (2 × 2).
    sigma : float
        Scatter of the values about the line (feature units).
    dof : int
        Residual degrees of freedom.
    f_stat : float
        F statistic against a flat line.
    taus : FloatArray
        Every change point with a rise (k), days.
    weights : FloatArray
        How probable each is given the values (k, summing to 1: the marginal
        likelihood with flat priors on the level, the slope and the log scatter).
    coefs : FloatArray
        The fit at each (k × 2).
    covs : FloatArray
        Its covariance at each (k × 2 × 2).
    sigmas : FloatArray
        Its scatter at each (k).
    """

    tau: float
    coef: FloatArray
    cov: FloatArray
    sigma: float
    dof: int
    f_stat: float
    taus: FloatArray
    weights: FloatArray
    coefs: FloatArray
    covs: FloatArray
    sigmas: FloatArray

    def mean(self, t: FloatArray) -> FloatArray:
        """The best line at times ``t`` (days), feature units."""
        s = np.maximum(0.0, np.asarray(t, dtype=np.float64) - self.tau)
        return np.asarray(self.coef[0] + self.coef[1] * s, dtype=np.float64)

    def spread(self, t: FloatArray) -> FloatArray:
        """Standard deviation of a new value at times ``t``: the best line's and the scatter's."""
        s = np.maximum(0.0, np.asarray(t, dtype=np.float64) - self.tau)
        var = self.cov[0, 0] + 2.0 * self.cov[0, 1] * s + self.cov[1, 1] * s * s
        return np.asarray(np.sqrt(np.maximum(var, 0.0) + self.sigma**2), dtype=np.float64)


def fit_rise(t: FloatArray, y: FloatArray) -> Rise | None:
    """The two-segment lines through (t, y), if the best is a significant rise.

    Every change point is kept with its probability, so that the futures
    drawn (:func:`forecast_alarm`) carry the change point's uncertainty too.

    Parameters
    ----------
    t : FloatArray
        Times, days, ascending.
    y : FloatArray
        Finite values, feature units.

    Returns
    -------
    Rise or None
        None with fewer than :data:`MIN_POINTS` values, no spread, a slope
        not positive or an F statistic below :data:`MIN_F`.
    """
    t = np.asarray(t, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    n = t.shape[0]
    if n < MIN_POINTS:
        return None
    ybar = float(y.mean())
    yc = y - ybar
    sst = float(yc @ yc)
    if not sst > 0.0:
        return None
    taus = t[: n - MIN_AFTER]
    s = np.maximum(0.0, t[None, :] - taus[:, None])
    sbar = s.mean(axis=1)
    sc = s - sbar[:, None]
    sxx = np.einsum("ij,ij->i", sc, sc)
    sxy = sc @ yc
    keep = sxx > 0.0
    slope = np.zeros_like(sxx)
    slope[keep] = sxy[keep] / sxx[keep]
    keep &= slope > 0.0
    if not keep.any():
        return None
    taus, sbar, sxx, slope = taus[keep], sbar[keep], sxx[keep], slope[keep]
    dof = n - 2
    sse = np.maximum(sst - sxy[keep] * slope, 1e-300 * max(sst, 1.0))
    best = int(np.argmin(sse))
    f_stat = (sst - float(sse[best])) / (float(sse[best]) / dof)
    if f_stat < MIN_F:
        return None
    sigma2 = sse / dof
    intercept = ybar - slope * sbar
    var_b = sigma2 / sxx
    covs = np.empty((taus.shape[0], 2, 2))
    covs[:, 0, 0] = sigma2 / n + sbar**2 * var_b
    covs[:, 0, 1] = covs[:, 1, 0] = -sbar * var_b
    covs[:, 1, 1] = var_b
    # marginal likelihood of each change point: |X'X|^-1/2 · SSE^-(n-2)/2
    log_w = -0.5 * np.log(n * sxx) - 0.5 * dof * np.log(sse)
    w = np.exp(log_w - log_w.max())
    coefs = np.column_stack((intercept, slope))
    return Rise(
        float(taus[best]),
        coefs[best],
        covs[best],
        math.sqrt(float(sigma2[best])),
        dof,
        f_stat,
        taus,
        w / w.sum(),
        coefs,
        covs,
        np.sqrt(sigma2),
    )


def alarm_open(exceeded: Sequence[bool], x: int, y: int) -> tuple[bool, int | None]:
    """Whether the X-of-Y rule holds an alarm open after the last recording, and since when.

    The alarm opens at a recording where X of the last Y exceeded and closes
    after Y recordings without an exceedance (as the monitor's alarms).

    Returns
    -------
    (bool, int or None)
        Open, and the index of the first exceedance in the window that
        opened it (None when not open).
    """
    ex = [bool(e) for e in exceeded]
    # after y recordings without an exceedance any alarm is closed: start after the last such
    start, quiet = 0, 0
    for i in range(len(ex) - 1, -1, -1):
        quiet = 0 if ex[i] else quiet + 1
        if quiet >= y:
            start = i + y
            break
    is_open = False
    since: int | None = None
    for i in range(start, len(ex)):
        lo = max(start, i - y + 1)
        window = ex[lo : i + 1]
        if not is_open and sum(window) >= x:
            is_open = True
            since = lo + window.index(True)
        elif is_open and i + 1 >= y and not any(ex[max(0, i - y + 1) : i + 1]):
            is_open, since = False, None
    return is_open, since


def _openings(
    rise: Rise,
    t_last: float,
    step: float,
    steps: int,
    healthy: float,
    margins: FloatArray,
    carried: Sequence[bool],
    x: int,
    y: int,
    level: float,
    rng: np.random.Generator,
) -> FloatArray:
    """The recordings ahead at which each drawn future's alarm opens (inf: not within)."""
    pick = rng.choice(rise.taus.shape[0], size=PATHS, p=rise.weights)
    tau = rise.taus[pick]
    cov = rise.covs[pick]
    # the level and slope drawn from each change point's fit (2 × 2 Cholesky by hand)
    l00 = np.sqrt(np.maximum(cov[:, 0, 0], 0.0))
    l10 = np.where(l00 > 0.0, cov[:, 1, 0] / np.where(l00 > 0.0, l00, 1.0), 0.0)
    l11 = np.sqrt(np.maximum(cov[:, 1, 1] - l10**2, 0.0))
    z = rng.standard_normal((PATHS, 2))
    coef = rise.coefs[pick].copy()
    coef[:, 0] += l00 * z[:, 0]
    coef[:, 1] += l10 * z[:, 0] + l11 * z[:, 1]
    sigma = rise.sigmas[pick] * np.sqrt(rise.dof / rng.chisquare(rise.dof, PATHS))
    flags = np.zeros((PATHS, y - 1), dtype=np.int64)
    tail = [bool(e) for e in carried][-(y - 1) :] if y > 1 else []
    if tail:
        flags[:, -len(tail) :] = np.asarray(tail, dtype=np.int64)
    opened = np.full(PATHS, np.inf)
    done = 0
    chunk = CHUNK
    while done < steps:
        j = np.arange(done + 1, min(steps, done + chunk) + 1, dtype=np.float64)
        chunk = min(2 * chunk, MAX_CHUNK)
        s = np.maximum(0.0, (t_last + j * step)[None, :] - tau[:, None])
        values = coef[:, :1] + coef[:, 1:] * s
        values += sigma[:, None] * rng.standard_normal((PATHS, j.shape[0]))
        limit = healthy + margins[rng.integers(0, margins.shape[0], (PATHS, j.shape[0]))]
        ex = np.concatenate((flags, (values > limit).astype(np.int64)), axis=1)
        csum = np.concatenate((np.zeros((PATHS, 1), dtype=np.int64), np.cumsum(ex, axis=1)), 1)
        counts = csum[:, y:] - csum[:, :-y] if y > 1 else csum[:, 1:] - csum[:, :-1]
        counts = counts[:, -j.shape[0] :]
        met = counts >= x
        first = np.where(met.any(axis=1), np.argmax(met, axis=1), -1)
        new = np.isinf(opened) & (first >= 0)
        opened[new] = j[first[new]]
        flags = ex[:, -(y - 1) :] if y > 1 else flags
        done = int(j[-1])
        if np.mean(np.isfinite(opened)) >= 0.5 + 0.5 * level:
            break
    return opened


def forecast_alarm(
    feature: str,
    times: Sequence[datetime],
    values: Sequence[float],
    margins: Sequence[float],
    exceeded: Sequence[bool],
    healthy: float,
    *,
    x: int = 3,
    y: int = 10,
    horizon_days: float = 365.0,
    level: float = 0.9,
    seed: int = 0,
    trend: Rise | None = None,
    limit: float | None = None,
) -> Forecast | None:
    """Forecast when a feature's alarm opens: its rise after the change point, the rule ahead.

    See the module notes.

    Parameters
    ----------
    feature : str
        Name, for the result.
    times : sequence of datetime
        When each recording was made, ascending.
    values : sequence of float
        The feature at the baseline's mean payload (NaN: unknown), feature units.
    margins : sequence of float
        How far above ``healthy`` the last recordings' values had to lie to
        exceed (:meth:`~chaintwin.diagnose.health.FeatureBaseline.rise_margin`,
        NaN: unknown; the last :data:`RECENT` are used), feature units.
    exceeded : sequence of bool
        Whether each recording exceeded on the feature (the alarm rule's own
        judgement, for the window ahead and whether the alarm is open).
    healthy : float
        The baseline's value at its mean payload, feature units.
    x, y : int
        The X-of-Y rule.
    horizon_days : float
        How far ahead to look from the last recording, days.
    level : float
        The band's level (0.9: ``earliest`` and ``latest`` are the 5 % and
        95 % quantiles of the opening).
    seed : int
        Of the drawn futures (the same answer for the same recordings).
    trend : Rise, optional
        The rise to draw the futures from instead of the one fitted to
        ``values`` (:func:`fit_rise` over other recordings: the evaluation's
        forecast with the trend known in hindsight).
    limit : float, optional
        The limit to report as the forecast's ``limit`` (the baseline's at its
        mean payload, as the trends show it); default the median threshold.

    Returns
    -------
    Forecast or None
        ``threshold`` is the median threshold of the last recordings (feature
        units at the mean payload), ``model`` ``line`` with ``trend_since``
        the change point; ``crossed`` with ``earliest`` = ``latest`` =
        ``crosses_at`` when the alarm is open. None without a significant
        rise (unless open), or when the median future opens no alarm within
        the horizon.
    """
    if len(times) < 2:
        return None
    t0 = times[0]
    day = timedelta(days=1)
    t_all = np.array([(ti - t0).total_seconds() / 86400.0 for ti in times])
    v = np.asarray(values, dtype=np.float64)
    m = np.asarray(margins, dtype=np.float64)
    ok = np.isfinite(v)
    if ok.sum() < MIN_POINTS or float(np.ptp(t_all)) <= 0.0:
        return None
    is_open, since = alarm_open(list(exceeded), x, y)
    recent_m = m[-RECENT:][np.isfinite(m[-RECENT:])]
    threshold = healthy + float(np.median(recent_m)) if recent_m.size else math.nan
    limit = threshold if limit is None else limit
    last = t0 + float(t_all[-1]) * day
    if is_open and since is not None:
        at = t0 + float(t_all[since]) * day
        # the straight line over the last recordings (0 when it cannot be fitted)
        slope, _ = line_slope(t_all[ok][-RECENT:], v[ok][-RECENT:])
        slope = slope if math.isfinite(slope) else 0.0
        return Forecast(
            feature, limit, slope, at, at, at, True, "line", None, last, threshold=threshold
        )
    if not recent_m.size:
        return None
    rise = fit_rise(t_all[ok][-FIT_POINTS:], v[ok][-FIT_POINTS:]) if trend is None else trend
    if rise is None:
        return None
    recent_t = t_all[-RECENT:]
    step = float(recent_t[-1] - recent_t[0]) / max(recent_t.shape[0] - 1, 1)
    if not step > 0.0:
        return None
    steps = max(1, math.ceil(horizon_days / step))
    rng = np.random.default_rng(seed)
    opened = _openings(
        rise, float(t_all[-1]), step, steps, healthy, recent_m, list(exceeded), x, y, level, rng
    )
    lo_q, hi_q = 0.5 - 0.5 * level, 0.5 + 0.5 * level
    # quantiles that are drawn openings (recordings), no interpolation with "never"
    mid, lo, hi = (float(q) for q in np.quantile(opened, [0.5, lo_q, hi_q], method="inverted_cdf"))
    if not math.isfinite(mid):
        return None
    tl = float(t_all[-1])
    crosses = tl + mid * step
    earliest = tl + lo * step
    latest = tl + hi * step if math.isfinite(hi) else None
    stop = latest if latest is not None else tl + 2.0 * (crosses - tl)
    ahead = np.linspace(tl, stop, BAND_POINTS)
    mean = rise.mean(ahead)
    half = _z(level) * rise.spread(ahead)
    band = ForecastBand(
        at=tuple(t0 + float(d) * day for d in ahead),
        mean=tuple(float(a) for a in mean),
        lower=tuple(float(a) for a in mean - half),
        upper=tuple(float(a) for a in mean + half),
        level=level,
    )
    return Forecast(
        feature=feature,
        limit=limit,
        slope_per_day=float(rise.coef[1]),
        crosses_at=t0 + crosses * day,
        earliest=t0 + earliest * day,
        latest=None if latest is None else t0 + latest * day,
        crossed=False,
        model="line",
        backtest_mae=None,
        last=last,
        band=band,
        trend_since=t0 + rise.tau * day,
        threshold=threshold,
    )


def _z(level: float) -> float:
    """The standard normal quantile of a two-sided ``level``."""
    return NormalDist().inv_cdf(0.5 + 0.5 * level)
