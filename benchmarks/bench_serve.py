"""Benchmark: the dashboard and API on a large store (a script, not a test).

Scenario: a store of ``--conveyors`` conveyors (200) with
``--results`` result rows each (10 000; synthetic rows without samples),
on SQLite (a file) and, with ``--postgres URL`` (an empty database) or
``--postgres auto`` (a private server started here from the distribution's
PostgreSQL binaries), on PostgreSQL. Beside them a fault fleet
(``--fault-conveyors`` virtual conveyors of ``--fault-days`` x
``--fault-per-day`` recordings each, their rail friction rising until its
alarm opens) is filled through real ingest (simulated recordings, the
calibration learned from their calibration runs), so that the pages of
conveyors in alarm, with rising trends and forecasts, are measured too.
At full size (``--fault-results 10000 --fault-conveyors 200``) the fault
fleet is made by ``benchmarks/fault_history.py`` (its docstring says
exactly how): ``--fault-kinds`` conveyors simulated and really ingested
into ``--fault-template`` (a SQLite file, built once and reused), each
copied under its own ids to make ``--fault-conveyors`` conveyors, and each
one's history grown to ``--fault-results`` results by replicating its
really ingested baseline backwards in time, written with the store's own
tables, statements and serializer, its stored forecasts as the real
ingest's refit left them (refitted where they are not current). Give
``--conveyors 0`` to measure the fault fleet alone.
``chaintwin serve`` runs in its own process; this script is the clients.
It prints, per store, the median time of

1. reference: ``GET /api/v1/health``;
2. ``GET /api/v1/conveyors`` (the fleet's data), and the same revalidated
   with its ETag (``If-None-Match``: 304);
3. ``GET /`` (the fleet page);
4. ``GET /api/v1/conveyors/{id}/recordings?limit=100`` (one conveyor's page of 100);
5. ``GET /conveyors/{id}`` (a conveyor's HTML page: a bounded read of its results)
   and ``GET .../trends?feature=friction`` (a trend, at most 1000 results read);
6. for a conveyor of the fault fleet in alarm: its HTML page,
   ``GET /api/v1/conveyors/{id}`` and ``GET .../trends`` (all its trends in
   one request) (targets: within 5x each);

each with its ratio to the reference (targets: 2 to 5 within 5x), and
then 50 clients each polling every 5 s for ``--seconds``: the fleet as a
browser does (sending back the ETag), the fleet without the ETag, and the
page of 100 recordings; the p99 of those requests and its ratio to the
reference median (target within 20x).

With ``--baseline-code DIR`` (another checkout, e.g. the commit before a
change) each store is then served twice at once, by this code and by
``DIR``'s, and every request is sent to both, alternating which goes first
(``--repeat`` x 2 pairs), so that both meet the same load on a shared
machine; each row's medians and their ratio (this / baseline) are printed:
a change's cost.

With ``--compare-ingest`` it also ingests the fault fleet's recordings into
fresh SQLite stores without and with the forecasts' refit after ingest
(``ingest(refit=False)``: the ingest as it was before forecasts were kept;
``refit=True``: as now), alternately ``--compare-rounds`` times, and prints
the seconds per recording of each and their ratio (target at most 1.10).

Run: ``.venv/bin/python benchmarks/bench_serve.py --postgres auto``; the
fault fleet at full size alone: ``--conveyors 0 --seconds 0 --fault-conveyors 200
--fault-results 10000 --fault-kinds 10 --fault-template /tmp/fault-template.db
--sqlite-file /tmp/bench-fault.db`` (SQLite; the store is built once, about
30 minutes on a loaded 2-core machine, and reused), then ``--no-sqlite
--postgres auto`` with the same fault options (PostgreSQL, built each time;
``--postgres URL`` builds into that database once and reuses it afterwards)
(about 3 minutes per store on a 2-core machine, plus the fault fleet's
simulation and ingest).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import math
import os
import sqlite3
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import httpx
import orjson
from sqlalchemy import insert

from chaintwin.calibrating.procedure import calibrate
from chaintwin.diagnose.records import MonitorSettings
from chaintwin.ingest.pipeline import ingest
from chaintwin.read.profile import ConveyorProfile, load_profile
from chaintwin.simulate.faults import Fault
from chaintwin.simulate.fleet import generate
from chaintwin.store.schema import ConveyorRow
from chaintwin.store.store import Store
from chaintwin.testing.postgres import free_port, postgres_binaries, throwaway_postgres
from chaintwin.validate import load_recording
from chaintwin.web.access import create_token

sys.path.insert(0, str(Path(__file__).resolve().parent))
import fault_history  # beside this script

PROFILE = Path(__file__).resolve().parents[1] / "chaintwin/examples/profiles/white-belt-01.yaml"


def build(url: str, conveyors: int, results: int) -> str:
    """Fill an empty store with synthetic rows; an admin token."""
    store = Store(url)
    base = load_profile(PROFILE)
    rows_per_batch = 10_000
    try:
        with store.engine.begin() as c:
            for k in range(conveyors):
                prof = base.model_copy(update={"id": f"conveyor-{k:03d}"})
                c.execute(
                    insert(ConveyorRow),
                    [
                        {
                            "id": prof.id,
                            "profile": prof.model_dump(mode="json"),
                            "profile_sha256": prof.content_hash(),
                        }
                    ],
                )
        # rows straight to the driver, JSON encoded once by orjson: SQLAlchemy's
        # per-row parameter processing would take most of the build's time
        mark = "?" if store.engine.dialect.paramstyle == "qmark" else "%s"

        def sql(table: str, columns: str) -> str:
            n = len(columns.split(","))
            return f"INSERT INTO {table} ({columns}) VALUES ({', '.join([mark] * n)})"

        rec_sql = sql(
            "recordings", "id, sha256, conveyor_id, file, recorded_at, meta, warnings, samples"
        )
        res_sql = sql(
            "results",
            "id, recording_id, conveyor_id, recorded_at, status, alarm, payload_kg, tlf, "
            "content, stored_at",
        )
        start_at = datetime(2026, 1, 1, tzinfo=UTC)
        ats = [f"{start_at + timedelta(minutes=10 * j):%FT%T}Z" for j in range(results)]
        rid = 0
        for k in range(conveyors):
            cid = f"conveyor-{k:03d}"
            for first in range(0, results, rows_per_batch):
                recs, res = [], []
                for j in range(first, min(results, first + rows_per_batch)):
                    rid += 1
                    at = ats[j]  # one recording every 10 minutes from 2026-01-01
                    name = f"{cid}-{j}.csv"
                    payload = 20.0 + j % 17
                    content = {
                        "file": name,
                        "recorded_at": at,
                        "status": "monitored",
                        "alarm": False,
                        "payload_kg": payload,
                        "tlf": 0.5,
                        "causes": [],
                        "warnings": [],
                        "features": {"friction": 1.0},
                    }
                    recs.append((rid, f"{rid:064x}", cid, name, at, "{}", "[]", b""))
                    res.append(
                        (rid, rid, cid, at, "monitored", False, payload, 0.5,
                         orjson.dumps(content).decode(), at)
                    )  # fmt: skip
                with store.engine.begin() as c:
                    c.exec_driver_sql(rec_sql, recs)
                    c.exec_driver_sql(res_sql, res)
        if rid and store.engine.dialect.name == "postgresql":  # ids given: move the sequences
            with store.engine.begin() as c:
                for table in ("recordings", "results"):
                    c.exec_driver_sql(
                        f"SELECT setval(pg_get_serial_sequence('{table}', 'id'), {rid})"
                    )
                c.exec_driver_sql("ANALYZE")
        return create_token(store, "bench", "admin")
    finally:
        store.close()


FAULT_SETTINGS = MonitorSettings(baseline_n=10)
"""The fault fleet's monitoring: a baseline of 10 recordings, then alarms."""


