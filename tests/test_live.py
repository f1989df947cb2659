"""The live service (``chaintwin serve --watch``), with real parts: the service as a
subprocess following a real folder, SIGTERM and ``kill -9``, a real HTTP receiver
for the notifications, the store's migration, two processes sharing one store.
"""

from __future__ import annotations

import asyncio
import hashlib
import hmac
import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

import httpx
import pytest
from conftest import EXAMPLES, REFERENCE_PROFILE, _free_port
from sqlalchemy import func, select, text
from sqlalchemy.orm import Session

from chaintwin.calibrating.procedure import calibrate
from chaintwin.cli.app import main
from chaintwin.cli.serve_cmd import system_malloc_command
from chaintwin.diagnose.records import MonitorSettings
from chaintwin.ingest.pipeline import ingest
from chaintwin.live.ledger import acquire_lease, release_lease
from chaintwin.live.metrics import Metrics
from chaintwin.live.notify import SIGNATURE_HEADER, Notifier
from chaintwin.live.watch import is_candidate
from chaintwin.read.profile import load_profile
from chaintwin.simulate.faults import Fault
from chaintwin.simulate.fleet import generate
from chaintwin.store import migrate
from chaintwin.store.engine import engine_for
from chaintwin.store.schema import DeliveryRow, LeaseRow, OutboxRow, RecordingRow, RefusedFileRow
from chaintwin.store.store import Store
from chaintwin.validate import load_recording
from chaintwin.web.access import create_token

PROFILE = load_profile(REFERENCE_PROFILE)
PROFILES = EXAMPLES / "profiles"
ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """20 recordings of one conveyor over 5 days, friction rising from day 2."""
    folder = tmp_path_factory.mktemp("fleet")
    generate(
        PROFILE, folder, days=5, per_day=4, faults=[Fault("friction", 0.8)], onset_day=2, seed=5
    )
    return folder


def recordings(fleet: Path) -> list[Path]:
    return sorted(fleet.glob("*.csv"))


def sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def calibrated(url: str, fleet: Path) -> None:
    """A store with the conveyor's calibration (its recordings get results at once)."""
    store = Store(url)
    recs = [
        load_recording(f, profile=PROFILE).recording
        for f in sorted((fleet / "calibration").glob("*.csv"))
    ]
    store.put_calibration(calibrate(recs, PROFILE))
    store.close()


class Service:
    """``chaintwin serve`` as a subprocess (a short order window unless one is given)."""

    def __init__(self, args: list[str], log: Path) -> None:
        if "--order-window-s" not in args:
            args = [*args, "--order-window-s", "0.5"]
        env = dict(os.environ, PYTHONPATH=str(ROOT), OPENBLAS_NUM_THREADS="1")
        env.pop("PYTHONMALLOC", None)  # the service's own default
        self.log = log
        with log.open("ab") as err:
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "chaintwin", "serve", *args],
                stdout=subprocess.DEVNULL,
                stderr=err,
                env=env,
                cwd=str(log.parent),
            )

    def stop(self, timeout: float = 30) -> int:
        self.proc.send_signal(signal.SIGTERM)
        return self.proc.wait(timeout)

    def kill(self) -> None:
        self.proc.kill()
        self.proc.wait(10)

    def lines(self) -> list[str]:
        return self.log.read_text().splitlines()


def wait_for(check: Callable[[], bool], seconds: float, what: str, service: Service | None = None):
    deadline = time.monotonic() + seconds
    while not check():
        if service is not None and service.proc.poll() is not None:
            pytest.fail(f"the service exited ({service.proc.returncode}): {service.lines()[-5:]}")
        assert time.monotonic() < deadline, f"{what} within {seconds} s"
        time.sleep(0.1)


def stored(url: str, shas: list[str]) -> Callable[[], bool]:
    """Whether the contents are stored (one engine for all the looks)."""
    engine = engine_for(url)

    def check() -> bool:
        with Session(engine) as s:
            found = set(s.scalars(select(RecordingRow.sha256).where(RecordingRow.sha256.in_(shas))))
        if len(found) == len(set(shas)):
            engine.dispose()
            return True
        return False

    return check


def count(url: str, table: Any) -> int:
    engine = engine_for(url)
    with Session(engine) as s:
        n = s.scalar(select(func.count()).select_from(table)) or 0
    engine.dispose()
    return int(n)


