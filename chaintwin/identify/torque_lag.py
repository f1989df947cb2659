"""Motor torque lag: identify τ of the lag from torque set point to actual torque.

The motor's actual torque follows the torque set point through a first-order
lag ``1/(1 + s·τ)``, τ ≈ 1 ms, after a delay of one controller cycle
(docs/design.md, section 2). Discretised exactly at the controller cycle Tc (the
set point held over each cycle)::

    T[k+1] = T[k] + a·(Tsp[k-d] - T[k]),    a = 1 - exp(-Tc/τ),    d = 1

With τ ≈ Tc the response is already at ``a`` ≈ 64 % one sample after the
delay, so the textbook reading of τ at the 63 % point only tells "under one
cycle". The recorded samples still pin ``a`` down, and ``a`` gives τ: this
module fits that discrete model to a recording taken at the controller
cycle (a torque step, or any set point that moves).

Why an output-error fit
-----------------------
The model is linear in ``a`` as an equation error (regress ``T[k+1] - T[k]``
on ``Tsp[k-d] - T[k]``), but the measured torque then sits in the regressor:
its noise and quantisation bias ``a`` towards 1 (errors in variables) and so
τ low, by an amount that grows with the noise and shrinks with the step.
The output-error fit (simulate the lag from the recorded set point, compare
with the measured torque, least squares on the residual) has the measured
torque only on the output side, so white measurement noise does not bias
it. Its two parameters are ``a`` and the initial torque; the simulation is
a first-order recursive filter with an exact Jacobian, solved by
:func:`scipy.optimize.least_squares` (bounded, ``0 ≤ a ≤ 1``) from the
equation-error estimate. On noise-free data both give the exact τ.

The standard error of τ comes from the Jacobian at the solution,
``cov = s²·(JᵀJ)⁻¹`` with ``s² = RSS/(n - 2)``, carried to τ by the delta
method ``σ_τ = |dτ/da|·σ_a``, ``dτ/da = -Tc/((1 - a)·ln²(1 - a))``. It
assumes white residuals; unmodelled dynamics make it optimistic.

What cannot be identified
-------------------------
* A constant set point carries no information on τ: refused.
* A recording sampled slower than the controller cycle (a scope at 6 ms)
  has lost the lag, which settles within ~5 ms: refused when the sample
  time exceeds ``max_sample_time_s`` (2 ms) or differs from the given
  controller cycle.
* τ below a tenth of the cycle (the step is complete to 5·10⁻⁵ within one
  sample, the fit is flat in ``a``) or longer than the recording (the torque
  does not follow its set point): refused.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any, Self

import numpy as np
import numpy.typing as npt
from scipy.optimize import least_squares
from scipy.signal import lfilter

from chaintwin._types import FloatArray
from chaintwin.errors import EstimationError, NotFittedError

__all__ = [
    "MAX_DELAY_CYCLES",
    "TorqueLagEstimator",
    "TorqueLagResult",
    "identify_torque_lag",
    "lag_gain",
    "simulate_torque_lag",
]


MAX_DELAY_CYCLES = 3
"""Largest delay, in controller cycles, tried when the delay is searched."""

_MAX_SAMPLE_TIME_S = 0.002
_MIN_SAMPLES = 8
_SAMPLE_TIME_TOLERANCE = 0.01
_MIN_TAU_CYCLES = 0.1
"""Below τ = Tc/10 the response is complete to 5e-5 within one sample: refused."""


@dataclass(frozen=True, slots=True)
class TorqueLagResult:
    """The identified torque lag.

    Parameters
    ----------
    tau_s : float
        Time constant τ of the lag ``1/(1 + s·τ)``, s.
    tau_stderr_s : float
        Standard error of τ, s (delta method from the variance of ``a``).
    delay_cycles : int
        Delay before the lag, controller cycles.
    cycle_s : float
        The controller cycle (the recording's sample time), s.
    rms_residual_nm : float
        RMS of measured minus fitted torque, Nm.
    n_samples : int
        Samples in the fit.
    """

    tau_s: float
    tau_stderr_s: float
    delay_cycles: int
    cycle_s: float
    rms_residual_nm: float
    n_samples: int

    @property
    def gain(self) -> float:
        """The discrete lag's step gain ``a = 1 - exp(-Tc/τ)`` (dimensionless)."""
        return lag_gain(self.tau_s, self.cycle_s)

    def to_dict(self) -> dict[str, object]:
        """Return the result as a JSON-ready mapping."""
        return asdict(self)


def lag_gain(tau_s: float, cycle_s: float) -> float:
    """The discrete lag's gain per cycle, ``a = 1 - exp(-Tc/τ)``.

    Parameters
    ----------
    tau_s : float
        Time constant τ, s (0 means the torque follows within one cycle: a = 1).
    cycle_s : float
        Controller cycle Tc, s.

    Returns
    -------
    float
        ``a`` in ``(0, 1]``.
    """
    if tau_s <= 0.0:
        return 1.0
    return -math.expm1(-cycle_s / tau_s)


def _as_1d(name: str, values: npt.ArrayLike) -> FloatArray:
    arr = np.asarray(values, dtype=np.float64)
    if arr.ndim != 1:
        raise EstimationError(f"{name} must be one-dimensional, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise EstimationError(
            f"{name} holds NaN or infinite values; cut the recording to its valid part"
        )
    return arr


def _sample_time(time_s: FloatArray) -> float:
    """Uniform sample time of a time column, s."""
    if time_s.size < _MIN_SAMPLES:
        raise EstimationError(
            f"{time_s.size} samples are too few to identify the torque lag; "
            f"give at least {_MIN_SAMPLES} around a torque set point change"
        )
    steps = np.diff(time_s)
    ts = float(np.median(steps))
    if ts <= 0.0 or np.any(steps <= 0.0):
        raise EstimationError("the time column must increase strictly; sort or repair it")
    if np.max(np.abs(steps - ts)) > _SAMPLE_TIME_TOLERANCE * ts:
        raise EstimationError(
            "the time steps are not uniform; the torque lag needs an unbroken recording "
            "at the controller cycle"
        )
    return float(time_s[-1] - time_s[0]) / (time_s.size - 1)


def _check_cycle(ts: float, cycle_s: float | None, max_sample_time_s: float) -> None:
    if cycle_s is not None:
        if abs(ts - cycle_s) > _SAMPLE_TIME_TOLERANCE * cycle_s:
            raise EstimationError(
                f"the recording is sampled every {ts * 1e3:.4g} ms, not at the controller "
                f"cycle of {cycle_s * 1e3:.4g} ms; the torque lag can only be identified "
                "from a scope recorded at the controller cycle"
            )
    elif ts > max_sample_time_s:
        raise EstimationError(
            f"the recording is sampled every {ts * 1e3:.4g} ms; the torque lag (τ ≈ 1 ms) "
            f"settles within a few ms and cannot be told from samples more than "
            f"{max_sample_time_s * 1e3:.4g} ms apart: record the torque set point and "
            "actual torque at the controller cycle"
        )


def _delayed(setpoint: FloatArray, delay: int) -> FloatArray:
    """``Tsp[k - delay]``, holding the first value before the recording."""
    if delay == 0:
        return setpoint
    return np.concatenate((np.full(delay, setpoint[0]), setpoint[:-delay]))


def _simulate(a: float, t0: float, v: FloatArray) -> FloatArray:
    """``T[0] = t0``, ``T[j+1] = (1 - a)·T[j] + a·v[j]``; same length as ``v``."""
    forced = np.asarray(lfilter([0.0, a], [1.0, a - 1.0], v), dtype=np.float64)
    return forced + t0 * np.power(1.0 - a, np.arange(v.size, dtype=np.float64))


@dataclass(frozen=True, slots=True)
class _Fit:
    a: float
    t0: float
    rss: float
    a_stderr: float
    n: int


def _fit_gain(v: FloatArray, y: FloatArray) -> _Fit:
    """Output-error fit of ``a`` and the initial torque; ``v[j]`` drives ``y[j+1]``."""
    x = v[:-1] - y[:-1]
    sxx = float(x @ x)
    a0 = float(x @ np.diff(y)) / sxx if sxx > 0.0 else 0.5
    a0 = min(max(a0, 1.0e-6), 1.0 - 1.0e-6)

    def residual(p: FloatArray) -> FloatArray:
        return _simulate(float(p[0]), float(p[1]), v) - y

    def jacobian(p: FloatArray) -> FloatArray:
        a, t0 = float(p[0]), float(p[1])
        sim = _simulate(a, t0, v)
        d_a = np.asarray(lfilter([0.0, 1.0], [1.0, a - 1.0], v - sim), dtype=np.float64)
        d_t0 = np.power(1.0 - a, np.arange(v.size, dtype=np.float64))
        return np.column_stack((d_a, d_t0))

    sol: Any = least_squares(
        residual,
        np.array([a0, y[0]]),
        jac=jacobian,
        bounds=([0.0, -np.inf], [1.0, np.inf]),
        method="trf",
        x_scale="jac",
        ftol=1e-12,
        xtol=1e-12,
        gtol=1e-12,
        max_nfev=200,
    )
    if sol.status <= 0:
        raise EstimationError(
            f"the torque lag fit did not converge ({sol.message}); check that the torque "
            "and torque set point channels belong together"
        )
    a, t0 = float(sol.x[0]), float(sol.x[1])
    res = residual(sol.x)
    rss = float(res @ res)
    n = int(y.size)
    jac = jacobian(sol.x)
    try:
        cov_unit = np.linalg.inv(jac.T @ jac)
        a_var = rss / max(n - 2, 1) * float(cov_unit[0, 0])
        a_stderr = math.sqrt(a_var) if a_var >= 0.0 else math.inf
    except np.linalg.LinAlgError:
        a_stderr = math.inf
    return _Fit(a=a, t0=t0, rss=rss, a_stderr=a_stderr, n=n)


def identify_torque_lag(
    time_s: npt.ArrayLike,
    torque_setpoint_nm: npt.ArrayLike,
    torque_nm: npt.ArrayLike,
    *,
    delay_cycles: int | None = 1,
    cycle_s: float | None = None,
    max_sample_time_s: float = _MAX_SAMPLE_TIME_S,
) -> TorqueLagResult:
    """Identify the torque lag τ from a recording at the controller cycle.

    Fits ``T[k+1] = T[k] + a·(Tsp[k-d] - T[k])`` by output-error least
    squares (see the module docstring for why, and for the standard error).

    Parameters
    ----------
    time_s : array_like
        Sample times, s; uniform, at the controller cycle.
    torque_setpoint_nm : array_like
        Torque set point Tsp, Nm; it must move (a step is best).
    torque_nm : array_like
        Actual torque T, Nm.
    delay_cycles : int or None
        Delay d before the lag, controller cycles (default 1). None searches
        0 to :data:`MAX_DELAY_CYCLES` and keeps the one with the smallest
        residual (all candidates fitted on the same samples).
    cycle_s : float, optional
        The controller cycle, s (``profile.controller.cycle_s``); when given
        the sample time must equal it.
    max_sample_time_s : float
        Without ``cycle_s``: the longest sample time accepted, s.

    Returns
    -------
    TorqueLagResult

    Raises
    ------
    EstimationError
        When the arrays do not match or hold non-finite values, the sample
        time is not the controller cycle, the set point is constant, or τ
        lies outside what the recording can tell (far below one cycle, or
        the torque does not follow the set point).
    """
    t = _as_1d("time_s", time_s)
    u = _as_1d("torque_setpoint_nm", torque_setpoint_nm)
    y = _as_1d("torque_nm", torque_nm)
    if not t.size == u.size == y.size:
        raise EstimationError(
            f"time_s, torque_setpoint_nm and torque_nm must have one length, got "
            f"{t.size}, {u.size} and {y.size}"
        )
    ts = _sample_time(t)
    _check_cycle(ts, cycle_s, max_sample_time_s)
    if delay_cycles is None:
        candidates = list(range(MAX_DELAY_CYCLES + 1))
    else:
        if delay_cycles < 0 or delay_cycles > t.size // 2:
            raise EstimationError(
                f"delay_cycles={delay_cycles} must lie between 0 and half the recording"
            )
        candidates = [int(delay_cycles)]
    start = max(candidates)
    if y.size - start < _MIN_SAMPLES:
        raise EstimationError(
            f"{y.size - start} samples after the delay are too few; give a longer recording"
        )
    used = u[: y.size - min(candidates)]
    scale = max(1.0, float(np.max(np.abs(used))))
    if float(np.ptp(used)) <= 1.0e-9 * scale:
        raise EstimationError(
            "the torque set point is constant: it carries no information on the torque "
            "lag; give a recording with a torque step (e.g. the start or end of a speed ramp)"
        )

    best: tuple[int, _Fit] | None = None
    for d in candidates:
        v = _delayed(u, d)[start:]
        fit = _fit_gain(v, y[start:])
        if best is None or fit.rss < best[1].rss:
            best = (d, fit)
    assert best is not None
    delay, fit = best

    duration = ts * (y.size - 1)
    if fit.a <= 0.0 or -ts / math.log1p(-fit.a) > duration:
        raise EstimationError(
            "the actual torque does not follow its set point within the recording; check "
            "that the two torque channels belong to the same drive"
        )
    if fit.a >= 1.0 or -ts / math.log1p(-fit.a) < _MIN_TAU_CYCLES * ts:
        raise EstimationError(
            f"the torque settles within one cycle of {ts * 1e3:.4g} ms (τ below "
            f"{_MIN_TAU_CYCLES:g} cycle): τ cannot be told from this recording"
        )
    log_q = math.log1p(-fit.a)
    tau = -ts / log_q
    dtau_da = ts / ((1.0 - fit.a) * log_q * log_q)
    tau_stderr = dtau_da * fit.a_stderr
    if not math.isfinite(tau_stderr):
        raise EstimationError(
            "the recording carries too little information on the torque lag; give one "
            "with a clear torque set point step"
        )
    return TorqueLagResult(
        tau_s=tau,
        tau_stderr_s=tau_stderr,
        delay_cycles=delay,
        cycle_s=ts,
        rms_residual_nm=math.sqrt(fit.rss / fit.n),
        n_samples=fit.n,
    )


def simulate_torque_lag(
    torque_setpoint_nm: npt.ArrayLike,
    *,
    tau_s: float,
    cycle_s: float,
    delay_cycles: int = 1,
    initial_torque_nm: float | None = None,
) -> FloatArray:
    """Actual torque from a set point through the delayed discrete lag.

    ``T[0] = initial_torque_nm``, ``T[k+1] = T[k] + a·(Tsp[k-d] - T[k])``
    with ``a = 1 - exp(-Tc/τ)``; the set point before the first sample is
    taken as ``Tsp[0]``.

    Parameters
    ----------
    torque_setpoint_nm : array_like
        Torque set point at every controller cycle, Nm.
    tau_s : float
        Time constant τ, s (≥ 0).
    cycle_s : float
        Controller cycle Tc, s (> 0).
    delay_cycles : int
        Delay d, controller cycles (≥ 0).
    initial_torque_nm : float, optional
        Actual torque at the first sample, Nm (default: the first set point).

    Returns
    -------
    numpy.ndarray
        Actual torque, Nm, one value per set point sample.

    Raises
    ------
    EstimationError
        When an argument is out of range.
    """
    u = _as_1d("torque_setpoint_nm", torque_setpoint_nm)
    if u.size == 0:
        return u.copy()
    if not (math.isfinite(tau_s) and tau_s >= 0.0):
        raise EstimationError(f"tau_s={tau_s!r} must be a finite number ≥ 0")
    if not (math.isfinite(cycle_s) and cycle_s > 0.0):
        raise EstimationError(f"cycle_s={cycle_s!r} must be a positive number")
    if delay_cycles < 0:
        raise EstimationError(f"delay_cycles={delay_cycles} must be ≥ 0")
    t0 = float(u[0]) if initial_torque_nm is None else float(initial_torque_nm)
    v = _delayed(u, delay_cycles) if delay_cycles < u.size else np.full(u.size, u[0])
    return _simulate(lag_gain(tau_s, cycle_s), t0, v)


class TorqueLagEstimator:
    """Estimator of the motor torque lag, in the scikit-learn manner.

    Parameters
    ----------
    delay_cycles : int or None
        Delay before the lag, controller cycles (default 1); None searches
        0 to :data:`MAX_DELAY_CYCLES`.
    cycle_s : float, optional
        The controller cycle, s; when given the recording must be sampled at it.
    max_sample_time_s : float
        Without ``cycle_s``: the longest sample time accepted, s.

    Attributes
    ----------
    tau_ : float
        Identified time constant τ, s.
    tau_stderr_ : float
        Its standard error, s.
    delay_cycles_ : int
        Delay used, controller cycles.
    cycle_s_ : float
        The controller cycle of the fitted recording, s.
    result_ : TorqueLagResult
        The whole result.

    Examples
    --------
    >>> import numpy as np
    >>> t = np.arange(40) * 1e-3
    >>> sp = np.where(t >= 0.01, 2.0, 0.0)
    >>> tq = simulate_torque_lag(sp, tau_s=0.98e-3, cycle_s=1e-3)
    >>> round(TorqueLagEstimator().fit(t, sp, tq).tau_ * 1e3, 6)
    0.98
    """

    # set by fit(); __init__ only stores settings
    _result: TorqueLagResult | None = None

    def __init__(
        self,
        *,
        delay_cycles: int | None = 1,
        cycle_s: float | None = None,
        max_sample_time_s: float = _MAX_SAMPLE_TIME_S,
    ) -> None:
        self.delay_cycles = delay_cycles
        self.cycle_s = cycle_s
        self.max_sample_time_s = max_sample_time_s

    def __repr__(self) -> str:
        return (
            f"TorqueLagEstimator(delay_cycles={self.delay_cycles!r}, cycle_s={self.cycle_s!r}, "
            f"max_sample_time_s={self.max_sample_time_s!r})"
        )

    def fit(
        self,
        time_s: npt.ArrayLike,
        torque_setpoint_nm: npt.ArrayLike,
        torque_nm: npt.ArrayLike,
    ) -> Self:
        """Fit the lag to a recording at the controller cycle; see :func:`identify_torque_lag`.

        Returns
        -------
        TorqueLagEstimator
            ``self``, fitted.
        """
        self._result = identify_torque_lag(
            time_s,
            torque_setpoint_nm,
            torque_nm,
            delay_cycles=self.delay_cycles,
            cycle_s=self.cycle_s,
            max_sample_time_s=self.max_sample_time_s,
        )
        return self

    @property
    def result_(self) -> TorqueLagResult:
        """The fitted result; raises :class:`~chaintwin.errors.NotFittedError` before ``fit``."""
        if self._result is None:
            raise NotFittedError(
                "this TorqueLagEstimator is not fitted yet; call fit(time_s, "
                "torque_setpoint_nm, torque_nm) first"
            )
        return self._result

    @property
    def tau_(self) -> float:
        """Identified time constant τ, s."""
        return self.result_.tau_s

    @property
    def tau_stderr_(self) -> float:
        """Standard error of τ, s."""
        return self.result_.tau_stderr_s

    @property
    def delay_cycles_(self) -> int:
        """Delay used, controller cycles."""
        return self.result_.delay_cycles

    @property
    def cycle_s_(self) -> float:
        """Controller cycle of the fitted recording, s."""
        return self.result_.cycle_s

    def predict(
        self,
        time_s: npt.ArrayLike,
        torque_setpoint_nm: npt.ArrayLike,
        initial_torque_nm: float | None = None,
    ) -> FloatArray:
        """Simulate the actual torque for a set point with the fitted lag.

        Parameters
        ----------
        time_s : array_like
            Sample times, s; uniform at the fitted controller cycle.
        torque_setpoint_nm : array_like
            Torque set point, Nm.
        initial_torque_nm : float, optional
            Actual torque at the first sample, Nm (default: the first set point).

        Returns
        -------
        numpy.ndarray
            Simulated actual torque, Nm.

        Raises
        ------
        NotFittedError
            Before ``fit``.
        EstimationError
            When the times do not match the set point or the fitted cycle.
        """
        result = self.result_
        t = _as_1d("time_s", time_s)
        u = _as_1d("torque_setpoint_nm", torque_setpoint_nm)
        if t.size != u.size:
            raise EstimationError(
                f"time_s and torque_setpoint_nm must have one length, got {t.size} and {u.size}"
            )
        if t.size >= 2:
            steps = np.diff(t)
            if np.max(np.abs(steps - result.cycle_s)) > _SAMPLE_TIME_TOLERANCE * result.cycle_s:
                raise EstimationError(
                    f"predict needs samples every {result.cycle_s * 1e3:.4g} ms, the cycle "
                    "the lag was fitted at"
                )
        return simulate_torque_lag(
            u,
            tau_s=result.tau_s,
            cycle_s=result.cycle_s,
            delay_cycles=result.delay_cycles,
            initial_torque_nm=initial_torque_nm,
        )
