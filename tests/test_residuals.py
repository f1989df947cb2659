"""Residuals of the rigid model: statistics, model torque, belt position."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest
from conftest import REFERENCE_PROFILE
from scipy import stats
from scipy.integrate import cumulative_trapezoid

from chaintwin.diagnose.residuals import (
    ResidualReport,
    belt_position_m,
    position_profile,
    residual_analysis,
    residual_stats,
)
from chaintwin.errors import EstimationError
from chaintwin.model.frequencies import _kinematic_ratio
from chaintwin.model.rigid import PARAMETER_NAMES, RigidParameters, model_torque
from chaintwin.physics import G
from chaintwin.read.profile import load_profile
from chaintwin.read.recording import Metadata, Recording
from chaintwin.simulate.virtual import Realism, run_virtual
from chaintwin.validate.phases import Phase

PROFILE = load_profile(REFERENCE_PROFILE)
MODEL = PROFILE.model
assert MODEL is not None
TRUE_PARAMETERS = {
    "mu": MODEL.friction,
    "BmA": MODEL.loss_constant_nm,
    "BmB": MODEL.loss_viscous_nm_s_rad,
    "BmC": MODEL.loss_quadratic_nm_s2_rad2,
    "J_d": PROFILE.motor.inertia_kgm2 + PROFILE.gear.inertia_kgm2,
}
PAYLOAD_KG = 30.0


@pytest.fixture(scope="module")
def rigid_run() -> Recording:
    """Noise-free rigid virtual run at 6 ms, 30 kg (2048 samples, one trapezoid move)."""
    return run_virtual(PROFILE, payload_kg=PAYLOAD_KG, seed=1, realism=Realism.off()).recording


def _recording(channels: dict[str, np.ndarray]) -> Recording:
    return Recording(
        source="<hand>",
        channels=channels,
        units={name: "" for name in channels},
        headers={name: name for name in channels},
        metadata=Metadata(),
    )


# ------------------------------------------------------------------ statistics
def test_stats_match_numpy_and_scipy() -> None:
    rng = np.random.default_rng(7)
    measured = rng.normal(1.0, 0.5, 500)
    model = measured + rng.standard_t(5, 500) * 0.1 + 0.02
    e = measured - model
    s = residual_stats(measured, model)
    assert s.samples == 500
    assert s.mean == pytest.approx(np.mean(e))
    assert s.median == pytest.approx(np.median(e))
    assert s.std == pytest.approx(np.std(e, ddof=0))
    assert s.variance == pytest.approx(np.var(e, ddof=0))
    assert s.rms == pytest.approx(np.sqrt(np.mean(e**2)))
    assert s.max_abs == pytest.approx(np.max(np.abs(e)))
    assert s.kurtosis == pytest.approx(stats.kurtosis(e, fisher=False))
    assert s.skewness == pytest.approx(stats.skew(e))
    assert s.crest_factor == pytest.approx(np.max(np.abs(e)) / np.sqrt(np.mean(e**2)))
    assert s.correlation == pytest.approx(np.corrcoef(measured, model)[0, 1])
    assert s.rel_error_pct == pytest.approx(
        100.0 * np.sqrt(np.mean(e**2)) / np.sqrt(np.mean(measured**2))
    )


def test_stats_hand_case() -> None:
    s = residual_stats(np.array([1.0, -1.0, 2.0, -2.0]), np.zeros(4))
    # e = measured: mean 0, e² = 1, 1, 4, 4 → mean square 2.5
    assert s.mean == 0.0
    assert s.median == 0.0
    assert s.variance == pytest.approx(2.5)
    assert s.std == pytest.approx(math.sqrt(2.5))
    assert s.rms == pytest.approx(1.5811388)
    assert s.max_abs == 2.0
    assert s.crest_factor == pytest.approx(2.0 / math.sqrt(2.5))  # 1.2649
    assert s.kurtosis == pytest.approx(8.5 / 2.5**2)  # mean e⁴ / (mean e²)² = 1.36
    assert s.skewness == pytest.approx(0.0)
    assert s.rel_error_pct == pytest.approx(100.0)  # the zero model explains nothing
    assert s.correlation == 0.0  # constant model: documented 0, not nan


def test_stats_constant_residual_and_json() -> None:
    s = residual_stats(np.full(4, 2.0), np.ones(4))
    assert s.rms == 1.0
    assert s.crest_factor == 1.0
    assert s.rel_error_pct == pytest.approx(50.0)
    assert s.std == 0.0
    assert math.isnan(s.kurtosis) and math.isnan(s.skewness)
    assert s.correlation == 0.0
    d = s.to_dict()
    assert d["kurtosis"] is None and d["samples"] == 4
    json.dumps(d, allow_nan=False)


def test_correlation_with_itself_and_its_negative() -> None:
    x = np.sin(np.linspace(0.0, 6.0, 100)) + 0.3
    assert residual_stats(x, x).correlation == pytest.approx(1.0)
    assert residual_stats(x, -x).correlation == pytest.approx(-1.0)
    assert residual_stats(x, x).rms == 0.0


def test_stats_errors_and_non_finite() -> None:
    with pytest.raises(EstimationError, match="same shape"):
        residual_stats(np.zeros(5), np.zeros(6))
    with pytest.raises(EstimationError, match="at least 4"):
        residual_stats(np.zeros(3), np.zeros(3))
    with pytest.raises(EstimationError, match="at least 4"):
        residual_stats(np.array([1.0, 2.0, 3.0, np.nan]), np.zeros(4))
    s = residual_stats(np.array([1.0, -1.0, 2.0, -2.0, np.nan]), np.array([0, 0, 0, 0, 1.0]))
    assert s.samples == 4
    assert s.rms == pytest.approx(math.sqrt(2.5))


# ------------------------------------------------------------------ model torque
def test_model_reproduces_the_rigid_virtual_conveyor(rigid_run: Recording) -> None:
    model = model_torque(rigid_run, PROFILE, TRUE_PARAMETERS, PAYLOAD_KG)
    assert model.shape == rigid_run.torque.shape
    rep = residual_analysis(rigid_run, model)
    assert set(rep.by_phase) == {"accelerate", "constant", "decelerate"}
    # measured (6 ms, seed 1): constant 0.17 %, corr 0.998; whole movement
    # 2.5 %, corr 0.998
    assert rep.by_phase["constant"].rel_error_pct < 0.5
    assert rep.by_phase["constant"].correlation > 0.99
    assert rep.whole.correlation > 0.99
    assert rep.whole.rel_error_pct < 4.0
    # The rest of the whole movement's error is at the ramp corners: the
    # Savitzky-Golay derivative rounds off the kink in the speed (up to 0.42 Nm
    # for about 3 samples at the start of motion). The per-phase statistics
    # leave 3 samples out at each end of a phase for that reason.
    assert rep.whole.max_abs > 0.2
    assert rep.by_phase["decelerate"].max_abs < 0.1
    # With the standstill after the stop included, the holding torque left by
    # the speed controller (held by stiction, -0.35 Nm, not modelled) dominates.
    with_standstill = residual_analysis(rigid_run, model, include_standstill=True).whole
    assert with_standstill.samples == rigid_run.samples
    assert with_standstill.rel_error_pct > rep.whole.rel_error_pct  # 14.8 % vs 2.5 %
    assert with_standstill.correlation > 0.97  # 0.984


def test_wrong_payload_shows_as_friction_torque(rigid_run: Recording) -> None:
    wrong = model_torque(rigid_run, PROFILE, TRUE_PARAMETERS, PAYLOAD_KG + 30.0)
    mean = residual_analysis(rigid_run, wrong).by_phase["constant"].mean
    r, i, eta = PROFILE.chordal_radius_m, PROFILE.gear.ratio, PROFILE.gear.efficiency
    hand = 30.0 * G * MODEL.friction * r / (i * eta)  # 0.1398 Nm
    assert mean < 0.0
    assert -mean == pytest.approx(hand, rel=0.02)  # measured: 0.1397 Nm (0.03 %)


def test_model_torque_inputs(rigid_run: Recording) -> None:
    base = model_torque(rigid_run, PROFILE, TRUE_PARAMETERS, PAYLOAD_KG)
    values = np.array([TRUE_PARAMETERS[n] for n in PARAMETER_NAMES])
    rigid = RigidParameters(values=values, covariance=np.zeros((5, 5)))
    np.testing.assert_allclose(model_torque(rigid_run, PROFILE, rigid, PAYLOAD_KG), base)
    # tray from the argument, then the metadata, then the profile (10 kg)
    np.testing.assert_allclose(
        model_torque(rigid_run, PROFILE, TRUE_PARAMETERS, PAYLOAD_KG - 5.0, tray_kg=15.0), base
    )
    meta = dataclasses.replace(rigid_run, metadata=Metadata(tray_kg=15.0))
    np.testing.assert_allclose(model_torque(meta, PROFILE, TRUE_PARAMETERS, PAYLOAD_KG - 5.0), base)
    # no friction or sign term at standstill: zero torque there on a flat belt
    # (where the 5-sample derivative window sees standstill only)
    zero = (rigid_run.speed == 0.0).astype(float)
    still = np.convolve(zero, np.ones(5), mode="same") == 5.0
    assert still.sum() > 100
    np.testing.assert_allclose(base[still], 0.0, atol=1e-12)
    # all generating: belt-side terms scaled by η² against all motoring
    moving = rigid_run.speed != 0.0
    belt_only = {**TRUE_PARAMETERS, "BmA": 0.0, "BmB": 0.0, "BmC": 0.0, "J_d": 0.0}
    n = rigid_run.samples
    mot = model_torque(rigid_run, PROFILE, belt_only, PAYLOAD_KG, motoring=np.ones(n, dtype=bool))
    gen = model_torque(rigid_run, PROFILE, belt_only, PAYLOAD_KG, motoring=np.zeros(n, dtype=bool))
    eta = PROFILE.gear.efficiency
    np.testing.assert_allclose(gen[moving], mot[moving] * eta**2)
    with pytest.raises(EstimationError, match="'mu' is missing"):
        model_torque(rigid_run, PROFILE, {"BmA": 0.0}, 0.0)
    with pytest.raises(EstimationError, match="motoring mask"):
        model_torque(rigid_run, PROFILE, TRUE_PARAMETERS, 0.0, motoring=np.ones(3, dtype=bool))


# ------------------------------------------------------------------ per-phase report
def test_phase_pooling_corners_and_json(rigid_run: Recording) -> None:
    model = model_torque(rigid_run, PROFILE, TRUE_PARAMETERS, PAYLOAD_KG)
    phases = [
        Phase("standstill", 0, 0, 100, 0.0, 0.6),
        Phase("constant", 1, 100, 200, 0.6, 1.2),
        Phase("accelerate", 1, 200, 209, 1.2, 1.254),  # 9 - 6 = 3 samples: left out
        Phase("constant", 1, 300, 400, 1.8, 2.4),
        Phase("standstill", 0, 400, rigid_run.samples, 2.4, 12.288),
    ]
    rep = residual_analysis(rigid_run, model, phases=phases)
    assert set(rep.by_phase) == {"constant"}
    assert rep.by_phase["constant"].samples == 2 * (100 - 6)
    idx = np.r_[103:197, 303:397]
    expected = residual_stats(rigid_run.torque[idx], model[idx])
    assert rep.by_phase["constant"] == expected
    assert rep.whole.samples == 100 + 9 + 100
    np.testing.assert_array_equal(rep.residual, rigid_run.torque - model)
    d = rep.to_dict()
    assert set(d) == {"whole", "by_phase"}
    json.loads(json.dumps(d, allow_nan=False))
    assert isinstance(rep, ResidualReport)
    with pytest.raises(EstimationError, match="shape"):
        residual_analysis(rigid_run, model[:-1])
    with pytest.raises(EstimationError, match="at least 4"):
        residual_analysis(rigid_run, model, phases=[phases[0]])


# ------------------------------------------------------------------ belt position
def test_belt_position_advances_and_wraps() -> None:
    dt, n = 0.006, 2000
    t = np.arange(n) * dt
    omega = 450.0  # rad/s; v = ω·r/i ≈ 0.86 m/s, 10.4 m in 12 s: more than the 8.98 m loop
    theta0 = 1234.5
    rec = _recording({"time": t, "speed": np.full(n, omega), "position": theta0 + omega * t})
    x = belt_position_m(rec, PROFILE)
    loop = PROFILE.loop_length_m
    assert np.all((x >= 0.0) & (x < loop))
    v = omega * PROFILE.chordal_radius_m / _kinematic_ratio(PROFILE)
    step = np.diff(x)
    wraps = step < 0.0
    assert wraps.sum() == math.floor((x[0] + v * t[-1]) / loop) == 1
    np.testing.assert_allclose(np.where(wraps, step + loop, step), v * dt, rtol=1e-9)
    # the kinematic ratio (tooth counts) is the nameplate ratio within 1e-5
    assert v == pytest.approx(omega * PROFILE.belt_speed_per_motor_speed, rel=1e-5)
    # without a position channel: relative, from 0 at the first sample
    rel = belt_position_m(_recording({"time": t, "speed": np.full(n, omega)}), PROFILE)
    assert rel[0] == 0.0
    np.testing.assert_allclose(rel, np.mod(v * t, loop), atol=1e-9)


def test_belt_position_on_the_virtual_conveyor(rigid_run: Recording) -> None:
    x = belt_position_m(rigid_run, PROFILE)
    loop = PROFILE.loop_length_m
    assert np.all((x >= 0.0) & (x < loop))
    step = np.diff(x)
    travel = np.cumsum(np.where(step < -0.5 * loop, step + loop, step))
    v = rigid_run.speed * PROFILE.chordal_radius_m / _kinematic_ratio(PROFILE)
    expected = cumulative_trapezoid(v, rigid_run.time)
    # position quantised to 1/4096 rev (3 µm at the belt), speed sampled at 6 ms
    np.testing.assert_allclose(travel, expected, atol=2e-5)
    assert travel[-1] == pytest.approx(2.40, abs=0.05)  # 2.4 m over the move


def test_position_profile_hand_case() -> None:
    pos = np.array([0.01, 0.02, 0.03, 0.26, -0.01, np.nan, 0.05])
    val = np.array([1.0, 2.0, 3.0, 4.0, 5.0, 6.0, np.nan])
    # loop 0.1 m, 25 mm bins → 4 bins; 0.26 → 0.06 (bin 2), -0.01 → 0.09 (bin 3)
    sums, counts = position_profile(pos, val, 0.1)
    np.testing.assert_allclose(sums, [3.0, 3.0, 4.0, 5.0])
    np.testing.assert_allclose(counts, [2.0, 1.0, 1.0, 1.0])
    sums2, counts2 = position_profile(pos, val, 0.1, bins=2)
    np.testing.assert_allclose(sums2, [6.0, 9.0])
    np.testing.assert_allclose(counts2, [3.0, 2.0])
    assert position_profile(np.zeros(1), np.zeros(1), 0.3)[0].shape == (12,)
    assert position_profile(np.zeros(1), np.zeros(1), PROFILE.loop_length_m)[1].shape == (360,)
    with pytest.raises(EstimationError, match="same shape"):
        position_profile(np.zeros(2), np.zeros(3), 1.0)
    with pytest.raises(EstimationError, match="loop length"):
        position_profile(np.zeros(2), np.zeros(2), 0.0)
