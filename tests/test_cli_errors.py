"""The command line names its options where the library names its fields."""

from __future__ import annotations

from pathlib import Path

import pytest
from conftest import EXAMPLES, REFERENCE_PROFILE

from chaintwin.cli.app import main


@pytest.mark.parametrize(
    ("args", "line"),
    [
        (["generate", "--days", "0"], "--days 0 must be at least 1"),
        (["generate", "--per-day", "0"], "--per-day 0 must be at least 1"),
        (["generate", "--days", "3", "--onset", "5"], "--onset 5 must be a day from 0 to 2"),
        (["generate", "--drift", "0.7"], "--drift 0.7 must be from 0 to 0.5"),
    ],
)
def test_generate_settings(
    args: list[str], line: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code = main([*args, "--profile", str(REFERENCE_PROFILE), "--out", str(tmp_path)])
    _, err = capsys.readouterr()
    assert code == 2
    assert err.startswith(f"chaintwin: error: {line}")
    assert err.count("\n") == 1


@pytest.mark.parametrize(
    ("option", "line"),
    [
        (["--baseline", "3"], "--baseline 3 must be at least 5 recordings"),
        (["--alarm-rule", "5/3"], "--alarm-rule 5/3 needs 1 <= X <= Y"),
        (["--z-limit", "-1"], "--z-limit -1.0 must be a positive number"),
    ],
)
def test_monitor_settings(option: list[str], line: str, capsys: pytest.CaptureFixture[str]) -> None:
    rec = str(EXAMPLES / "recordings" / "white-belt-01-40kg.csv")
    code = main(["monitor", "--profile", str(REFERENCE_PROFILE), *option, rec])
    _, err = capsys.readouterr()
    assert code == 2
    assert line in err
    assert err.count("\n") == 1


def test_a_command_asked_for_json_prints_its_error_as_json_too(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    import json

    missing = tmp_path / "typo.db"
    code = main(["export", "--db", f"sqlite:///{missing}", "--format", "json"])
    out, err = capsys.readouterr()
    assert code == 2
    error = json.loads(out)["error"]
    assert error["code"] == "store_error"
    assert error["field"] == "url"
    assert error["message"] == err.strip().removeprefix("chaintwin: error: ")
    # without --json only the one line on stderr
    assert main(["export", "--db", f"sqlite:///{missing}"]) == 2
    out, err = capsys.readouterr()
    assert out == ""
    assert err.count("\n") == 1


def test_calibrate_with_no_usable_file_names_each_file_and_why(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    a, b = tmp_path / "a.csv", tmp_path / "b.csv"
    a.write_text("time [s],speed [rpm]\n0,0\n")
    b.write_text("hello\n")
    out = tmp_path / "cal.json"
    code = main(
        ["calibrate", "--profile", str(REFERENCE_PROFILE), str(a), str(b), "--out", str(out)]
    )
    _, err = capsys.readouterr()
    assert code == 2
    assert err.count("\n") == 1
    assert f"{a}, line 1: missing required column 'torque'" in err
    assert f"{b}, line 1: header of column 1 is 'hello'" in err
    assert not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.csv", "b.csv"]  # no temp file left