@dataclass
class FaultFleet:
    """Virtual conveyors whose friction rises: their profiles and recordings."""

    profiles: dict[str, ConveyorProfile]
    files: list[str]
    calibration_files: dict[str, list[Path]]


def fault_fleet(folder: Path, conveyors: int, days: int, per_day: int) -> FaultFleet:
    """Simulate the fault fleet's recordings (friction rising from day 2 to 0.8 more)."""
    base = load_profile(PROFILE)
    profiles, files, cal = {}, [], {}
    for k in range(conveyors):
        prof = base.model_copy(update={"id": f"faulty-{k:03d}"})
        out = folder / prof.id
        generate(
            prof,
            out,
            days=days,
            per_day=per_day,
            faults=[Fault("friction", 0.8)],
            onset_day=2,
            seed=100 + k,
        )
        profiles[prof.id] = prof
        files += sorted(str(f) for f in out.glob("*.csv"))
        cal[prof.id] = sorted((out / "calibration").glob("*.csv"))
    return FaultFleet(profiles, files, cal)


def ingest_fault_fleet(url: str, fleet: FaultFleet, *, refit: bool = True) -> tuple[float, int]:
    """Ingest the fault fleet into a store (calibrations first); seconds, recordings stored."""
    with Store(url) as store:
        for cid, cal_files in fleet.calibration_files.items():
            prof = fleet.profiles[cid]
            recs = [load_recording(f, profile=prof).recording for f in cal_files]
            store.put_profile(prof)
            store.put_calibration(calibrate(recs, prof))
        t0 = time.perf_counter()
        summary = ingest(
            fleet.files, fleet.profiles, store, settings=FAULT_SETTINGS, workers=1, refit=refit
        )
        seconds = time.perf_counter() - t0
        assert summary.refused == 0, summary.refusals[:3]
        return seconds, summary.processed


