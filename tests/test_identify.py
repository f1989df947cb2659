"""Identification, calibration and weighing: known answers on the virtual conveyor."""

from __future__ import annotations

import dataclasses
import json
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import REFERENCE_PROFILE

from chaintwin.calibrating.procedure import calibrate
from chaintwin.cli.app import main
from chaintwin.errors import CalibrationError, EstimationError, NotFittedError
from chaintwin.identify.calibration import (
    Calibration,
    load_calibration,
    sensitivity_nm_per_kg,
)
from chaintwin.identify.regression import RigidModelRegression
from chaintwin.model.rigid import PARAMETER_NAMES
from chaintwin.read.profile import ModelSpec, load_profile
from chaintwin.read.recording import Recording
from chaintwin.read.writer import write_recording
from chaintwin.simulate.faults import Fault
from chaintwin.simulate.virtual import Realism, run_virtual
from chaintwin.validate import Inspection, inspect_recording
from chaintwin.weigh import transport_loss_factor, weigh

PROFILE = load_profile(REFERENCE_PROFILE)
MODEL = PROFILE.model
assert MODEL is not None
J_D = PROFILE.motor.inertia_kgm2 + PROFILE.gear.inertia_kgm2


def inspected(
    payload: float, seed: int, *, realism: Realism | None = None, known: bool = True, **kw: object
) -> Inspection:
    run = run_virtual(
        PROFILE,
        payload_kg=payload,
        seed=seed,
        realism=realism,
        calibration=known,
        **kw,  # type: ignore[arg-type]
    )
    return inspect_recording(run.recording, PROFILE)


def virtual(
    payload: float, seed: int, *, realism: Realism | None = None, known: bool = True, **kw: object
) -> Recording:
    return inspected(payload, seed, realism=realism, known=known, **kw).recording


SEVERAL = [(0, 1.0), (30, 1.0), (60, 1.0), (90, 1.0), (0, 0.5), (60, 0.6)]


@pytest.fixture(scope="module")
def realistic_set() -> list[Recording]:
    return [
        virtual(load, 200 + k, speed_rpm=1415 * share) for k, (load, share) in enumerate(SEVERAL)
    ]


@pytest.fixture(scope="module")
def cal_p2() -> Calibration:
    recs = [virtual(load, 300 + k) for k, load in enumerate([0, 0, 0, 50])]
    return calibrate(recs, PROFILE)


def test_rigid_noise_free_recovers_every_parameter() -> None:
    recs = [
        virtual(load, 100 + k, realism=Realism.off(), speed_rpm=1415 * share)
        for k, (load, share) in enumerate(SEVERAL)
    ]
    est = RigidModelRegression().fit(recs, PROFILE)
    p = est.parameters_
    assert p["mu"] == pytest.approx(MODEL.friction, rel=2e-3)
    assert p["J_d"] == pytest.approx(J_D, rel=5e-3)
    assert p["BmB"] == pytest.approx(MODEL.loss_viscous_nm_s_rad, rel=0.01)
    assert p["BmC"] == pytest.approx(MODEL.loss_quadratic_nm_s2_rad2, rel=0.05)
    assert abs(p["BmA"] - MODEL.loss_constant_nm) < 1e-3  # 0.1 % of the friction torque
    assert est.warnings_ == ()


def test_realistic_several_loads_and_speeds_meets_targets(realistic_set: list[Recording]) -> None:
    """Issue target: mu within 3 %, BmB known to 10 % (all realism on).

    BmB: its standard error is within the target and the true value within
    three of them (with the set point's noise in the actual torque this
    realisation lies 1.4 standard errors low, 12 %).
    """
    est = RigidModelRegression().fit(realistic_set, PROFILE)
    p = est.parameters_
    assert p["mu"] == pytest.approx(MODEL.friction, rel=0.03)
    assert p.stderr("BmB") <= 0.10 * MODEL.loss_viscous_nm_s_rad
    assert abs(p["BmB"] - MODEL.loss_viscous_nm_s_rad) < 3 * p.stderr("BmB")
    assert p["J_d"] == pytest.approx(J_D, rel=0.03)
    # the true value lies within 3 standard errors
    assert abs(p["mu"] - MODEL.friction) < 3 * p.stderr("mu")


