"""Verification of the twin (REP): known answers on the virtual conveyor and the CLI."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
from conftest import REFERENCE_PROFILE

from chaintwin.cli.app import main
from chaintwin.identify.verification import (
    movement_label,
    rep_series,
    rep_stats,
    verify_recording,
)
from chaintwin.read.profile import ConveyorProfile, load_profile
from chaintwin.read.recording import Recording
from chaintwin.read.writer import write_recording
from chaintwin.simulate import Realism, run_virtual
from chaintwin.simulate.setpoints import stairs, trapezoid, trapezoid2
from chaintwin.validate.phases import segment_speed

PROFILE = load_profile(REFERENCE_PROFILE)
PAYLOAD_KG = 30.0


def _with_friction(profile: ConveyorProfile, factor: float) -> ConveyorProfile:
    model = profile.model
    assert model is not None
    return profile.model_copy(
        update={"model": model.model_copy(update={"friction": model.friction * factor})}
    )


@pytest.fixture(scope="module")
def clean() -> Recording:
    """A noise-free rigid trapezoid sampled at 2 ms (the whole 10 s movement)."""
    realism = dataclasses.replace(Realism.off(), scope_limits=False)
    run = run_virtual(
        PROFILE,
        payload_kg=PAYLOAD_KG,
        realism=realism,
        seed=1,
        sample_time_s=0.002,
        calibration=True,
    )
    return run.recording


def test_rep_series_normalises_by_the_largest_measured_value() -> None:
    measured = np.array([0.0, 1.0, -2.0, 2.0, 0.0])
    model = np.array([0.0, 1.1, -2.0, 1.8, 0.1])
    series = rep_series(measured, model)
    np.testing.assert_allclose(series, [0.0, 5.0, 0.0, -10.0, 5.0])
    stats = rep_stats(series)
    assert stats is not None
    assert stats.mean_pct == pytest.approx(0.0)
    assert stats.std_pct == pytest.approx(np.sqrt((25 + 100 + 25) / 5))
    assert stats.absmax_pct == pytest.approx(10.0)
    assert rep_stats(series, np.array([0, 1])) is None  # too few samples


def test_closed_loop_rep_of_a_noise_free_trapezoid_is_below_one_percent(
    clean: Recording,
) -> None:
    v = verify_recording(clean, PROFILE, residual="closed-loop")
    assert v.movement == "trapezoid"
    assert v.parameters.source == "profile"
    assert [w["code"] for w in v.warnings] == ["nominal_parameters"]
    for ch in (v.speed, v.torque):
        assert ch.whole is not None
        assert ch.whole.absmax_pct < 1.0
        assert abs(ch.whole.mean_pct) < 0.1
    assert [p["kind"] for p in v.phases] == ["accelerate", "constant", "decelerate"]


def test_a_ten_percent_friction_error_shows_clearly(clean: Recording) -> None:
    wrong = verify_recording(clean, _with_friction(PROFILE, 1.1), residual="closed-loop")
    assert wrong.torque.whole is not None
    # more friction in the model: it needs more torque, REP > 0 throughout the move
    assert wrong.torque.whole.mean_pct > 2.0
    assert wrong.torque.whole.absmax_pct > 2.0
    constant = next(p for p in wrong.phases if p["kind"] == "constant")
    assert constant["torque"]["rep_mean_pct"] > 2.0
    less = verify_recording(clean, _with_friction(PROFILE, 0.9), residual="closed-loop")
    assert less.torque.whole is not None
    assert less.torque.whole.mean_pct < -2.0


def test_inverse_residual_has_no_speed_of_its_own(clean: Recording) -> None:
    v = verify_recording(clean, PROFILE, residual="inverse")
    out = v.to_dict()
    assert out["speed"]["rep_mean_pct"] is None
    assert "measured speed" in out["speed"]["reason"]
    assert v.torque.whole is not None
    # the inverse model differentiates the measured speed: close in the constant phase
    constant = next(p for p in v.phases if p["kind"] == "constant")
    assert abs(constant["torque"]["rep_mean_pct"]) < 0.5


@pytest.mark.parametrize(
    ("setpoints", "label"),
    [
        (trapezoid(speed_rad_s=100.0, accel_rad_s2=200.0, hold_s=1.0), "trapezoid"),
        (
            trapezoid(speed_rad_s=100.0, accel_rad_s2=200.0, hold_s=1.0, direction=-1),
            "trapezoid, backward",
        ),
        (trapezoid(speed_rad_s=100.0, accel_rad_s2=200.0, hold_s=0.0), "ramp"),
        (
            trapezoid2(speed_rad_s=100.0, accel1_rad_s2=400.0, accel2_rad_s2=100.0, hold_s=1.0),
            "two accelerations",
        ),
        (stairs(speeds_rad_s=[50.0, 100.0, 150.0], step_s=1.0, accel_rad_s2=200.0), "stairs"),
        (
            stairs(speeds_rad_s=[100.0, -100.0], step_s=1.0, accel_rad_s2=200.0),
            "trapezoid, both directions",
        ),
    ],
)
def test_movement_label(setpoints: object, label: str) -> None:
    t = np.asarray(setpoints.time)  # type: ignore[attr-defined]
    w = np.asarray(setpoints.speed)  # type: ignore[attr-defined]
    phases = segment_speed(t, w, clean=True)
    assert movement_label(phases, t, w) == label


def test_cli_verify_json_and_table(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("COLUMNS", "200")
    run = run_virtual(PROFILE, payload_kg=10.0, seed=3, calibration=True)
    good = write_recording(run.recording, tmp_path / "run.csv")
    bad = tmp_path / "bad.csv"
    bad.write_text("not a recording\n")
    code = main(["verify", "--profile", str(REFERENCE_PROFILE), str(good), str(bad), "--json"])
    assert code == 2
    out = json.loads(capsys.readouterr().out)
    assert out[0]["file"] == str(good)
    for ch in ("speed", "torque"):
        assert {"rep_mean_pct", "rep_std_pct", "rep_absmax_pct"} <= set(out[0][ch])
    assert out[0]["residual"] == "closed-loop"
    assert out[0]["warnings"][0]["code"] == "nominal_parameters"
    # the realistic virtual conveyor (noise, elastic belt, 6 ms scope): a few percent at most
    assert abs(out[0]["torque"]["rep_mean_pct"]) < 3.0
    assert out[1]["file"] == str(bad) and "error" in out[1]

    code = main(["verify", "--profile", str(REFERENCE_PROFILE), str(good), "--residual", "inverse"])
    assert code == 0
    text = capsys.readouterr().out
    assert "no calibration given" in text
    assert "trapezoid" in text and "inverse" in text

    code = main(["verify", "--profile", str(REFERENCE_PROFILE), str(good), "--residual", "other"])
    assert code == 2
    assert "--residual" in capsys.readouterr().err


# ---------------------------------------------------------------- monitor --residual
def test_monitor_residual_closed_loop(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from chaintwin.diagnose.records import MonitorSettings
    from chaintwin.errors import MonitorError
    from chaintwin.simulate.fleet import generate

    with pytest.raises(MonitorError, match="residual"):
        MonitorSettings(residual="forward")
    out = generate(PROFILE, tmp_path / "runs", days=1, per_day=7, seed=4)
    cal = tmp_path / "cal.json"
    cal_files = [str(f) for f in sorted((out.folder / "calibration").glob("*.csv"))]
    assert (
        main(["calibrate", "--profile", str(REFERENCE_PROFILE), *cal_files, "--out", str(cal)]) == 0
    )
    capsys.readouterr()
    files = [str(f) for f in sorted(out.folder.glob("*.csv"))]
    state = tmp_path / "state.json"
    runs: dict[str, list[float]] = {}
    for mode in ("inverse", "closed-loop"):
        args = ["monitor", "--profile", str(REFERENCE_PROFILE), "--calibration", str(cal)]
        args += ["--baseline", "5", "--json", "--residual", mode, *files]
        if mode == "closed-loop":
            args += ["--state", str(state)]
        assert main(args) == 0
        res = json.loads(capsys.readouterr().out)["recordings"]
        unavailable = "closed_loop_unavailable"
        msgs = [w["message"] for r in res for w in r["warnings"] if w["code"] == unavailable]
        assert not msgs, msgs[:1]
        runs[mode] = [r["features"]["residual_std"] for r in res]
    # both residuals are small against the torque (a few 0.01 Nm), and they differ: the
    # closed loop's torque is simulated, the inverse model's follows the measured speed
    assert all(0.0 < v < 0.2 for v in runs["closed-loop"])
    assert runs["closed-loop"] != runs["inverse"]
    saved = json.loads(state.read_text())
    (conveyor,) = saved["conveyors"].values()
    assert conveyor["settings"]["residual"] == "closed-loop"
    code = main(["monitor", "--profile", str(REFERENCE_PROFILE), "--residual", "x", *files[:1]])
    assert code == 2
    assert "--residual" in capsys.readouterr().err