def compare_ingest(fleet: FaultFleet, rounds: int) -> dict[str, Any]:
    """Seconds per recording of the fault fleet's ingest without and with the refit."""
    per: dict[str, list[float]] = {"without refit": [], "with refit": []}
    with tempfile.TemporaryDirectory() as folder:
        for r in range(rounds):
            order = [False, True] if r % 2 == 0 else [True, False]
            for refit in order:
                url = f"sqlite:///{folder}/cmp-{r}-{int(refit)}.db"
                seconds, n = ingest_fault_fleet(url, fleet, refit=refit)
                per["with refit" if refit else "without refit"].append(seconds / n)
    old = statistics.median(per["without refit"])
    new = statistics.median(per["with refit"])
    return {"per_recording_s": per, "old_s": old, "new_s": new, "ratio": new / old}


@contextlib.contextmanager
def private_postgres() -> Iterator[str]:
    """A PostgreSQL server of our own on a free port (as the tests start one); its URL."""
    bindir = postgres_binaries()
    if bindir is None:
        raise SystemExit("bench_serve: no PostgreSQL binaries (apt-get install postgresql)")
    with throwaway_postgres(bindir, prefix="chaintwin-bench-pg-") as url:
        yield url


def median_ms(
    client: httpx.Client, path: str, n: int, headers: dict[str, str] | None = None
) -> float:
    times = []
    for _ in range(n):
        t0 = time.perf_counter()
        r = client.get(path, headers=headers or {})
        times.append(time.perf_counter() - t0)
        assert r.status_code in (200, 304), (path, r.status_code, r.text[:200])
    return 1e3 * statistics.median(times)


def p99(times: list[float]) -> float:
    """The 99th percentile (nearest rank), ms."""
    if not times:
        return math.nan
    ordered = sorted(times)
    return ordered[max(0, math.ceil(0.99 * len(ordered)) - 1)]


