"""The virtual conveyor: realistic recordings that pass inspect, faults, time series."""

from __future__ import annotations

import itertools
import json
import math
from pathlib import Path

import numpy as np
import pytest
from conftest import REFERENCE_PROFILE

from chaintwin import inspect_recording, load_recording, read_recording
from chaintwin.cli.app import main
from chaintwin.errors import ModelError
from chaintwin.read.profile import ConveyorProfile
from chaintwin.read.writer import write_recording
from chaintwin.simulate.faults import Fault, parse_fault, parse_faults
from chaintwin.simulate.fleet import fault_severity, generate
from chaintwin.simulate.virtual import Realism, faulty_plant, run_virtual


def codes(ins) -> list[str]:  # type: ignore[no-untyped-def]
    return [w.code for w in ins.warnings]


def test_6ms_recording_is_a_clean_complete_cycle(
    reference_profile: ConveyorProfile, tmp_path: Path
) -> None:
    run = run_virtual(reference_profile, payload_kg=40, sample_time_s=0.006, seed=1)
    path = write_recording(run.recording, tmp_path / "r.csv")
    ins = load_recording(path, profile=reference_profile)
    rec = ins.recording
    assert rec.samples == 2048
    assert rec.sample_time_s == pytest.approx(0.006)
    assert ins.complete_cycle
    assert codes(ins) == []
    assert [p.kind for p in ins.phases] == [
        "standstill",
        "accelerate",
        "constant",
        "decelerate",
        "standstill",
    ]
    # the truth stays out of the metadata
    assert rec.metadata.payload_kg is None
    text = path.read_text()
    assert "payload" not in text and "fault" not in text


def test_1ms_scope_holds_only_part_of_the_cycle(reference_profile: ConveyorProfile) -> None:
    run = run_virtual(reference_profile, payload_kg=10, sample_time_s=0.001, seed=2)
    ins = inspect_recording(run.recording, reference_profile)
    assert run.recording.samples == 2048
    assert run.recording.duration_s == pytest.approx(2.047)
    assert "incomplete_cycle" in codes(ins)
    assert not ins.complete_cycle


def test_12ms_backward_and_calibration_metadata(reference_profile: ConveyorProfile) -> None:
    from chaintwin.simulate.virtual import default_setpoints

    sp = default_setpoints(reference_profile, duration_s=2048 * 0.012, direction=-1)
    run = run_virtual(
        reference_profile,
        payload_kg=25,
        sample_time_s=0.012,
        seed=3,
        setpoints=sp,
        calibration=True,
    )
    ins = inspect_recording(run.recording, reference_profile)
    assert ins.complete_cycle
    assert {p.direction for p in ins.phases if p.moving} == {-1}
    assert run.recording.metadata.payload_kg == 25


def test_export_is_quantised_and_in_drive_units(
    reference_profile: ConveyorProfile, tmp_path: Path
) -> None:
    run = run_virtual(reference_profile, payload_kg=20, seed=4)
    path = write_recording(run.recording, tmp_path / "q.csv")
    header = next(line for line in path.read_text().split("\n") if line.startswith("time"))
    assert header == (
        "time [s],speed_setpoint [rpm],speed [rpm],position_setpoint [inc],"
        "position [inc],torque_setpoint [%],torque [%],digital_inputs [-]"
    )
    rec = read_recording(path)
    rpm = rec.speed / (2 * math.pi / 60)
    np.testing.assert_allclose(rpm, np.round(rpm, 1), atol=1e-9)
    pct = rec.torque / 2.5 * 100
    np.testing.assert_allclose(pct, np.round(pct, 1), atol=1e-9)
    assert rec.position is not None
    inc = rec.position / (2 * math.pi / 4096)
    np.testing.assert_allclose(inc, np.round(inc), atol=1e-6)


def test_ideal_steady_torque_equals_hand_calculation(reference_profile: ConveyorProfile) -> None:
    """Rigid model, exact export: the recorded torque at constant speed is the hand value."""
    run = run_virtual(reference_profile, payload_kg=40, realism=Realism.off(), seed=0)
    rec = run.recording
    m = reference_profile.model
    assert m is not None
    r = reference_profile.chordal_radius_m
    i, eta = (43 / 12) * (75 / 23) * (61 / 23), 0.93  # the teeth, not the nameplate 30.99
    w = 1415 * 2 * math.pi / 60
    f = m.friction * 9.81 * (reference_profile.belt_mass_kg + 10 + 40)
    hand = (
        f * r / (i * eta)
        + m.loss_constant_nm
        + m.loss_viscous_nm_s_rad * w
        + m.loss_quadratic_nm_s2_rad2 * w * w
    )
    t = rec.time
    steady = (t > 4.0) & (t < 8.0)
    assert np.mean(rec.torque[steady]) == pytest.approx(hand, rel=2e-3)