def test_one_load_cannot_separate_friction_from_bma() -> None:
    recs = [virtual(0, 400 + k) for k in range(2)]
    cal = calibrate(recs, PROFILE)
    codes = [w.code for w in cal.warnings]
    assert "friction_not_separable" in codes
    assert "calibration_weak" in codes
    assert cal.case == "one_load_one_speed"
    assert cal.parameters.fixed == ("BmA",)
    assert cal.parameters.stderr("BmA") == 0.0
    rec = cal.recommendation()
    assert rec is not None
    assert "reference load" in rec
    assert "two or three speeds" in rec
    assert cal.sensitivity_rel_uncertainty > 0.0


@pytest.mark.parametrize(
    ("name", "sample_time"), [("white-belt-01", 0.006), ("incline-line-02", 0.012)]
)
def test_one_load_one_speed_uncertainty_covers_the_ramp_bias(name: str, sample_time: float) -> None:
    """Empty runs at one speed: the sensitivity error stays within its reported uncertainty.

    Before the ramp check, incline-line-02 at 12 ms was 5.3 % off with a stated
    1.6 % (3.3 sigma); the extrapolation of the losses to standstill is biased
    by what the rigid model misses in the ramps, which its statistics do not see.
    """
    prof = load_profile(REFERENCE_PROFILE.parent / f"{name}.yaml")
    assert prof.model is not None
    recs = [
        inspect_recording(
            run_virtual(
                prof, payload_kg=0.0, seed=100 + k, sample_time_s=sample_time, calibration=True
            ).recording,
            prof,
        ).recording
        for k in range(3)
    ]
    cal = calibrate(recs, prof)
    assert cal.case == "one_load_one_speed"
    notes = [w.message for w in cal.warnings if w.code == "ramp_check"]
    assert len(notes) == 1 and "accelerating ramps alone give mu" in notes[0]
    plain = RigidModelRegression().fit(recs, prof).parameters_
    assert cal.parameters.stderr("mu") > plain.stderr("mu")  # the check adds to it
    assert cal.parameters["mu"] == plain["mu"]  # and leaves the estimate alone
    true = sensitivity_nm_per_kg(prof, prof.model.friction)
    error = cal.sensitivity_nm_per_kg / true - 1.0
    assert abs(error) < 2.0 * cal.sensitivity_rel_uncertainty


def test_a_constant_loss_below_zero_is_refitted_without_it_by_hand() -> None:
    """A several-loads fit with BmA = -1.15 ± 0.32 N·m (3.6 standard errors below
    zero) and μ = 0.348: refitted with BmA fixed at 0 (μ = 0.1225 ± 0.02), half
    the difference of the two μ (0.11275) joins μ's uncertainty:
    sqrt(0.02² + 0.11275²) = 0.1145. A BmA only 0.3 standard errors below zero
    is kept as it is, refit not asked."""
    from chaintwin.calibrating.procedure import _constant_loss_check
    from chaintwin.model.rigid import RigidParameters

    def params(mu: float, bma: float, sd_mu: float, sd_bma: float) -> RigidParameters:
        cov = np.diag([1e-8, sd_mu**2, sd_bma**2, 1e-8, 1e-12])
        return RigidParameters(np.array([0.003, mu, bma, 0.0023, 0.0]), cov, ())

    asked: list[bool] = []

    class Refit:
        fit_bma = True

        def fit(self, recordings: list[Recording], profile: Any) -> Any:
            asked.append(self.fit_bma)
            return dataclasses.make_dataclass("Fitted", ["parameters_"])(
                RigidParameters(
                    np.array([0.003, 0.1225, 0.0, 0.0038, 0.0]),
                    np.diag([1e-8, 0.02**2, 0.0, 1e-8, 1e-12]),
                    ("BmA",),
                )
            )

    checked, notes = _constant_loss_check(Refit(), [], PROFILE, params(0.348, -1.15, 0.056, 0.32))  # type: ignore[arg-type]
    assert asked == [False]  # refitted with BmA fixed
    assert checked["mu"] == pytest.approx(0.1225) and checked["BmA"] == 0.0
    assert checked.stderr("mu") == pytest.approx(np.hypot(0.02, 0.5 * (0.348 - 0.1225)))
    assert [n.code for n in notes] == ["losses_not_physical"]
    kept, none = _constant_loss_check(Refit(), [], PROFILE, params(0.2, -0.1, 0.05, 0.32))  # type: ignore[arg-type]
    assert none == [] and kept["BmA"] == -0.1 and asked == [False]