def polling(
    base: str,
    token: str,
    clients: int,
    period: float,
    seconds: float,
    path: str = "/api/v1/conveyors",
    etag: bool = False,
) -> list[float]:
    """``clients`` clients each polling ``path`` every ``period`` s; request times, ms.

    The clients are asyncio tasks with a connection each (50 threads would
    measure this process' own lock contention more than the server). With
    ``etag``, each client sends back the last ETag it got (as a browser
    does). Each client's first request (its connection's set-up) is left
    out: a dashboard keeps its connection (``serve`` keeps it open 75 s).
    """
    out: list[float] = []
    errors: list[int] = []

    async def run(k: int, stop: float) -> None:
        async with httpx.AsyncClient(
            base_url=base, headers={"Authorization": f"Bearer {token}"}, timeout=60
        ) as c:
            await asyncio.sleep(period * k / clients)  # spread the clients over the period
            tag: str | None = None
            warm = False  # the first request done
            while time.monotonic() < stop:
                t0 = time.perf_counter()
                try:
                    headers = {"If-None-Match": tag} if etag and tag else {}
                    r = await c.get(path, headers=headers)
                    if r.status_code != 304:
                        r.raise_for_status()
                    tag = r.headers.get("etag")
                except httpx.HTTPError:
                    errors.append(1)
                dt = time.perf_counter() - t0
                if warm:
                    out.append(1e3 * dt)
                warm = True
                await asyncio.sleep(max(0.0, period - dt))

    async def main() -> None:
        stop = time.monotonic() + seconds
        await asyncio.gather(*(run(k, stop) for k in range(clients)))

    asyncio.run(main())
    if errors:
        print(f"{len(errors)} of {len(out)} polls failed", file=sys.stderr)
    return out


def fault_conveyor_ids(args: argparse.Namespace, faults: FaultFleet | None) -> list[str]:
    """The fault fleet's conveyors: grown (``--fault-results``) or ingested."""
    if args.fault_results:
        return [fault_history.fault_id(k) for k in range(args.fault_conveyors)]
    return list(faults.profiles) if faults is not None else []


def reuse(url: str) -> str:
    """A new admin token in a store built by an earlier run (``--sqlite-file``, or
    ``--postgres URL`` holding the fault fleet)."""
    with Store(url) as store:
        return create_token(store, f"bench-{time.time_ns()}", "admin")


def holds_fault_fleet(url: str, args: argparse.Namespace) -> bool:
    """Whether the store at ``url`` already holds the fault fleet's conveyors (then reused)."""
    if not args.fault_results or args.fault_conveyors <= 0:
        return False
    with Store(url) as store:
        held = set(store.conveyors())
    return all(fault_history.fault_id(k) in held for k in range(args.fault_conveyors))


def refit_reused(url: str, ids: list[str]) -> dict[str, Any]:
    """Refit a reused store's fault conveyors, as ingest does after it
    (its forecasts, ``chaintwin.store.derived.refit``, and its stored trends,
    ``refit_trends``; nothing is computed where they are current): a store filled by
    older code gets what this code stores after ingest. Seconds, and how many conveyors
    had their trends built."""
    from chaintwin.report.trend_series import refit_trends
    from chaintwin.store.derived import refit

    t0 = time.perf_counter()
    built = 0
    with Store(url) as store:
        for cid in ids:
            refit(store, cid)
            built += refit_trends(store, cid)
    return {"seconds": time.perf_counter() - t0, "conveyors": len(ids), "trends_built": built}


