"""Motor torque lag identification: known answers, refusals, estimator contract."""

from __future__ import annotations

import math

import numpy as np
import pytest

from chaintwin.errors import EstimationError, NotFittedError
from chaintwin.identify import (
    TorqueLagEstimator,
    TorqueLagResult,
    identify_torque_lag,
    lag_gain,
    simulate_torque_lag,
)

TC = 1.0e-3  # controller cycle, s
N = 300
STEP_UP, STEP_DOWN = 50, 150  # sample indices of the set point steps
LOW, HIGH = 0.2, 2.0  # Nm


def _time(n: int = N, ts: float = TC) -> np.ndarray:
    return np.arange(n) * ts


def _step_setpoint(n: int = N) -> np.ndarray:
    sp = np.full(n, LOW)
    sp[STEP_UP:STEP_DOWN] = HIGH
    return sp


def _measured(clean: np.ndarray, seed: int, sigma: float = 0.005, quantum: float = 0.01):
    """Gaussian noise (seeded) and quantisation to ``quantum`` Nm."""
    rng = np.random.default_rng(seed)
    return np.round((clean + rng.normal(0.0, sigma, clean.size)) / quantum) * quantum


def _reference_recursion(sp: np.ndarray, tau: float, delay: int) -> np.ndarray:
    """T[k+1] = T[k] + a·(Tsp[k-d] - T[k]) written out as a loop."""
    a = 1.0 - math.exp(-TC / tau)
    out = np.empty_like(sp)
    out[0] = sp[0]
    for k in range(sp.size - 1):
        out[k + 1] = out[k] + a * (sp[max(k - delay, 0)] - out[k])
    return out


@pytest.mark.parametrize("delay", [0, 1, 2])
def test_simulation_matches_the_written_out_recursion(delay: int) -> None:
    sp = _step_setpoint()
    fast = simulate_torque_lag(sp, tau_s=0.98e-3, cycle_s=TC, delay_cycles=delay)
    np.testing.assert_allclose(fast, _reference_recursion(sp, 0.98e-3, delay), atol=1e-12)
    assert lag_gain(0.98e-3, TC) == pytest.approx(1 - math.exp(-1 / 0.98))


@pytest.mark.parametrize(("tau", "seed"), [(0.5e-3, 11), (0.98e-3, 12), (2.0e-3, 13)])
def test_known_answer_noisy_quantised_step(tau: float, seed: int) -> None:
    sp = _step_setpoint()
    torque = _measured(simulate_torque_lag(sp, tau_s=tau, cycle_s=TC), seed)
    result = identify_torque_lag(_time(), sp, torque)
    assert isinstance(result, TorqueLagResult)
    assert result.delay_cycles == 1
    assert result.cycle_s == pytest.approx(TC, rel=1e-12)
    assert result.n_samples == N - 1
    assert result.tau_s == pytest.approx(tau, rel=0.03)
    # a sensible standard error: small, and the true τ within 3 of it
    assert 0.0 < result.tau_stderr_s < 0.02 * tau
    assert abs(result.tau_s - tau) < 3.0 * result.tau_stderr_s
    # the residual is the measurement noise (5 mNm noise + 10 mNm quantum)
    assert 0.004 < result.rms_residual_nm < 0.008


def _naive_63_percent(time_s: np.ndarray, sp: np.ndarray, torque: np.ndarray) -> float:
    """Time from the set point step (plus one cycle of delay) to the first sample ≥ 63 %."""
    target = LOW + (1.0 - math.exp(-1.0)) * (HIGH - LOW)
    first = STEP_UP + int(np.argmax(torque[STEP_UP:] >= target))
    return float(time_s[first] - time_s[STEP_UP]) - TC


