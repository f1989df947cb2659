"""Condition monitoring: health model, X-of-Y rule, causes, state, CLI."""

from __future__ import annotations

import json
from datetime import UTC, datetime, timedelta
from pathlib import Path

import numpy as np
import pytest
from conftest import REFERENCE_PROFILE

from chaintwin.cli.app import EXIT_ALARM, main
from chaintwin.diagnose.health import fit_baseline, forecast_crossing, x_of_y
from chaintwin.diagnose.monitor import (
    ConveyorMonitor,
    MonitorSettings,
    RecordingResult,
    resolve_causes,
)
from chaintwin.diagnose.state import load_state
from chaintwin.errors import MonitorError, StoreError
from chaintwin.identify.calibration import Calibration, calibrate
from chaintwin.read.profile import load_profile
from chaintwin.simulate.faults import Fault
from chaintwin.simulate.fleet import generate
from chaintwin.validate.checks import load_recording

PROFILE = load_profile(REFERENCE_PROFILE)
BASELINE = 10


# ---------------------------------------------------------------- hand-made cases
def test_x_of_y_rule_on_a_hand_made_sequence() -> None:
    seq = [True, False, False, True, False, True, False, False, False, False, False, True]
    # never 3 exceedances among 5 in a row
    assert x_of_y(seq, 3, 5) == [False] * len(seq)
    assert x_of_y(seq, 3, 6)[5] is True  # indices 0..5 hold 0, 3 and 5
    assert x_of_y(seq, 3, 6)[6] is False  # 0 left the window
    assert x_of_y([True] * 3, 3, 10) == [False, False, True]
    assert x_of_y([False, True], 1, 1) == [False, True]
    with pytest.raises(ValueError, match="X-of-Y"):
        x_of_y(seq, 4, 3)


def test_baseline_regresses_on_payload_and_leaves_out_outliers() -> None:
    rng = np.random.default_rng(0)
    payload = rng.uniform(10, 40, 40)
    values = 0.05 + 0.001 * payload + rng.normal(0, 0.002, 40)
    values[7] = 1.0  # a bad scope in the baseline
    fb = fit_baseline(values, payload, payload_dependent=True)
    assert fb is not None
    assert fb.outliers == 1
    assert fb.slope == pytest.approx(0.001, rel=0.15)
    assert fb.intercept == pytest.approx(0.05, abs=0.004)
    assert fb.scale == pytest.approx(0.002, rel=0.35)
    # a value 20 % above the line at 40 kg: far beyond 5 scales and beyond 10 %
    high = fb.check(1.2 * fb.expected(40.0), 40.0, 5.0, 0.10)
    assert high.exceeded and high.change == pytest.approx(0.2)
    # many scales above, but under the smallest relative change: no exceedance
    assert not fb.check(1.05 * fb.expected(40.0), 40.0, 5.0, 0.10).exceeded
    # a fall is never an exceedance
    assert not fb.check(0.5 * fb.expected(40.0), 40.0, 5.0, 0.10).exceeded
    flat = fit_baseline([1.0, 1.1, 0.9, 1.0, 1.05], [10, 20, 30, 40, 25], payload_dependent=False)
    assert flat is not None and flat.slope == 0.0 and flat.intercept == 1.0
    assert fit_baseline([1.0, np.nan, 2.0], [1, 2, 3], payload_dependent=False) is None


def test_forecast_of_a_linear_trend_brackets_the_true_crossing() -> None:
    t0 = datetime(2026, 1, 1, tzinfo=UTC)
    rng = np.random.default_rng(1)
    times = [t0 + timedelta(days=0.5 * k) for k in range(40)]
    values = [1.0 + 0.01 * 0.5 * k + rng.normal(0, 0.005) for k in range(40)]
    fc = forecast_crossing("friction", times, values, limit=1.3)
    assert fc is not None
    true = t0 + timedelta(days=30.0)  # 1 + 0.01 d = 1.3
    assert fc.earliest <= true <= (fc.latest or true)
    assert abs((fc.crosses_at - true).total_seconds()) < 2 * 86400
    assert fc.slope_per_day == pytest.approx(0.01, rel=0.1)
    flat = [1.0 + rng.normal(0, 0.005) for _ in range(40)]
    assert forecast_crossing("friction", times, flat, limit=1.3) is None


def test_causes_name_the_specific_fault() -> None:
    assert resolve_causes(["friction"]) == {"friction": "friction"}
    assert resolve_causes(["friction", "tooth_pass"]) == {
        "friction": "elongation",
        "tooth_pass": "elongation",
    }
    assert resolve_causes(["residual_std"]) == {"residual_std": "bearing"}
    assert resolve_causes(["residual_std", "comb_stage2_shaft"]) == {
        "residual_std": "gear",
        "comb_stage2_shaft": "gear",
    }
    assert resolve_causes(["comb_stage3_shaft", "belt_bump"])["comb_stage3_shaft"] == (
        "obstruction"
    )
    assert resolve_causes(["speed_loss", "friction"]) == {
        "speed_loss": "lubrication",
        "friction": "friction",
    }