def test_one_load_several_speeds_case() -> None:
    recs = [virtual(0, 410, speed_rpm=1415), virtual(0, 411, speed_rpm=700)]
    cal = calibrate(recs, PROFILE)
    assert cal.case == "one_load_several_speeds"


def test_model_section_is_never_read() -> None:
    recs = [virtual(load, 420 + k) for k, load in enumerate([0, 40])]
    absurd = PROFILE.model_copy(
        update={"model": ModelSpec(friction=1.9, loss_viscous_nm_s_rad=9.0, loss_constant_nm=5.0)}
    )
    bare = PROFILE.model_copy(update={"model": None})
    a = calibrate(recs, absurd).parameters.values
    b = calibrate(recs, bare).parameters.values
    np.testing.assert_array_equal(a, b)


def test_calibration_file_round_trip_and_tamper(cal_p2: Calibration, tmp_path: Path) -> None:
    path = cal_p2.save(tmp_path / "cal.json")
    back = load_calibration(path)
    np.testing.assert_array_equal(back.parameters.values, cal_p2.parameters.values)
    np.testing.assert_array_equal(back.parameters.covariance, cal_p2.parameters.covariance)
    assert back.profile_hash == cal_p2.profile_hash
    assert back.inertia_gain == cal_p2.inertia_gain
    data = json.loads(path.read_text())
    assert data["format"] == "chaintwin.calibration"
    assert data["conveyor"] == "white-belt-01"
    assert len(data["recordings"]) == 4
    data["profile"]["tray_mass_kg"] = 99.0
    (tmp_path / "edited.json").write_text(json.dumps(data))
    with pytest.raises(CalibrationError, match="does not match its hash"):
        load_calibration(tmp_path / "edited.json")
    (tmp_path / "other.json").write_text('{"a": 1}')
    with pytest.raises(CalibrationError, match="not a chaintwin calibration"):
        load_calibration(tmp_path / "other.json")
    (tmp_path / "broken.json").write_text("{")
    with pytest.raises(CalibrationError, match="line 1"):
        load_calibration(tmp_path / "broken.json")


def test_weigh_p2_belt_scale_class(cal_p2: Calibration) -> None:
    """With the calibration's losses trusted: belt scale; by default: honest.

    By default a ±10 % loss drift is allowed for; on this conveyor it is worth
    4 kg on the friction signature, so the payload leans on the inertia
    signature (±1.4 kg at no load): about ±2-4 kg, one standard uncertainty.
    """
    from chaintwin.weigh import LossDrift

    for payload, seed in ((0.0, 501), (40.0, 502), (100.0, 503)):
        ins = inspected(payload, seed, known=False)
        res = weigh(ins, cal_p2, loss_drift=LossDrift())
        assert res.payload_kg == pytest.approx(payload, abs=0.5), res
        assert res.consistent
        assert res.segments == ()
        assert 0 < res.uncertainty_kg < 1.0
        assert res.payload_inertia_kg == pytest.approx(payload, abs=4 * res.inertia_uncertainty_kg)
        # the default allows for a ±10 % loss drift the recording cannot rule out
        default = weigh(ins, cal_p2)
        assert default.loss_drift == LossDrift.unknown()
        assert default.uncertainty_kg > res.uncertainty_kg
        assert default.uncertainty_kg < 4.0
        assert default.payload_kg == pytest.approx(payload, abs=2.5 * default.uncertainty_kg)


