"""The live service takes the files it finds in recorded order (``serve --order-window-s``).

A burst of files moved into a watched folder in shuffled order, under
shuffled names, gives the same stored results, alarms and notifications as
``chaintwin ingest`` of the same files, compared as ``scripts/check_same.py``
compares (ids aside). The number of files is ``CHAINTWIN_ORDER_BURST`` (72 by
default, to keep the suite's time; 1000 for the full burst).

``ingest`` is run with ``commit_group=1`` (``--commit-group 1``), one
recording a transaction as the service stores them: a notification carries
the alarm's cause when its transaction is committed, and with the default
group of 64 that is the cause at the end of the group (a later recording may
have changed it), not at the recording that opened the alarm.
"""

from __future__ import annotations

import asyncio
import importlib.util
import json
import os
import random
import sys
from pathlib import Path
from types import ModuleType
from typing import Any

import pytest
from conftest import EXAMPLES
from sqlalchemy import func, select
from sqlalchemy.orm import Session
from test_live import Service, wait_for

from chaintwin.calibrating.procedure import calibrate
from chaintwin.ingest.pipeline import ingest
from chaintwin.live.sources import Ingestor, Job, ReorderWindow
from chaintwin.read.profile import ConveyorProfile, load_profile
from chaintwin.simulate.faults import Fault
from chaintwin.simulate.fleet import generate
from chaintwin.store.schema import OutboxRow, RecordingRow
from chaintwin.store.store import Store
from chaintwin.validate import load_recording

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "check_same.py"


@pytest.fixture(scope="module")
def check_same() -> ModuleType:
    spec = importlib.util.spec_from_file_location("check_same", SCRIPT)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules["check_same"] = module
    spec.loader.exec_module(module)
    return module


# ---------------------------------------------------------------- the window
def _job(name: str) -> Job:
    return Job(name, "folder:x", 0.0)


def test_the_window_lets_files_through_in_recorded_order_each_after_the_window() -> None:
    w = ReorderWindow(10.0)
    w.add(_job("c"), "2026-01-01T03:00:00+00:00", now=0.0)
    w.add(_job("a"), "2026-01-01T01:00:00+00:00", now=1.0)
    w.add(_job("d"), "2026-01-01T04:00:00+00:00", now=2.0)
    w.add(_job("b"), "2026-01-01T02:00:00+00:00", now=3.0)
    assert len(w) == 4 and w.next_due() == 10.0
    assert w.release(9.9) == []
    # c's window ends: c and every file recorded before it, in recorded order
    assert [j.path for j in w.release(10.0)] == ["a", "b", "c"]
    assert len(w) == 1 and w.next_due() == 11.0  # a's deadline: a is gone already
    assert w.release(11.5) == []
    assert [j.path for j in w.release(12.0)] == ["d"]
    assert w.next_due() == 13.0 and w.release(13.0) == [] and w.next_due() is None
    # later than the window: let through in its turn (the monitor says out_of_order)
    w.add(_job("e"), "2026-01-01T00:30:00+00:00", now=20.0)
    assert [j.path for j in w.release(30.0)] == ["e"]


def test_the_window_breaks_ties_by_path_and_drains_in_order() -> None:
    w = ReorderWindow(5.0)
    same = "2026-01-01T01:00:00+00:00"
    for name in ("z", "m", "a"):
        w.add(_job(name), same, now=0.0)
    w.add(_job("early"), "2026-01-01T00:00:00+00:00", now=1.0)
    assert [j.path for j in w.drain()] == ["early", "a", "m", "z"]
    assert len(w) == 0 and w.next_due() is None


def test_put_file_holds_a_file_with_a_recorded_time_only(tmp_path: Path) -> None:
    """A file without a recorded time (or unreadable metadata) is not held: the ingest
    says what is wrong with it at once."""
    with Store(f"sqlite:///{tmp_path / 'w.db'}") as store:
        ingestor = Ingestor(store, {}, order_window_s=60.0)
        timed = tmp_path / "timed.csv"
        timed.write_text("# recorded_at: 2026-01-01T01:00:00+01:00\ntime_s,torque_nm\n0,1\n")
        untimed = tmp_path / "untimed.csv"
        untimed.write_text("time_s,torque_nm\n0,1\n")

        async def put() -> None:
            await ingestor.put_file(str(timed), "folder:x")
            await ingestor.put_file(str(untimed), "folder:x")
            await ingestor.put_file(str(tmp_path / "gone.csv"), "folder:x")

        asyncio.run(put())
        assert len(ingestor.window) == 1 and ingestor.queue.qsize() == 2
        assert ingestor.depth() == 2  # the held one waits by design: not counted
        assert [j.path for j in ingestor.window.drain()] == [str(timed)]
        ingestor.close()


# ---------------------------------------------------------------- the burst
PLANT: list[tuple[str, Fault, int, bool]] = [
    ("white-belt-01", Fault("friction", 0.6), 31, True),
    ("short-fast-03", Fault("rail_obstacle", 1.0), 32, True),
    ("incline-line-02", Fault("bearing", 0.6), 33, False),
]
"""As scripts/check_same.py's plant: (conveyor, fault, seed, calibrated before)."""


