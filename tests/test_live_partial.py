"""A file whose writer pauses longer than the settle time is not stored half-way.

The partial file ends in motion (mid-cycle): the service waits for the rest
of it (``PARTIAL_WAIT_S`` after its last change) and stores the complete
file once, whatever the pause.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import pytest
from conftest import REFERENCE_PROFILE
from sqlalchemy import select
from sqlalchemy.orm import Session
from test_live import Service, count, stored, wait_for

from chaintwin.live.ledger import known_paths
from chaintwin.live.sources import PARTIAL_WAIT_S, Ingestor, Job
from chaintwin.read.profile import load_profile
from chaintwin.simulate.fleet import generate
from chaintwin.store.schema import RecordingRow
from chaintwin.store.store import Store
from chaintwin.validate import load_recording

PROFILE = load_profile(REFERENCE_PROFILE)


@pytest.fixture(scope="module")
def complete(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One whole recording (standstill, move, standstill)."""
    folder = tmp_path_factory.mktemp("one")
    generate(PROFILE, folder, days=1, per_day=1, seed=3, calibration=False)
    (path,) = sorted(folder.glob("*.csv"))
    assert load_recording(path, profile=PROFILE).complete_cycle
    return path


def halves(path: Path) -> tuple[bytes, bytes]:
    """The file cut after a whole line in the middle of the move: (first part, rest)."""
    raw = path.read_bytes()
    cut = raw.index(b"\n", len(raw) // 2) + 1
    return raw[:cut], raw[cut:]


def test_a_file_ending_in_motion_waits_then_is_stored_as_it_is(
    complete: Path, tmp_path: Path
) -> None:
    part, _rest = halves(complete)
    partial = tmp_path / complete.name
    partial.write_bytes(part)
    assert load_recording(partial, profile=PROFILE).phases[-1].moving  # ends in motion
    store = Store(f"sqlite:///{tmp_path / 'p.db'}")
    ingestor = Ingestor(store, {PROFILE.id: PROFILE}, partial_wait_s=PARTIAL_WAIT_S)
    try:
        first = ingestor.ingest_one(Job(str(partial), "folder:x"))
        assert first.status == "deferred" and first.reason == "ends in motion"
        assert first.retry_in_s is not None and 0 < first.retry_in_s <= ingestor.partial_wait_s
        assert count(store.url, RecordingRow) == 0
        # the wait is over (no more to come): stored as it is, with its warning
        ingestor.partial_wait_s = 0.0
        then = ingestor.ingest_one(Job(str(partial), "folder:x"))
        assert then.status in ("stored", "waiting")
        assert then.sha256 == hashlib.sha256(part).hexdigest()
        with Session(store.engine) as s:
            (warnings,) = s.scalars(select(RecordingRow.warnings)).all()
        assert "incomplete_cycle" in {w["code"] for w in warnings or []}
    finally:
        ingestor.close()
        store.close()


def test_a_whole_file_is_not_held(complete: Path, tmp_path: Path) -> None:
    store = Store(f"sqlite:///{tmp_path / 'w.db'}")
    ingestor = Ingestor(store, {PROFILE.id: PROFILE}, partial_wait_s=PARTIAL_WAIT_S)
    try:
        out = ingestor.ingest_one(Job(str(complete), "folder:x"))
        assert out.status in ("stored", "waiting") and out.retry_in_s is None
    finally:
        ingestor.close()
        store.close()


@pytest.mark.slow
def test_a_writer_pausing_longer_than_the_settle_time_gets_its_file_stored_once_whole(
    complete: Path, tmp_path: Path
) -> None:
    url = f"sqlite:///{tmp_path / 'plant.db'}"
    watched = tmp_path / "drop"
    watched.mkdir()
    profiles = tmp_path / "profiles"
    profiles.mkdir()
    (profiles / "p.yaml").write_text(REFERENCE_PROFILE.read_text())
    args = [
        "--db", url, "--watch", str(watched), "--profiles", str(profiles), "--no-web",
        "--settle-s", "0.3", "--order-window-s", "0",
    ]  # fmt: skip
    part, rest = halves(complete)
    service = Service(args, tmp_path / "serve.log")
    try:
        wait_for(lambda: any("following" in x for x in service.lines()), 300, "start", service)
        target = watched / complete.name
        with target.open("wb") as f:
            f.write(part)
            f.flush()
            # the writer pauses: the file settles, is found ending in motion, and waits
            wait_for(
                lambda: any("ends in motion: waiting" in x for x in service.lines()),
                60,
                "the partial file deferred",
                service,
            )
            assert count(url, RecordingRow) == 0
            f.write(rest)
        whole = hashlib.sha256(part + rest).hexdigest()
        wait_for(stored(url, [whole]), 60, "the whole file stored", service)
        assert count(url, RecordingRow) == 1
        assert service.stop() == 0
    finally:
        if service.proc.poll() is None:
            service.kill()


def test_refused_retry_reads_a_file_ending_in_motion_at_once(
    complete: Path, tmp_path: Path
) -> None:
    """Outside the live service (``chaintwin refused retry``) nothing waits: the ingestor
    is made without a wait, and the file is stored as it is."""
    part, _rest = halves(complete)
    partial = tmp_path / complete.name
    partial.write_bytes(part)
    store = Store(f"sqlite:///{tmp_path / 'r.db'}")
    ingestor = Ingestor(store, {PROFILE.id: PROFILE})
    try:
        assert ingestor.partial_wait_s == 0.0
        out = ingestor.ingest_one(Job(str(partial), "folder:x"))
        assert out.status in ("stored", "waiting")
    finally:
        ingestor.close()
        store.close()


def test_the_complete_version_of_a_stored_partial_file_supersedes_it(
    complete: Path, tmp_path: Path
) -> None:
    """The partial file was stored (its wait ran out); the rest then came: the complete
    one is stored, the partial one marked superseded, the health model as if only the
    complete one had come."""
    part, rest = halves(complete)
    target = tmp_path / "drop" / complete.name
    target.parent.mkdir()
    target.write_bytes(part)
    store = Store(f"sqlite:///{tmp_path / 'p.db'}")
    alone = Store(f"sqlite:///{tmp_path / 'alone.db'}")
    ingestor = Ingestor(store, {PROFILE.id: PROFILE}, partial_wait_s=0.0)
    only = Ingestor(alone, {PROFILE.id: PROFILE}, partial_wait_s=0.0)
    try:
        first = ingestor.ingest_one(Job(str(target), "folder:x"))
        assert first.status in ("stored", "waiting")
        # a rescan reads a file stored only partially again (its rest may come)
        assert known_paths(store, [str(target)]) == set()
        target.write_bytes(part + rest)
        then = ingestor.ingest_one(Job(str(target), "folder:x"))
        assert then.status in ("stored", "waiting")
        assert then.sha256 == hashlib.sha256(part + rest).hexdigest()
        with Session(store.engine) as s:
            rows = s.execute(
                select(RecordingRow.id, RecordingRow.sha256, RecordingRow.superseded_by)
            ).all()
        by_sha = {sha: (rid, by) for rid, sha, by in rows}
        assert len(rows) == 2  # nothing deleted
        assert by_sha[first.sha256 or ""][1] == by_sha[then.sha256][0]
        assert by_sha[then.sha256][1] is None
        assert known_paths(store, [str(target)]) == {str(target)}
        # the same file again (unchanged): already stored, nothing more superseded
        assert ingestor.ingest_one(Job(str(target), "folder:x")).status == "already_stored"

        assert only.ingest_one(Job(str(target), "folder:x")).status == then.status
        mine, theirs = store.state(PROFILE.id), alone.state(PROFILE.id)
        assert mine is not None and theirs is not None
        assert [p["sha256"] for p in mine.to_dict()["pending"]] == [then.sha256]
        assert mine.to_dict() == theirs.to_dict()
        assert store.results() == alone.results()
    finally:
        ingestor.close()
        only.close()
        store.close()
        alone.close()