def test_friction_rise_is_unweighable_or_weighed_honestly(cal_p2: Calibration) -> None:
    """A 10 % friction rise at 20 kg: never a wrong number.

    Trusting the calibration's losses, the signatures disagree: no payload,
    the warning ``unweighable`` with both readings. With the default loss
    drift allowance the rise is within what a drift could do, and the
    payload leans on the inertia signature: within its uncertainty.
    """
    from chaintwin.weigh import LossDrift, reweigh

    ins = inspected(20.0, 510, known=False, faults=[Fault("friction", 0.1)])
    res = weigh(ins, cal_p2, loss_drift=LossDrift())
    assert not res.consistent
    assert res.payload_kg is None and res.uncertainty_kg is None and res.tlf is None
    assert res.payload_friction_kg is None and res.payload_inertia_kg is None
    assert res.unweighable is not None and "friction signature says" in res.unweighable
    assert [w.code for w in res.warnings].count("unweighable") == 1
    assert res.signatures is not None and res.signatures.friction_kg > 24.0
    assert res.to_dict()["payload_kg"] is None
    default = weigh(ins, cal_p2)
    assert default.payload_kg == pytest.approx(20.0, abs=2.5 * default.uncertainty_kg)
    # monitoring with a friction alarm open hands the payload to the inertia signature
    by_inertia = reweigh(res, LossDrift(), friction=False)
    assert by_inertia.payload_kg == pytest.approx(20.0, abs=3 * by_inertia.uncertainty_kg)
    assert "weighed_by_inertia" in [w.code for w in by_inertia.warnings]
    assert by_inertia.unweighable is None


def test_payload_step_is_found_and_weighed_per_segment(cal_p2: Calibration) -> None:
    run = run_virtual(PROFILE, payload_kg=15.0, seed=520, faults=[Fault("payload_step", 1.0)])
    res = weigh(inspect_recording(run.recording, PROFILE), cal_p2)
    assert len(res.segments) == 2
    t_step = run.truth["payload_step_time_s"]
    assert res.segments[0].end_s == pytest.approx(t_step, abs=0.3)
    assert res.segments[0].payload_kg == pytest.approx(15.0, abs=1.0)
    assert res.segments[1].payload_kg == pytest.approx(35.0, abs=1.0)
    # the payload combines the last part's friction signature with the inertia
    # signature: within two of its reported uncertainties
    assert res.uncertainty_kg is not None
    assert res.payload_kg == pytest.approx(35.0, abs=2 * res.uncertainty_kg)
    assert "payload_changed" in [w.code for w in res.warnings]


def test_incomplete_cycle_weighed_with_warning(cal_p2: Calibration) -> None:
    ins = inspected(30.0, 530, known=False, sample_time_s=0.001)
    assert ins.recording.has_warning("incomplete_cycle")
    res = weigh(ins, cal_p2)
    codes = [w.code for w in res.warnings]
    assert "weighed_incomplete_cycle" in codes
    assert "incomplete_cycle" in codes
    assert res.payload_kg == pytest.approx(30.0, abs=3 * res.uncertainty_kg + 0.5)


def test_no_motion_is_unweighable(cal_p2: Calibration) -> None:
    from chaintwin.simulate.setpoints import trapezoid

    still = trapezoid(speed_rad_s=0.0, accel_rad_s2=1.0, hold_s=1.0)
    ins = inspected(0.0, 540, setpoints=still)
    assert ins.recording.has_warning("no_motion")
    res = weigh(ins, cal_p2)
    assert res.payload_kg is None
    assert res.unweighable is not None and "does not move" in res.unweighable


def test_transport_loss_factor_hand_case(cal_p2: Calibration) -> None:
    """Flat conveyor, nearly constant speed: f_T = mu (m_b + m_t + m_p) / m_p."""
    rec = virtual(60.0, 550, realism=Realism.off())
    tlf = transport_loss_factor(rec, PROFILE, cal_p2.parameters, 60.0)
    hand = MODEL.friction * (PROFILE.belt_mass_kg + 10.0 + 60.0) / 60.0
    assert tlf == pytest.approx(hand, rel=0.02)
    assert transport_loss_factor(rec, PROFILE, cal_p2.parameters, 0.5) is None


def test_estimator_contract() -> None:
    est = RigidModelRegression(window_s=0.05)
    with pytest.raises(NotFittedError):
        est.predict(virtual(0, 560), payload_kg=0.0)
    with pytest.raises(NotFittedError):
        _ = est.stderr_
    with pytest.raises(EstimationError, match="no payload_kg"):
        est.fit([virtual(10, 561, known=False)], PROFILE)
    rec = virtual(10, 562, realism=Realism.off())
    est.fit([rec, virtual(50, 563, realism=Realism.off())], PROFILE)
    model = est.predict(rec, payload_kg=10.0)
    steady = (rec.time > 3) & (rec.time < 7)
    np.testing.assert_allclose(model[steady].mean(), rec.torque[steady].mean(), rtol=2e-3)