def _plant(folder: Path, n: int) -> tuple[dict[str, ConveyorProfile], list[Path]]:
    """About ``n`` recordings of the three conveyors (their faults from the second third),
    with their empty calibration runs; the profiles and the recordings."""
    per_day = 8
    days = max(3, -(-n // (len(PLANT) * per_day)))
    profiles: dict[str, ConveyorProfile] = {}
    files: list[Path] = []
    for cid, fault, seed, _cal in PLANT:
        prof = load_profile(EXAMPLES / "profiles" / f"{cid}.yaml")
        profiles[cid] = prof
        generate(
            prof,
            folder / cid,
            days=days,
            per_day=per_day,
            faults=[fault],
            onset_day=days // 3,
            seed=seed,
        )
        files += sorted((folder / cid).glob("*.csv"))
    return profiles, files


def _calibrated_store(url: str, profiles: dict[str, ConveyorProfile], folder: Path) -> None:
    with Store(url) as store:
        for cid, _fault, _seed, calibrated in PLANT:
            if calibrated:
                prof = profiles[cid]
                runs = sorted((folder / cid / "calibration").glob("*.csv"))
                recs = [load_recording(f, profile=prof).recording for f in runs]
                recs = [r for r in recs if r.metadata.payload_kg == 0.0]
                store.put_calibration(calibrate(recs, prof, version="order-test"))


def _notifications(store: Store, alarm_names: dict[str, str]) -> list[dict[str, Any]]:
    """The outbox (the notifications sent to every receiver), alarm ids renamed."""
    with Session(store.engine) as s:
        rows = s.scalars(select(OutboxRow)).all()
        out = [
            {
                "event": r.event,
                "alarm": alarm_names[r.alarm_id],
                "conveyor": r.conveyor_id,
                "feature": r.feature,
                "cause": r.cause,
                "at": r.at,
            }
            for r in rows
        ]
    return sorted(out, key=lambda d: json.dumps(d, sort_keys=True))


def _dumped(check_same: ModuleType, url: str, data: Path, out: Path) -> dict[str, Any]:
    """What check_same compares of a store (written to ``out``), with the notifications."""
    with Store(url) as store:
        dump = check_same._dump(store, data)
        names = {a: f"alarm-{k + 1}" for k, a in enumerate(dump["alarm_ids"])}
        dump["notifications"] = _notifications(store, names)
    dump["inputs"] = {}
    dump["summary"] = {}
    out.write_text(check_same.dump_text(dump, data))
    return dump


def _out_of_order(dump: dict[str, Any]) -> int:
    return sum(1 for w in dump["warnings"] if w[2] == "out_of_order")


@pytest.mark.slow
def test_a_shuffled_burst_gives_what_ingest_of_the_same_files_gives(
    check_same: ModuleType, tmp_path: Path
) -> None:
    n = int(os.environ.get("CHAINTWIN_ORDER_BURST", "72"))
    profiles, made = _plant(tmp_path / "made", n)
    made = made[:n] if len(made) >= n else made
    watched = tmp_path / "watched"
    watched.mkdir()
    live_url = f"sqlite:///{tmp_path / 'live.db'}"
    ingest_url = f"sqlite:///{tmp_path / 'ingest.db'}"
    for url in (live_url, ingest_url):
        _calibrated_store(url, profiles, tmp_path / "made")
    (tmp_path / "profiles").mkdir()
    for cid in profiles:
        (tmp_path / "profiles" / f"{cid}.yaml").write_text(
            (EXAMPLES / "profiles" / f"{cid}.yaml").read_text()
        )
    # the order window: longer than it takes to notice the whole burst
    args = [
        "--db", live_url, "--no-web", "--watch", str(watched),
        "--profiles", str(tmp_path / "profiles"),
        "--settle-s", "0.3", "--order-window-s", str(max(8.0, n / 50)),
    ]  # fmt: skip
    service = Service(args, tmp_path / "serve.log")
    try:
        # moved in at once, in shuffled order, under shuffled names: the order the
        # files are noticed in (and their names) says nothing of when they were recorded
        rng = random.Random(7)
        shuffled = list(made)
        rng.shuffle(shuffled)
        wait_for(lambda: any("following" in x for x in service.lines()), 300, "start", service)
        for k, f in enumerate(shuffled):
            f.rename(watched / f"{rng.getrandbits(32):08x}-{k:04d}.csv")
        with Store(live_url) as store:

            def all_stored() -> bool:
                with Session(store.engine) as s:
                    return s.scalar(select(func.count()).select_from(RecordingRow)) == len(made)

            wait_for(all_stored, 60 + 2.0 * len(made), "every file stored", service)
        assert service.stop() == 0
    finally:
        if service.proc.poll() is None:
            service.kill()
    files = sorted(str(p) for p in watched.glob("*.csv"))
    assert len(files) == len(made)
    with Store(ingest_url) as store:
        summary = ingest(files, profiles, store, workers=1, commit_group=1)
    assert summary.refused == 0
    live = _dumped(check_same, live_url, watched, tmp_path / "live.json")
    batch = _dumped(check_same, ingest_url, watched, tmp_path / "ingest.json")
    assert check_same.compare(tmp_path / "ingest.json", tmp_path / "live.json", 1e-9) == 0
    # what was compared is not empty, and in recorded order on both sides
    assert len(live["recordings"]) == len(made) and live["results"]
    assert live["alarms"] and live["notifications"]
    assert _out_of_order(live) == _out_of_order(batch) == 0
    assert live["notifications"] == batch["notifications"]