def write_slowly(src: Path, dst: Path, chunks: int = 5, pause_s: float = 0.25) -> None:
    """Copy a file in chunks with pauses (a slow network copy)."""
    raw = src.read_bytes()
    step = -(-len(raw) // chunks)
    with dst.open("wb") as f:
        for k in range(0, len(raw), step):
            f.write(raw[k : k + step])
            f.flush()
            time.sleep(pause_s)


def test_which_names_are_read() -> None:
    assert is_candidate("/a/b/white-belt-01-1.csv") and is_candidate("X.CSV")
    assert not is_candidate("/a/x.csv.part") and not is_candidate("/a/x.csv.tmp")
    assert not is_candidate("/a/truth.jsonl")


@pytest.mark.slow
def test_slowly_written_files_are_read_once_complete_with_metrics_health_and_sigterm(
    fleet: Path, tmp_path: Path
) -> None:
    url = f"sqlite:///{tmp_path / 'plant.db'}"
    calibrated(url, fleet)
    store = Store(url)
    viewer = create_token(store, "prometheus", "viewer")
    store.close()
    watched = tmp_path / "drop" / "line-1"
    watched.mkdir(parents=True)
    port = _free_port()
    service = Service(
        [
            "--db", url, "--watch", str(watched.parent), "--profiles", str(PROFILES),
            "--settle-s", "0.6", "--port", str(port), "--log-json", "--lease-s", "1.5",
        ],
        tmp_path / "serve.log",
    )  # fmt: skip
    base = f"http://127.0.0.1:{port}"

    def up() -> bool:
        try:
            return httpx.get(f"{base}/api/v1/health", timeout=2).status_code == 200
        except httpx.HTTPError:
            return False

    try:
        wait_for(up, 60, "the service answers", service)
        # serve ran itself again, the same process, with Python's objects in glibc's heap
        environ = Path(f"/proc/{service.proc.pid}/environ").read_bytes().split(b"\0")
        assert b"PYTHONMALLOC=malloc" in environ
        files = recordings(fleet)[:3]
        # chunks every 0.25 s, settle time 0.6 s: never read half-way
        writers = [threading.Thread(target=write_slowly, args=(f, watched / f.name)) for f in files]
        for w in writers:
            w.start()
        # a fourth copied under a temporary name and renamed when complete
        part = watched / (recordings(fleet)[3].name + ".part")
        write_slowly(recordings(fleet)[3], part, chunks=3, pause_s=0.7)  # slower than settling
        part.rename(watched / recordings(fleet)[3].name)
        for w in writers:
            w.join()
        # and a file that is not a recording
        (watched / "notes.csv").write_text("not a recording\n")
        shas = [sha(f) for f in recordings(fleet)[:4]]
        wait_for(stored(url, shas), 60, "the four recordings stored", service)
        wait_for(lambda: count(url, RefusedFileRow) == 1, 60, "the bad file refused", service)

        events = [json.loads(line) for line in service.lines() if line.startswith("{")]
        done = [e for e in events if e.get("status") == "stored"]
        # each read once, whole: stored with its result, none refused
        assert sorted(Path(e["file"]).name for e in done) == sorted(
            f.name for f in recordings(fleet)[:4]
        )
        assert all(e["seconds"] > 0 for e in done)
        refused = [e for e in events if e.get("level") == "warning" and "reason" in e]
        assert [Path(e["file"]).name for e in refused] == ["notes.csv"]
        assert "has no 'conveyor'" in refused[0]["reason"]
        engine = engine_for(url)
        with Session(engine) as s:
            assert s.scalar(select(func.count()).select_from(RecordingRow)) == 4
            row = s.scalars(select(RefusedFileRow)).one()
            assert row.path.endswith("notes.csv") and "conveyor" in row.reason
        engine.dispose()

        # metrics from this machine (no token needed), in the Prometheus text format
        metrics = httpx.get(f"{base}/metrics", timeout=5).text
        assert 'chaintwin_recordings_ingested_total{source="folder"} 4.0' in metrics
        assert 'chaintwin_recordings_refused_total{source="folder"} 1.0' in metrics
        assert "chaintwin_ingest_latency_seconds_count 4.0" in metrics
        assert "chaintwin_ingest_queue_depth 0.0" in metrics
        assert "chaintwin_opcua_connections_up 0.0" in metrics
        # from elsewhere (through the reverse proxy), a viewer token is needed
        remote = {"X-Forwarded-For": "203.0.113.5"}
        assert httpx.get(f"{base}/metrics", headers=remote, timeout=5).status_code == 401
        remote["Authorization"] = f"Bearer {viewer}"
        assert "chaintwin_open_alarms" in httpx.get(f"{base}/metrics", headers=remote).text
        schema = httpx.get(f"{base}/openapi.json", timeout=5).json()
        assert "/metrics" not in schema["paths"]

        # health: without a token only that it is up; with one, each source's state
        anon = httpx.get(f"{base}/api/v1/health", timeout=5).json()
        assert anon["status"] == "ok" and anon["live"] is None
        assert anon["store"]["revision"] == migrate.HEAD_REVISION

        def published() -> bool:
            got = httpx.get(
                f"{base}/api/v1/health",
                headers={"Authorization": f"Bearer {viewer}"},
                timeout=5,
            ).json()["live"]
            src = {s["key"]: s for s in got["sources"]}
            folder = src.get(f"folder:{watched.parent.resolve()}")
            return folder is not None and folder["ingested"] == 4 and folder["refused"] == 1

        wait_for(published, 60, "the folder's counts in the health", service)

        # a refused file is not read again unless it changes
        (watched / "notes.csv").touch()
        (watched / "notes2.csv").write_text("still not a recording\n")
        wait_for(lambda: count(url, RefusedFileRow) == 2, 60, "the new bad file refused", service)
        assert count(url, RefusedFileRow) == 2
    finally:
        code = service.stop()
    assert code == 0, service.lines()[-5:]
    assert any("stopping" in line for line in service.lines())


@pytest.mark.slow
def test_kill_9_while_files_arrive_then_restart_stores_every_file_once(
    fleet: Path, tmp_path: Path
) -> None:
    url = f"sqlite:///{tmp_path / 'plant.db'}"
    calibrated(url, fleet)
    watched = tmp_path / "drop"
    watched.mkdir()
    args = [
        "--db", url, "--watch", str(watched), "--profiles", str(PROFILES), "--no-web",
        "--settle-s", "0.3", "--lease-s", "1.5",
    ]  # fmt: skip
    files = recordings(fleet)[:12]
    service = Service(args, tmp_path / "serve.log")
    try:
        wait_for(lambda: any("following" in line for line in service.lines()), 60, "start", service)
        for k, f in enumerate(files):
            shutil.copyfile(f, watched / f.name)
            time.sleep(0.15)
            if k == 5:
                service.kill()  # at whatever it was doing
        assert service.proc.returncode == -signal.SIGKILL
        before = count(url, RecordingRow)
        assert before < len(files)  # the rest arrived while it was down
        service = Service(args, tmp_path / "serve.log")
        wait_for(stored(url, [sha(f) for f in files]), 60, "every file stored", service)
        time.sleep(1.0)  # a second look: nothing stored twice afterwards
        assert count(url, RecordingRow) == len(files)
        engine = engine_for(url)
        with engine.connect() as c:
            results = c.execute(text("SELECT COUNT(*) FROM results")).scalar()
            names = [r[0] for r in c.execute(text("SELECT file FROM recordings"))]
        engine.dispose()
        assert results == len(files)
        assert sorted(Path(n).name for n in names) == sorted(f.name for f in files)
        assert count(url, RefusedFileRow) == 0
        # SIGTERM while recordings are queued: the one in hand is committed, exit 0
        more = recordings(fleet)[12:16]
        for f in more:
            shutil.copyfile(f, watched / f.name)
        wait_for(lambda: count(url, RecordingRow) > len(files), 60, "one more stored", service)
        assert service.stop() == 0
        lines = service.lines()
        assert any("stopping: finishing the recording in hand" in line for line in lines)
        said = {line.split(" stored ")[1].split(" in ")[0] for line in lines if " stored " in line}
        engine = engine_for(url)
        with engine.connect() as c:
            kept = {r[0] for r in c.execute(text("SELECT file FROM recordings"))}
        engine.dispose()
        assert {str(watched / f.name) for f in more} & kept <= said  # nothing half-done
        assert kept >= said
    finally:
        if service.proc.poll() is None:
            assert service.stop() == 0


class Receiver:
    """A webhook receiver over real HTTP that fails its first requests."""

    def __init__(self, secret: bytes, fail_first: int) -> None:
        self.secret = secret
        self.fail_left = fail_first
        self.attempts = 0
        self.accepted: list[dict[str, Any]] = []
        self.bad_signatures = 0
        outer = self

        class Handler(BaseHTTPRequestHandler):
            def do_POST(self) -> None:
                body = self.rfile.read(int(self.headers["Content-Length"]))
                outer.attempts += 1
                expected = "sha256=" + hmac.new(outer.secret, body, hashlib.sha256).hexdigest()
                if not hmac.compare_digest(self.headers.get(SIGNATURE_HEADER, ""), expected):
                    outer.bad_signatures += 1
                    self.send_response(401)
                elif outer.fail_left > 0:
                    outer.fail_left -= 1
                    self.send_response(503)
                else:
                    outer.accepted.append(json.loads(body))
                    self.send_response(204)
                self.end_headers()

            def log_message(self, *args: Any) -> None:
                pass

        self.server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.url = f"http://127.0.0.1:{self.server.server_address[1]}/hook"
        self.thread = threading.Thread(target=self.server.serve_forever, daemon=True)
        self.thread.start()

    def close(self) -> None:
        self.server.shutdown()
        self.server.server_close()


@pytest.fixture
def receiver() -> Iterator[Receiver]:
    r = Receiver(b"s3cret-key", fail_first=2)
    yield r
    r.close()


def _notify_until(store: Store, receiver: Receiver, done: Callable[[], bool], seconds: float):
    """Run a notifier (a service process's) until ``done`` or ``seconds``."""

    async def run() -> None:
        notifier = Notifier(
            store,
            [receiver.url],
            receiver.secret,
            "https://twin.example/",
            Metrics(store, lambda: 0.0),
        )
        stop = asyncio.Event()
        task = asyncio.create_task(notifier.run(stop, tick_s=0.1))
        deadline = time.monotonic() + seconds
        while not done() and time.monotonic() < deadline:
            await asyncio.sleep(0.05)
        stop.set()
        await task

    asyncio.run(run())


def test_alarm_notifications_reach_a_failing_receiver_once_per_id_signed(
    fleet: Path, tmp_path: Path, receiver: Receiver
) -> None:
    url = f"sqlite:///{tmp_path / 'plant.db'}"
    calibrated(url, fleet)
    store = Store(url)
    ingest(
        [str(f) for f in recordings(fleet)],
        {PROFILE.id: PROFILE},
        store,
        settings=MonitorSettings(baseline_n=5),
        workers=1,
    )
    alarms = store.alarms()
    assert alarms, "the friction rise opens an alarm"
    with Session(store.engine) as s:
        outbox = {r.id: r for r in s.scalars(select(OutboxRow))}
    expected = {f"{a.id}-opened" for a in alarms} | {
        f"{a.id}-closed" for a in alarms if a.status == "closed"
    }
    assert set(outbox) == expected  # written with the alarms, one per alarm and event

    # the receiver fails the first two attempts; the process stops after the first,
    # a new one (a restart) goes on from the attempts kept in the store
    _notify_until(store, receiver, lambda: receiver.attempts >= 1, 10)
    assert receiver.attempts >= 1 and not receiver.accepted
    _notify_until(store, receiver, lambda: len(receiver.accepted) >= len(outbox), 30)
    _notify_until(store, receiver, lambda: False, 0.5)  # nothing is sent twice after

    assert receiver.bad_signatures == 0
    ids = [doc["id"] for doc in receiver.accepted]
    assert sorted(ids) == sorted(outbox) and len(set(ids)) == len(ids)
    first = next(a for a in alarms)
    doc = next(d for d in receiver.accepted if d["id"] == f"{first.id}-opened")
    assert doc == {
        "id": f"{first.id}-opened",
        "event": "opened",
        "alarm_id": first.id,
        "conveyor": PROFILE.id,
        "feature": first.feature,
        "cause": first.cause,
        "time": first.opened_at or first.since,
        "link": f"https://twin.example/conveyors/{PROFILE.id}",
        "health": "alarm",  # the verdict as the opening left it
        "ne107": "failure",
    }
    with Session(store.engine) as s:
        deliveries = list(s.scalars(select(DeliveryRow)))
    assert all(d.delivered_at is not None for d in deliveries)
    assert sum(d.attempts for d in deliveries) == len(outbox) + 2  # the two that failed
    store.close()


def test_serve_refuses_an_old_store_naming_db_upgrade_then_upgraded_it_runs(
    db: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from test_migrations import _legacy_store

    _legacy_store(db, tmp_path)
    code = main(["serve", "--db", db, "--no-web", "--watch", str(tmp_path)])
    err = capsys.readouterr().err
    assert code == 2
    assert "revision 0001" in err and f"run `chaintwin db upgrade --db {db}`" in err
    assert main(["db", "upgrade", "--db", db]) == 0
    capsys.readouterr()
    engine = engine_for(db)
    with engine.connect() as c:
        assert migrate.revision_of(c) == migrate.HEAD_REVISION == migrate.head_from_scripts()
        # the new tables, empty: an upgraded store does not notify its past alarms
        for table in ("refused_files", "outbox", "outbox_deliveries", "live_sources", "leases"):
            assert c.execute(text(f"SELECT COUNT(*) FROM {table}")).scalar() == 0
        assert c.execute(text("SELECT COUNT(*) FROM alarms")).scalar() == 1
    engine.dispose()
    store = Store(db)
    # leases work on the upgraded store
    assert acquire_lease(store, "folder:/x", "a", 30)
    assert not acquire_lease(store, "folder:/x", "b", 30)
    release_lease(store, "folder:/x", "a")
    assert acquire_lease(store, "folder:/x", "b", 30)
    store.close()


def test_a_lease_expires_when_its_holder_stops_renewing(tmp_path: Path) -> None:
    store = Store(f"sqlite:///{tmp_path / 'plant.db'}")
    lease_s = 2.0  # held between the calls below even should a loaded machine pause a while
    assert acquire_lease(store, "opcua:white-belt-01", "host-a:1", lease_s)
    assert acquire_lease(store, "opcua:white-belt-01", "host-a:1", lease_s)  # renewed
    assert not acquire_lease(store, "opcua:white-belt-01", "host-b:2", lease_s)
    # a's lease expires unrenewed: b takes it then
    wait_for(lambda: acquire_lease(store, "opcua:white-belt-01", "host-b:2", lease_s), 20, "expiry")
    assert not acquire_lease(store, "opcua:white-belt-01", "host-a:1", lease_s)
    with Session(store.engine) as s:
        assert s.get(LeaseRow, "opcua:white-belt-01").holder == "host-b:2"  # type: ignore[union-attr]
    store.close()


def _pg_database(base: str) -> str:
    import psycopg

    name = f"live{os.getpid()}_{int(time.time() * 1e6) % 10**9}"
    with psycopg.connect(base, autocommit=True) as c:
        c.execute(f"CREATE DATABASE {name}")
    return base.rsplit("/", 1)[0] + "/" + name


def test_two_processes_share_a_folder_on_postgresql_and_one_takes_over_when_the_other_dies(
    fleet: Path, tmp_path: Path, postgres: str
) -> None:
    url = _pg_database(postgres)
    calibrated(url, fleet)
    watched = tmp_path / "share"
    watched.mkdir()
    args = [
        "--db", url, "--watch", str(watched), "--profiles", str(PROFILES), "--no-web",
        "--settle-s", "0.3", "--lease-s", "1.5",
    ]  # fmt: skip
    services = [Service(args, tmp_path / f"serve-{k}.log") for k in range(2)]
    key = f"folder:{watched.resolve()}"

    engine = engine_for(url)

    def holder() -> str | None:
        with Session(engine) as s:
            row = s.get(LeaseRow, key)
            return None if row is None else row.holder

    try:
        wait_for(lambda: holder() is not None, 60, "a process takes the folder")
        pid = int(str(holder()).split(":")[1])
        first = next(s for s in services if s.proc.pid == pid)
        other = next(s for s in services if s is not first)
        files = recordings(fleet)[:8]
        for f in files[:4]:
            shutil.copyfile(f, watched / f.name)
        wait_for(stored(url, [sha(f) for f in files[:4]]), 60, "the first files stored", first)
        first.kill()  # the holder dies: its lease expires, the other takes over
        for f in files[4:]:
            shutil.copyfile(f, watched / f.name)
        wait_for(stored(url, [sha(f) for f in files]), 60, "the rest stored by the other", other)
        assert str(holder()).split(":")[1] == str(other.proc.pid)
        time.sleep(0.5)
        assert count(url, RecordingRow) == len(files)  # nothing twice, nothing skipped
        assert count(url, RefusedFileRow) == 0
        took = [line for line in other.lines() if f"following {key}" in line]
        assert len(took) == 1  # in standby until then
    finally:
        engine.dispose()
        for s in services:
            if s.proc.poll() is None:
                assert s.stop() == 0


def test_retention_drops_old_samples_and_keeps_results(fleet: Path, tmp_path: Path) -> None:
    from chaintwin.errors import StoreError
    from chaintwin.live.retention import drop_samples

    url = f"sqlite:///{tmp_path / 'plant.db'}"
    calibrated(url, fleet)
    store = Store(url)
    files = recordings(fleet)[:6]
    ingest([str(f) for f in files], {PROFILE.id: PROFILE}, store, workers=1)
    results = store.results(PROFILE.id)
    index = store.recording_index(PROFILE.id)
    assert len(index) == 6
    # the fleet was recorded in January 2026: a retention of ten thousand days keeps all
    assert drop_samples(store, 10_000) == 0
    assert drop_samples(store, 1) == 6
    assert drop_samples(store, 1) == 0  # done once
    assert store.results(PROFILE.id) == results  # the results are whole
    assert store.recording_index(PROFILE.id) == []  # nothing to plot from
    with pytest.raises(StoreError, match="dropped by retention"):
        store.recording(index[0][0])
    store.close()


def test_submit_stores_a_drives_recording_once_and_records_a_refusal(
    fleet: Path, tmp_path: Path
) -> None:
    """The contract of live sources (OPC UA): submit(recording, source_key)."""
    from dataclasses import replace

    from chaintwin.live.sources import Ingestor, Job, Outcome

    url = f"sqlite:///{tmp_path / 'plant.db'}"
    calibrated(url, fleet)
    store = Store(url)
    rec = load_recording(recordings(fleet)[0], profile=PROFILE).recording
    ghost = replace(rec, metadata=replace(rec.metadata, conveyor="ghost-belt"))
    seen: list[tuple[str, str]] = []

    def noted(job: Job, outcome: Outcome) -> None:
        seen.append((job.source, outcome.status))

    async def run() -> None:
        ingestor = Ingestor(store, {PROFILE.id: PROFILE}, on_outcome=noted)
        stop = asyncio.Event()
        worker = asyncio.create_task(ingestor.run(stop))
        await ingestor.submit(rec, "opcua:white-belt-01:1")
        await ingestor.submit(rec, "opcua:white-belt-01:1")  # read twice: stored once
        await ingestor.submit(ghost, "opcua:ghost-belt:7")  # never raises
        stop.set()
        await worker
        ingestor.close()

    asyncio.run(run())
    assert seen == [
        ("opcua:white-belt-01:1", "stored"),
        ("opcua:white-belt-01:1", "already_stored"),
        ("opcua:ghost-belt:7", "refused"),
    ]
    assert count(url, RecordingRow) == 1
    result = store.results(PROFILE.id)[0]
    assert result["status"] != "refused"
    # stored and shown under the drive's stable name, not the spool file's
    assert result["file"] == "opcua://white-belt-01/1"
    with Session(store.engine) as s:
        assert s.scalars(select(RecordingRow.file)).one() == "opcua://white-belt-01/1"
        row = s.scalars(select(RefusedFileRow)).one()
    assert row.path == "opcua://ghost-belt/7" and row.source == "opcua:ghost-belt:7"
    assert "ghost-belt" in row.reason and "/chaintwin-spool-" not in row.reason
    store.close()


def test_stored_name_of_a_drives_scope() -> None:
    from chaintwin.live.sources import stored_name

    assert stored_name("opcua:white-belt-01:1234") == "opcua://white-belt-01/1234"
    assert stored_name("folder:/data/in") == "folder:/data/in"
    assert stored_name("opcua:white-belt-01") == "opcua:white-belt-01"


def test_ingest_names_a_file_as_asked_in_the_store_results_and_refusals(
    fleet: Path, tmp_path: Path
) -> None:
    url = f"sqlite:///{tmp_path / 'plant.db'}"
    calibrated(url, fleet)
    store = Store(url)
    good, bad = recordings(fleet)[0], tmp_path / "bad.csv"
    bad.write_text("not a recording\n")
    summary = ingest(
        [str(good), str(bad)],
        {PROFILE.id: PROFILE},
        store,
        workers=1,
        names={str(good): "opcua://white-belt-01/5", str(bad): "opcua://white-belt-01/6"},
    )
    assert summary.processed == 1 and summary.refused == 1
    assert store.results(PROFILE.id)[0]["file"] == "opcua://white-belt-01/5"
    with Session(store.engine) as s:
        assert s.scalars(select(RecordingRow.file)).one() == "opcua://white-belt-01/5"
    (refusal,) = summary.refusals
    assert refusal["file"] == "opcua://white-belt-01/6"
    assert str(bad) not in refusal["error"] and "opcua://white-belt-01/6" in refusal["error"]
    store.close()


def test_drives_hook_counts_recordings_connections_and_missed_scopes(
    fleet: Path, tmp_path: Path
) -> None:
    """How ``--opcua`` plugs in: a follower handing scopes to submit, its status read by
    the metrics and the health (the follower here is the test's, the service is real)."""
    from dataclasses import dataclass, field
    from datetime import datetime

    from chaintwin.live.service import LiveOptions, LiveService

    @dataclass
    class DriveState:
        endpoint: str
        connected: bool = False
        scopes_read: int = 0
        missed: int = 0
        last_error: str | None = None
        last_scope_at: datetime | None = None

    @dataclass
    class DriveStatus:
        drives: dict[str, DriveState] = field(default_factory=dict)

    url = f"sqlite:///{tmp_path / 'plant.db'}"
    calibrated(url, fleet)
    store = Store(url)
    recs = [load_recording(f, profile=PROFILE).recording for f in recordings(fleet)[:2]]
    status = DriveStatus()
    service = LiveService(store, {PROFILE.id: PROFILE}, LiveOptions(lease_s=0.6))

    async def follow(submit: Any, stop: asyncio.Event) -> None:
        drive = status.drives.setdefault(PROFILE.id, DriveState("opc.tcp://127.0.0.1:4840"))
        drive.connected = True
        for k, rec in enumerate(recs):
            await submit(rec, f"opcua:{PROFILE.id}:{10 + 4 * k}")
            drive.scopes_read += 1
        drive.missed = 3  # the counter jumped from 10 to 14
        await stop.wait()
        drive.connected = False

    service.add_drives(f"opcua:{PROFILE.id}", follow, status)

    def health_row() -> dict[str, Any] | None:
        rows = {r["key"]: r for r in service.health()["sources"]}
        return rows.get(f"opcua:{PROFILE.id}")

    async def run() -> str:
        task = asyncio.create_task(service.run(None))
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:
            row = await asyncio.to_thread(health_row)
            if row is not None and row["ingested"] == 2 and row["missed"] == 3:
                break
            await asyncio.sleep(0.1)
        text = service.metrics.text().decode()
        service.request_stop()
        await task
        return text

    metrics = asyncio.run(run())
    assert count(url, RecordingRow) == 2
    assert "chaintwin_opcua_connections_up 1.0" in metrics
    assert f'chaintwin_opcua_missed_scopes_total{{conveyor="{PROFILE.id}"}} 3.0' in metrics
    assert 'chaintwin_recordings_ingested_total{source="opcua"} 2.0' in metrics
    row = health_row()
    assert row is not None
    assert (row["ingested"], row["missed"], row["state"]) == (2, 3, "stopped")
    assert service.health()["drives"][PROFILE.id]["scopes_read"] == 2
    with Session(store.engine) as s:
        assert s.get(LeaseRow, f"opcua:{PROFILE.id}") is None  # handed back on stop
    store.close()


@pytest.mark.parametrize(
    ("args", "says"),
    [
        (["--notify-url", "http://127.0.0.1:9/hook"], "--notify-url needs --notify-secret-file"),
        (["--notify-url", "ftp://x", "--notify-secret-file", "KEY"], "not an http"),
        (["--notify-url", "http://x/h", "--notify-secret-file", "EMPTY"], "the file is empty"),
        (["--watch", "NOWHERE"], "no such folder"),
        (["--settle-s", "-1"], "--settle-s -1.0 must be zero or more"),
        (["--order-window-s", "-1"], "--order-window-s -1.0 must be from 0 (no ordering)"),
        (["--order-window-s", "nan"], "--order-window-s nan must be from 0"),
        (["--opcua", "NOWHERE"], "cannot be read (No such file or directory)"),
    ],
)
def test_serve_refuses_bad_options_in_one_line(
    args: list[str], says: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / "KEY").write_text("k\n")
    (tmp_path / "EMPTY").write_text("\n")
    named = [str(tmp_path / a) if a in ("KEY", "EMPTY", "NOWHERE") else a for a in args]
    db = tmp_path / "plant.db"
    code = main(["serve", "--db", f"sqlite:///{db}", "--no-web", *named])
    err = capsys.readouterr().err
    assert code == 2
    assert says in err and len(err.strip().splitlines()) == 1
    assert not db.exists()  # refused before the store is touched


@pytest.mark.slow
def test_files_refused_for_want_of_a_profile_are_read_again_when_it_is_added(
    fleet: Path, tmp_path: Path
) -> None:
    """The profiles folder is followed: a profile added reads the files it was missing."""
    url = f"sqlite:///{tmp_path / 'plant.db'}"
    Store(url).close()  # no profile in the store either
    watched, profiles = tmp_path / "drop", tmp_path / "profiles"
    watched.mkdir()
    profiles.mkdir()
    shutil.copy(PROFILES / "short-fast-03.yaml", profiles)  # not white-belt-01's
    service = Service(
        [
            "--db", url, "--watch", str(watched), "--profiles", str(profiles),
            "--settle-s", "0.3", "--no-web", "--log-json",
        ],
        tmp_path / "serve.log",
    )  # fmt: skip
    try:
        files = recordings(fleet)[:2]
        for f in files:
            shutil.copy(f, watched / f.name)
        (watched / "notes.csv").write_text("not a recording\n")
        wait_for(lambda: count(url, RefusedFileRow) == 3, 60, "three files refused", service)
        engine = engine_for(url)
        with Session(engine) as s:
            rows = {Path(r.path).name: r for r in s.scalars(select(RefusedFileRow))}
        engine.dispose()
        assert {rows[f.name].cause for f in files} == {"profile"}
        assert {rows[f.name].conveyor for f in files} == {PROFILE.id}
        assert rows["notes.csv"].cause == "recording"
        # a profile that does not load: said in one line, nothing read again
        (profiles / "white-belt-01.yaml").write_text("id: white-belt-01\nbelt: [\n")
        wait_for(
            lambda: any("not valid YAML" in line for line in service.lines()),
            30,
            "the bad profile said",
            service,
        )
        assert count(url, RefusedFileRow) == 3
        # fixed: the two recordings are read again and stored; the bad file stays refused
        (profiles / "white-belt-01.yaml").write_text(REFERENCE_PROFILE.read_text())
        wait_for(stored(url, [sha(f) for f in files]), 60, "the two stored", service)
        wait_for(lambda: count(url, RefusedFileRow) == 1, 30, "their refusals gone", service)
        assert any("reading" in line and "again" in line for line in service.lines())
    finally:
        code = service.stop()
    assert code == 0, service.lines()[-5:]
    assert count(url, RecordingRow) == 2


def test_web_uploads_take_the_profiles_the_live_service_reads_again(
    fleet: Path, tmp_path: Path
) -> None:
    """An upload is weighed with the --profiles the service follows, not those it started with."""
    from chaintwin.live.service import LiveOptions, LiveService
    from chaintwin.web.app import create_app
    from chaintwin.web.routes.recordings import Staged, ingest_uploads

    url = f"sqlite:///{tmp_path / 'plant.db'}"
    store = Store(url)  # no profile in the store
    try:
        service = LiveService(store, {}, LiveOptions())
        web = create_app(store, {}, live=service).state.web
        f = recordings(fleet)[0]
        upload = [Staged(f.name, str(f), sha(f))]  # as the upload's handler copies it aside
        (first,) = ingest_uploads(web, upload, "tester")
        assert first.status == "refused" and "profile" in (first.reason or "")
        service.use_profiles({PROFILE.id: PROFILE})  # as the folder's follower does
        assert service.profiles == {PROFILE.id: PROFILE} == service.profiles_now
        (again,) = ingest_uploads(web, upload, "tester")
        assert again.status == "stored" and again.recording_id == sha(f)
    finally:
        store.close()


@pytest.mark.slow
def test_a_profile_added_while_the_service_was_down_reads_the_refused_files_at_start(
    fleet: Path, tmp_path: Path
) -> None:
    from chaintwin.live.sources import Ingestor, Job

    url = f"sqlite:///{tmp_path / 'plant.db'}"
    Store(url).close()  # no profile in the store either
    store = Store(url)
    f = recordings(fleet)[0]
    refused = Ingestor(store, {}).ingest_one(Job(str(f), "folder:x"))
    assert refused.status == "refused" and refused.cause == "profile"
    store.close()
    service = Service(
        ["--db", url, "--profiles", str(PROFILES), "--no-web"], tmp_path / "serve.log"
    )
    try:
        wait_for(stored(url, [sha(f)]), 60, "the refused file stored at start", service)
    finally:
        assert service.stop() == 0
    assert count(url, RefusedFileRow) == 0


def test_refused_list_and_retry_commands(
    fleet: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from chaintwin.live.ledger import record_refusal
    from chaintwin.live.sources import Ingestor, Job

    url = f"sqlite:///{tmp_path / 'plant.db'}"
    Store(url).close()  # no profile in the store either
    store = Store(url)
    good = [str(f) for f in recordings(fleet)[:2]]
    bad = tmp_path / "notes.csv"
    bad.write_text("not a recording\n")
    ingestor = Ingestor(store, {})
    for f in [*good, str(bad)]:
        assert ingestor.ingest_one(Job(f, "folder:x")).status == "refused"
    ingestor.close()
    record_refusal(store, "f" * 64, "opcua://ghost-belt/7", "opcua:ghost-belt:7", "no profile")
    store.close()

    assert main(["refused", "list", "--db", url, "--json"]) == 0
    listed = json.loads(capsys.readouterr().out)
    assert [(r["path"], r["cause"], r["conveyor"]) for r in listed] == [
        (good[0], "profile", PROFILE.id),
        (good[1], "profile", PROFILE.id),
        (str(bad), "recording", None),
        ("opcua://ghost-belt/7", "recording", None),
    ]
    assert "has no 'conveyor'" in listed[2]["reason"]
    assert main(["refused", "list", "--db", url]) == 0
    assert "chaintwin refused files (4)" in capsys.readouterr().out

    # not among them: one line, exit 2
    assert main(["refused", "retry", "--db", url, str(tmp_path / "other.csv")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "other.csv" in err and "refused list" in err

    # one file, with its profile now: stored, its refusal gone
    args = ["refused", "retry", "--db", url, "--profiles", str(PROFILES), "--json", good[0]]
    assert main(args) == 0
    # (stored waiting for the conveyor's calibration: this store has none yet)
    assert json.loads(capsys.readouterr().out) == [
        {"path": good[0], "status": "waiting", "reason": None}
    ]
    # all the others: one stored, the bad file refused again, the scope not kept
    assert main(["refused", "retry", "--db", url, "--profiles", str(PROFILES), "--json"]) == 0
    done = {d["path"]: d for d in json.loads(capsys.readouterr().out)}
    assert done[good[1]]["status"] == "waiting"
    assert done[str(bad)]["status"] == "refused" and "conveyor" in done[str(bad)]["reason"]
    assert done["opcua://ghost-belt/7"]["status"] == "not_kept"
    assert main(["refused", "list", "--db", url, "--json"]) == 0
    left = [r["path"] for r in json.loads(capsys.readouterr().out)]
    assert sorted(left) == sorted([str(bad), "opcua://ghost-belt/7"])
    assert count(url, RecordingRow) == 2


class MailReceiver:
    """A real SMTP server (aiosmtpd) that answers 451 to the first ``fail_first`` messages
    and asks for a login."""

    def __init__(self, fail_first: int, user: str = "twin", password: str = "pa ss") -> None:
        from aiosmtpd.controller import Controller
        from aiosmtpd.smtp import AuthResult, LoginPassword

        self.fail_left = fail_first
        self.attempts = 0
        self.accepted: list[tuple[list[str], bytes]] = []
        self.logins: list[str] = []
        outer = self

        class Handler:
            async def handle_DATA(self, server: Any, session: Any, envelope: Any) -> str:
                outer.attempts += 1
                if outer.fail_left > 0:
                    outer.fail_left -= 1
                    return "451 4.3.0 try again later"
                outer.accepted.append((list(envelope.rcpt_tos), bytes(envelope.content)))
                return "250 OK"

        def authenticator(
            server: Any, session: Any, envelope: Any, mechanism: str, data: Any
        ) -> Any:
            ok = isinstance(data, LoginPassword) and (data.login, data.password) == (
                user.encode(),
                password.encode(),
            )
            if ok:
                outer.logins.append(user)
            return AuthResult(success=ok)

        self.controller = Controller(
            Handler(),
            hostname="127.0.0.1",
            port=_free_port(),
            authenticator=authenticator,
            auth_require_tls=False,
        )
        self.controller.start()
        self.address = f"127.0.0.1:{self.controller.port}"

    def messages(self) -> list[Any]:
        from email import message_from_bytes, policy

        return [message_from_bytes(raw, policy=policy.default) for _to, raw in self.accepted]

    def close(self) -> None:
        self.controller.stop()


def test_alarm_notifications_by_mail_through_a_failing_smtp_server_once_per_id(
    fleet: Path, tmp_path: Path
) -> None:
    from chaintwin.live.notify import ID_HEADER, MailSettings

    url = f"sqlite:///{tmp_path / 'plant.db'}"
    calibrated(url, fleet)
    store = Store(url)
    ingest(
        [str(f) for f in recordings(fleet)],
        {PROFILE.id: PROFILE},
        store,
        settings=MonitorSettings(baseline_n=5),
        workers=1,
    )
    with Session(store.engine) as s:
        outbox = {r.id: r for r in s.scalars(select(OutboxRow))}
    assert outbox, "the friction rise opens an alarm"
    smtp = MailReceiver(fail_first=1)
    host, port = smtp.address.split(":")
    to = ("ops@plant.example", "shift@plant.example")
    mail = MailSettings(host, int(port), to, "twin@plant.example", False, "twin", "pa ss")
    secret = b"s3cret-key"

    def run(done: Callable[[], bool], seconds: float) -> None:
        async def go() -> None:
            notifier = Notifier(
                store, [], secret, "https://twin.example/", Metrics(store, lambda: 0.0), mail
            )
            stop = asyncio.Event()
            task = asyncio.create_task(notifier.run(stop, tick_s=0.1))
            deadline = time.monotonic() + seconds
            while not done() and time.monotonic() < deadline:
                await asyncio.sleep(0.05)
            stop.set()
            await task

        asyncio.run(go())

    try:
        # the first attempt is refused (451); a restart goes on from the store's attempts
        run(lambda: smtp.attempts >= 1, 10)
        assert smtp.attempts >= 1 and len(smtp.accepted) < len(outbox) * len(to)
        # one recipient's failure holds back none of the other's
        assert all(rcpt != ["ops@plant.example"] for rcpt, _raw in smtp.accepted)
        run(lambda: len(smtp.accepted) >= len(outbox) * len(to), 30)
        run(lambda: False, 0.5)  # nothing sent twice after
    finally:
        smtp.close()
    assert smtp.logins  # logged in with the user and password given
    messages = smtp.messages()
    assert len(messages) == len(outbox) * len(to)
    for addr in to:  # each recipient once per notification, in order
        ids = [
            m[ID_HEADER]
            for (rcpt, _raw), m in zip(smtp.accepted, messages, strict=True)
            if rcpt == [addr]
        ]
        assert sorted(ids) == sorted(outbox) and len(set(ids)) == len(ids)
    first = messages[0]
    nid = first[ID_HEADER]
    assert f"[{nid}]" in first["Subject"] and first["Message-ID"] == f"<{nid}@chaintwin>"
    assert first["From"] == "twin@plant.example"
    (attached,) = [
        p for p in first.iter_attachments() if p.get_content_type() == "application/json"
    ]
    body = attached.get_content()
    body = body if isinstance(body, bytes) else body.encode()
    doc = json.loads(body)
    assert doc["id"] == nid and doc["link"] == f"https://twin.example/conveyors/{PROFILE.id}"
    expected = "sha256=" + hmac.new(secret, body, hashlib.sha256).hexdigest()
    assert str(first[SIGNATURE_HEADER]).strip() == expected  # a long header is folded
    text_part = first.get_body(preferencelist=("plain",))
    assert text_part is not None and doc["link"] in text_part.get_content()
    with Session(store.engine) as s:
        deliveries = list(s.scalars(select(DeliveryRow)))
    assert len(deliveries) == len(outbox) * len(to)
    assert all(d.delivered_at is not None for d in deliveries)
    assert sum(d.attempts for d in deliveries) == len(outbox) * len(to) + 1  # the one refused
    store.close()


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["--notify-smtp", "mail.example:99999", "--notify-mail-to", "a@b.c"], "--notify-smtp"),
        (["--notify-smtp", "mail.example"], "--notify-mail-to"),
        (["--notify-mail-to", "a@b.c"], "needs --notify-smtp"),
        (["--notify-smtp", "mail.example", "--notify-mail-to", "not an address"], "not an e-mail"),
        (
            ["--notify-smtp", "m.example", "--notify-mail-to", "a@b.c", "--notify-smtp-login-file",
             "/nonexistent/login"],
            "--notify-smtp-login-file",
        ),
    ],
)  # fmt: skip
def test_serve_refuses_bad_mail_options_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], args: list[str], needle: str
) -> None:
    url = f"sqlite:///{tmp_path / 'plant.db'}"
    assert main(["serve", "--db", url, "--no-web", *args]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and needle in err, err


@pytest.mark.slow
def test_serve_mails_the_outbox_with_its_options(fleet: Path, tmp_path: Path) -> None:
    """``serve --notify-smtp ... --notify-mail-to ...`` end to end, with a login file."""
    url = f"sqlite:///{tmp_path / 'plant.db'}"
    calibrated(url, fleet)
    store = Store(url)
    ingest(
        [str(f) for f in recordings(fleet)],
        {PROFILE.id: PROFILE},
        store,
        settings=MonitorSettings(baseline_n=5),
        workers=1,
    )
    with Session(store.engine) as s:
        n = len(list(s.scalars(select(OutboxRow.id))))
    store.close()
    smtp = MailReceiver(fail_first=1)
    login = tmp_path / "smtp-login"
    login.write_text("twin\npa ss\n")
    service = Service(
        [
            "--db", url, "--no-web", "--notify-smtp", smtp.address,
            "--notify-mail-to", "ops@plant.example", "--notify-mail-from", "twin@plant.example",
            "--notify-smtp-login-file", str(login), "--public-url", "https://twin.example",
        ],
        tmp_path / "serve.log",
    )  # fmt: skip
    try:
        wait_for(lambda: len(smtp.accepted) >= n, 60, "the notifications mailed", service)
    finally:
        code = service.stop()
        smtp.close()
    assert code == 0
    assert smtp.logins and len(smtp.accepted) == n and smtp.attempts == n + 1
    assert all(m["From"] == "twin@plant.example" for m in smtp.messages())


def test_a_folder_remembers_recent_files_only_and_asks_the_store_about_older_ones(
    fleet: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from chaintwin.live import watch
    from chaintwin.live.ledger import known_paths, record_refusal

    monkeypatch.setattr(watch, "MAX_REMEMBERED", 3)
    folder = tmp_path / "in"
    folder.mkdir()
    names = [f"r{i}.csv" for i in range(5)]
    for n in names:
        (folder / n).write_text("x")
    asked: list[list[str]] = []

    def known(paths: list[str]) -> set[str]:
        asked.append(sorted(paths))
        return {p for p in paths if Path(p).name in names}  # the five are stored

    async def enqueue(path: str, ready_at: float) -> None:
        pass

    source = watch.FolderSource(folder, 0.0, False, enqueue, known)
    source._add(source._scan())
    ready, _ = source._settled()
    assert len(ready) == 5 and len(source.handed) == 3  # the latest three remembered
    remembered = set(source.handed)
    forgotten = sorted(set(ready) - remembered)
    again = source._rescan()
    # the two forgotten ones are asked about: stored, so not handed again; the
    # remembered ones are looked at again (a change missed by the events)
    assert asked == [forgotten]
    assert set(again) == remembered
    source._add(again)
    assert source._settled()[0] == []  # unchanged: not handed again
    # a file the store does not know is handed
    (folder / "r5.csv").write_text("y")
    source.handed.clear()
    assert [Path(p).name for p in source._rescan()] == ["r5.csv"]

    # the store's answer, by path: stored recordings and refused files
    url = f"sqlite:///{tmp_path / 'plant.db'}"
    calibrated(url, fleet)
    store = Store(url)
    f = str(recordings(fleet)[0])
    ingest([f], {PROFILE.id: PROFILE}, store, workers=1)
    record_refusal(store, "e" * 64, "/in/bad.csv", "folder:/in", "bad")
    assert known_paths(store, [f, "/in/bad.csv", "/in/new.csv"], chunk=2) == {f, "/in/bad.csv"}
    store.close()


def test_serve_from_the_command_line_runs_again_with_python_s_objects_in_glibc_s_heap() -> None:
    """Only ``serve``, only from the command line, and a PYTHONMALLOC the user set is kept."""
    argv = ["/venv/bin/python", "-X", "dev", "-m", "chaintwin", "serve", "--db", "x"]
    again = system_malloc_command(["serve", "--db", "x"], {"PATH": "/bin"}, argv)
    assert again == (argv, {"PATH": "/bin", "PYTHONMALLOC": "malloc"})
    assert system_malloc_command(["serve"], {"PYTHONMALLOC": "pymalloc"}, argv) is None
    assert system_malloc_command(["ingest", "serve"], {}, argv) is None
    assert system_malloc_command(["--help"], {}, argv) is None
    assert system_malloc_command([], {}, argv) is None


def test_memory_usage_and_trim_on_glibc() -> None:
    import ctypes

    from chaintwin.live.memory import trim, usage

    before = usage()
    assert before["rss"] > 1.0
    if not hasattr(ctypes.CDLL(None), "mallinfo2"):
        pytest.skip("not glibc 2.33 or later")
    blocks = [bytearray(64 * 1024) for _ in range(400)]  # 25 MB in the heap, then freed
    assert usage()["heap_used"] > before["heap_used"] + 20
    del blocks
    assert trim() is True
    assert usage()["heap_used"] < before["heap_used"] + 5


def test_serve_bounds_its_sqlite_connections_and_their_page_caches(tmp_path: Path) -> None:
    """The live service's memory grew for hours as its pool opened SQLite
    connections one by one (16 kept), each with SQLite's default 2 MB page cache.
    ``serve`` keeps few on SQLite, each with a small cache set on every new connection;
    a burst opens more, closed when given back."""
    from sqlalchemy import text

    from chaintwin.cli.serve_cmd import (
        SERVE_POOL_SIZE,
        SERVE_SQLITE_CACHE_KIB,
        SERVE_SQLITE_POOL_SIZE,
        serve_store,
    )
    from chaintwin.live.memory import usage

    url = f"sqlite:///{tmp_path / 'serve.db'}"
    default, store = Store(url), serve_store(url)
    try:
        with default.engine.connect() as c:  # SQLite's own default: 2 000 KiB
            assert c.execute(text("PRAGMA cache_size")).scalar() == -2000
        pool = store.engine.pool
        assert pool.size() == SERVE_SQLITE_POOL_SIZE < SERVE_POOL_SIZE  # type: ignore[attr-defined]
        held = [store.engine.connect() for _ in range(2 * SERVE_POOL_SIZE)]  # a burst
        assert usage(pool)["db_conns"] == 2 * SERVE_POOL_SIZE
        for c in held:  # each new connection has the small cache
            assert c.execute(text("PRAGMA cache_size")).scalar() == -SERVE_SQLITE_CACHE_KIB
            c.close()
        # the burst's extra connections are closed: their caches' memory goes with them
        assert usage(pool)["db_conns"] == SERVE_SQLITE_POOL_SIZE
        assert "db_conns" not in usage()
    finally:
        default.close()
        store.close()


def test_the_page_cache_pragma_applies_to_a_read_only_store_too(tmp_path: Path) -> None:
    from sqlalchemy import text

    url = f"sqlite:///{tmp_path / 'ro.db'}"
    Store(url).close()
    with Store(url, read_only=True, sqlite_cache_kib=256) as store, store.engine.connect() as c:
        assert c.execute(text("PRAGMA cache_size")).scalar() == -256


def test_a_drive_with_a_lease_of_its_own_has_its_row_written_by_its_own_source_only(
    fleet: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``--opcua`` follows each drive under its own lease: each source writes its own
    drive's row, not every drive's (20 drives wrote 420 rows every few seconds, each a
    write transaction beside the recordings'). A source following several drives under
    one lease still writes a row for each of them."""
    from chaintwin.live import service as service_module
    from chaintwin.live.opcua import DriveState, DriveStatus
    from chaintwin.live.service import LiveOptions, LiveService

    written: list[str] = []
    monkeypatch.setattr(
        service_module, "update_source", lambda _store, key, *a, **k: written.append(key)
    )
    store = Store(f"sqlite:///{tmp_path / 'plant.db'}")

    async def idle(submit: Any, stop: asyncio.Event) -> None:
        await stop.wait()

    def publish(service: LiveService, key: str) -> list[str]:
        written.clear()
        source = next(s for s in service.sources if s.key == key)
        asyncio.run(service._publish(source))
        return sorted(written)

    drives = {c: DriveState(f"opc.tcp://127.0.0.1:{4840 + i}") for i, c in enumerate("abc")}
    status = DriveStatus(drives=dict(drives))
    each = LiveService(store, {}, LiveOptions())
    for conveyor in drives:
        each.add_drives(f"opcua:{conveyor}", idle, status)
    assert publish(each, "opcua:b") == ["opcua:b"]

    status_line = DriveStatus(drives=dict(drives))
    line = LiveService(store, {}, LiveOptions())
    line.add_drives("opcua:line-1", idle, status_line)
    assert publish(line, "opcua:line-1") == ["opcua:a", "opcua:b", "opcua:c", "opcua:line-1"]
    store.close()
