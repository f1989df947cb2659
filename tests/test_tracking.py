"""RLS tracking of the gear losses and ``identify --method ls|rls|oe``."""

from __future__ import annotations

import json
from datetime import UTC, datetime, timedelta
from pathlib import Path

import numpy as np
import pytest
from conftest import REFERENCE_PROFILE

from chaintwin.calibrating.methods import in_time_order
from chaintwin.cli.app import main
from chaintwin.errors import EstimationError
from chaintwin.identify.regression import RigidModelRegression
from chaintwin.identify.tracking import ParameterTracker, track_losses
from chaintwin.read.profile import load_profile
from chaintwin.read.recording import Recording
from chaintwin.read.writer import write_recording
from chaintwin.simulate import run_virtual

PROFILE = load_profile(REFERENCE_PROFILE)
SPEEDS_RPM = (700.0, 1050.0, 1400.0)
LOADS_KG = (0.0, 25.0, 50.0)
N = 60
STEP_AT = 30


def _recordings(n: int, step_at: int) -> list[Recording]:
    model = PROFILE.model
    assert model is not None
    stepped = model.model_copy(update={"loss_viscous_nm_s_rad": model.loss_viscous_nm_s_rad * 1.2})
    t0 = datetime(2026, 1, 1, tzinfo=UTC)
    return [
        run_virtual(
            PROFILE,
            payload_kg=LOADS_KG[k % 3],
            speed_rpm=SPEEDS_RPM[(k // 3) % 3],
            seed=100 + k,
            calibration=True,
            model=model if k < step_at else stepped,
            recorded_at=t0 + timedelta(hours=k),
            source=f"virtual-{k:03d}",
        ).recording
        for k in range(n)
    ]


@pytest.fixture(scope="module")
def fleet() -> list[Recording]:
    return _recordings(N, STEP_AT)


def test_tracked_viscous_loss_follows_a_20_percent_step(fleet: list[Recording]) -> None:
    model = PROFILE.model
    assert model is not None
    b0 = model.loss_viscous_nm_s_rad
    # J_d, mu and BmC from a batch fit of the first 20 recordings (before the step)
    held = RigidModelRegression().fit(fleet[:20], PROFILE).parameters_
    points, params = track_losses(fleet, PROFILE, held)
    bmb = np.array([p.values["BmB"] for p in points])
    # nothing changes: within 3 % of the truth from the fifth recording on
    assert np.all(np.abs(bmb[4:STEP_AT] / b0 - 1.0) <= 0.03)
    # after the step: within 3 % of the new truth within 30 recordings, and it stays there
    after = bmb[STEP_AT:] / (1.2 * b0) - 1.0
    settled = next(i for i in range(after.size) if np.all(np.abs(after[i:]) <= 0.03))
    assert settled < 30
    assert abs(after[-1]) <= 0.03
    # without forgetting the estimate averages both halves: it cannot follow
    still, _ = track_losses(fleet, PROFILE, held, forgetting=1.0)
    assert still[-1].values["BmB"] < 0.97 * 1.2 * b0
    # held parameters keep the batch values and covariance; tracked ones get RLS's
    assert params["mu"] == held["mu"]
    assert params.stderr("mu") == pytest.approx(held.stderr("mu"))
    assert 0.0 < params.stderr("BmB") < 0.05 * params["BmB"]


def test_tracker_checks_its_settings() -> None:
    with pytest.raises(EstimationError, match="forgetting"):
        ParameterTracker(PROFILE, forgetting=1.5)
    with pytest.raises(EstimationError, match="unknown"):
        ParameterTracker(PROFILE, fixed={"nope": 1.0})
    with pytest.raises(EstimationError, match="update"):
        ParameterTracker(PROFILE).parameters()


def test_recordings_are_tracked_oldest_first(fleet: list[Recording]) -> None:
    shuffled = [fleet[2], fleet[0], fleet[1]]
    assert [r.source for r in in_time_order(shuffled)] == [r.source for r in fleet[:3]]


@pytest.mark.slow
def test_cli_identify_methods(
    tmp_path: Path, fleet: list[Recording], capsys: pytest.CaptureFixture[str]
) -> None:
    files = [str(write_recording(r, tmp_path / f"{r.source}.csv")) for r in fleet[:9]]
    shapes = {}
    for method in ("ls", "rls", "oe"):
        code = main(
            ["identify", "--profile", str(REFERENCE_PROFILE), *files, "--json", "--method", method]
        )
        assert code == 0, method
        out = json.loads(capsys.readouterr().out)
        assert out["method"] == method
        shapes[method] = set(out) - {"track", "forgetting", "output_error", "method_description"}
        # three loads and three speeds: every method finds friction within a few percent
        assert out["mu"] == pytest.approx(0.23, rel=0.03), method
        assert out["BmB"] == pytest.approx(2.1e-3, rel=0.25), method
        if method == "rls":
            assert len(out["track"]) == 9
            assert out["residual_rms_nm"] is None
        if method == "oe":
            assert out["output_error"]["fitted"][-1] == "loss_quadratic_nm_s2_rad2"
    assert shapes["ls"] == shapes["rls"] == shapes["oe"]

    code = main(["identify", "--profile", str(REFERENCE_PROFILE), *files, "--method", "xx"])
    assert code == 2
    assert "--method" in capsys.readouterr().err
