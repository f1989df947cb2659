"""The reader registry: a format registered once is read by the commands and the
watched folders, through the same guarded way in for bytes."""

from __future__ import annotations

import asyncio
import json
import re
import types
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from conftest import EXAMPLES, REFERENCE_PROFILE

from chaintwin.calibrating import calibrate
from chaintwin.cli.app import main
from chaintwin.errors import RecordingError
from chaintwin.ingest import ingest
from chaintwin.live import watch
from chaintwin.read.files import MAX_FILE_MB_ENV
from chaintwin.read.formats import (
    CSV,
    format_of,
    is_recording_name,
    read_metadata,
    read_recording,
    recording_formats,
    recording_patterns,
    register_format,
    unregister_format,
)
from chaintwin.read.profile import load_profile
from chaintwin.store.store import Store
from chaintwin.validate.checks import load_recording

PAGE = Path(__file__).resolve().parents[1] / "docs" / "adding-a-reader.md"
CSV_FILE = EXAMPLES / "recordings" / "white-belt-01-40kg.csv"


def _page_module() -> types.ModuleType:
    """The format module of docs/adding-a-reader.md, as written there."""
    text = PAGE.read_text(encoding="utf-8")
    after = text.split("The whole format module:", 1)[1]
    code = re.search(r"```python\n(.*?)```", after, re.S)
    assert code is not None
    module = types.ModuleType("scope_json")
    exec(compile(code.group(1), str(PAGE), "exec"), module.__dict__)
    return module


@pytest.fixture
def scope_json() -> Iterator[types.ModuleType]:
    module = _page_module()
    register_format(module)  # type: ignore[arg-type]
    try:
        yield module
    finally:
        unregister_format(module.NAME)


def _as_json(csv: Path, out: Path) -> Path:
    """The CSV example written as a JSON scope export (same numbers, same text)."""
    lines = csv.read_text(encoding="utf-8").splitlines()
    meta = dict(line[2:].split(": ", 1) for line in lines if line.startswith("# "))
    body = [line for line in lines if not line.startswith("#")]
    doc = {
        "metadata": meta,
        "columns": body[0].split(","),
        "samples": [[float(v) for v in row.split(",")] for row in body[1:] if row],
    }
    out.write_text(json.dumps(doc), encoding="utf-8")
    return out


def test_the_csv_is_the_first_format_and_reads_what_no_other_claims() -> None:
    assert recording_formats()[0] is CSV
    assert recording_patterns() == ("*.csv",)
    assert format_of("scope.bin", b"\x00\x01") is CSV  # its refusal names the problem
    assert is_recording_name("/a/B.CSV") and not is_recording_name("/a/b.scope.json")


@pytest.mark.usefixtures("scope_json")
def test_a_toy_format_reads_the_same_recording_as_the_csv(tmp_path: Path) -> None:
    toy = _as_json(CSV_FILE, tmp_path / "white-belt-01.scope.json")
    assert recording_patterns() == ("*.csv", "*.scope.json")
    assert is_recording_name(str(toy)) and format_of(str(toy), toy.read_bytes()).NAME == (
        "scope-json"
    )
    profile = load_profile(REFERENCE_PROFILE)
    mine = read_recording(toy, profile=profile)
    theirs = read_recording(CSV_FILE, profile=profile)
    assert mine.source == str(toy)
    assert mine.metadata == theirs.metadata
    assert mine.units == theirs.units
    for name, values in theirs.channels.items():
        np.testing.assert_allclose(mine.channels[name], values, rtol=1e-15, atol=0.0)
    assert read_metadata(toy).conveyor == "white-belt-01"


@pytest.mark.usefixtures("scope_json")
def test_a_toy_format_through_the_command_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    folder = tmp_path / "exports"
    folder.mkdir()
    _as_json(CSV_FILE, folder / "white-belt-01.scope.json")
    (folder / "notes.txt").write_text("not a recording")
    capsys.readouterr()
    assert main(["inspect", "--profile", str(REFERENCE_PROFILE), "--json", str(folder)]) == 0
    mine = json.loads(capsys.readouterr().out)
    assert main(["inspect", "--profile", str(REFERENCE_PROFILE), "--json", str(CSV_FILE)]) == 0
    theirs = json.loads(capsys.readouterr().out)
    assert [r["file"] for r in mine] == [str(folder / "white-belt-01.scope.json")]
    for r in (*mine, *theirs):
        del r["file"]
    assert mine == theirs

    # a broken export: refused with the file named and what to do, the others go on
    bad = folder / "broken.scope.json"
    bad.write_text('{"columns": ["time [s]"]')
    assert main(["inspect", "--json", str(folder)]) == 2
    refused = [r for r in json.loads(capsys.readouterr().out) if "error" in r]
    assert refused == [
        {"file": str(bad), "error": refused[0]["error"]},
    ]
    assert refused[0]["error"].startswith(f"{bad}: is no JSON scope export")
    assert refused[0]["error"].endswith("export it again")


@pytest.mark.usefixtures("scope_json")
def test_a_toy_format_is_read_once_in_through_the_file_limit(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    toy = _as_json(CSV_FILE, tmp_path / "white-belt-01.scope.json")
    monkeypatch.setenv(MAX_FILE_MB_ENV, "0.01")  # 10 kB: the export is larger
    with pytest.raises(RecordingError, match="is more than a recording file may hold"):
        read_recording(toy)


@pytest.mark.usefixtures("scope_json")
def test_a_toy_format_through_a_watched_folder(tmp_path: Path) -> None:
    folder = tmp_path / "in"
    folder.mkdir()
    toy = _as_json(CSV_FILE, folder / "white-belt-01.scope.json")
    (folder / "late.scope.json.part").write_text("{")  # still being written
    (folder / "notes.txt").write_text("not a recording")
    handed: list[str] = []

    async def enqueue(path: str, ready_at: float) -> None:
        handed.append(path)

    source = watch.FolderSource(folder, 0.0, False, enqueue, None)
    source._add(source._scan())
    ready, _ = source._settled()
    assert ready == [str(toy)]

    async def hand_over() -> None:
        for path in ready:
            await source.enqueue(path, 0.0)

    asyncio.run(hand_over())
    profile = load_profile(REFERENCE_PROFILE)
    with Store(f"sqlite:///{tmp_path / 'plant.db'}") as store:
        calibration = [
            load_recording(EXAMPLES / "recordings" / name, profile=profile).recording
            for name in ("white-belt-01-cal-empty.csv", "white-belt-01-cal-50kg.csv")
        ]
        store.put_calibration(calibrate(calibration, profile))
        summary = ingest(handed, {profile.id: profile}, store, workers=1)
        assert (summary.processed, summary.refused) == (1, 0)
        assert [file for _id, file, _at in store.recording_index(profile.id)] == [str(toy)]
