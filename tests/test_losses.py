"""The verdict on separating the viscous and quadratic gear losses."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from conftest import REFERENCE_PROFILE

from chaintwin.calibrating.procedure import calibrate
from chaintwin.cli.app import main
from chaintwin.identify.losses import loss_verdict
from chaintwin.model.rigid import PARAMETER_NAMES, RigidParameters
from chaintwin.read.profile import load_profile
from chaintwin.read.writer import write_recording
from chaintwin.simulate import run_virtual
from chaintwin.units import RPM_TO_RAD_S

PROFILE = load_profile(REFERENCE_PROFILE)
MODEL = PROFILE.model
assert MODEL is not None


def _true_loss(rpm: float) -> float:
    w = rpm * RPM_TO_RAD_S
    return (
        MODEL.loss_constant_nm
        + MODEL.loss_viscous_nm_s_rad * w
        + MODEL.loss_quadratic_nm_s2_rad2 * w * w
    )


def test_one_speed_gives_a_verdict_and_the_known_sum(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    files = []
    for k, load in enumerate([0.0, 0.0, 50.0]):
        run = run_virtual(PROFILE, payload_kg=load, seed=k, calibration=True)
        files.append(str(write_recording(run.recording, tmp_path / f"r{k}.csv")))
    assert main(["identify", "--profile", str(REFERENCE_PROFILE), *files, "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    losses = out["losses"]
    assert losses["verdict"] == "not_separable"
    assert out["BmB"] is None and out["BmC"] is None and out["BmB_stderr"] is None
    (at,) = losses["at_speed"]
    # the sum at the run's speed is known to a fraction of a percent, within 3 standard errors
    assert abs(at["loss_nm"] - _true_loss(at["speed_rpm"])) < 3 * at["loss_nm_stderr"]
    assert at["loss_nm_stderr"] < 0.01 * at["loss_nm"]
    assert f"at {at['speed_rpm']:.0f} rpm" in losses["message"]
    monkeypatch.setenv("COLUMNS", "200")
    assert main(["identify", "--profile", str(REFERENCE_PROFILE), *files]) == 0
    text = capsys.readouterr().out
    assert "not separable" in text and "Add runs at two or three other speeds" in text


def test_three_speeds_separate_them() -> None:
    recs = [
        run_virtual(PROFILE, payload_kg=0.0, seed=k, calibration=True, speed_rpm=rpm).recording
        for k, rpm in enumerate([700.0, 1050.0, 1400.0])
    ]
    cal = calibrate(recs, PROFILE)
    verdict = loss_verdict(cal.parameters, cal.plateau_speeds_rpm)
    assert verdict.verdict == "separated"
    assert len(verdict.at_speed) == 3
    for at in verdict.at_speed:
        assert abs(at["loss_nm"] - _true_loss(at["speed_rpm"])) < 3 * at["loss_nm_stderr"]


def _params(bmb: float, bmc: float, rel: float, fixed: tuple[str, ...] = ()) -> RigidParameters:
    values = np.array([2e-3, 0.23, 1e-4, bmb, bmc])
    cov = np.diag((rel * values) ** 2)
    assert PARAMETER_NAMES[3:] == ("BmB", "BmC")
    return RigidParameters(values, cov, fixed)


def test_verdict_cases_by_hand() -> None:
    # two speeds but BmB and BmC known to ±80 %: not separable, with the sum at each speed
    v = loss_verdict(_params(2e-3, 2e-6, 0.8), [700.0, 1400.0])
    assert v.verdict == "not_separable" and "± 80%" in v.message
    w = 700.0 * RPM_TO_RAD_S
    assert v.at_speed[0]["loss_nm"] == pytest.approx(1e-4 + 2e-3 * w + 2e-6 * w * w)
    expected = np.sqrt((0.8e-4) ** 2 + (0.8 * 2e-3 * w) ** 2 + (0.8 * 2e-6 * w * w) ** 2)
    assert v.at_speed[0]["loss_nm_stderr"] == pytest.approx(expected)
    assert loss_verdict(_params(2e-3, 2e-6, 0.1), [700.0, 1400.0]).verdict == "separated"
    fixed = loss_verdict(_params(2e-3, 0.0, 0.1, ("BmC",)), [1400.0])
    assert fixed.verdict == "quadratic_fixed" and fixed.separated
