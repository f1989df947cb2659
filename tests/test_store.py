"""The results store on SQLite and on a real PostgreSQL server; ingest and export."""

from __future__ import annotations

import csv
import io
import json
import os
import shutil
import signal
import subprocess
import sys
import time
import zlib
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import EXAMPLES, REFERENCE_PROFILE

from chaintwin.cli.app import main
from chaintwin.diagnose.records import MonitorSettings
from chaintwin.errors import StoreError
from chaintwin.ingest.pipeline import ingest
from chaintwin.read.profile import load_profile
from chaintwin.simulate.faults import Fault
from chaintwin.simulate.fleet import generate
from chaintwin.store.store import Store
from chaintwin.validate.checks import load_recording

PROFILE = load_profile(REFERENCE_PROFILE)


# ---------------------------------------------------------------- data
@pytest.fixture(scope="module")
def plant(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The reference conveyor's recordings over three days (friction rising) and its profile."""
    root = tmp_path_factory.mktemp("plant")
    generate(
        PROFILE,
        root / "recs" / "wb",
        days=3,
        per_day=6,
        faults=[Fault("friction", 0.6)],
        onset_day=1,
        seed=5,
    )
    (root / "profiles").mkdir()
    shutil.copy(REFERENCE_PROFILE, root / "profiles" / "white-belt-01.yaml")
    return root


def _recordings(plant: Path) -> list[str]:
    return sorted(str(p) for p in (plant / "recs" / "wb").glob("*.csv"))


def _calibrate(plant: Path, url: str) -> None:
    cal = sorted(str(p) for p in (plant / "recs" / "wb" / "calibration").glob("*.csv"))
    assert main(["calibrate", "--profile", str(REFERENCE_PROFILE), *cal, "--db", url]) == 0


# ---------------------------------------------------------------- tests
@pytest.mark.slow
def test_ingest_is_idempotent_and_keeps_a_refused_file_out(
    plant: Path, db: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    _calibrate(plant, db)
    bad = tmp_path / "bad.csv"
    bad.write_text("# conveyor: white-belt-01\ntime [s],speed [rpm]\n0,1\n", encoding="utf-8")
    files = _recordings(plant)
    args = ["ingest", *files, str(bad), "--profiles", str(plant / "profiles"), "--db", db]
    capsys.readouterr()
    assert main([*args, "--json", "--workers", "2", "--baseline", "6"]) == 0
    first = json.loads(capsys.readouterr().out)
    assert first["processed"] == len(files)
    assert first["refused"] == 1 and first["refusals"][0]["file"] == str(bad)
    assert first["new_alarms"] >= 1  # friction rises by 60 % over the days
    assert main([*args, "--json"]) == 0
    again = json.loads(capsys.readouterr().out)
    assert again["processed"] == 0 and again["duplicates"] == len(files)
    with Store(db) as store:
        assert store.counts()["results"] == len(files)
        assert store.counts()["recordings"] == len(files)
        rows = store.results("white-belt-01")
    assert [r["recorded_at"] for r in rows] == sorted(r["recorded_at"] for r in rows)
    assert any(r["alarm"] and r["causes"][0]["cause"] == "friction" for r in rows)
    # export: CSV for other tools, one row per recording
    assert main(["export", "--db", db, "--conveyor", "white-belt-01", "--format", "csv"]) == 0
    table = list(csv.DictReader(io.StringIO(capsys.readouterr().out)))
    assert len(table) == len(files)
    assert {"conveyor", "file", "payload_kg", "friction", "alarm"} <= set(table[0])
    assert main(["export", "--db", db, "--conveyor", "nope"]) == 2
    assert "nope" in capsys.readouterr().err


def test_store_keeps_samples_acknowledgements_and_maintenance(
    plant: Path, db: str, capsys: pytest.CaptureFixture[str]
) -> None:
    _calibrate(plant, db)
    files = _recordings(plant)
    args = ["ingest", *files, "--profiles", str(plant / "profiles"), "--db", db, "--json"]
    assert main([*args, "--baseline", "6", "--commit-group", "5"]) == 0
    capsys.readouterr()
    with Store(db) as store:
        # the samples are kept: a stored recording is the file's recording again
        index = store.recording_index("white-belt-01")
        assert len(index) == len(files)
        rid, name, _at = index[-1]
        again = store.recording(rid)
        orig = load_recording(name, profile=PROFILE).recording
        assert set(again.channels) == set(orig.channels)
        for k, v in orig.channels.items():
            np.testing.assert_array_equal(again.channels[k], v)
        assert again.metadata.recorded_at == orig.metadata.recorded_at
        opened = [a for a in store.alarms("white-belt-01") if a.is_open]
        assert opened, "friction rises by 60 %: an alarm is open"
        target = opened[0].id
        assert main(["acknowledge", target, "--db", db, "--by", "A. Fitter", "--why", "WO 7"]) == 0
        acked = {a.id: a for a in store.alarms("white-belt-01")}[target]
        assert acked.acknowledged is not None and acked.acknowledged.by == "A. Fitter"
        assert acked.is_open
        state = store.state("white-belt-01")
        assert state is not None
        ack = {a.id: a for a in state.alarms}[target].acknowledged
        assert ack is not None and ack.why == "WO 7"
        # twice is refused in one line, exit 2, nothing changed
        assert main(["acknowledge", target, "--db", db, "--by", "B"]) == 2
        assert "acknowledged by A. Fitter" in capsys.readouterr().err
        assert main(["acknowledge", "nope", "--db", db, "--by", "B"]) == 2
        assert "no alarm 'nope'" in capsys.readouterr().err
        # maintenance closes the open alarms at once and is kept as an event
        assert (
            main(
                [
                    "maintenance",
                    "--db",
                    db,
                    "--conveyor",
                    "white-belt-01",
                    "--kind",
                    "cleaning",
                    "--by",
                    "A. Fitter",
                    "--why",
                    "rails cleaned",
                ]
            )
            == 0
        )
        assert all(not a.is_open for a in store.alarms("white-belt-01"))
        events = store.events("white-belt-01")
        assert [e.kind for e in events] == ["cleaning"] and events[0].by == "A. Fitter"
        # the next ingest continues from the changed model (its baseline restarts)
        mon, _version = store.monitor(PROFILE, MonitorSettings(baseline_n=6))
        assert mon is not None and [e.kind for e in mon.events] == ["cleaning"]
        assert (
            main(
                ["maintenance", "--db", db, "--conveyor", "nope", "--kind", "cleaning", "--by", "x"]
            )
            == 2
        )
        assert "no health model of conveyor 'nope'" in capsys.readouterr().err


def _ingest_cmd(plant: Path, url: str, group: int) -> list[str]:
    return [
        sys.executable,
        "-m",
        "chaintwin",
        "ingest",
        *_recordings(plant),
        "--profiles",
        str(plant / "profiles"),
        "--db",
        url,
        "--baseline",
        "6",
        "--workers",
        "1",
        "--commit-group",
        str(group),
        "--json",
    ]


@pytest.mark.slow
def test_killed_ingest_leaves_one_result_per_recording(plant: Path, db: str) -> None:
    _calibrate(plant, db)
    files = _recordings(plant)
    # its own process group: the kill takes its worker processes too, as a
    # service manager stopping it would
    # groups of 2 recordings per transaction: the kill lands between or inside groups
    proc = subprocess.Popen(
        _ingest_cmd(plant, db, 2), stdout=subprocess.DEVNULL, start_new_session=True
    )
    store = Store(db)
    try:
        deadline = time.monotonic() + 120
        while store.counts()["results"] < 3 and time.monotonic() < deadline:
            if proc.poll() is not None:
                break
            time.sleep(0.05)
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
        partial = store.counts()["results"]
        assert 0 < partial < len(files), "the kill came too late to test anything"
        # nothing half-written: every stored recording has its result
        assert store.counts()["recordings"] == partial
        done = subprocess.run(_ingest_cmd(plant, db, 2), capture_output=True, check=True, text=True)
        summary = json.loads(done.stdout)
        assert summary["duplicates"] == partial
        assert summary["processed"] == len(files) - partial
        assert store.counts()["results"] == len(files)
        rows = store.results()
        assert len({r["file"] for r in rows}) == len(files)
    finally:
        store.close()
        if proc.poll() is None:
            proc.kill()


@pytest.mark.slow
def test_two_ingests_at_once_store_each_recording_once(plant: Path, db: str) -> None:
    _calibrate(plant, db)
    files = _recordings(plant)
    # one writes each recording on its own, the other in groups of 3: races
    # between groups and single recordings both happen
    a = subprocess.Popen(
        _ingest_cmd(plant, db, 1), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    b = subprocess.Popen(
        _ingest_cmd(plant, db, 3), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    out_a, err_a = a.communicate(timeout=300)
    out_b, err_b = b.communicate(timeout=300)
    assert a.returncode == 0, err_a
    assert b.returncode == 0, err_b
    sa, sb = json.loads(out_a), json.loads(out_b)
    assert sa["processed"] + sb["processed"] == len(files)
    assert sa["processed"] + sa["duplicates"] == len(files)
    with Store(db) as store:
        assert store.counts()["results"] == len(files)
        assert len({r["file"] for r in store.results()}) == len(files)


@pytest.mark.slow
def test_dask_cluster_and_this_process_give_the_same_results_as_the_local_pool(
    plant: Path, tmp_path: Path
) -> None:
    from distributed import LocalCluster

    files = _recordings(plant)
    profiles = {PROFILE.id: PROFILE}
    settings = MonitorSettings(baseline_n=6)
    out: dict[str, list[dict[str, object]]] = {}
    cluster = LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
    )
    try:
        for kind, scheduler, workers in (
            ("local", None, 2),
            ("dask", cluster.scheduler_address, 2),
            ("inline", None, 1),  # one worker: the pipeline runs in this process
        ):
            url = f"sqlite:///{tmp_path / kind}.db"
            _calibrate(plant, url)
            with Store(url) as store:
                s = ingest(
                    files, profiles, store, settings=settings, workers=workers, scheduler=scheduler
                )
                assert s.processed == len(files)
                out[kind] = store.results()
    finally:
        cluster.close()
    for other in ("dask", "inline"):
        _same_results(out["local"], out[other])


def _same_results(local: list[dict[str, object]], dask: list[dict[str, object]]) -> None:
    assert [r["file"] for r in local] == [r["file"] for r in dask]
    for x, y in zip(local, dask, strict=True):
        assert x["payload_kg"] == pytest.approx(y["payload_kg"], rel=1e-9)
        assert x["alarm"] == y["alarm"]
        assert x["status"] == y["status"]
        fx, fy = x["features"], y["features"]
        assert isinstance(fx, dict) and isinstance(fy, dict) and fx.keys() == fy.keys()
        for k, v in fx.items():
            if v is None:
                assert fy[k] is None, k
            else:
                assert fy[k] == pytest.approx(v, rel=1e-9), k


def test_samples_round_trip_in_every_packing() -> None:
    from chaintwin.store.samples import load_samples, pack_samples

    rec = load_recording(EXAMPLES / "recordings" / "white-belt-01-40kg.csv").recording
    blob = pack_samples(rec)
    raw = sum(np.asarray(v).nbytes for v in rec.channels.values())
    assert len(blob) < 0.4 * raw  # compressed
    for got in (load_samples(blob), *_earlier_packings(rec)):
        assert set(got) == set(rec.channels)
        for k, v in rec.channels.items():
            assert got[k].dtype == np.asarray(v).dtype
            np.testing.assert_array_equal(got[k], v)


def _earlier_packings(rec: Any) -> list[dict[str, np.ndarray]]:
    """Stores written before hold numpy's compressed .npz, a zlib-compressed .npz, or a
    Zstandard-compressed .npz of transposed byte views with a dtypes entry."""
    import zstandard

    from chaintwin.store.samples import load_samples

    arrays = {k: np.asarray(v) for k, v in rec.channels.items()}
    npz, plain, views = io.BytesIO(), io.BytesIO(), io.BytesIO()
    np.savez_compressed(npz, **arrays)
    np.savez(plain, **arrays)
    byte_views = {k: a.view(np.uint8).reshape(-1, a.dtype.itemsize).T for k, a in arrays.items()}
    dtypes = json.dumps({k: a.dtype.str for k, a in arrays.items()})
    np.savez(views, **byte_views, __dtypes__=np.array(dtypes))
    return [
        load_samples(npz.getvalue()),
        load_samples(zlib.compress(plain.getvalue(), 1)),
        load_samples(zstandard.ZstdCompressor().compress(views.getvalue())),
    ]


def test_a_learning_conveyor_goes_on_across_ingests(tmp_path: Path) -> None:
    """Without a calibration the first 20 recordings wait: they are stored, not lost."""
    root = tmp_path / "plant"
    out = generate(PROFILE, root, days=6, per_day=6, seed=9, calibration=False)
    files = sorted(str(f) for f in out.folder.glob("*.csv"))
    assert len(files) == 36
    store = Store(f"sqlite:///{tmp_path / 'plant.db'}")
    profiles = {PROFILE.id: PROFILE}
    settings = MonitorSettings(baseline_n=20)
    try:
        first = ingest(files[:10], profiles, store, settings=settings, workers=1)
        assert (first.processed, first.waiting, first.refused) == (0, 10, 0)
        assert store.counts()["recordings"] == 10 and store.counts()["results"] == 0
        # the 20th recording completes the learning: the 10 stored ones get their results
        second = ingest(files[:25], profiles, store, settings=settings, workers=1)
        assert (second.processed, second.duplicates, second.waiting) == (25, 10, 0)
        third = ingest(files, profiles, store, settings=settings, workers=1)
        assert (third.processed, third.duplicates) == (11, 25)
        assert store.counts()["recordings"] == store.counts()["results"] == 36
        rows = store.results(PROFILE.id)
        assert [r["file"] for r in rows] == files
        assert {r["status"] for r in rows[:20]} == {"baseline"}
        state = store.state(PROFILE.id)
        assert state is not None and state.calibration_source == "learned"
        assert not [n for n in state.notes if n["code"] == "pending_lost"]
    finally:
        store.close()


def test_a_changed_profile_is_refused_and_changes_nothing(
    plant: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    db = f"sqlite:///{tmp_path / 'p.db'}"
    _calibrate(plant, db)
    files = _recordings(plant)
    args = ["ingest", *files[:8], "--profiles", str(plant / "profiles"), "--db", db, "--json"]
    assert main([*args, "--baseline", "6"]) == 0
    changed = tmp_path / "profiles"
    changed.mkdir()
    text = REFERENCE_PROFILE.read_text(encoding="utf-8").replace("length_m: 4.3", "length_m: 4.4")
    (changed / "white-belt-01.yaml").write_text(text, encoding="utf-8")
    with Store(db) as store:
        before = store.profile(PROFILE.id)
        capsys.readouterr()
        again = ["ingest", *files[8:], "--profiles", str(changed), "--db", db, "--json"]
        assert main(again) == 0
        summary = json.loads(capsys.readouterr().out)
        assert summary["processed"] == 0 and summary["refused"] == len(files) - 8
        assert "another version of its profile" in summary["refusals"][0]["error"]
        assert store.profile(PROFILE.id) == before  # the stored profile is untouched
        assert store.counts()["results"] == 8
        cal = sorted(str(p) for p in (plant / "recs" / "wb" / "calibration").glob("*.csv"))
        profile = str(changed / "white-belt-01.yaml")
        assert main(["calibrate", "--profile", profile, *cal, "--db", db]) == 2
        assert "another version of its profile" in capsys.readouterr().err
        assert store.profile(PROFILE.id) == before


def test_json_columns_write_standard_json_and_read_earlier_nan(tmp_path: Path) -> None:
    """The store's JSON serializer (orjson) writes what json_ready + json.dumps wrote,
    and values stored before it with NaN (the standard library's extension) still read."""
    import sqlite3

    from chaintwin.diagnose.state import json_ready
    from chaintwin.store.engine import _from_json, _to_json

    value = {
        "a": float("nan"),
        "b": (1.5, float("inf"), -float("inf")),
        "c": [np.float64(0.1), np.arange(3), {"d": None, "e": "x"}],
        7: 1e16,
    }
    text = _to_json(value)
    assert "NaN" not in text and "Infinity" not in text
    expected = json.loads(json.dumps(json_ready({**value, "c": [0.1, [0, 1, 2], value["c"][2]]})))
    assert _from_json(text) == expected
    # earlier stores: a health model written with NaN reads as before
    db = tmp_path / "old.db"
    store = Store(f"sqlite:///{db}")
    store.put_profile(PROFILE)
    store.close()
    with sqlite3.connect(db) as con:
        con.execute(
            "UPDATE conveyors SET profile = ? WHERE id = ?",
            (json.dumps(PROFILE.model_dump(mode="json") | {"legacy": float("nan")}), PROFILE.id),
        )
    from sqlalchemy.orm import Session

    from chaintwin.store.schema import ConveyorRow

    with Store(f"sqlite:///{db}") as store, Session(store.engine) as s:
        row = s.get(ConveyorRow, PROFILE.id)
        assert row is not None
        assert np.isnan(row.profile["legacy"])


def test_guided_tasks_shrink_towards_the_end() -> None:
    from chaintwin.ingest.pipeline import _Window

    w = _Window(tasks=6, biggest=8, lanes=2, left=400)
    sizes = []
    while w.left:
        k = w.size()
        sizes.append(k)
        w.left -= k
    assert sum(sizes) == 400
    assert sizes[0] == 8 and set(sizes[:40]) == {8}  # full tasks while much is left
    assert sizes[-4:] == [1, 1, 1, 1]  # the last ones one recording each
    assert sizes == sorted(sizes, reverse=True)


class _FakeClient:
    """What :class:`ClusterExecutor` asks of a Dask client, without a cluster."""

    def __init__(self, threads: int) -> None:
        self.threads = threads
        self.scattered: list[object] = []

    def get_executor(self, **kwargs: object) -> Any:
        from chaintwin.ingest.executors import InlineExecutor

        assert kwargs == {"pure": False}  # tasks read files: never merged by their arguments
        return InlineExecutor()

    def scheduler_info(self) -> dict[str, Any]:
        return {"workers": {f"w{k}": {"nthreads": 1} for k in range(self.threads)}}

    def scatter(self, data: list[object], *, broadcast: bool, hash: bool) -> list[object]:
        assert broadcast and not hash
        self.scattered.append(data[0])
        return [("future", data[0])]


def test_tasks_for_a_dask_cluster_follow_its_worker_threads() -> None:
    """Full tasks on a known cluster (not a few recordings each, as for 21 unknown lanes)."""
    from chaintwin.ingest.executors import ClusterExecutor
    from chaintwin.ingest.pipeline import CHUNK, DASK_IN_FLIGHT, IN_FLIGHT_PER_WORKER, _window

    w = _window(ClusterExecutor(_FakeClient(2)), None, 400)
    assert (w.lanes, w.tasks, w.biggest) == (2, 2 * IN_FLIGHT_PER_WORKER, CHUNK)
    assert w.size() == CHUNK
    w = _window(ClusterExecutor(_FakeClient(0)), None, 400)  # no worker yet
    assert w.tasks == DASK_IN_FLIGHT // IN_FLIGHT_PER_WORKER * IN_FLIGHT_PER_WORKER


def test_what_tasks_share_goes_to_a_dask_cluster_once() -> None:
    import copy

    from chaintwin.ingest.executors import ClusterExecutor, InlineExecutor, shared

    client = _FakeClient(2)
    ex = ClusterExecutor(client)
    assert shared(ex, PROFILE) == ("future", PROFILE)
    assert shared(ex, PROFILE) == ("future", PROFILE)
    other = copy.deepcopy(PROFILE)  # a new object (a calibration learned anew): sent anew
    assert shared(ex, other)[1] is other
    assert shared(ex, None) is None
    assert client.scattered == [PROFILE, other]
    assert shared(InlineExecutor(), PROFILE) is PROFILE  # a local pool pickles it with the task
    assert ex.submit(len, [1, 2]).result() == 2
    ex.shutdown()


@pytest.mark.slow
def test_a_fleet_ingest_on_workers_equals_each_conveyor_ingested_alone(tmp_path: Path) -> None:
    """Three conveyors in one shuffled batch on two workers (tasks across conveyors, small
    commit groups, one conveyor learning its calibration) against one conveyor at a time here."""
    profs = {
        p.id: p
        for p in (
            load_profile(EXAMPLES / "profiles" / f"{name}.yaml")
            for name in ("white-belt-01", "incline-line-02", "short-fast-03")
        )
    }
    files: dict[str, list[str]] = {}
    for k, (cid, prof) in enumerate(profs.items()):
        learning = cid == "short-fast-03"
        out = generate(
            prof,
            tmp_path / "recs" / cid,
            days=4 if learning else 2,
            per_day=6,
            seed=20 + k,
            calibration=not learning,
            faults=[Fault("friction", 0.5)] if cid == "incline-line-02" else (),
            onset_day=1,
        )
        files[cid] = sorted(str(f) for f in out.folder.glob("*.csv"))
    settings = MonitorSettings(baseline_n=6)
    results: dict[str, list[dict[str, object]]] = {}
    for kind in ("fleet", "alone"):
        url = f"sqlite:///{tmp_path / kind}.db"
        for cid in ("white-belt-01", "incline-line-02"):
            cal = sorted(str(p) for p in (tmp_path / "recs" / cid / "calibration").glob("*.csv"))
            prof_file = EXAMPLES / "profiles" / f"{cid}.yaml"
            assert main(["calibrate", "--profile", str(prof_file), *cal, "--db", url]) == 0
        with Store(url) as store:
            if kind == "fleet":
                # given out of recorded order: sent so while the scan runs, taken in order
                batch = [f for cid in sorted(files) for f in files[cid]]
                np.random.default_rng(3).shuffle(batch)
                s = ingest(batch, profs, store, settings=settings, workers=2, commit_group=5)
                assert s.processed == len(batch) and s.refused == 0
            else:
                for cid, some in files.items():
                    ingest(some, {cid: profs[cid]}, store, settings=settings, workers=1)
            results[kind] = store.results()
    assert len(results["fleet"]) == sum(len(v) for v in files.values()) == 48
    by_file = {r["file"]: r for r in results["alone"]}
    _same_results(results["fleet"], [by_file[str(r["file"])] for r in results["fleet"]])
    statuses: dict[tuple[object, object], int] = {}
    for r in results["fleet"]:
        statuses[r["conveyor"], r["status"]] = statuses.get((r["conveyor"], r["status"]), 0) + 1
    assert statuses == {
        ("white-belt-01", "baseline"): 6,
        ("white-belt-01", "monitored"): 6,
        ("incline-line-02", "baseline"): 6,
        ("incline-line-02", "monitored"): 6,
        ("short-fast-03", "baseline"): 6,
        ("short-fast-03", "monitored"): 18,
    }
    # the one without a stored calibration learned one from its own recordings
    for r in results["fleet"]:
        codes = {w["code"] for w in r["warnings"]}  # type: ignore[attr-defined]
        assert ("payload_uncalibrated" in codes) == (r["conveyor"] == "short-fast-03")


def test_local_workers_run_with_a_short_thread_switch_interval() -> None:
    import sys

    from chaintwin.ingest.executors import SWITCH_INTERVAL_S, executor

    before = sys.getswitchinterval()
    with executor(1, None):
        assert sys.getswitchinterval() == before  # this process alone: nothing to hand over
    with executor(2, None):
        assert sys.getswitchinterval() == pytest.approx(SWITCH_INTERVAL_S)  # held in µs
    assert sys.getswitchinterval() == before


def test_a_file_given_twice_is_read_once_and_the_health_model_stores_as_before(
    plant: Path, tmp_path: Path
) -> None:
    from chaintwin.diagnose.state import json_ready
    from chaintwin.store.engine import _to_json

    files = _recordings(plant)[:8]
    url = f"sqlite:///{tmp_path / 'twice.db'}"
    _calibrate(plant, url)
    store = Store(url)
    settings = MonitorSettings(baseline_n=6)
    try:
        s = ingest([files[0], *files, files[3]], {PROFILE.id: PROFILE}, store, settings=settings)
        assert (s.processed, s.duplicates, s.refused) == (8, 2, 0)
        assert store.counts()["recordings"] == store.counts()["results"] == 8
        # the health model as orjson writes it reads back as json_ready + json wrote it
        mon, _version = store.monitor(PROFILE, settings)
        assert mon is not None
        state = mon.to_state().to_dict()
        assert json.loads(_to_json(state)) == json.loads(json.dumps(json_ready(state)))
        assert json.loads(_to_json({"big": 2**70})) == {"big": 2**70}  # beyond orjson
    finally:
        store.close()


def test_an_unexpected_failure_refuses_that_recording_and_the_batch_goes_on(
    plant: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """One recording whose analysis fails in an unforeseen way is refused with its reason;
    every other recording is stored (one worker: the pipeline runs in this process)."""
    from chaintwin.ingest import worker

    url = f"sqlite:///{tmp_path / 'plant.db'}"
    _calibrate(plant, url)
    files = _recordings(plant)
    victim = files[7]
    real = worker.recording_features

    def fragile(ins: Any, cal: Any) -> Any:
        if ins.recording.source == victim:
            raise FloatingPointError("overflow in a fit")
        return real(ins, cal)

    monkeypatch.setattr(worker, "recording_features", fragile)
    with Store(url) as store:
        summary = ingest(files, {PROFILE.id: PROFILE}, store, workers=1)
        assert summary.refused == 1
        (refusal,) = summary.refusals
        assert refusal["file"] == victim
        assert "FloatingPointError: overflow in a fit" in refusal["error"]
        assert summary.processed == len(files) - 1
        assert len(store.results(PROFILE.id)) == len(files) - 1


def _digest(path: Path) -> str:
    import hashlib

    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_reading_commands_open_read_only_and_damaged_stores_are_refused_untouched(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    good = tmp_path / "good.db"
    store = Store(f"sqlite:///{good}")
    store.put_profile(PROFILE)
    store.close()
    before = _digest(good)
    # export only reads: the file is the same, and the read-only object cannot write
    assert main(["export", "--db", f"sqlite:///{good}", "--format", "json"]) == 0
    assert json.loads(capsys.readouterr().out) == []
    assert _digest(good) == before
    with Store(f"sqlite:///{good}", read_only=True) as ro:
        assert ro.conveyors() == [PROFILE.id]
        with pytest.raises(Exception, match="readonly"):
            ro.put_profile(PROFILE.model_copy(update={"id": "another-belt"}))
    assert _digest(good) == before
    # truncated, garbage pages, an empty file: one line, exit 2, file unchanged
    data = good.read_bytes()
    page = 4096
    damaged = {
        "truncated": data[: len(data) // 2],
        "garbage": data[: 2 * page] + bytes(range(256)) * (page // 256) + data[3 * page :],
        "not-sqlite": b"name,value\nthis,is a csv\n" * 50,
    }
    for name, content in damaged.items():
        path = tmp_path / f"{name}.db"
        path.write_bytes(content)
        for argv in (
            ["export", "--db", f"sqlite:///{path}"],
            ["ingest", "--db", f"sqlite:///{path}", "--profile", str(REFERENCE_PROFILE), str(path)],
        ):
            assert main(argv) == 2, (name, argv[0])
            err = capsys.readouterr().err.strip()
            assert len(err.splitlines()) == 1, err
            assert "damaged" in err or "not a usable SQLite database" in err, err
            assert path.read_bytes() == content, (name, argv[0])


def _session(sid: int) -> list[int]:
    """Processes still running in session ``sid`` (zombies left out)."""
    found = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue  # ended meanwhile
        if int(fields[3]) == sid and fields[0] != "Z":
            found.append(int(stat.parent.name))
    return found


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc")
def test_no_process_outlives_a_killed_ingest_and_sigterm_says_what_was_stored(
    tmp_path: Path,
) -> None:
    generate(PROFILE, tmp_path / "recs", days=5, per_day=12, seed=9)
    files = sorted(str(p) for p in (tmp_path / "recs").glob("*.csv"))
    calib = sorted(str(p) for p in (tmp_path / "recs" / "calibration").glob("*.csv"))
    for sig in (signal.SIGKILL, signal.SIGTERM):
        url = f"sqlite:///{tmp_path / f'{sig.name}.db'}"
        assert main(["calibrate", "--profile", str(REFERENCE_PROFILE), *calib, "--db", url]) == 0
        cmd = [sys.executable, "-m", "chaintwin", "ingest", *files, "--db", url]
        cmd += ["--profile", str(REFERENCE_PROFILE), "--workers", "2", "--commit-group", "2"]
        # its own session: only the ingest itself is signalled, as a crash or
        # an OOM kill would take it; its fork server and workers must follow
        proc = subprocess.Popen(
            cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True, text=True
        )
        store = Store(url)
        try:
            deadline = time.monotonic() + 120
            while store.counts()["results"] < 3 and time.monotonic() < deadline:
                assert proc.poll() is None, proc.communicate()
                time.sleep(0.02)
            assert len(_session(proc.pid)) >= 4, "ingest, fork server, tracker and workers run"
            os.kill(proc.pid, sig)
            _out, err = proc.communicate(timeout=60)
            deadline = time.monotonic() + 20
            while _session(proc.pid) and time.monotonic() < deadline:
                time.sleep(0.05)
            assert _session(proc.pid) == [], f"{sig.name}: processes left behind"
            stored = store.counts()["results"]
        finally:
            store.close()
            if proc.poll() is None:
                proc.kill()
        assert 0 < stored < len(files), "the signal came too late to test anything"
        if sig == signal.SIGTERM:
            assert proc.returncode == 128 + signal.SIGTERM
            assert "stopped by SIGTERM" in err
            assert f"{stored} recording(s) stored with their results" in err, err


class _Stop(Exception):
    pass


def _stop(_signum: int, _frame: object) -> None:
    raise _Stop


def _commit_during(how: str, done: list[str]) -> None:
    from chaintwin.ingest.executors import signals_deferred

    with signals_deferred():
        if how == "delivered":  # blocked until the block ends
            os.kill(os.getpid(), signal.SIGTERM)
        else:  # as the interpreter would run the handler of a signal already in
            handler = signal.getsignal(signal.SIGTERM)
            assert callable(handler) and handler is not _stop
            handler(signal.SIGTERM, None)
        done.append(how)  # the bookkeeping after the commit


def test_a_signal_handled_inside_a_commit_lands_after_it() -> None:
    """A SIGTERM that arrived just before the block has its handler run inside it: held too."""
    before = signal.signal(signal.SIGTERM, _stop)
    done: list[str] = []
    try:
        for how in ("delivered", "handled"):
            with pytest.raises(_Stop):
                _commit_during(how, done)
            assert signal.getsignal(signal.SIGTERM) is _stop
    finally:
        signal.signal(signal.SIGTERM, before)
    assert done == ["delivered", "handled"]


def test_a_damaged_stored_health_model_leaves_the_page_with_a_note(tmp_path: Path) -> None:
    from sqlalchemy.orm import Session

    from chaintwin.report.data import conveyor_data
    from chaintwin.store.schema import MonitorStateRow

    with Store(f"sqlite:///{tmp_path / 'damaged.db'}") as store:
        store.put_profile(PROFILE)
        with Session(store.engine) as s, s.begin():
            broken = {"conveyor": PROFILE.id, "profile_sha256": PROFILE.content_hash()}
            s.add(MonitorStateRow(conveyor_id=PROFILE.id, state=broken, updated_at="", version=1))
        with pytest.raises(StoreError, match="monitoring state of 'white-belt-01' is damaged"):
            store.state(PROFILE.id)
        page = conveyor_data(store, PROFILE.id, waterfall=0)
        assert any("health model not readable" in n for n in page.notes)


@pytest.mark.slow
def test_a_long_ingest_keeps_only_the_stored_history_in_memory(
    plant: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Memory stays flat over a long batch, and the results stay the same."""
    import chaintwin.diagnose.monitor as monitor_module
    import chaintwin.ingest.pipeline as ingest_module
    from chaintwin.diagnose.impacts import POOL
    from chaintwin.diagnose.monitor import ConveyorMonitor
    from chaintwin.store.store import HISTORY_IN_STATE

    # monitoring reads the latest POOL - 1 results (the knocks pooled over them): the
    # stored history holds at least that many, so a new ingest reads back what it needs
    assert HISTORY_IN_STATE >= POOL
    # here the pool is 5 recordings, so that a cap of 4 results shows the batch's results
    # do not depend on the results dropped from memory
    monkeypatch.setattr(monitor_module, "POOL", 5)
    files = _recordings(plant)
    settings = MonitorSettings(baseline_n=5)

    def run(name: str) -> tuple[list[dict[str, Any]], list[dict[str, Any]], int]:
        url = f"sqlite:///{tmp_path / name}"
        _calibrate(plant, url)
        lengths: list[int] = []
        process = ConveyorMonitor.process

        def spy(self: ConveyorMonitor, *args: Any, **kwargs: Any) -> Any:
            lengths.append(len(self.history))
            return process(self, *args, **kwargs)

        with monkeypatch.context() as m:
            m.setattr(ConveyorMonitor, "process", spy)
            store = Store(url)
            summary = ingest(
                files, {PROFILE.id: PROFILE}, store, settings=settings, workers=1, commit_group=3
            )
        assert summary.processed == len(files)
        alarms = [a.to_dict() | {"id": None} for a in store.alarms()]
        results = store.results()
        store.close()
        return results, alarms, max(lengths)

    whole, whole_alarms, longest = run("whole.db")
    assert longest == len(files) - 1  # without a cap the model keeps every result
    monkeypatch.setattr(ingest_module, "HISTORY_IN_STATE", 4)
    capped, capped_alarms, longest = run("capped.db")
    assert longest <= 4 + 3  # the kept history and at most one group not yet stored
    assert capped == whole
    assert capped_alarms == whole_alarms


def test_a_failing_read_names_what_was_read_and_the_store(tmp_path: Path) -> None:
    from sqlalchemy import text

    url = f"sqlite:///{tmp_path / 'plant.db'}"
    with Store(url) as store:
        with pytest.raises(StoreError) as caught, store.reading("the trends of 'belt-01'") as s:
            s.execute(text("SELECT * FROM no_such_table"))
        assert str(caught.value) == (
            f"{url}: cannot read the trends of 'belt-01' (no such table: no_such_table)"
        )
        with store.reading("the conveyors") as s:  # the store reads on afterwards
            assert s.execute(text("SELECT 1")).scalar() == 1