def test_faults_change_the_plant(reference_profile: ConveyorProfile) -> None:
    healthy = faulty_plant(reference_profile, payload_kg=0)
    assert faulty_plant(
        reference_profile, payload_kg=0, faults=[Fault("friction", 0.2)]
    ).mu == pytest.approx(healthy.mu * 1.2)
    lub = faulty_plant(reference_profile, payload_kg=0, faults=[Fault("lubrication", 1.0)])
    assert lub.loss_viscous_nm_s_rad == pytest.approx(2 * healthy.loss_viscous_nm_s_rad)
    brg = faulty_plant(reference_profile, payload_kg=0, faults=[Fault("bearing", 0.5)])
    assert 3.57 in brg.ripple_orders
    amp = brg.ripple_amplitudes_nm[brg.ripple_orders.index(3.57)]
    assert amp == pytest.approx(0.5 * 0.04 * 2.5)
    gear = faulty_plant(reference_profile, payload_kg=0, faults=[Fault("gear_tooth", 1.0)])
    assert gear.impulse_period_rad == pytest.approx(2 * math.pi * 43 / 12)
    obs = faulty_plant(reference_profile, payload_kg=0, faults=[Fault("obstruction", 1.0)])
    assert obs.obstruction_force_n == pytest.approx(
        0.23 * 9.81 * (reference_profile.belt_mass_kg + 10)
    )
    elo = faulty_plant(reference_profile, payload_kg=0, faults=[Fault("elongation", 1.0)])
    assert elo.pitch_radius_m == pytest.approx(healthy.pitch_radius_m * 1.03)
    assert elo.polygon


def test_fault_parsing_errors() -> None:
    assert parse_fault("bearing:0.5") == Fault("bearing", 0.5)
    with pytest.raises(ModelError, match="unknown fault 'rust'"):
        parse_fault("rust:1")
    with pytest.raises(ModelError, match="NAME:SEVERITY"):
        parse_fault("friction")
    with pytest.raises(ModelError, match="not a number"):
        parse_fault("friction:high")
    with pytest.raises(ModelError, match="given twice"):
        parse_faults(["friction:0.1", "friction:0.2"])
    with pytest.raises(ModelError, match="from 0 to 10"):
        parse_fault("friction:-1")


def test_sample_time_must_be_whole_cycles(reference_profile: ConveyorProfile) -> None:
    with pytest.raises(ModelError, match="whole multiple"):
        run_virtual(reference_profile, sample_time_s=0.0025)


def test_severity_grows_linearly_from_onset() -> None:
    f = Fault("friction", 0.4)
    assert fault_severity(f, 29, 60, 30) == 0.0
    assert fault_severity(f, 30, 60, 30) == 0.0
    assert fault_severity(f, 59, 60, 30) == pytest.approx(0.4)
    assert fault_severity(f, 44, 60, 30) == pytest.approx(0.4 * 14 / 29)


def test_generate_writes_recordings_and_truth(
    reference_profile: ConveyorProfile, tmp_path: Path
) -> None:
    summary = generate(
        reference_profile,
        tmp_path,
        days=3,
        per_day=2,
        faults=[Fault("friction", 0.3)],
        onset_day=1,
        seed=5,
    )
    assert summary.recordings == 6
    rows = [json.loads(line) for line in (tmp_path / "truth.jsonl").read_text().splitlines()]
    main_rows = [r for r in rows if not r["file"].startswith("calibration/")]
    cal_rows = [r for r in rows if r["file"].startswith("calibration/")]
    assert len(main_rows) == 6
    assert len(cal_rows) == summary.calibration_recordings > 0
    sev = [r["faults"]["friction"] for r in main_rows]
    assert sev == [0.0, 0.0, 0.0, 0.0, pytest.approx(0.3), pytest.approx(0.3)]
    assert all(10 <= r["payload_kg"] <= 40 for r in main_rows)
    recs = [read_recording(tmp_path / r["file"]) for r in main_rows]
    stamps = [r.metadata.recorded_at for r in recs]
    assert stamps == sorted(stamps)
    assert all(r.metadata.payload_kg is None for r in recs)
    # as drives export them, positions start at an offset of their own in every
    # recording: most near zero (the counter reset at the trigger), some anywhere
    starts = [r.position[0] for r in recs if r.position is not None]
    near_zero = [p for p in starts if 0.0 <= p <= 50 * 2 * np.pi / 4096]
    assert len(starts) == len(recs) and len(recs) // 3 <= len(near_zero) < len(recs)
    assert any(b.position[0] < a.position[-1] for a, b in itertools.pairwise(recs))  # type: ignore[index]
    cal = read_recording(tmp_path / cal_rows[3]["file"])
    assert cal.metadata.payload_kg == cal_rows[3]["payload_kg"]