def measure(
    url: str,
    args: argparse.Namespace,
    faults: FaultFleet | None,
    *,
    built_before: bool = False,
    code: Path | None = None,
) -> dict[str, Any]:
    t0 = time.perf_counter()
    token = reuse(url) if built_before else build(url, args.conveyors, args.results)
    built = time.perf_counter() - t0
    ingested = None
    grown = None
    if args.fault_results and not built_before:
        grown = fault_history.grow(
            args.fault_template,
            url,
            args.fault_conveyors,
            args.fault_results,
            onset=fault_history.ONSET_DAY * args.fault_per_day,
        )
        print(f"fault fleet grown: {json.dumps(grown)}", file=sys.stderr)
    elif faults is not None and not built_before:
        seconds, n = ingest_fault_fleet(url, faults)
        ingested = {"seconds": seconds, "recordings": n}
    fault_ids = fault_conveyor_ids(args, faults)
    refitted = None
    if built_before and fault_ids and code is None:
        refitted = refit_reused(url, fault_ids)
        print(f"reused store refitted: {json.dumps(refitted)}", file=sys.stderr)
    port = free_port()
    env = os.environ | {"OPENBLAS_NUM_THREADS": "1"}
    if code is not None:  # the server runs another checkout's chaintwin
        env["PYTHONPATH"] = str(code)
    if args.trace_ms:
        env["CHAINTWIN_TRACE_SLOW_MS"] = str(args.trace_ms)
    log = open(args.server_log, "ab") if args.server_log else None  # noqa: SIM115
    server = subprocess.Popen(
        [sys.executable, "-m", "chaintwin", "serve", "--db", url, "--port", str(port)],
        env=env,
        stderr=log or subprocess.DEVNULL,
    )
    base = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 300  # a loaded 2-core machine: 40 s on an empty store
        while True:
            try:
                httpx.get(base + "/api/v1/health", timeout=5)
                break
            except httpx.TransportError:
                assert time.monotonic() < deadline, "the server did not start"
                time.sleep(0.2)
        headers = {"Authorization": f"Bearer {token}"}
        with httpx.Client(base_url=base, headers=headers, timeout=60) as c:
            # the fleet page needs the browser's cookie
            c.post("/login", data={"token": token})
            n = args.repeat
            one = f"conveyor-{min(7, args.conveyors - 1):03d}" if args.conveyors else None
            if one is None:
                assert fault_ids, "no conveyor to measure: give --conveyors"
                one = fault_ids[0]
            page = f"/api/v1/conveyors/{one}/recordings?limit=100"
            median_ms(c, "/api/v1/conveyors", 3)  # warm: the first fleet read fills caches
            health = median_ms(c, "/api/v1/health", n)
            tag = c.get("/api/v1/conveyors").headers["etag"]
            rows = {
                "GET /api/v1/conveyors": median_ms(c, "/api/v1/conveyors", n),
                "GET /api/v1/conveyors, ETag (304)": median_ms(
                    c, "/api/v1/conveyors", n, {"If-None-Match": tag}
                ),
                "GET / (fleet page)": median_ms(c, "/", n),
                "GET .../recordings?limit=100": median_ms(c, page, n),
                "GET /conveyors/{id} (the conveyor's HTML page)": median_ms(
                    c, f"/conveyors/{one}", n
                ),
                "GET .../trends?feature=friction (max_points 1000)": median_ms(
                    c, f"/api/v1/conveyors/{one}/trends?feature=friction", n
                ),
            }
            alarmed = None
            for cid in fault_ids:
                if c.get(f"/api/v1/conveyors/{cid}").json()["open_alarms"]:
                    alarmed = cid
                    break
            if fault_ids:
                assert alarmed is not None, "no conveyor of the fault fleet is in alarm"
                rows |= {
                    f"GET /conveyors/{alarmed} (the page of a conveyor in alarm)": median_ms(
                        c, f"/conveyors/{alarmed}", n
                    ),
                    "GET /api/v1/conveyors/{id} (in alarm)": median_ms(
                        c, f"/api/v1/conveyors/{alarmed}", n
                    ),
                    "GET .../trends (all its trends, one request)": median_ms(
                        c, f"/api/v1/conveyors/{alarmed}/trends", n
                    ),
                }
        print(json.dumps({"health_ms": health, "rows": rows}, indent=1), file=sys.stderr)
        polls = {}
        for name, path, etag in (
            ()
            if args.seconds <= 0
            else (
                ("fleet, with ETag (as browsers)", "/api/v1/conveyors", True),
                ("fleet, without ETag", "/api/v1/conveyors", False),
                ("recordings?limit=100", page, False),
            )
        ):
            polled = polling(base, token, 50, 5.0, args.seconds, path, etag)
            polls[name] = {"p99_ms": p99(polled), "n": len(polled)}
    finally:
        server.terminate()
        server.wait(30)
        if log is not None:
            log.close()
    return {
        "built_s": built,
        "fault_fleet_ingest": ingested,
        "fault_fleet_grown": grown,
        "reused_refit": refitted,
        "health_ms": health,
        "rows": rows,
        "polls": polls,
    }