def test_naive_63_percent_reading_is_wrong_and_the_fit_is_not() -> None:
    t, sp = _time(), _step_setpoint()
    naive = {}
    for tau, seed in ((0.5e-3, 21), (0.98e-3, 22)):
        torque = _measured(simulate_torque_lag(sp, tau_s=tau, cycle_s=TC), seed)
        naive[tau] = _naive_63_percent(t, sp, torque)
        fitted = identify_torque_lag(t, sp, torque).tau_s
        assert fitted == pytest.approx(tau, rel=0.03)
    # 63 % is reached within the first sample after the delay whatever τ ≤ 1 ms is:
    # the reading only says "one cycle", 100 % off at τ = 0.5 ms
    assert naive[0.5e-3] == pytest.approx(TC)
    assert naive[0.98e-3] == pytest.approx(TC)
    assert abs(naive[0.5e-3] - 0.5e-3) > 0.5 * 0.5e-3


@pytest.mark.parametrize("tau", [0.3e-3, 0.5e-3, 0.98e-3, 2.0e-3, 5.0e-3])
def test_noise_free_recovers_tau_exactly(tau: float) -> None:
    sp = _step_setpoint()
    torque = simulate_torque_lag(sp, tau_s=tau, cycle_s=TC)
    result = identify_torque_lag(_time(), sp, torque)
    assert result.tau_s == pytest.approx(tau, rel=1e-6)
    assert result.rms_residual_nm < 1e-9


def test_any_moving_setpoint_works_not_only_a_step() -> None:
    rng = np.random.default_rng(5)
    sp = np.cumsum(rng.normal(0.0, 0.05, N))  # a random walk, as a speed controller's output
    torque = simulate_torque_lag(sp, tau_s=1.3e-3, cycle_s=TC, initial_torque_nm=0.4)
    assert identify_torque_lag(_time(), sp, torque).tau_s == pytest.approx(1.3e-3, rel=1e-6)
    noisy = _measured(torque, seed=6, sigma=0.002, quantum=0.001)
    result = identify_torque_lag(_time(), sp, noisy)
    assert abs(result.tau_s - 1.3e-3) < 3.0 * result.tau_stderr_s


@pytest.mark.parametrize("true_delay", [0, 1, 2, 3])
def test_delay_search_finds_the_delay(true_delay: int) -> None:
    sp = _step_setpoint()
    clean = simulate_torque_lag(sp, tau_s=0.98e-3, cycle_s=TC, delay_cycles=true_delay)
    torque = _measured(clean, seed=30 + true_delay)
    result = identify_torque_lag(_time(), sp, torque, delay_cycles=None)
    assert result.delay_cycles == true_delay
    assert result.tau_s == pytest.approx(0.98e-3, rel=0.03)
    assert result.n_samples == N - 3  # all candidates on the same samples


def test_output_error_is_unbiased_where_equation_error_is_not() -> None:
    """Why the output-error fit: noise in the regressor biases the linear regression."""
    tau, sigma = 0.5e-3, 0.05
    sp = _step_setpoint()
    clean = simulate_torque_lag(sp, tau_s=tau, cycle_s=TC)
    rng = np.random.default_rng(7)
    oe, ee = [], []
    for _ in range(100):
        y = clean + rng.normal(0.0, sigma, N)
        oe.append(identify_torque_lag(_time(), sp, y).tau_s / tau - 1.0)
        x = np.concatenate(([sp[0]], sp[:-2])) - y[:-1]
        a = float(x @ np.diff(y)) / float(x @ x)
        ee.append(-TC / math.log(1.0 - a) / tau - 1.0)
    assert abs(np.mean(oe)) < 0.02
    assert np.mean(ee) < -0.03


def test_constant_setpoint_is_refused() -> None:
    sp = np.full(N, 1.5)
    torque = _measured(np.full(N, 1.5), seed=1)
    with pytest.raises(EstimationError, match="constant"):
        identify_torque_lag(_time(), sp, torque)
    with pytest.raises(EstimationError, match="constant"):
        TorqueLagEstimator(delay_cycles=None).fit(_time(), sp, torque)


@pytest.mark.parametrize("ts", [0.006, 0.012, 0.0025])
def test_scope_sample_time_is_refused(ts: float) -> None:
    sp = _step_setpoint()
    torque = simulate_torque_lag(sp, tau_s=0.98e-3, cycle_s=ts)
    with pytest.raises(EstimationError, match="controller cycle"):
        identify_torque_lag(_time(ts=ts), sp, torque)


