"""Output-error fit: recover the virtual conveyor's parameters through the closed loop."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from conftest import REFERENCE_PROFILE

from chaintwin.errors import EstimationError, NotFittedError
from chaintwin.identify.output_error import (
    PARAMETER_NAMES,
    ConvergenceWarning,
    OutputErrorFit,
    StartResult,
)
from chaintwin.read.profile import ModelSpec, load_profile
from chaintwin.read.recording import Recording
from chaintwin.simulate import Realism, SimulationResult, run_virtual

PROFILE = load_profile(REFERENCE_PROFILE)


def _truth_model() -> ModelSpec:
    """What the virtual conveyor simulates (the profile's model); the fit never reads it."""
    model = PROFILE.model
    assert model is not None
    return model


TRUTH = _truth_model()
PAYLOAD_KG = 30.0
THREE = ("mu", "loss_viscous_nm_s_rad", "drive_inertia_scale")
# With one recording at one speed, BmC·ω|ω| (0.044 Nm at nominal speed) cannot be told
# from BmB·ω and μ; these tests give BmA and BmC their true values, as a calibration from
# recordings at several speeds would (see test_three_speeds_separate_the_losses).
KNOWN_LOSSES = {
    "loss_constant_nm": TRUTH.loss_constant_nm,
    "loss_quadratic_nm_s2_rad2": TRUTH.loss_quadratic_nm_s2_rad2,
}


def _virtual(realism: Realism, seed: int = 1, speed_rpm: float | None = None) -> Recording:
    return run_virtual(
        PROFILE,
        payload_kg=PAYLOAD_KG,
        realism=realism,
        seed=seed,
        sample_time_s=0.006,
        speed_rpm=speed_rpm,
    ).recording


@pytest.fixture(scope="module")
def clean() -> Recording:
    return _virtual(Realism.off())


@pytest.fixture(scope="module")
def clean_fit(clean: Recording) -> OutputErrorFit:
    return OutputErrorFit(parameters=THREE, fixed=KNOWN_LOSSES).fit(
        clean, PROFILE, payload_kg=PAYLOAD_KG
    )


def _truth(name: str) -> float:
    if name == "drive_inertia_scale":
        return 1.0
    return float(getattr(TRUTH, "friction" if name == "mu" else name))  # ModelSpec's name


# ---------------------------------------------------------------- (a) noise-free
def test_noise_free_recording_recovers_the_parameters(clean_fit: OutputErrorFit) -> None:
    # measured: friction +0.045 %, BmB -0.046 %, inertia scale -0.14 % (the 6 ms set
    # point samples round the ramp corners off); all four starts agree
    for name in THREE:
        assert clean_fit.theta_[name] == pytest.approx(_truth(name), rel=0.005), name
        assert 0.0 < clean_fit.stderr_[name] < 0.005 * _truth(name)
    assert clean_fit.agree_
    assert len(clean_fit.starts_) == 4
    assert all(isinstance(s, StartResult) and s.converged for s in clean_fit.starts_)
    assert min(s.cost for s in clean_fit.starts_) == pytest.approx(clean_fit.cost_)
    assert clean_fit.nfev_ >= sum(s.nfev for s in clean_fit.starts_)
    assert clean_fit.covariance_.shape == (3, 3)
    assert clean_fit.rms_torque_nm_ < 0.01  # Nm, against a 1.5 Nm peak
    assert clean_fit.rms_speed_rad_s_ < 0.02


def test_bmc_fitted_too_on_noise_free_data(clean: Recording) -> None:
    fit = OutputErrorFit(parameters=(*THREE, "loss_quadratic_nm_s2_rad2")).fit(
        clean, PROFILE, payload_kg=PAYLOAD_KG
    )
    # measured: friction +0.21 %, BmB -0.65 %, scale -0.13 %, BmC +3.2 % (BmA left at 0)
    for name in THREE:
        assert fit.theta_[name] == pytest.approx(_truth(name), rel=0.01), name
    assert fit.theta_["loss_quadratic_nm_s2_rad2"] == pytest.approx(
        TRUTH.loss_quadratic_nm_s2_rad2, rel=0.1
    )


def test_predict_reproduces_the_recording(clean: Recording, clean_fit: OutputErrorFit) -> None:
    sim = clean_fit.predict(clean, PROFILE, PAYLOAD_KG)
    assert isinstance(sim, SimulationResult)
    assert sim.success
    np.testing.assert_array_equal(sim.time, clean.time)
    assert sim.torque.shape == clean.torque.shape
    # the simulated position set point is the recorded one
    assert clean.position_setpoint is not None
    np.testing.assert_allclose(sim.position_setpoint, clean.position_setpoint, atol=1e-9)
    moving = np.abs(clean.speed) > 5.0
    assert np.sqrt(np.mean((sim.torque - clean.torque)[moving] ** 2)) < 0.02
    plant = clean_fit.plant_parameters(PROFILE, payload_kg=PAYLOAD_KG)
    assert plant.mu == clean_fit.theta_["mu"]
    assert plant.loss_quadratic_nm_s2_rad2 == TRUTH.loss_quadratic_nm_s2_rad2
    assert not (plant.elastic or plant.stick_slip or plant.polygon)


def test_the_profile_model_section_is_not_read(clean: Recording) -> None:
    wrong = PROFILE.model_copy(update={"model": ModelSpec(friction=0.9, loss_viscous_nm_s_rad=0.1)})
    settings = {"parameters": THREE, "fixed": KNOWN_LOSSES, "starts": 1}
    a = OutputErrorFit(**settings).fit(clean, PROFILE, payload_kg=PAYLOAD_KG)  # type: ignore[arg-type]
    b = OutputErrorFit(**settings).fit(clean, wrong, payload_kg=PAYLOAD_KG)  # type: ignore[arg-type]
    assert a.theta_ == b.theta_


def test_recording_without_position_setpoint_integrates_the_speed(clean: Recording) -> None:
    channels = {k: v for k, v in clean.channels.items() if k != "position_setpoint"}
    rec = dataclasses.replace(clean, channels=channels)
    fit = OutputErrorFit(parameters=THREE, fixed=KNOWN_LOSSES, starts=1).fit(
        rec, PROFILE, payload_kg=PAYLOAD_KG
    )
    assert fit.theta_["mu"] == pytest.approx(TRUTH.friction, rel=0.01)


# ---------------------------------------------------------------- (b) realism on
def test_realistic_recording_recovers_friction_and_viscous_loss() -> None:
    # noise, quantisation, elastic belt, stick-slip, polygon effect, gear mesh ripple,
    # random scope phase. Measured (seed 1): friction -0.49 %, BmB +0.50 %, inertia scale
    # -0.18 %; over seeds 1-6 friction stayed within ±0.9 % and BmB within ±1.0 %.
    rec = _virtual(Realism(), seed=1)
    fit = OutputErrorFit(parameters=THREE, fixed=KNOWN_LOSSES).fit(
        rec, PROFILE, payload_kg=PAYLOAD_KG
    )
    assert fit.theta_["mu"] == pytest.approx(TRUTH.friction, rel=0.03)
    assert fit.theta_["loss_viscous_nm_s_rad"] == pytest.approx(
        TRUTH.loss_viscous_nm_s_rad, rel=0.15
    )
    assert fit.theta_["drive_inertia_scale"] == pytest.approx(1.0, rel=0.03)
    assert fit.agree_
    # the polygon ripple (not in the rigid model) dominates what is left: ~0.06 Nm RMS
    assert fit.rms_torque_nm_ < 0.1


def test_three_speeds_separate_the_losses() -> None:
    # Nothing fixed from the truth (BmA left at 0: 1.1e-4 Nm, below what one load can
    # tell from friction). Measured (seeds 1, 11, 21, 31, 41): friction within 1.1 %,
    # BmB within 4.4 %, inertia scale within 0.8 %, BmC within 22 %.
    recs = [
        _virtual(Realism(), seed=1 + i, speed_rpm=rpm) for i, rpm in enumerate((1415, 900, 500))
    ]
    fit = OutputErrorFit(parameters=(*THREE, "loss_quadratic_nm_s2_rad2")).fit(
        recs, PROFILE, payload_kg=PAYLOAD_KG
    )
    assert fit.theta_["mu"] == pytest.approx(TRUTH.friction, rel=0.03)
    assert fit.theta_["loss_viscous_nm_s_rad"] == pytest.approx(
        TRUTH.loss_viscous_nm_s_rad, rel=0.15
    )
    assert fit.theta_["drive_inertia_scale"] == pytest.approx(1.0, rel=0.03)
    assert fit.theta_["loss_quadratic_nm_s2_rad2"] == pytest.approx(
        TRUTH.loss_quadratic_nm_s2_rad2, rel=0.5
    )
    assert fit.agree_


# ---------------------------------------------------------------- (c), (d) contract
def test_unfitted_use_raises(clean: Recording) -> None:
    fit = OutputErrorFit()
    for name in ("theta_", "stderr_", "cost_", "starts_", "agree_", "nfev_", "covariance_"):
        with pytest.raises(NotFittedError):
            getattr(fit, name)
    with pytest.raises(NotFittedError):
        fit.predict(clean, PROFILE, PAYLOAD_KG)
    with pytest.raises(NotFittedError):
        fit.plant_parameters(PROFILE, payload_kg=0.0)


def test_recording_without_speed_setpoint_is_refused(clean: Recording) -> None:
    channels = {k: v for k, v in clean.channels.items() if k != "speed_setpoint"}
    rec = dataclasses.replace(clean, channels=channels)
    with pytest.raises(EstimationError, match=r"no speed_setpoint channel.*record the speed set"):
        OutputErrorFit().fit(rec, PROFILE, payload_kg=PAYLOAD_KG)


def test_recording_that_starts_in_motion_is_refused(clean: Recording) -> None:
    cut = int(np.argmax(np.abs(clean.speed) > 50.0))
    channels = {k: v[cut:] for k, v in clean.channels.items()}
    with pytest.raises(EstimationError, match="starts in motion"):
        OutputErrorFit().fit(
            dataclasses.replace(clean, channels=channels), PROFILE, payload_kg=PAYLOAD_KG
        )


@pytest.mark.parametrize(
    ("settings", "match"),
    [
        ({"parameters": ("mu", "stiffness")}, "unknown parameter"),
        ({"parameters": ()}, "at least one"),
        ({"parameters": ("mu", "mu")}, "twice"),
        ({"bounds": {"loss_constant_nm": (0.0, 1.0)}}, "not fitted"),
        ({"bounds": {"mu": (0.5, 0.1)}}, "lower < upper"),
        ({"fixed": {"mu": 0.2}}, "also fitted"),
        ({"fixed": {"loss_constant_nm": -1.0}}, "finite number ≥ 0"),
        ({"starts": 0}, "starts"),
    ],
)
def test_invalid_settings_are_refused(
    clean: Recording, settings: dict[str, object], match: str
) -> None:
    fit = OutputErrorFit(**settings)  # type: ignore[arg-type]
    with pytest.raises(EstimationError, match=match):
        fit.fit(clean, PROFILE, payload_kg=PAYLOAD_KG)


def test_payload_count_must_match(clean: Recording) -> None:
    with pytest.raises(EstimationError, match="one per recording"):
        OutputErrorFit().fit([clean, clean], PROFILE, payload_kg=[1.0])
    with pytest.raises(EstimationError, match="payload_kg"):
        OutputErrorFit().fit(clean, PROFILE, payload_kg=-1.0)


def test_poor_convergence_warns(clean: Recording) -> None:
    fit = OutputErrorFit(parameters=THREE, starts=2, max_nfev=1)
    with pytest.warns(ConvergenceWarning):
        fit.fit(clean, PROFILE, payload_kg=PAYLOAD_KG)
    assert not all(s.converged for s in fit.starts_)


def test_parameter_names_are_documented() -> None:
    assert set(THREE) <= set(PARAMETER_NAMES)
    assert "mu" in repr(OutputErrorFit())