def both(
    name: str,
    url: str,
    args: argparse.Namespace,
    faults: FaultFleet | None,
    *,
    built_before: bool = False,
) -> dict[str, dict[str, Any]]:
    """The store measured with this code and, with ``--baseline-code``, this code's server
    against that code's on the same store, request by request (:func:`paired`)."""
    out = {name: measure(url, args, faults, built_before=built_before)}
    if args.baseline_code is not None:
        out[f"{name}, paired"] = paired(url, args, faults)
    return out


def start_server(url: str, code: Path | None) -> tuple[subprocess.Popen[bytes], str]:
    """``chaintwin serve`` on ``url`` from this code or another checkout; its base URL."""
    env = os.environ | {"OPENBLAS_NUM_THREADS": "1"}
    if code is not None:
        env["PYTHONPATH"] = str(code)
    port = free_port()
    server = subprocess.Popen(
        [sys.executable, "-m", "chaintwin", "serve", "--db", url, "--port", str(port)],
        env=env,
        stderr=subprocess.DEVNULL,
        # ``-m`` puts the working folder first on the path, before PYTHONPATH: run the
        # other checkout's from its own folder, else both servers run this code
        cwd=None if code is None else code,
    )
    base = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + 300
    while True:
        try:
            httpx.get(base + "/api/v1/health", timeout=5)
            return server, base
        except httpx.TransportError:
            assert time.monotonic() < deadline, "the server did not start"
            time.sleep(0.2)