def test_settings_are_checked() -> None:
    with pytest.raises(MonitorError, match="X <= Y"):
        MonitorSettings(x=4, y=3)
    with pytest.raises(MonitorError, match="at least 5"):
        MonitorSettings(baseline_n=2)


# ---------------------------------------------------------------- virtual series
def _series(folder: Path, faults: list[Fault], seed: int) -> Path:
    generate(PROFILE, folder, days=6, per_day=6, faults=faults, onset_day=2, seed=seed)
    return folder


@pytest.fixture(scope="module")
def series(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("series")
    return {
        "healthy": _series(root / "healthy", [], 11),
        "friction": _series(root / "friction", [Fault("friction", 0.6)], 12),
        "obstruction": _series(root / "obstruction", [Fault("obstruction", 0.6)], 13),
    }


@pytest.fixture(scope="module")
def cal(series: dict[str, Path]) -> Calibration:
    files = sorted((series["healthy"] / "calibration").glob("*.csv"))
    return calibrate([load_recording(f, profile=PROFILE).recording for f in files], PROFILE)


def _files(folder: Path) -> list[Path]:
    return sorted(folder.glob("*.csv"))


def _run(mon: ConveyorMonitor, files: list[Path]) -> list[RecordingResult]:
    out: list[RecordingResult] = []
    for f in files:
        out += mon.process(load_recording(f, profile=PROFILE).recording, f.name)
    return out + mon.finish()


def _onset(folder: Path) -> str:
    truth = [json.loads(x) for x in (folder / "truth.jsonl").read_text().splitlines()]
    return next(t["recorded_at"] for t in truth if any(v > 0 for v in t["faults"].values()))


def test_healthy_series_raises_no_alarm(series: dict[str, Path], cal: Calibration) -> None:
    mon = ConveyorMonitor(PROFILE, MonitorSettings(baseline_n=BASELINE), cal)
    results = _run(mon, _files(series["healthy"]))
    assert [r.status for r in results[:BASELINE]] == ["baseline"] * BASELINE
    assert all(r.status == "monitored" for r in results[BASELINE:])
    assert not any(r.alarm for r in results)
    assert mon.open_alarms() == []
    # the JSON fields, numbers where the recording tells
    d = results[-1].to_dict()
    assert {"file", "recorded_at", "alarm", "causes", "payload_kg", "tlf", "warnings"} <= set(d)
    assert 5.0 < d["payload_kg"] < 45.0


@pytest.mark.parametrize(
    ("name", "cause", "feature"),
    [("friction", "friction", "friction"), ("obstruction", "obstruction", "belt_bump")],
)
def test_fault_series_alarm_with_the_right_cause(
    series: dict[str, Path], cal: Calibration, name: str, cause: str, feature: str
) -> None:
    mon = ConveyorMonitor(PROFILE, MonitorSettings(baseline_n=BASELINE), cal)
    results = _run(mon, _files(series[name]))
    alarms = [r for r in results if r.alarm]
    assert alarms, f"{name}: no alarm"
    first = alarms[0]
    assert (first.recorded_at or "") >= _onset(series[name])
    assert first.causes[0]["cause"] == cause
    assert first.causes[0]["feature"] == feature
    assert first.causes[0]["change"] > 0
    assert first.causes[0]["since"] <= first.recorded_at
    opened = mon.open_alarms()
    assert [a["cause"] for a in opened if a["feature"] == feature] == [cause]


def test_state_round_trip_continues_where_it_stopped(
    series: dict[str, Path], cal: Calibration
) -> None:
    files = _files(series["friction"])
    whole = _run(ConveyorMonitor(PROFILE, MonitorSettings(baseline_n=BASELINE), cal), files)
    mon = ConveyorMonitor(PROFILE, MonitorSettings(baseline_n=BASELINE), cal)
    first = _run(mon, files[:20])
    state = json.loads(json.dumps(mon.to_state()))
    again = ConveyorMonitor.from_state(state, PROFILE)
    second = _run(again, files[20:])
    split = first + second
    assert [r.alarm for r in split] == [r.alarm for r in whole]
    assert [r.exceeded for r in split] == [r.exceeded for r in whole]
    # the same recording again is recognised, the model left as it was
    dup = again.process(load_recording(files[-1], profile=PROFILE).recording, files[-1].name)
    assert dup[0].status == "duplicate"
    assert "already_processed" in [w["code"] for w in dup[0].warnings]
    assert len(again.history) == len(files)
    other = load_profile(REFERENCE_PROFILE).model_copy(update={"tray_mass_kg": 11.0})
    with pytest.raises(StoreError, match="another version of its profile"):
        ConveyorMonitor.from_state(state, other)


def test_maintenance_restarts_the_baseline_and_closes_alarms(
    series: dict[str, Path], cal: Calibration
) -> None:
    files = _files(series["friction"])
    mon = ConveyorMonitor(PROFILE, MonitorSettings(baseline_n=BASELINE), cal)
    before = _run(mon, files)
    assert mon.open_alarms()
    at = datetime.fromisoformat(before[-1].recorded_at or "") - timedelta(seconds=1)
    mon.add_event("repair", at, "A. Fitter", "rails cleaned")
    after = mon.process(load_recording(files[-1], profile=PROFILE).recording, "again")
    assert after[0].status == "baseline"
    assert "baseline_restarted" in [w["code"] for w in after[0].warnings]
    assert mon.open_alarms() == []
    closed = [a for a in mon.alarms if a["status"] == "closed"]
    assert closed and all("A. Fitter" in a["closed_by"] for a in closed)


def test_without_calibration_one_is_learned(series: dict[str, Path]) -> None:
    mon = ConveyorMonitor(PROFILE, MonitorSettings(baseline_n=BASELINE))
    files = _files(series["healthy"])
    waiting = []
    for f in files[: BASELINE - 1]:
        waiting += mon.process(load_recording(f, profile=PROFILE).recording)
    assert waiting == []
    assert [r.status for r in mon.finish()] == ["learning"] * (BASELINE - 1)
    results = mon.process(load_recording(files[BASELINE - 1], profile=PROFILE).recording)
    assert len(results) == BASELINE  # the waiting ones are monitored now
    assert mon.calibration_source == "learned"
    codes = {w["code"] for w in results[0].warnings}
    assert "payload_uncalibrated" in codes
    # friction is well learned: the learned model reads mu within 10 %
    assert mon.calibration is not None
    assert mon.calibration.parameters["mu"] == pytest.approx(0.23, rel=0.1)


# ---------------------------------------------------------------- command line
def test_cli_monitor_state_fail_on_alarm_and_acknowledge(
    series: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    folder = series["friction"]
    cal_file = tmp_path / "cal.json"
    cal_files = [str(f) for f in sorted((folder / "calibration").glob("*.csv"))]
    assert (
        main(["calibrate", "--profile", REFERENCE_PROFILE, *cal_files, "--out", str(cal_file)]) == 0
    )
    capsys.readouterr()
    files = [str(f) for f in _files(folder)]
    state = tmp_path / "plant.state"
    args = ["monitor", "--profile", REFERENCE_PROFILE, "--calibration", str(cal_file)]
    args += ["--state", str(state), "--baseline", str(BASELINE)]
    assert main([*args, *files[:20], "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert len(out["recordings"]) == 20
    assert out["conveyors"][0]["conveyor"] == "white-belt-01"
    code = main([*args, *files[20:], "--json", "--fail-on-alarm"])
    out = json.loads(capsys.readouterr().out)
    assert code == EXIT_ALARM
    alarms = out["conveyors"][0]["open_alarms"]
    assert alarms and alarms[0]["cause"] == "friction"
    assert any(r["alarm"] for r in out["recordings"])
    for a in alarms:
        assert (
            main(["acknowledge", a["id"], "--state", str(state), "--by", "me", "--why", "WO 17"])
            == 0
        )
    capsys.readouterr()
    # nothing new, everything acknowledged: scripts pass
    assert main([*args, files[-1], "--json", "--fail-on-alarm"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["recordings"][0]["status"] == "duplicate"
    assert (
        load_state(state)["conveyors"]["white-belt-01"]["alarms"][0]["acknowledged"]["by"] == "me"
    )
    # maintenance: recorded with who and why
    assert (
        main(
            [
                "maintenance",
                "--state",
                str(state),
                "--conveyor",
                "white-belt-01",
                "--kind",
                "repair",
                "--by",
                "me",
                "--why",
                "rails",
            ]
        )
        == 0
    )
    events = load_state(state)["conveyors"]["white-belt-01"]["events"]
    assert events[0]["by"] == "me" and events[0]["kind"] == "repair"


def test_cli_refusals_are_one_line_and_keep_the_state(
    series: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = tmp_path / "bad.csv"
    bad.write_text("# conveyor: white-belt-01\ntime [s],speed [rpm]\n0,1\n", encoding="utf-8")
    foreign = tmp_path / "foreign.csv"
    foreign.write_text("# conveyor: other-line\ntime [s],speed [rpm],torque [Nm]\n0,1,2\n")
    good = [str(f) for f in _files(series["healthy"])[:3]]
    state = tmp_path / "s.state"
    code = main(
        [
            "monitor",
            "--profile",
            REFERENCE_PROFILE,
            "--state",
            str(state),
            "--json",
            str(bad),
            str(foreign),
            *good,
        ]
    )
    out = json.loads(capsys.readouterr().out)
    assert code == 2
    errors = {r["file"]: r["error"] for r in out["recordings"] if "error" in r}
    assert set(errors) == {str(bad), str(foreign)}
    assert "other-line" in errors[str(foreign)]
    assert "\n" not in errors[str(bad)]
    # the good recordings wait for a learned calibration, kept in the state
    saved = load_state(state)["conveyors"]["white-belt-01"]
    assert saved["pending_files"] == good
    # a damaged state is refused on one line and left as it was
    state.write_text("{not json", encoding="utf-8")
    assert main(["monitor", "--profile", REFERENCE_PROFILE, "--state", str(state), *good]) == 2
    assert "not valid JSON" in capsys.readouterr().err
    assert state.read_text(encoding="utf-8") == "{not json"
    assert main(["monitor", *good]) == 2
    assert "--profile" in capsys.readouterr().err
