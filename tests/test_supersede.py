"""A stored partial file superseded by its complete version (same conveyor, name, time).

The partial one stays in the store, marked ``superseded_by``; results, exports
and the health model read as if only the complete one had come.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import pytest
from conftest import REFERENCE_PROFILE
from sqlalchemy import select
from sqlalchemy.orm import Session

from chaintwin.calibrating.procedure import calibrate
from chaintwin.cli import main
from chaintwin.identify.calibration import Calibration
from chaintwin.read.profile import load_profile
from chaintwin.simulate.fleet import generate
from chaintwin.store.queries import results_page, trend_rows
from chaintwin.store.schema import RecordingRow
from chaintwin.store.store import Store
from chaintwin.validate import load_recording

PROFILE = load_profile(REFERENCE_PROFILE)


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Four whole recordings of one conveyor, and its calibration recordings."""
    folder = tmp_path_factory.mktemp("fleet")
    generate(PROFILE, folder, days=1, per_day=4, seed=7)
    return folder


@pytest.fixture(scope="module")
def calibration(fleet: Path) -> Calibration:
    """The conveyor's calibration from the calibration recordings (the same for every store)."""
    recs = [
        load_recording(f, profile=PROFILE).recording
        for f in sorted((fleet / "calibration").glob("*.csv"))
    ]
    return calibrate(recs, PROFILE)


def calibrated(url: str, calibration: Calibration) -> None:
    """A store with the conveyor's calibration (its recordings get results at once)."""
    store = Store(url)
    store.put_calibration(calibration)
    store.close()


def first_half(raw: bytes) -> bytes:
    """The file cut after a whole line in the middle (it ends in motion)."""
    return raw[: raw.index(b"\n", len(raw) // 2) + 1]


def run(args: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    code = main(args)
    out, err = capsys.readouterr()
    assert code == 0, err
    return out


def ingest(url: str, files: list[Path], profiles: Path, capsys: Any) -> None:
    args = ["ingest", *map(str, files), "--profiles", str(profiles), "--db", url, "--workers", "1"]
    run(args, capsys)


def comparable(url: str) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """The results and the health model of a store (what does not depend on when it ran)."""
    with Store(url, create=False) as store:
        results = store.results()
        state = store.state(PROFILE.id)
        assert state is not None
        return results, state.to_dict()


def test_the_complete_version_through_ingest_supersedes_the_stored_partial(
    fleet: Path, calibration: Calibration, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    profiles = tmp_path / "profiles"
    profiles.mkdir()
    shutil.copy(REFERENCE_PROFILE, profiles)
    drop = tmp_path / "drop"
    shutil.copytree(fleet, drop, ignore=shutil.ignore_patterns("calibration"))
    files = sorted(drop.glob("*.csv"))
    assert len(files) == 4
    whole = files[2].read_bytes()

    url = f"sqlite:///{tmp_path / 'plant.db'}"
    calibrated(url, calibration)
    files[2].write_bytes(first_half(whole))  # the writer paused: stored as it was
    assert load_recording(files[2], profile=PROFILE).recording.has_warning("incomplete_cycle")
    ingest(url, files[:3], profiles, capsys)
    files[2].write_bytes(whole)  # ... and then finished it
    ingest(url, files[2:3], profiles, capsys)
    ingest(url, files[3:], profiles, capsys)

    alone = f"sqlite:///{tmp_path / 'alone.db'}"  # as if only the complete one had come
    calibrated(alone, calibration)
    ingest(alone, files[:3], profiles, capsys)
    ingest(alone, files[3:], profiles, capsys)

    store = Store(url, create=False)
    with Session(store.engine) as s:
        rows = s.execute(
            select(RecordingRow.id, RecordingRow.file, RecordingRow.superseded_by).order_by(
                RecordingRow.id
            )
        ).all()
    store.close()
    assert len(rows) == 5  # nothing deleted
    partial, complete = rows[2], rows[3]
    assert partial.file == complete.file == str(files[2])
    assert partial.superseded_by == complete.id
    assert [r.superseded_by for r in rows if r is not partial] == [None] * 4

    results, state = comparable(url)
    expected, expected_state = comparable(alone)
    assert [r["file"] for r in results] == [str(f) for f in files]  # one listed per file
    assert results == expected
    assert state == expected_state
    assert len(state["baseline_rows"]) == 4  # the partial one is no part of the baseline
    assert [h["file"] for h in state["history"]] == [str(f) for f in files]

    # the web API's pages and trends, and the export, likewise
    with Store(url, create=False) as store:
        page = results_page(store, PROFILE.id)
        assert [r["file"] for r in page.items] == [str(f) for f in reversed(files)]
        trend = trend_rows(store, PROFILE.id, 100)
        assert trend.results == expected and trend.total == 4
    exported = json.loads(run(["export", "--db", url, "--format", "json"], capsys))
    assert [r["file"] for r in exported] == [str(f) for f in files]


def test_a_partial_followed_by_later_recordings_is_superseded_with_a_warning(
    fleet: Path, calibration: Calibration, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The rest of the partial file comes after a later recording was monitored: the
    complete one is stored, flagged, and the later result is not rewritten."""
    profiles = tmp_path / "profiles"
    profiles.mkdir()
    shutil.copy(REFERENCE_PROFILE, profiles)
    drop = tmp_path / "drop"
    shutil.copytree(fleet, drop, ignore=shutil.ignore_patterns("calibration"))
    files = sorted(drop.glob("*.csv"))[:3]
    whole = files[1].read_bytes()
    url = f"sqlite:///{tmp_path / 'plant.db'}"
    calibrated(url, calibration)
    files[1].write_bytes(first_half(whole))
    ingest(url, files, profiles, capsys)
    before = comparable(url)[0]
    files[1].write_bytes(whole)
    ingest(url, files[1:2], profiles, capsys)

    results, state = comparable(url)
    assert [r["file"] for r in results] == [str(files[k]) for k in (0, 2, 1)]
    assert results[:2] == [before[0], before[2]]  # the later one as it was judged
    codes = {w["code"] for w in results[2]["warnings"]}
    assert {"supersedes_partial", "out_of_order"} <= codes
    assert "incomplete_cycle" not in codes
    assert [h["file"] for h in state["history"]] == [str(files[k]) for k in (0, 2, 1)]