def test_sample_time_must_equal_the_given_cycle() -> None:
    sp = _step_setpoint()
    torque = simulate_torque_lag(sp, tau_s=0.98e-3, cycle_s=0.5e-3)
    result = identify_torque_lag(_time(ts=0.5e-3), sp, torque, cycle_s=0.5e-3)
    assert result.tau_s == pytest.approx(0.98e-3, rel=1e-6)
    with pytest.raises(EstimationError, match="not at the controller cycle"):
        identify_torque_lag(_time(ts=0.5e-3), sp, torque, cycle_s=TC)


def test_torque_not_following_or_instant_is_refused() -> None:
    sp = _step_setpoint()
    with pytest.raises(EstimationError, match="does not follow"):
        identify_torque_lag(_time(), sp, np.zeros(N))
    instant = simulate_torque_lag(sp, tau_s=1e-5, cycle_s=TC)
    with pytest.raises(EstimationError, match="within one cycle"):
        identify_torque_lag(_time(), sp, instant)


@pytest.mark.parametrize(
    ("time_s", "sp", "torque", "match"),
    [
        (np.arange(10) * TC, np.zeros(9), np.zeros(10), "one length"),
        (np.arange(5) * TC, np.arange(5.0), np.arange(5.0), "too few"),
        (np.arange(20) * TC, np.r_[np.zeros(10), np.ones(10)], np.full(20, np.nan), "NaN"),
        (np.r_[np.arange(10), np.arange(11, 21)] * TC, np.arange(20.0), np.arange(20.0), "uniform"),
        (np.arange(20)[::-1] * TC, np.arange(20.0), np.arange(20.0), "increase"),
        (np.zeros((2, 10)), np.zeros(10), np.zeros(10), "one-dimensional"),
    ],
)
def test_bad_arrays_are_refused(
    time_s: np.ndarray, sp: np.ndarray, torque: np.ndarray, match: str
) -> None:
    with pytest.raises(EstimationError, match=match):
        identify_torque_lag(time_s, sp, torque)


def test_bad_delay_is_refused() -> None:
    with pytest.raises(EstimationError, match="delay_cycles"):
        identify_torque_lag(_time(), _step_setpoint(), _step_setpoint(), delay_cycles=-1)


def test_estimator_contract() -> None:
    est = TorqueLagEstimator(delay_cycles=None, cycle_s=TC)
    assert "delay_cycles=None" in repr(est)
    for name in ("tau_", "tau_stderr_", "delay_cycles_", "cycle_s_", "result_"):
        with pytest.raises(NotFittedError):
            getattr(est, name)
    with pytest.raises(NotFittedError, match="fit"):
        est.predict(_time(), _step_setpoint())

    sp = _step_setpoint()
    torque = _measured(simulate_torque_lag(sp, tau_s=0.98e-3, cycle_s=TC), seed=40)
    assert est.fit(_time(), sp, torque) is est
    assert est.tau_ == pytest.approx(0.98e-3, rel=0.03)
    assert est.tau_stderr_ == est.result_.tau_stderr_s > 0.0
    assert est.delay_cycles_ == 1
    assert est.cycle_s_ == pytest.approx(TC)
    assert est.result_.gain == pytest.approx(lag_gain(est.tau_, TC))
    assert est.result_.to_dict()["delay_cycles"] == 1

    predicted = est.predict(_time(), sp, initial_torque_nm=LOW)
    expected = simulate_torque_lag(sp, tau_s=est.tau_, cycle_s=TC, initial_torque_nm=LOW)
    np.testing.assert_allclose(predicted, expected)
    assert float(np.sqrt(np.mean((predicted - torque) ** 2))) < 0.01
    with pytest.raises(EstimationError, match="cycle"):
        est.predict(_time(ts=0.006), sp)
    with pytest.raises(EstimationError, match="one length"):
        est.predict(_time(), sp[:-1])
