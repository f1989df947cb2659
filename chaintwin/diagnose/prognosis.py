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
   level), its covariance and the residuals' scatter; beside it a curved rise
   (:func:`fit_curve`: flat, then ``a + b·s + c·s²`` with ``c > 0``, every
   change point weighed alike), the two weighed by their Akaike weights
   (AICc). **Model error**: the rise's own out-of-sample check
   (:func:`model_error`: fitted without the last third of the recordings
   since the change point, how far it missed their mean against the
   uncertainty it claimed) widens the covariances when it missed by more;
   the scatter since the change point, when larger than over all the values,
   widens the futures' noise.
4. **The alarm rule ahead**: :data:`PATHS` futures are drawn (the line's
   parameters from their covariance, the scatter from its chi-square
   distribution, each recording's noise and margin; with a curve, half of
   them from the curve), one recording per mean spacing of the recent ones;
   a future's alarm opens at the first recording where X of the last Y
   exceedances counted (the window continues the recordings' exceedances as
   the monitor counted them, :func:`counted`; a future recording's
   exceedance counts as the monitor will count it, :func:`window_counts`:
   beside another where it needs a neighbour's confirmation, as often as
   the last :data:`RECENT` recordings needed one).
   ``crosses_at`` is the median opening (the models' futures weighed by their
   weights), ``earliest`` the earliest of the models' 5 % quantiles and
   ``latest`` the latest of their 95 % quantiles (the 90 % band holds the
   futures of whichever model is right; ``latest`` None when more than 5 %
   of a model's futures stay quiet for the horizon). None when the median
   future stays quiet.
5. **Crossed**: when the alarm rule holds the feature's alarm open at the
   last recording (opened by X of Y counted exceedances, not yet Y
   recordings without one: the monitor's alarm is open), the forecast says
   so, dated from the first exceedance of the window that opened it (as the
   alarm's ``since``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from datetime import datetime, timedelta
from statistics import NormalDist

import numpy as np

from chaintwin._types import BoolArray, FloatArray, IntArray

from .confirmation import count_exceedance
from .forecasting import line_slope
from .health import Forecast, ForecastBand

__all__ = [
    "HELD_OUT",
    "MAX_STEPS",
    "MIN_AFTER",
    "MIN_F",
    "MIN_POINTS",
    "NOISE_AFTER",
    "PATHS",
    "RECENT",
    "Counted",
    "Curve",
    "Rise",
    "alarm_open",
    "counted",
    "fit_curve",
    "fit_rise",
    "forecast_alarm",
    "model_error",
    "window_counts",
]

MIN_POINTS = 12
"""Fewest recordings a rise is fitted to."""

MAX_STEPS = 20_000
"""Most future recordings a future is drawn over: where the horizon holds more (recordings
closer than 26 minutes over a year), every ``k``-th is drawn and the alarm rule applied to
those, so that a slow rise costs at most this many steps per future (a forecast of a
rise opening in 200 days at one recording every 25 s took 4.6 CPU s without it, 0.14 s
with it). The opening then comes a little late (fewer chances for X of Y among the drawn
recordings: 3 % of the time ahead with every 18th drawn)."""

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

NOISE_AFTER = 6
"""Fewest recordings since the change point whose scatter widens the futures' noise."""

HELD_OUT = (1.0 / 3.0,)
"""Shares of the recordings since the change point left out, each in turn, to check the
rise's forecast of them (:func:`model_error`)."""

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
    curve : Curve or None
        The curved rise fitted beside the line (None: none rising faster).
    curve_weight : float
        How much the curve is to be believed against the line (their Akaike
        weights, 0 without a curve).
    inflation : float
        The factor (1 or more) the covariances above were widened by for the
        rise's model error (:func:`model_error`).
    noise_ratio : float
        How much larger the scatter is since the change point than over all
        the values (1 or more): the futures' noise is widened by it.
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
    curve: Curve | None = None
    curve_weight: float = 0.0
    inflation: float = 1.0
    noise_ratio: float = 1.0

    def mean(self, t: FloatArray) -> FloatArray:
        """The expected value at times ``t`` (days): the best line's and curve's by their weights.

        Feature units.
        """
        s = np.maximum(0.0, np.asarray(t, dtype=np.float64) - self.tau)
        line = self.coef[0] + self.coef[1] * s
        if self.curve is None:
            return np.asarray(line, dtype=np.float64)
        w = self.curve_weight
        return np.asarray((1.0 - w) * line + w * self.curve.mean(t), dtype=np.float64)

    def spread(self, t: FloatArray) -> FloatArray:
        """Standard deviation of a new value at times ``t``, feature units.

        The best line's and the scatter's; with a curve, the mixture's (each
        model's own spread and the distance between them).
        """
        s = np.maximum(0.0, np.asarray(t, dtype=np.float64) - self.tau)
        var = self.cov[0, 0] + 2.0 * self.cov[0, 1] * s + self.cov[1, 1] * s * s
        var = np.maximum(var, 0.0) + self.sigma**2
        if self.curve is not None:
            w = self.curve_weight
            line = self.coef[0] + self.coef[1] * s
            curve = self.curve.mean(t)
            var = (
                (1.0 - w) * var
                + w * self.curve.spread(t) ** 2
                + w * (1.0 - w) * (curve - line) ** 2
            )
        return np.asarray(np.sqrt(var), dtype=np.float64)


@dataclass(frozen=True, slots=True)
class Curve:
    """A flat-then-curved rise: flat until ``tau``, then ``a + b·s + c·s²`` (s days since ``tau``).

    Attributes
    ----------
    tau : float
        The change point of the best fit, days.
    coef : FloatArray
        Its level (feature units), slope (per day) and curvature (per day²).
    cov : FloatArray
        Their covariance (3 × 3).
    sigma : float
        Scatter of the values about the curve (feature units).
    dof : int
        Residual degrees of freedom.
    taus, weights, coefs, covs, sigmas : FloatArray
        Every change point with a curve rising ever faster (k), its
        probability given the values (as :class:`Rise`'s), fit (k × 3),
        covariance (k × 3 × 3) and scatter (k).
    """

    tau: float
    coef: FloatArray
    cov: FloatArray
    sigma: float
    dof: int
    taus: FloatArray
    weights: FloatArray
    coefs: FloatArray
    covs: FloatArray
    sigmas: FloatArray

    def mean(self, t: FloatArray) -> FloatArray:
        """The best curve at times ``t`` (days), feature units."""
        s = np.maximum(0.0, np.asarray(t, dtype=np.float64) - self.tau)
        return np.asarray(self.coef[0] + self.coef[1] * s + self.coef[2] * s * s, dtype=np.float64)

    def spread(self, t: FloatArray) -> FloatArray:
        """Standard deviation of a new value at times ``t``: the best curve's and the scatter's."""
        s = np.maximum(0.0, np.asarray(t, dtype=np.float64) - self.tau)
        x = np.stack((np.ones_like(s), s, s * s), axis=-1)
        var = np.einsum("...i,ij,...j->...", x, self.cov, x)
        return np.asarray(np.sqrt(np.maximum(var, 0.0) + self.sigma**2), dtype=np.float64)


def _aicc(sse: float, n: int, k: int) -> float:
    """The corrected Akaike information criterion of a least-squares fit with ``k`` parameters."""
    return n * math.log(sse / n) + 2.0 * k + 2.0 * k * (k + 1) / max(n - k - 1, 1)


def _centred(
    t: FloatArray, y: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray, float] | None:
    """``t`` and ``y`` as float arrays, ``y`` less its mean and its sum of squares about it.

    None with fewer than :data:`MIN_POINTS` values or no spread (no rise to fit).
    """
    t = np.asarray(t, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    if t.shape[0] < MIN_POINTS:
        return None
    yc = y - float(y.mean())
    sst = float(yc @ yc)
    if not sst > 0.0:
        return None
    return t, y, yc, sst


def fit_curve(t: FloatArray, y: FloatArray) -> Curve | None:
    """The flat-then-curved rises through (t, y) at every change point, if any rises ever faster.

    Parameters
    ----------
    t : FloatArray
        Times, days, ascending.
    y : FloatArray
        Finite values, feature units.

    Returns
    -------
    Curve or None
        Over the change points that leave at least :data:`MIN_AFTER` + 1
        recordings after them and give a positive curvature; None when there
        are none (or fewer than :data:`MIN_POINTS` values).
    """
    centred = _centred(t, y)
    if centred is None:
        return None
    t, y, yc, sst = centred
    n = t.shape[0]
    taus = t[: n - MIN_AFTER - 1]
    s = np.maximum(0.0, t[None, :] - taus[:, None])
    s2 = s * s
    gram = np.empty((taus.shape[0], 3, 3))
    gram[:, 0, 0] = n
    gram[:, 0, 1] = gram[:, 1, 0] = s.sum(axis=1)
    gram[:, 0, 2] = gram[:, 2, 0] = gram[:, 1, 1] = s2.sum(axis=1)
    gram[:, 1, 2] = gram[:, 2, 1] = np.einsum("ij,ij->i", s2, s)
    gram[:, 2, 2] = np.einsum("ij,ij->i", s2, s2)
    rhs = np.column_stack((np.full(taus.shape[0], yc.sum()), s @ yc, s2 @ yc))
    det = np.linalg.det(gram)
    keep = det > 1e-12 * np.maximum(gram[:, 2, 2] * gram[:, 1, 1] * n, 1e-300)
    if not keep.any():
        return None
    taus, gram, rhs, det = taus[keep], gram[keep], rhs[keep], det[keep]
    inv = np.linalg.inv(gram)
    beta = np.einsum("kij,kj->ki", inv, rhs)
    keep = beta[:, 2] > 0.0
    if not keep.any():
        return None
    taus, inv, rhs, det, beta = taus[keep], inv[keep], rhs[keep], det[keep], beta[keep]
    dof = n - 3
    sse = np.maximum(sst - np.einsum("ki,ki->k", beta, rhs), 1e-300 * max(sst, 1.0))
    sigma2 = sse / dof
    log_w = -0.5 * np.log(det) - 0.5 * dof * np.log(sse)
    w = np.exp(log_w - log_w.max())
    coefs = beta.copy()
    coefs[:, 0] += float(y.mean())
    covs = inv * sigma2[:, None, None]
    best = int(np.argmin(sse))
    return Curve(
        float(taus[best]),
        coefs[best],
        covs[best],
        math.sqrt(float(sigma2[best])),
        dof,
        taus,
        w / w.sum(),
        coefs,
        covs,
        np.sqrt(sigma2),
    )


def fit_rise(t: FloatArray, y: FloatArray, *, curved: bool = True) -> Rise | None:
    """The two-segment lines through (t, y), if the best is a significant rise.

    Every change point is kept with its probability, so that the futures
    drawn (:func:`forecast_alarm`) carry the change point's uncertainty too.

    Parameters
    ----------
    t : FloatArray
        Times, days, ascending.
    y : FloatArray
        Finite values, feature units.
    curved : bool
        Fit the curved rise beside the line (:func:`fit_curve`) and weigh
        the two by their Akaike weights.

    Returns
    -------
    Rise or None
        None with fewer than :data:`MIN_POINTS` values, no spread, a slope
        not positive or an F statistic below :data:`MIN_F`.
    """
    centred = _centred(t, y)
    if centred is None:
        return None
    t, y, yc, sst = centred
    n = t.shape[0]
    ybar = float(y.mean())
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
    curve = fit_curve(t, y) if curved else None
    curve_weight = 0.0
    if curve is not None:
        sse_curve = float(curve.sigmas.min()) ** 2 * curve.dof
        gap = _aicc(sse_curve, n, 5) - _aicc(float(sse[best]), n, 4)
        curve_weight = 1.0 / (1.0 + math.exp(min(gap / 2.0, 700.0)))
    inflation = noise_ratio = 1.0
    if curved:
        inflation = model_error(t, y, float(taus[best]), curve, curve_weight)
        noise_ratio = _noise_after(t, y, float(taus[best]), coefs[best], float(sigma2[best]))
        covs = covs * inflation
        if curve is not None:
            curve = replace(curve, cov=curve.cov * inflation, covs=curve.covs * inflation)
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
        curve,
        curve_weight,
        inflation,
        noise_ratio,
    )


def _noise_after(
    t: FloatArray, y: FloatArray, tau: float, coef: FloatArray, sigma2: float
) -> float:
    """The scatter about the line since ``tau`` over the scatter over all values (1 or more).

    A feature often scatters more as its fault grows; the scatter of the
    healthy recordings would draw the futures too calm. With fewer than
    :data:`NOISE_AFTER` recordings since ``tau``: 1.
    """
    after = t > tau
    m = int(np.count_nonzero(after))
    if m < NOISE_AFTER or not sigma2 > 0.0:
        return 1.0
    r = y[after] - (coef[0] + coef[1] * (t[after] - tau))
    return max(1.0, math.sqrt(float(r @ r) / (m - 2) / sigma2))


def _held_out(
    t: FloatArray, y: FloatArray, tau: float, cut: int, degree: int
) -> tuple[float, float] | None:
    """The mean of the values from ``cut`` on as a rise fitted before it predicts it.

    The rise is flat until ``tau`` and then a polynomial of ``degree`` in the
    time since; fitted to the values before ``cut``. Returns the predicted
    mean and its variance (the fit's and the scatter's), or None when the
    values before ``cut`` cannot fix the fit.
    """
    s = np.maximum(0.0, t - tau)
    x = np.vander(s, degree + 1, increasing=True)
    fit_x, fit_y = x[:cut], y[:cut]
    dof = cut - degree - 1
    if dof < 1:
        return None
    gram = fit_x.T @ fit_x
    if np.linalg.cond(gram) > 1e12:
        return None
    inv = np.linalg.inv(gram)
    beta = inv @ (fit_x.T @ fit_y)
    r = fit_y - fit_x @ beta
    sigma2 = float(r @ r) / dof
    xbar = x[cut:].mean(axis=0)
    k = t.shape[0] - cut
    return float(xbar @ beta), sigma2 * float(xbar @ inv @ xbar) + sigma2 / k


def model_error(
    t: FloatArray, y: FloatArray, tau: float, curve: Curve | None, curve_weight: float
) -> float:
    """How much further the rise missed its last recordings than its uncertainty promised.

    The rise's own out-of-sample check: the line (and the curve, by their
    weights) fitted without the last third of the recordings since the
    change point (at least :data:`MIN_AFTER`) predicts their mean; the squared
    miss over the predicted variance (the fit's, the scatter's and the two
    models' spread) is the factor the trend's covariance is widened by when
    above 1. A right model misses by about its uncertainty (the factor stays
    near 1); a straight line on an accelerating rise falls behind it.

    Parameters
    ----------
    t, y : FloatArray
        The values the rise was fitted to (days, feature units).
    tau : float
        The line's change point, days.
    curve : Curve or None
        The curved rise beside it.
    curve_weight : float
        The curve's weight.

    Returns
    -------
    float
        1 or more (1 when too few recordings follow the change point).
    """
    after = int(np.count_nonzero(t > tau))
    misses = []
    for share in HELD_OUT:
        k = max(MIN_AFTER, round(after * share))
        cut = t.shape[0] - k
        if after - k < MIN_AFTER:
            continue
        line = _held_out(t, y, tau, cut, 1)
        if line is None:
            continue
        mean, var = line
        if curve is not None and curve_weight > 0.0:
            bent = _held_out(t, y, curve.tau, cut, 2)
            if bent is not None:
                w = curve_weight
                mean, var = (
                    (1.0 - w) * line[0] + w * bent[0],
                    (1.0 - w) * line[1] + w * bent[1] + w * (1.0 - w) * (bent[0] - line[0]) ** 2,
                )
        if var > 0.0:
            miss = float(y[cut:].mean()) - mean
            misses.append(miss * miss / var)
    return max(1.0, float(np.mean(misses))) if misses else 1.0


def alarm_open(
    exceeded: Sequence[bool],
    x: int,
    y: int,
    late: Sequence[bool] | None = None,
    noted: Sequence[bool] | None = None,
) -> tuple[bool, int | None]:
    """Whether the X-of-Y rule holds an alarm open after the last recording, and since when.

    The alarm opens at a recording where X of the last Y exceeded and closes
    after Y recordings without an exceedance (as the monitor's alarms).

    Parameters
    ----------
    exceeded : sequence of bool
        Whether each recording's exceedance counts (:func:`counted`).
    x, y : int
        The X-of-Y rule.
    late : sequence of bool, optional
        Whether each exceedance counted only from the next recording on (a
        neighbour's confirmation, :func:`counted`): at its own recording it
        did not count yet.
    noted : sequence of bool, optional
        Whether the monitor noted an event of operation on the feature
        instead of alarming (an item caught): the rule met there opens no alarm.

    Returns
    -------
    (bool, int or None)
        Open, and the index of the first exceedance in the window that
        opened it (None when not open).
    """
    ex = [bool(e) for e in exceeded]
    pending = [bool(e) for e in late] if late is not None else [False] * len(ex)
    note = [bool(e) for e in noted] if noted is not None else [False] * len(ex)
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
        window[-1] = window[-1] and not pending[i]  # as the window stood at recording i
        if not is_open and sum(window) >= x and not note[i]:
            is_open = True
            since = lo + window.index(True)
        elif is_open and i + 1 >= y and not any([*ex[max(0, i - y + 1) : i], window[-1]]):
            is_open, since = False, None
    return is_open, since


@dataclass(frozen=True)
class Counted:
    """A feature's exceedances as the monitor counted them (:func:`counted`).

    Attributes
    ----------
    counted : list of bool
        Whether each recording's exceedance counts (after its neighbours).
    late : list of bool
        Whether it counted only from the next recording on.
    waiting : bool
        The last recording's exceedance waits for the next one to confirm it.
    held : bool
        The last recording was caught (it confirms no exceedance).
    share : float
        The share of the last :data:`RECENT` recordings whose exceedances
        needed a neighbour's confirmation (1 on a 1 ms scope), for the
        recordings ahead.
    """

    counted: list[bool]
    late: list[bool]
    waiting: bool
    held: bool
    share: float


def counted(
    exceeded: Sequence[bool],
    confirm: Sequence[bool] | None = None,
    caught: Sequence[bool] | None = None,
) -> Counted:
    """Replay the monitor's confirmation (:func:`~chaintwin.diagnose.confirmation.
    count_exceedance`) over a feature's exceedances.

    ``confirm`` and ``caught`` per recording as
    :func:`~chaintwin.diagnose.confirmation.needs_confirmation` gives them
    (None: no recording needed a neighbour, every exceedance counts).
    """
    n = len(exceeded)
    need = [False] * n if confirm is None else [bool(c) for c in confirm]
    hit = [False] * n if caught is None else [bool(c) for c in caught]
    if len(need) != n or len(hit) != n:
        raise ValueError(
            f"confirm and caught need one entry per recording ({n}), got {len(need)} and {len(hit)}"
        )
    window: list[bool] = []
    waiting: list[bool] = []
    was_caught: list[bool] = []
    now: list[bool] = []  # whether each counted at its own recording
    for i, e in enumerate(exceeded):
        now.append(
            count_exceedance(window, waiting, was_caught, bool(e), confirm=need[i], caught=hit[i])
        )
    late = [w and not m for w, m in zip(window, now, strict=True)]
    recent = need[-RECENT:]
    return Counted(
        counted=window,
        late=late,
        waiting=bool(waiting and waiting[-1]),
        held=bool(was_caught and was_caught[-1]),
        share=sum(recent) / len(recent) if recent else 0.0,
    )


def window_counts(
    new: BoolArray,
    need: BoolArray,
    flags: IntArray,
    before: BoolArray,
    waiting: BoolArray,
    held: bool,
) -> tuple[IntArray, IntArray, BoolArray]:
    """The monitor's count of counted exceedances in each window, over many futures at once.

    The vectorised :func:`~chaintwin.diagnose.confirmation.count_exceedance`
    for recordings that are not caught: an exceedance that needs a
    neighbour's confirmation counts beside the exceedance before it (not a
    caught one) and is confirmed late by the next one.

    Parameters
    ----------
    new : (paths, n) bool array
        Whether each recording ahead exceeded.
    need : (paths, n) bool array
        Whether its exceedance needs a neighbour's confirmation.
    flags : (paths, y - 1) int array
        The window's counted exceedances before the first of ``new`` (0/1).
    before, waiting : (paths,) bool array
        The recording before exceeded (counted or waiting); its exceedance waits.
    held : bool
        The recording before was caught.

    Returns
    -------
    (int array, int array, bool array)
        The count of the window at each recording of ``new`` as it stands
        then (paths × n), the window's flags with those of ``new``
        (paths × (y - 1 + n), the last ones as they stand after the last
        recording), and whether each exceedance waits after its recording.
    """
    paths, n = new.shape
    y = flags.shape[1] + 1
    prev = np.concatenate((before[:, None], new[:, :-1]), axis=1)
    prev[:, 0] &= not held
    now = new & (~need | prev)  # counts at its own recording
    wait = new & ~now
    # counted once the next recording exceeded too (the last: not yet)
    final = now | (wait & np.concatenate((new[:, 1:], np.zeros((paths, 1), bool)), axis=1))
    carried = flags.copy()
    if y > 1:
        carried[:, -1] |= (waiting & new[:, 0]).astype(np.int64)
    ex = np.concatenate((carried, final.astype(np.int64)), axis=1)
    csum = np.concatenate((np.zeros((paths, 1), dtype=np.int64), np.cumsum(ex, axis=1)), axis=1)
    # at recording k: the y - 1 before it as they stand then, and its own as it counts then
    counts = csum[:, y - 1 : y - 1 + n] - csum[:, :n] + now
    return counts, ex, wait


def _openings(
    rise: Rise,
    t_last: float,
    step: float,
    steps: int,
    healthy: float,
    margins: FloatArray,
    past: Counted,
    x: int,
    y: int,
    level: float,
    rng: np.random.Generator,
) -> tuple[FloatArray, BoolArray]:
    """The recordings ahead at which each drawn future's alarm opens (inf: not within).

    And which futures were drawn from the curve (half of them when there is
    one, none without). A future recording's exceedance counts as the
    monitor counts it (:func:`~chaintwin.diagnose.confirmation.
    count_exceedance`): where it needs a neighbour's confirmation (drawn
    with ``past.share``; the futures are of a wear, not of items caught),
    only beside another exceedance, the next one confirming it late.
    """
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
    sigma *= rise.noise_ratio
    curv = np.zeros(PATHS)
    curve = rise.curve
    on = np.zeros(PATHS, dtype=bool)
    if curve is not None:
        # half the futures drawn from the curve: each model's own band is known
        on[: PATHS // 2] = True
        k = int(on.sum())
        pick_c = rng.choice(curve.taus.shape[0], size=k, p=curve.weights)
        val, vec = np.linalg.eigh(curve.covs[pick_c])
        root = vec * np.sqrt(np.maximum(val, 0.0))[:, None, :]
        drawn = curve.coefs[pick_c] + np.einsum("kij,kj->ki", root, rng.standard_normal((k, 3)))
        tau[on] = curve.taus[pick_c]
        coef[on] = drawn[:, :2]
        # a wearing part does not heal: the curvature drawn is not below zero
        curv[on] = np.maximum(drawn[:, 2], 0.0)
        sigma[on] = curve.sigmas[pick_c] * np.sqrt(curve.dof / rng.chisquare(curve.dof, k))
        sigma[on] *= rise.noise_ratio
    flags = np.zeros((PATHS, y - 1), dtype=np.int64)
    tail = past.counted[-(y - 1) :] if y > 1 else []
    if tail:
        flags[:, -len(tail) :] = np.asarray(tail, dtype=np.int64)
    # the last recording's state: exceeded (counted or waiting), waiting, caught
    before = np.full(PATHS, bool(past.counted and past.counted[-1]) or past.waiting)
    waiting = np.full(PATHS, past.waiting)
    held = past.held
    opened = np.full(PATHS, np.inf)
    active = np.arange(PATHS)  # the futures whose alarm has not opened yet
    done = 0
    chunk = CHUNK
    while done < steps and active.size:
        j = np.arange(done + 1, min(steps, done + chunk) + 1, dtype=np.float64)
        chunk = min(2 * chunk, MAX_CHUNK)
        a, n = active, j.shape[0]
        s = np.maximum(0.0, (t_last + j * step)[None, :] - tau[a, None])
        values = coef[a, :1] + (coef[a, 1:] + curv[a, None] * s) * s
        values += sigma[a, None] * rng.standard_normal((a.size, n))
        limit = healthy + margins[rng.integers(0, margins.shape[0], (a.size, n))]
        new = values > limit
        if past.share >= 1.0:
            need = np.ones((a.size, n), dtype=bool)
        elif past.share > 0.0:
            need = rng.random((a.size, n)) < past.share
        else:
            need = np.zeros((a.size, n), dtype=bool)
        counts, ex, wait = window_counts(new, need, flags, before, waiting, held)
        met = counts >= x
        hit = met.any(axis=1)
        opened[a[hit]] = j[np.argmax(met[hit], axis=1)]
        flags = ex[~hit][:, ex.shape[1] - (y - 1) :]
        before = new[~hit, -1]
        waiting = wait[~hit, -1]
        held = False
        active = a[~hit]
        done = int(j[-1])
        known = np.isfinite(opened)
        if all(known[g].mean() >= 0.5 + 0.5 * level for g in (on, ~on) if g.any()):
            break
    return opened, on


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
    curved: bool = True,
    confirm: Sequence[bool] | None = None,
    caught: Sequence[bool] | None = None,
    noted: Sequence[bool] | None = None,
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
        judgement, for the window ahead and whether the alarm is open),
        counted as the monitor counts them with ``confirm`` and ``caught``
        (:func:`counted`).
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
    curved : bool
        Weigh a curved rise beside the line (:func:`fit_rise`); False: the
        line alone, as the forecasts were before the curve.
    confirm, caught : sequence of bool, optional
        Per recording, whether its exceedances needed a neighbour's
        confirmation and whether it was caught
        (:func:`~chaintwin.diagnose.confirmation.needs_confirmation`; None:
        none did). The share of the last :data:`RECENT` that needed it is
        the chance that a recording ahead needs it (1 on a 1 ms scope).
    noted : sequence of bool, optional
        Per recording, whether the monitor noted an event of operation on
        the feature instead of alarming (its rule met there opened no alarm;
        :func:`alarm_open`).

    Returns
    -------
    Forecast or None
        ``threshold`` is the median threshold of the last recordings (feature
        units at the mean payload), ``model`` ``line`` (the rise after the
        change point, the line's and the curve's) with ``trend_since`` the
        change point (the curve's when it is the likelier); ``crossed`` with
        ``earliest`` = ``latest`` = ``crosses_at`` when the alarm is open.
        None without a significant rise (unless open), or when the median
        future opens no alarm within the horizon.
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
    past = counted(exceeded, confirm, caught)
    is_open, since = alarm_open(past.counted, x, y, past.late, noted)
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
    if trend is None:
        rise = fit_rise(t_all[ok][-FIT_POINTS:], v[ok][-FIT_POINTS:], curved=curved)
    else:
        rise = trend
    if rise is None:
        return None
    recent_t = t_all[-RECENT:]
    step = float(recent_t[-1] - recent_t[0]) / max(recent_t.shape[0] - 1, 1)
    if not step > 0.0:
        return None
    steps = max(1, math.ceil(horizon_days / step))
    if steps > MAX_STEPS:
        # recordings closer than the horizon over MAX_STEPS (26 min for a year): the futures
        # are drawn at every ``stride``-th recording, the rule applied to those
        stride = math.ceil(steps / MAX_STEPS)
        step *= stride
        steps = max(1, math.ceil(horizon_days / step))
    rng = np.random.default_rng(seed)
    opened, on = _openings(
        rise, float(t_all[-1]), step, steps, healthy, recent_m, past, x, y, level, rng
    )
    mid, lo, hi = _opening_quantiles(opened, on, rise.curve_weight, level)
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
        trend_since=t0 + _change_point(rise) * day,
        threshold=threshold,
    )


def _change_point(rise: Rise) -> float:
    """The change point of the likelier model (the curve's when its weight is above half), days."""
    if rise.curve is not None and rise.curve_weight > 0.5:
        return rise.curve.tau
    return rise.tau


def _opening_quantiles(
    opened: FloatArray, on: BoolArray, curve_weight: float, level: float
) -> tuple[float, float, float]:
    """The expected opening and the band's ends, in recordings ahead (inf: never).

    The expected opening is the median of the futures weighted by their
    model's weight (the line's futures by ``1 - curve_weight``, the curve's by
    ``curve_weight``); the band reaches from the earliest of the models' lower
    quantiles to the latest of their upper ones, so that it holds the futures
    of whichever model is right (the model error the weights cannot tell yet).
    Quantiles are drawn openings (no interpolation with "never").
    """
    lo_q, hi_q = 0.5 - 0.5 * level, 0.5 + 0.5 * level
    groups = [g for g in (~on, on) if g.any()]
    if len(groups) == 1:
        mid, lo, hi = np.quantile(opened, [0.5, lo_q, hi_q], method="inverted_cdf")
        return float(mid), float(lo), float(hi)
    weight = np.where(on, curve_weight / on.sum(), (1.0 - curve_weight) / (~on).sum())
    order = np.argsort(opened, kind="stable")
    cum = np.cumsum(weight[order])
    mid = float(opened[order][min(int(np.searchsorted(cum, 0.5 * cum[-1])), order.size - 1)])
    ends = [np.quantile(opened[g], [lo_q, hi_q], method="inverted_cdf") for g in groups]
    return mid, float(min(e[0] for e in ends)), float(max(e[1] for e in ends))


def _z(level: float) -> float:
    """The standard normal quantile of a two-sided ``level``."""
    return NormalDist().inv_cdf(0.5 + 0.5 * level)
