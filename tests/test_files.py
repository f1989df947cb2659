"""Input files: regular files only, none over the size limit, no hang, bounded memory."""

from __future__ import annotations

import json
import os
import shutil
import tracemalloc
from pathlib import Path

import pytest
from conftest import EXAMPLES, REFERENCE_PROFILE, make_text

from chaintwin.cli.app import main
from chaintwin.diagnose.state import load_state
from chaintwin.errors import (
    CalibrationError,
    ChaintwinError,
    ColumnMapError,
    ProfileError,
    RecordingError,
    StoreError,
)
from chaintwin.identify.calibration import load_calibration
from chaintwin.read.columns import load_column_map
from chaintwin.read.files import MAX_FILE_MB_ENV, max_file_bytes
from chaintwin.read.formats import read_recording
from chaintwin.read.profile import load_profile

LOADERS = [
    (read_recording, RecordingError),
    (load_profile, ProfileError),
    (load_column_map, ColumnMapError),
    (load_calibration, CalibrationError),
    (load_state, StoreError),
]


@pytest.fixture
def fifo(tmp_path: Path) -> Path:
    path = tmp_path / "pipe.csv"
    os.mkfifo(path)
    return path


@pytest.mark.parametrize(("load", "error"), LOADERS)
def test_a_named_pipe_is_refused_without_waiting_for_a_writer(
    load: object, error: type[ChaintwinError], fifo: Path
) -> None:
    with pytest.raises(error, match="not a regular file"):
        load(fifo)  # type: ignore[operator]


@pytest.mark.parametrize(("load", "error"), LOADERS)
def test_an_oversized_file_is_refused_before_it_is_read(
    load: object,
    error: type[ChaintwinError],
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    big = tmp_path / "big.csv"
    with big.open("wb") as f:  # sparse: 70 MB on paper, nothing on disk
        f.truncate(70_000_000)
    tracemalloc.start()
    try:
        with pytest.raises(error, match=r"70\.0 MB is more than .* \(max_file_mb 64 MB\)") as info:
            load(big)  # type: ignore[operator]
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 1_000_000  # bytes: refused from its size, not read
    assert info.value.field == "max_file_mb"
    # a higher limit lets it be read (and then judged on its content)
    monkeypatch.setenv(MAX_FILE_MB_ENV, "100")
    assert max_file_bytes() == 100_000_000
    with pytest.raises(error) as again:
        load(big)  # type: ignore[operator]
    assert "max_file_mb" not in str(again.value)


def test_the_limit_from_the_environment_must_be_a_positive_number(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    for bad in ("0", "-3", "lots", "nan"):
        monkeypatch.setenv(MAX_FILE_MB_ENV, bad)
        with pytest.raises(ChaintwinError, match="must be a positive number"):
            max_file_bytes()


def test_links_are_followed_and_loops_refused(tmp_path: Path) -> None:
    real = tmp_path / "rec.csv"
    real.write_text(make_text())
    link = tmp_path / "link.csv"
    link.symlink_to(real)
    assert read_recording(link).samples == read_recording(real).samples
    a, b = tmp_path / "a.csv", tmp_path / "b.csv"
    a.symlink_to(b)
    b.symlink_to(a)
    with pytest.raises(RecordingError, match="cannot be read"):
        read_recording(a)


@pytest.mark.slow
def test_deep_nesting_is_a_one_line_error(tmp_path: Path) -> None:
    deep_yaml = tmp_path / "deep.yaml"
    deep_yaml.write_text("[" * 5000 + "]" * 5000)
    with pytest.raises(ProfileError, match="nested too deeply"):
        load_profile(deep_yaml)
    with pytest.raises(ColumnMapError, match="nested too deeply"):
        load_column_map(deep_yaml)
    deep_json = tmp_path / "deep.json"
    deep_json.write_text("[" * 100_000 + "]" * 100_000)
    with pytest.raises(CalibrationError, match="nested too deeply"):
        load_calibration(deep_json)


def test_the_command_line_names_its_option_and_goes_on_past_a_pipe(
    tmp_path: Path,
    fifo: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.delenv(MAX_FILE_MB_ENV, raising=False)  # the option sets it: undone after
    shutil.copy(EXAMPLES / "recordings" / "white-belt-01-40kg.csv", tmp_path)
    big = tmp_path / "big.csv"
    with big.open("wb") as f:
        f.truncate(3_000_000)
    profile = str(REFERENCE_PROFILE)
    code = main(["--max-file-mb", "2", "inspect", str(tmp_path), "--profile", profile, "--json"])
    out, _ = capsys.readouterr()
    assert code == 2
    by_file = {Path(r["file"]).name: r for r in json.loads(out)}
    assert "not a regular file" in by_file["pipe.csv"]["error"]
    assert "(--max-file-mb 2 MB)" in by_file["big.csv"]["error"]
    assert by_file["white-belt-01-40kg.csv"]["samples"] > 0


def test_atomic_writes_leave_no_temporary_file_and_keep_the_old_one(tmp_path: Path) -> None:
    from chaintwin.read.files import write_atomic

    def fail(target: str, message: str) -> ChaintwinError:
        return ChaintwinError(f"{target}: {message}")

    target = tmp_path / "out.json"
    write_atomic(target, "old\n", what="file", error=fail)
    assert target.read_text() == "old\n"
    assert oct(target.stat().st_mode & 0o777) != oct(0o600)  # not mkstemp's private mode

    def half_then_crash(path: Path) -> None:
        path.write_text("half")
        raise OSError(28, "No space left on device")

    with pytest.raises(ChaintwinError, match=r"out\.json: cannot write the file \(No space"):
        write_atomic(target, half_then_crash, what="file", error=fail)
    assert target.read_text() == "old\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.json"]  # no .tmp left

    # a read-only folder: the error says so, nothing else is masked or left behind
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        if os.access(ro, os.W_OK):  # root writes anyway: nothing to check here
            return
        with pytest.raises(ChaintwinError, match="cannot write the file"):
            write_atomic(ro / "x.json", "x", what="file", error=fail)
        assert list(ro.iterdir()) == []
    finally:
        ro.chmod(0o700)
