"""``chaintwin inspect``: JSON fields, exit codes, one-line errors, profile and column map."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import REFERENCE_PROFILE, make_text

from chaintwin.cli.app import main

JSON_KEYS = {
    "file",
    "conveyor",
    "samples",
    "sample_time_s",
    "duration_s",
    "channels",
    "complete_cycle",
    "phases",
    "warnings",
}


def run_json(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, list[dict]]:  # type: ignore[type-arg]
    code = main(["inspect", *args, "--json"])
    return code, json.loads(capsys.readouterr().out)


def test_json_fields_for_a_good_recording(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    f = tmp_path / "good.csv"
    f.write_text(make_text())
    code, out = run_json([str(f)], capsys)
    assert code == 0
    (obj,) = out
    assert set(obj) >= JSON_KEYS
    assert obj["file"] == str(f)
    assert obj["conveyor"] == "white-belt-01"
    assert obj["samples"] == 400
    assert obj["sample_time_s"] == pytest.approx(0.006)
    assert obj["duration_s"] == pytest.approx(2.394)
    assert obj["channels"] == {
        "time": "s",
        "speed_setpoint": "rad/s",
        "speed": "rad/s",
        "position_setpoint": "rad",
        "position": "rad",
        "torque_setpoint": "Nm",
        "torque": "Nm",
        "digital_inputs": "-",
    }
    assert obj["complete_cycle"] is True
    assert [p["kind"] for p in obj["phases"]] == [
        "standstill",
        "accelerate",
        "constant",
        "decelerate",
        "standstill",
    ]
    assert set(obj["phases"][1]) == {"kind", "direction", "start_s", "end_s"}
    assert obj["phases"][1]["direction"] == 1
    assert obj["warnings"] == []


def test_refused_file_among_good_ones(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    good = tmp_path / "good.csv"
    good.write_text(make_text())
    bad = tmp_path / "bad.csv"
    bad.write_text(make_text().replace("time [s]", "time [h]"))
    code, out = run_json([str(bad), str(good)], capsys)
    assert code == 2
    assert out[0] == {"file": str(bad), "error": out[0]["error"]}
    assert "unknown unit 'h' for time" in out[0]["error"]
    assert str(bad) in out[0]["error"]
    assert out[1]["samples"] == 400


def test_warnings_in_json(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    f = tmp_path / "partial.csv"
    f.write_text(make_text(lead_s=-0.2, hold_s=5.0))
    code, (obj,) = run_json([str(f)], capsys)
    assert code == 0
    assert obj["complete_cycle"] is False
    assert [w["code"] for w in obj["warnings"]] == ["incomplete_cycle", "incomplete_cycle"]
    assert all(set(w) == {"code", "message"} for w in obj["warnings"])


def test_profile_supplies_nominal_torque(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    text = make_text().replace("# nominal_torque_nm: 2.5\n", "")
    f = tmp_path / "pct.csv"
    f.write_text(text)
    code, (obj,) = run_json([str(f)], capsys)
    assert code == 2 and "nominal_torque_nm" in obj["error"]
    code, (obj,) = run_json([str(f), "--profile", str(REFERENCE_PROFILE)], capsys)
    assert code == 0 and obj["tray_kg"] == 10.0


def test_columns_map(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    text = make_text().replace("speed [rpm]", "Actual speed [1/min]", 1)
    text = text.replace("speed_setpoint [rpm]", "n_soll")
    cmap = tmp_path / "map.yaml"
    cmap.write_text(
        'columns:\n  "Actual speed [1/min]": {name: speed, unit: rpm}\n'
        '  "n_soll": {name: speed_setpoint, unit: rpm}\n'
    )
    f = tmp_path / "vendor.csv"
    f.write_text(text)
    code, (obj,) = run_json([str(f), "--columns", str(cmap)], capsys)
    assert code == 0, obj
    assert "speed" in obj["channels"] and "speed_setpoint" in obj["channels"]


def test_bad_profile_is_one_line_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    prof = tmp_path / "p.yaml"
    prof.write_text(REFERENCE_PROFILE.read_text().replace("ratio: 30.99", "ratio: -1"))
    f = tmp_path / "r.csv"
    f.write_text(make_text())
    code = main(["inspect", str(f), "--profile", str(prof)])
    err = capsys.readouterr().err
    assert code == 2
    assert err.count("\n") == 1
    assert "gear.ratio" in err and str(prof) in err


def test_folder_argument_and_table_output(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / "a.csv").write_text(make_text())
    (tmp_path / "b.csv").write_text(make_text(direction=-1))
    code = main(["inspect", str(tmp_path)])
    out = capsys.readouterr().out
    assert code == 0
    assert "a.csv" in out and "b.csv" in out and "complete" in out


@pytest.mark.slow
def test_python_dash_m_and_no_traceback(tmp_path: Path) -> None:
    f = tmp_path / "nan.csv"
    f.write_text(make_text().replace("\n0.030,", "\n0.030,nan,", 1).replace("nan,0.0,", "nan,", 1))
    proc = subprocess.run(
        [sys.executable, "-m", "chaintwin", "inspect", str(f)],
        capture_output=True,
        text=True,
        check=False,
    )
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr + proc.stdout
    # 5 metadata lines, the header on line 6, the row at 0.030 s (row 5) on line 12
    assert "line 12, column 'speed_setpoint [rpm]'" in proc.stdout


def test_control_characters_from_a_file_never_reach_the_terminal(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from chaintwin.cli.app import main

    hostile = "\x1b]0;owned\x07\x1b[2J"
    ok = tmp_path / "meta.csv"
    ok.write_text(make_text(meta={"conveyor": f"belt{hostile}", "operator": hostile}))
    bad = tmp_path / "bad.csv"
    bad.write_text(make_text(meta={"recorded_at": f"2026-01-01{hostile}"}))
    code = main(["inspect", str(ok), str(bad)])
    out, err = capsys.readouterr()
    assert code == 2
    assert "\x1b" not in out + err and "\x07" not in out + err
    assert "belt\ufffd]0;owned" in out  # shown, defused
    # the JSON form keeps the text, escaped by JSON itself
    main(["inspect", str(ok), "--json"])
    out, _ = capsys.readouterr()
    assert "\x1b" not in out
    assert json.loads(out)[0]["conveyor"] == f"belt{hostile}"