def test_cli_simulate_and_generate(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "rec.csv"
    code = main(
        [
            "simulate",
            "--profile",
            str(REFERENCE_PROFILE),
            "--payload",
            "40",
            "--fault",
            "bearing:0.5",
            "--seed",
            "7",
            "--out",
            str(out),
            "--json",
        ]
    )
    assert code == 0
    truth = json.loads(capsys.readouterr().out)
    assert truth["faults"] == {"bearing": 0.5}
    assert read_recording(out).samples == 2048
    code = main(
        ["simulate", "--profile", str(REFERENCE_PROFILE), "--fault", "rust:1", "--out", str(out)]
    )
    err = capsys.readouterr().err
    assert code == 2
    assert "unknown fault 'rust'" in err and err.count("\n") == 1
    code = main(
        [
            "generate",
            "--profile",
            str(REFERENCE_PROFILE),
            "--days",
            "2",
            "--per-day",
            "1",
            "--fault",
            "friction:0.4",
            "--onset",
            "1",
            "--out",
            str(tmp_path / "fleet"),
            "--no-calibration",
        ]
    )
    assert code == 0
    assert len(list((tmp_path / "fleet").glob("*.csv"))) == 2


def test_cli_simulate_with_calibration(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """--calibration supplies friction and losses; command-line options still win."""
    from chaintwin.calibrating.procedure import calibrate
    from chaintwin.read.profile import load_profile

    prof = load_profile(REFERENCE_PROFILE)
    recs = [
        run_virtual(prof, payload_kg=load, seed=70 + k, calibration=True).recording
        for k, load in enumerate((0.0, 40.0))
    ]
    cal = calibrate(recs, prof)
    path = cal.save(tmp_path / "cal.json")
    out = tmp_path / "r.csv"
    args = ["simulate", "--profile", str(REFERENCE_PROFILE), "--calibration", str(path)]
    assert main([*args, "--out", str(out), "--json"]) == 0
    truth = json.loads(capsys.readouterr().out)
    assert truth["friction"] == pytest.approx(cal.parameters["mu"])
    assert main([*args, "--friction", "0.3", "--out", str(out), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["friction"] == pytest.approx(0.3)
    other = tmp_path / "other.yaml"
    other.write_text(REFERENCE_PROFILE.read_text().replace("id: white-belt-01", "id: other-belt"))
    code = main(
        ["simulate", "--profile", str(other), "--calibration", str(path), "--out", str(out)]
    )
    assert code == 2
    assert "not of 'other-belt'" in capsys.readouterr().err


def test_the_set_point_carries_the_controller_gain_times_the_speed_noise(
    reference_profile: ConveyorProfile,
) -> None:
    """The set point's noise against Kp times the filtered speed noise, by hand.

    The speed controller sees the encoder's speed: whole increments per
    cycle, a quantisation error ``(r_(k-1) - r_k)·inc/dt`` with ``r``
    uniform in [0, 1), plus white noise ``σ``; through the speed filter
    (first order, ``α`` of a new sample per cycle) their variances become
    ``σ²·α/(2-α)`` and ``(inc/dt)²/12·2α²/(2-α)``. The set point carries
    ``Kp`` times that, unfiltered by the torque lag; the actual torque less.
    """
    from chaintwin.simulate.virtual import speed_filter_alpha
    from chaintwin.units import RPM_TO_RAD_S

    quiet = Realism(noise=False, quantisation=False, setpoint_noise=False)
    noisy = Realism(noise=False, quantisation=False, setpoint_noise=True)
    kw = {"payload_kg": 20.0, "sample_time_s": 0.001, "seed": 7}
    a = run_virtual(reference_profile, realism=quiet, **kw).recording
    b = run_virtual(reference_profile, realism=noisy, **kw).recording
    assert a.torque_setpoint is not None and b.torque_setpoint is not None
    du = b.torque_setpoint - a.torque_setpoint
    dt = reference_profile.controller.cycle_s
    alpha = speed_filter_alpha(dt, noisy.speed_filter_s)
    sigma = noisy.speed_noise_rpm * RPM_TO_RAD_S
    inc = 2.0 * math.pi / noisy.speed_increments_per_rev
    var = sigma**2 * alpha / (2.0 - alpha) + (inc / dt) ** 2 / 12.0 * 2.0 * alpha**2 / (2.0 - alpha)
    kp = reference_profile.controller.speed_gain_nm_s_rad
    moving = np.abs(a.speed) > 0.5 * np.max(np.abs(a.speed))  # quantisation at speed
    spread = float(np.std(du[moving]))
    assert spread == pytest.approx(kp * math.sqrt(var), rel=0.1)
    assert float(np.mean(du[moving])) == pytest.approx(0.0, abs=0.1 * spread)
    # the actual torque sees it through the torque lag: less, not more
    lagged = float(np.std((b.torque - a.torque)[moving]))
    assert 0.0 < lagged < spread