def test_cli_identify_calibrate_weigh(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    files = []
    for k, load in enumerate([0, 0, 50]):
        run = run_virtual(PROFILE, payload_kg=load, seed=600 + k, calibration=True)
        files.append(str(write_recording(run.recording, tmp_path / f"cal{k}.csv")))
    assert main(["identify", "--profile", str(REFERENCE_PROFILE), *files, "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    for key in ("mu", "BmA", "BmB", "BmC", "inertia_kgm2", "torque_lag_s"):
        assert key in out
        assert f"{key}_stderr" in out
    assert out["torque_lag_s"] is None
    assert isinstance(out["warnings"], list)
    cal = tmp_path / "cal.json"
    code = main(["calibrate", "--profile", str(REFERENCE_PROFILE), *files, "--out", str(cal)])
    assert code == 0
    capsys.readouterr()
    run = run_virtual(PROFILE, payload_kg=25.0, seed=610)
    rec = write_recording(run.recording, tmp_path / "today.csv")
    bad = tmp_path / "bad.csv"
    bad.write_text("time [s],speed [rpm]\n")
    code = main(["weigh", "--calibration", str(cal), str(rec), str(bad), "--json"])
    results = json.loads(capsys.readouterr().out)
    assert code == 2
    assert set(results[0]) >= {
        "file",
        "payload_kg",
        "uncertainty_kg",
        "payload_friction_kg",
        "payload_inertia_kg",
        "consistent",
        "segments",
        "tlf",
        "warnings",
    }
    assert results[0]["file"] == str(rec)
    assert results[0]["payload_kg"] == pytest.approx(25.0, abs=2 * results[0]["uncertainty_kg"])
    assert results[1]["file"] == str(bad)
    assert "missing required column 'torque'" in results[1]["error"]


def test_cli_refuses_foreign_conveyor_and_takes_column_maps(
    cal_p2: Calibration, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from conftest import EXAMPLES

    cal = cal_p2.save(tmp_path / "cal.json")
    other = load_profile(EXAMPLES / "profiles" / "short-fast-03.yaml")
    foreign = write_recording(
        run_virtual(other, payload_kg=10.0, seed=700).recording, tmp_path / "foreign.csv"
    )
    vendor = EXAMPLES / "vendor" / "white-belt-01-vendor-export.csv"
    cmap = EXAMPLES / "columns" / "vendor-de.yaml"
    code = main(["weigh", "--calibration", str(cal), str(foreign), str(vendor),
                 "--columns", str(cmap), "--json", "--loss-drift", "0"])  # fmt: skip
    captured = capsys.readouterr()
    out = json.loads(captured.out)
    assert code == 2
    assert "not of 'white-belt-01'" in out[0]["error"]
    assert out[1]["payload_kg"] == pytest.approx(30.0, abs=1.0)
    assert captured.err.strip() == "1 weighed, 0 unweighable, 1 refused"


def test_cli_bad_output_path_is_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    recs = []
    for k in range(2):
        run = run_virtual(PROFILE, payload_kg=0.0, seed=710 + k, calibration=True)
        recs.append(str(write_recording(run.recording, tmp_path / f"c{k}.csv")))
    code = main(["calibrate", "--profile", str(REFERENCE_PROFILE), *recs,
                 "--out", str(tmp_path / "missing" / "c.json")])  # fmt: skip
    err = capsys.readouterr().err
    assert code == 2
    assert "cannot write the calibration" in err
    assert err.count("\n") == 1
    code = main(["simulate", "--profile", str(REFERENCE_PROFILE), "--out", str(tmp_path)])
    err = capsys.readouterr().err
    assert code == 2
    assert "cannot write the recording" in err


def test_weigh_short_slices_are_weighed_or_refused_never_crash(cal_p2: Calibration) -> None:
    """Slices of a steady run without position channels: weighed or unweighable, never a crash."""
    from dataclasses import replace as dc_replace

    rec = virtual(20.0, 720, known=False)
    outcomes = set()
    for length in (0.2, 0.5, 0.6, 0.8, 1.5):
        keep = (rec.time > 4.0) & (rec.time < 4.0 + length)
        short = dc_replace(
            rec,
            channels={k: v[keep] for k, v in rec.channels.items() if "position" not in k},
            warnings=(),
        )
        res = weigh(inspect_recording(short, PROFILE), cal_p2)
        if res.payload_kg is None:
            assert res.unweighable
            outcomes.add("unweighable")
        else:
            outcomes.add("weighed")
            assert res.payload_kg == pytest.approx(20.0, abs=3 * res.uncertainty_kg)
    assert outcomes == {"unweighable", "weighed"}


def _without_setpoints(rec: Recording) -> Inspection:
    """The same recording as a drive that scopes actual values only would write it."""
    keep = {k: v for k, v in rec.channels.items() if not k.endswith("_setpoint")}
    bare = dataclasses.replace(rec, channels=keep, warnings=())
    return inspect_recording(bare, PROFILE)


def test_recordings_without_set_points_are_calibrated_and_weighed(cal_p2: Calibration) -> None:
    """Steady phases come from the segmented actual speed when no set point is scoped."""
    recs = [
        _without_setpoints(virtual(load, 300 + k)).recording for k, load in enumerate([0, 0, 0, 50])
    ]
    cal = calibrate(recs, PROFILE)
    assert cal.case == cal_p2.case
    assert cal.parameters["mu"] == pytest.approx(cal_p2.parameters["mu"], rel=0.01)
    ins = inspected(40.0, 502, known=False)
    bare = _without_setpoints(ins.recording)
    assert bare.recording.speed_setpoint is None
    with_sp, without = weigh(ins, cal_p2), weigh(bare, cal)
    assert without.payload_kg == pytest.approx(40.0, abs=0.5)
    # the friction signature reads the same plateaus either way; the combined
    # payloads (their calibrations differ) agree within a tenth of their
    # uncertainties
    assert without.payload_friction_kg == pytest.approx(with_sp.payload_friction_kg, abs=0.3)
    assert without.uncertainty_kg is not None and with_sp.uncertainty_kg is not None
    both = float(np.hypot(without.uncertainty_kg, with_sp.uncertainty_kg))
    assert without.payload_kg == pytest.approx(with_sp.payload_kg, abs=0.1 * both)
    assert without.consistent


def test_a_calibration_with_impossible_numbers_is_refused(
    cal_p2: Calibration, tmp_path: Path
) -> None:
    path = cal_p2.save(tmp_path / "cal.json")
    good = json.loads(path.read_text())
    mu, jd = PARAMETER_NAMES.index("mu"), PARAMETER_NAMES.index("J_d")

    def edited(edit: Callable[[dict[str, Any]], None]) -> Path:
        data = json.loads(json.dumps(good))
        edit(data)
        out = tmp_path / "edited.json"
        out.write_text(json.dumps(data))
        return out

    def values(k: int, v: float) -> Callable[[dict[str, Any]], None]:
        return lambda d: d["parameters"]["values"].__setitem__(k, v)

    cases: list[tuple[Callable[[dict[str, Any]], None], str]] = [
        (values(mu, -0.1), "friction coefficient mu is -0.1"),
        (values(mu, 40.0), "friction coefficient mu is 40"),
        (values(jd, 0.0), "drive inertia J_d is 0"),
        (values(PARAMETER_NAMES.index("BmB"), 5.0), "more than the drive's torque limit"),
        (lambda d: d["inertia_signature"].__setitem__("gain", 0.0), "gain is 0, not positive"),
        (lambda d: d.__setitem__("recordings", "abc"), "'recordings' must be a list"),
        (lambda d: d["parameters"]["covariance"][0].__setitem__(0, -1.0), "not a covariance"),
    ]
    for edit, message in cases:
        with pytest.raises(CalibrationError, match=re.escape(message)):
            load_calibration(edited(edit))
    assert load_calibration(edited(lambda d: None)).case == cal_p2.case


def test_a_loss_drift_allowance_widens_the_signatures_by_hand(
    cal_p2: Calibration,
) -> None:
    """The drift's effect on the friction signature: a hand calculation and a refit agree."""
    import dataclasses

    from chaintwin.model.rigid import RigidParameters
    from chaintwin.weigh import LossDrift, reweigh
    from chaintwin.weigh.drift import LOSS_DRIFT_REL

    ins = inspected(40.0, 502, known=False)
    plain = weigh(ins, cal_p2, loss_drift=LossDrift())
    drift = weigh(ins, cal_p2, loss_drift=LossDrift.unknown())
    assert plain.signatures is not None
    k_f = plain.signatures.drift_friction_kg
    # by hand: BmA + BmB·ω + BmC·ω² at the plateau's 1415 rpm over g·μ·r/(i·η)
    # (flat): the losses of about 75 kg of payload. The fit also sees the
    # ramps, where the speed and so the viscous loss are lower: within 15 %.
    w = 1415 * 2 * np.pi / 60
    bma, bmb, bmc = cal_p2.parameters.losses
    loss = bma + bmb * w + bmc * w * w
    sens = 9.81 * cal_p2.parameters["mu"] * PROFILE.chordal_radius_m
    sens /= PROFILE.kinematic_ratio * PROFILE.gear.efficiency
    assert k_f == pytest.approx(loss / sens, rel=0.15)
    # a second method: weigh with the calibration's losses 5 % higher
    values = cal_p2.parameters.values.copy()
    values[2:] *= 1.05
    params = RigidParameters(values, cal_p2.parameters.covariance, cal_p2.parameters.fixed)
    higher = weigh(ins, dataclasses.replace(cal_p2, parameters=params), loss_drift=LossDrift())
    assert higher.payload_friction_kg is not None and plain.payload_friction_kg is not None
    moved = plain.payload_friction_kg - higher.payload_friction_kg
    assert moved == pytest.approx(0.05 * k_f, rel=0.02)
    # the allowance adds (σ·k_f)² to the friction signature's variance
    assert drift.friction_uncertainty_kg is not None and plain.friction_uncertainty_kg is not None
    added = np.sqrt(drift.friction_uncertainty_kg**2 - plain.friction_uncertainty_kg**2)
    assert added == pytest.approx(LOSS_DRIFT_REL * k_f, rel=1e-9)
    # a known drift moves the friction signature by drift times k_f
    known = weigh(ins, cal_p2, loss_drift=LossDrift(0.05, 0.0))
    assert known.payload_friction_kg == pytest.approx(plain.payload_friction_kg - 0.05 * k_f)
    # combining again from the stored signatures gives what weighing with it gives
    again = reweigh(plain, LossDrift.unknown())
    assert again.payload_kg == pytest.approx(drift.payload_kg, rel=1e-12)
    assert again.uncertainty_kg == pytest.approx(drift.uncertainty_kg, rel=1e-12)


def test_a_direction_the_calibration_never_ran_is_unweighable(
    cal_p2: Calibration, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Weighed backwards with a forward-only calibration: no number, exit code 0."""
    from chaintwin.simulate.virtual import default_setpoints

    assert cal_p2.directions == {1}
    back_sp = default_setpoints(PROFILE, duration_s=12.0, direction=-1)
    back = inspected(20.0, 560, known=False, setpoints=back_sp)
    res = weigh(back, cal_p2)
    assert res.payload_kg is None
    assert res.unweighable is not None and "negative direction" in res.unweighable
    cal = cal_p2.save(tmp_path / "cal.json")
    f = write_recording(back.recording, tmp_path / "back.csv")
    code = main(["weigh", "--calibration", str(cal), str(f)])
    out = capsys.readouterr().out
    assert code == 0
    assert "unweighable" in out
    assert "0 weighed, 1 unweighable, 0 refused" in out
    # a calibration with an empty run backwards covers it
    recs = [virtual(load, 300 + k) for k, load in enumerate([0, 0, 0, 50])]
    recs.append(virtual(0.0, 561, setpoints=back_sp))
    both = calibrate(recs, PROFILE)
    assert both.directions == {1, -1}
    res = weigh(back, both)
    assert res.payload_kg == pytest.approx(20.0, abs=3 * res.uncertainty_kg)
    # and a calibration file says so: an unknown case or direction is refused
    data = json.loads(cal.read_text())
    data["case"] = "guessed"
    (tmp_path / "case.json").write_text(json.dumps(data))
    with pytest.raises(CalibrationError, match="case 'guessed'"):
        load_calibration(tmp_path / "case.json")


def test_friction_sensitivity_reads_a_friction_rise_by_hand(cal_p2: Calibration) -> None:
    """Known answer: a 20 % rail friction rise moves the friction payload by 0.2·k_μ.

    k_μ (``friction_rel_kg``) is the hand formula μ·cosβ·m/(μ·cosβ + sinβ)
    for a one-direction recording (m: belt, tray and payload on the rails);
    the recording with the rise measures the same shift, and since the
    rise lies above the smallest change its inertia signature can catch
    (``friction_checked_rel``), the trusted-loss weighing refuses it.
    """
    from chaintwin.model.rigid import incline_terms
    from chaintwin.weigh import LossDrift

    clean = weigh(inspected(20.0, 511, known=False), cal_p2, loss_drift=LossDrift())
    risen = weigh(
        inspected(20.0, 511, known=False, faults=[Fault("friction", 0.2)]),
        cal_p2,
        loss_drift=LossDrift(),
    )
    assert clean.signatures is not None and risen.signatures is not None
    g_cos, g_sin = incline_terms(PROFILE)
    mu = float(cal_p2.parameters["mu"])
    m = PROFILE.belt_mass_kg + PROFILE.tray_mass_kg + clean.signatures.friction_kg
    by_hand = mu * g_cos * m / (mu * g_cos + g_sin)
    assert clean.signatures.friction_rel_kg == pytest.approx(by_hand, rel=0.02)
    shift = risen.signatures.friction_kg - clean.signatures.friction_kg
    assert shift == pytest.approx(0.2 * clean.signatures.friction_rel_kg, rel=0.15)
    assert clean.friction_10pct_kg == pytest.approx(0.1 * clean.signatures.friction_rel_kg)
    checked = clean.friction_checked_rel
    assert checked is not None and checked < 0.2 and risen.unweighable is not None
    assert clean.to_dict()["friction_checked_rel"] == checked
    assert not any(w.code == "friction_unchecked" for w in cal_p2.warnings)


def test_a_heavy_drive_warns_friction_unchecked_and_the_allowance_covers_a_rise() -> None:
    """Where the ramps cannot check the friction, the calibration says so.

    A drive 60 times as heavy hides the payload's inertia: a doubled rail friction
    rise passes the consistency check and reads as payload, several reported
    uncertainties off. The calibration warns ``friction_unchecked`` (with
    what to record); a 30 % friction allowance (``friction_drift``, 1 sigma)
    carries the rise into the uncertainty.
    """
    from chaintwin.weigh import LossDrift

    heavy = PROFILE.model_copy(
        update={
            "motor": PROFILE.motor.model_copy(
                update={"inertia_kgm2": 60.0 * PROFILE.motor.inertia_kgm2}
            )
        }
    )

    def rec(payload: float, seed: int, share: float = 1.0, **kw: object) -> Inspection:
        run = run_virtual(
            heavy,
            payload_kg=payload,
            seed=seed,
            speed_rpm=1415 * share,
            calibration=bool(kw.pop("known", True)),
            **kw,  # type: ignore[arg-type]
        )
        return inspect_recording(run.recording, heavy)

    runs = [rec(0.0, 600 + k, share).recording for k, share in enumerate([0.3, 0.6, 1.0])]
    cal = calibrate(runs, heavy)
    notes = [w for w in cal.warnings if w.code == "friction_unchecked"]
    assert len(notes) == 1 and "--friction-drift" in notes[0].message
    risen = rec(20.0, 610, known=False, faults=[Fault("friction", 1.0)])
    plain = weigh(risen, cal, loss_drift=LossDrift())
    checked = plain.friction_checked_rel
    assert checked is None or checked > 1.0
    assert plain.payload_kg is not None and plain.uncertainty_kg is not None
    assert abs(plain.payload_kg - 20.0) > 3 * plain.uncertainty_kg  # the rise reads as payload
    allowed = weigh(risen, cal, loss_drift=LossDrift(), friction_drift=0.3)
    assert allowed.payload_kg is not None and allowed.uncertainty_kg is not None
    assert abs(allowed.payload_kg - 20.0) <= 2.0 * allowed.uncertainty_kg