def paired(url: str, args: argparse.Namespace, faults: FaultFleet | None) -> dict[str, Any]:
    """This code's server and ``--baseline-code``'s on the same store at once, each request
    sent to one then the other (alternating which goes first), so that both meet the
    same load; per row the median of each and their ratio (this / baseline)."""
    token = reuse(url)
    servers = [start_server(url, None), start_server(url, args.baseline_code)]
    try:
        clients = []
        for _server, base in servers:
            c = httpx.Client(base_url=base, headers={"Authorization": f"Bearer {token}"},
                             timeout=60)  # fmt: skip
            c.post("/login", data={"token": token})
            clients.append(c)
        fault_ids = fault_conveyor_ids(args, faults)
        one = f"conveyor-{min(7, args.conveyors - 1):03d}" if args.conveyors else None
        if one is None:
            assert fault_ids, "no conveyor to measure: give --conveyors"
            one = fault_ids[0]
        paths = {
            "GET /api/v1/health (reference)": "/api/v1/health",
            "GET /api/v1/conveyors": "/api/v1/conveyors",
            "GET / (fleet page)": "/",
            "GET .../recordings?limit=100": f"/api/v1/conveyors/{one}/recordings?limit=100",
            "GET /conveyors/{id} (the conveyor's HTML page)": f"/conveyors/{one}",
            "GET /api/v1/conveyors/{id}": f"/api/v1/conveyors/{one}",
            "GET .../trends?feature=friction": f"/api/v1/conveyors/{one}/trends?feature=friction",
        }
        for cid in fault_ids:
            if clients[0].get(f"/api/v1/conveyors/{cid}").json()["open_alarms"]:
                paths |= {
                    "GET /conveyors/{id} (in alarm)": f"/conveyors/{cid}",
                    "GET /api/v1/conveyors/{id} (in alarm)": f"/api/v1/conveyors/{cid}",
                    "GET .../trends (in alarm, all)": f"/api/v1/conveyors/{cid}/trends",
                }
                break
        rows = {}
        for row, path in paths.items():
            for c in clients:  # warm
                c.get(path)
            times: list[list[float]] = [[], []]
            for k in range(2 * args.repeat):
                order = (0, 1) if k % 2 == 0 else (1, 0)
                for i in order:
                    t0 = time.perf_counter()
                    r = clients[i].get(path)
                    times[i].append(time.perf_counter() - t0)
                    assert r.status_code == 200, (path, r.status_code, r.text[:200])
            this, base = (1e3 * statistics.median(t) for t in times)
            rows[row] = {"this_ms": this, "baseline_ms": base, "ratio": this / base}
        for c in clients:
            c.close()
    finally:
        for server, _base in servers:
            server.terminate()
            server.wait(30)
    return {"paired": rows}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--conveyors", type=int, default=200)
    parser.add_argument("--results", type=int, default=10_000)
    parser.add_argument(
        "--seconds", type=float, default=30.0, help="each polling phase, s (0: none)"
    )
    parser.add_argument("--repeat", type=int, default=21)
    parser.add_argument("--no-sqlite", action="store_true", help="PostgreSQL only")
    parser.add_argument(
        "--postgres",
        help="a PostgreSQL database's URL: built there when empty, reused (not rebuilt) when "
        "it already holds the fault fleet's conveyors (--fault-results), as --sqlite-file; "
        "or 'auto': a private server, built each time",
    )
    parser.add_argument(
        "--sqlite-file",
        type=Path,
        help="the SQLite store's file: built there when missing, reused (not rebuilt) when "
        "present, so that repeated runs skip the build (its --conveyors/--results are the "
        "first run's); a reused store's fault conveyors are refitted first, as ingest "
        "does (forecasts and stored trends, where not current)",
    )
    parser.add_argument(
        "--trace-ms",
        type=float,
        help="run the server with CHAINTWIN_TRACE_SLOW_MS (chaintwin.web.trace): a line per "
        "request slower than this, per full garbage collection, per stall of its event loop",
    )
    parser.add_argument("--server-log", type=Path, help="append the server's stderr to this file")
    parser.add_argument(
        "--fault-conveyors", type=int, default=20, help="conveyors of the fault fleet (0: none)"
    )
    parser.add_argument("--fault-days", type=int, default=6, help="simulated days of each")
    parser.add_argument("--fault-per-day", type=int, default=5, help="recordings a day of each")
    parser.add_argument(
        "--fault-results",
        type=int,
        default=0,
        help="grow each fault conveyor's history to this many results (benchmarks/"
        "fault_history.py: --fault-kinds conveyors really ingested into --fault-template, "
        "then copied to --fault-conveyors and their baseline replicated backwards); "
        "0: ingest the fault fleet as it is",
    )
    parser.add_argument(
        "--fault-kinds",
        type=int,
        help="with --fault-results: conveyors really ingested (default --fault-conveyors)",
    )
    parser.add_argument(
        "--fault-template",
        type=Path,
        help="with --fault-results: the SQLite file of the really ingested fault fleet, built "
        "there when missing (minutes), reused when present",
    )
    parser.add_argument(
        "--compare-ingest",
        action="store_true",
        help="also time the fault fleet's ingest without and with the forecasts' refit",
    )
    parser.add_argument("--compare-rounds", type=int, default=2)
    parser.add_argument(
        "--baseline-code",
        type=Path,
        help="a checkout of another chaintwin (e.g. `git archive` of an older commit): each "
        "store is also served by it beside this code, every request sent to both in turn, "
        "and each row's medians compared (this code / baseline)",
    )
    args = parser.parse_args()
    work = tempfile.TemporaryDirectory()
    faults = None
    if args.fault_results and args.fault_conveyors > 0:
        if args.fault_template is None:
            args.fault_template = Path(work.name) / "fault-template.db"
        if not args.fault_template.exists():
            done = fault_history.build_template(
                args.fault_template,
                args.fault_kinds or args.fault_conveyors,
                args.fault_days,
                args.fault_per_day,
                Path(work.name),
            )
            print(f"fault fleet template: {json.dumps(done)}", file=sys.stderr)
    elif args.fault_conveyors > 0:
        t0 = time.perf_counter()
        faults = fault_fleet(
            Path(work.name), args.fault_conveyors, args.fault_days, args.fault_per_day
        )
        print(
            f"fault fleet: {len(faults.files)} recordings of {args.fault_conveyors} conveyors "
            f"simulated in {time.perf_counter() - t0:.0f} s",
            file=sys.stderr,
        )
    compared = None
    if args.compare_ingest and faults is not None:
        compared = compare_ingest(faults, args.compare_rounds)
        print(json.dumps({"ingest": compared}, indent=1), file=sys.stderr)
    stores = {}
    if not args.no_sqlite and args.sqlite_file is not None:
        path = args.sqlite_file.resolve()
        stores |= both("SQLite", f"sqlite:///{path}", args, faults, built_before=path.exists())
    elif not args.no_sqlite:
        with tempfile.TemporaryDirectory() as folder:
            stores |= both("SQLite", f"sqlite:///{folder}/bench.db", args, faults)
    if args.postgres == "auto":
        with private_postgres() as url:
            stores |= both("PostgreSQL", url, args, faults)
    elif args.postgres:
        reused = holds_fault_fleet(args.postgres, args)
        stores |= both("PostgreSQL", args.postgres, args, faults, built_before=reused)
    work.cleanup()
    kinds = args.fault_kinds or args.fault_conveyors
    if args.fault_results and args.fault_template is not None and args.fault_template.exists():
        # the template's, also when a store is reused (read as a plain file: it may be at
        # an older revision than this code's)
        with sqlite3.connect(f"file:{args.fault_template}?mode=ro", uri=True) as template:
            kinds = int(template.execute("SELECT count(*) FROM conveyors").fetchone()[0])
    print(
        f"{args.conveyors} conveyors x {args.results} results each"
        + (
            f", and a fault fleet of {args.fault_conveyors} conveyors x "
            f"{args.fault_results} results (copies of {kinds} really ingested conveyors of "
            f"{args.fault_days * args.fault_per_day} recordings, grown by "
            "benchmarks/fault_history.py)"
            if args.fault_results
            else f", and a fault fleet of {args.fault_conveyors} conveyors x "
            f"{args.fault_days * args.fault_per_day} recordings ingested"
            if faults is not None
            else ""
        )
        + "; times are medians, ratio against GET /api/v1/health"
    )
    if compared is not None:
        print(
            f"\ningest of the fault fleet, s per recording (median of {args.compare_rounds}): "
            f"without refit {compared['old_s']:.3f}, with refit {compared['new_s']:.3f}, "
            f"ratio {compared['ratio']:.3f} (target <= 1.10)"
        )
    for name, m in stores.items():
        if "paired" in m:
            continue  # printed below
        print(f"\n{name} (store built in {m['built_s']:.0f} s)")
        if m["fault_fleet_grown"] is not None:
            fg = m["fault_fleet_grown"]
            print(f"  fault fleet grown to {fg['results']} results in {fg['seconds']:.0f} s")
        if m.get("reused_refit") is not None:
            rr = m["reused_refit"]
            print(
                f"  reused store: {rr['conveyors']} conveyors refitted in {rr['seconds']:.0f} s "
                f"({rr['trends_built']} had their trends built)"
            )
        if m["fault_fleet_ingest"] is not None:
            fi = m["fault_fleet_ingest"]
            print(
                f"  fault fleet ingested in {fi['seconds']:.0f} s ({fi['recordings']} recordings)"
            )
        print(f"  {'GET /api/v1/health (reference)':58} {m['health_ms']:8.1f} ms   1.0x")
        for row, ms in m["rows"].items():
            print(f"  {row:58} {ms:8.1f} ms {ms / m['health_ms']:5.1f}x")
        for name, poll in m["polls"].items():
            print(
                f"  {'50 clients polling ' + name + ', p99':58} {poll['p99_ms']:8.1f} ms "
                f"{poll['p99_ms'] / m['health_ms']:5.1f}x  ({poll['n']} requests)"
            )
    if args.baseline_code is not None:
        for name in [n for n in stores if f"{n}, paired" in stores]:
            print(
                f"\n{name}: this code against {args.baseline_code}, the same requests alternating"
            )
            for row, m in stores[f"{name}, paired"]["paired"].items():
                print(f"  {row:58} {m['this_ms']:8.1f} ms {m['baseline_ms']:8.1f} ms "
                      f"{m['ratio']:5.2f}")  # fmt: skip
    print(json.dumps({"stores": stores, "ingest": compared}, indent=1), file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
