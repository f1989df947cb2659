"""Benchmark: the dashboard and API on a large store (a script, not a test).

Scenario (issue 20): a store of ``--conveyors`` conveyors (200) with
``--results`` result rows each (10 000; synthetic rows without samples),
on SQLite and, with ``--postgres URL``, on PostgreSQL. ``chaintwin serve``
runs in its own process; this script is the clients. It prints, per store,
the median time of

1. reference: ``GET /api/v1/health``;
2. ``GET /api/v1/conveyors`` (the fleet's data);
3. ``GET /`` (the fleet page);
4. ``GET /api/v1/conveyors/{id}/recordings?limit=100`` (one conveyor's page of 100);

each with its ratio to the reference (targets: 2 and 3 within 5x, 4 likewise),
and then 50 clients polling ``/api/v1/conveyors`` every 5 s for ``--seconds``
(60): the p99 of those requests and its ratio to the reference median
(target within 20x).

Run: ``.venv/bin/python benchmarks/bench_serve.py [--postgres postgresql://...]``
(building the SQLite store of 2 million rows takes about a minute).
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import httpx
from sqlalchemy import insert

from chaintwin.read.profile import load_profile
from chaintwin.store.access import create_token
from chaintwin.store.schema import ConveyorRow, RecordingRow, ResultRow
from chaintwin.store.store import Store

PROFILE = Path(__file__).resolve().parents[1] / "chaintwin/examples/profiles/white-belt-01.yaml"


def build(url: str, conveyors: int, results: int) -> str:
    """Fill an empty store with synthetic rows; an admin token."""
    store = Store(url)
    base = load_profile(PROFILE)
    rows_per_batch = 5000
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
        rid = 0
        for k in range(conveyors):
            cid = f"conveyor-{k:03d}"
            for start in range(0, results, rows_per_batch):
                n = min(rows_per_batch, results - start)
                recs, res = [], []
                for j in range(start, start + n):
                    rid += 1
                    # one recording every 10 minutes from 2026-01-01
                    at = f"{datetime(2026, 1, 1, tzinfo=UTC) + timedelta(minutes=10 * j):%FT%T}Z"
                    recs.append(
                        {
                            "id": rid,
                            "sha256": f"{rid:064x}",
                            "conveyor_id": cid,
                            "file": f"{cid}-{j}.csv",
                            "recorded_at": at,
                            "meta": {},
                            "warnings": [],
                            "samples": b"",
                        }
                    )
                    content = {
                        "file": f"{cid}-{j}.csv",
                        "recorded_at": at,
                        "status": "monitored",
                        "alarm": False,
                        "payload_kg": 20.0 + j % 17,
                        "tlf": 0.5,
                        "causes": [],
                        "warnings": [],
                        "features": {"friction": 1.0},
                    }
                    res.append(
                        {
                            "recording_id": rid,
                            "conveyor_id": cid,
                            "recorded_at": at,
                            "status": "monitored",
                            "alarm": False,
                            "payload_kg": content["payload_kg"],
                            "tlf": 0.5,
                            "content": content,
                            "stored_at": at,
                        }
                    )
                with store.engine.begin() as c:
                    c.execute(insert(RecordingRow), recs)
                    c.execute(insert(ResultRow), res)
        return create_token(store, "bench", "admin")
    finally:
        store.close()


def _port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def median_ms(client: httpx.Client, path: str, n: int) -> float:
    times = []
    for _ in range(n):
        t0 = time.perf_counter()
        r = client.get(path)
        times.append(time.perf_counter() - t0)
        assert r.status_code == 200, (path, r.status_code, r.text[:200])
    return 1e3 * statistics.median(times)


def polling(base: str, token: str, clients: int, period: float, seconds: float) -> list[float]:
    """``clients`` threads each polling the fleet every ``period`` s; request times, ms."""
    out: list[float] = []
    errors: list[int] = []
    lock = threading.Lock()
    stop = time.monotonic() + seconds

    def run(k: int) -> None:
        with httpx.Client(
            base_url=base, headers={"Authorization": f"Bearer {token}"}, timeout=60
        ) as c:
            time.sleep(period * k / clients)  # spread the clients over the period
            while time.monotonic() < stop:
                t0 = time.perf_counter()
                try:
                    c.get("/api/v1/conveyors").raise_for_status()
                except httpx.HTTPError:
                    with lock:
                        errors.append(1)
                dt = time.perf_counter() - t0
                with lock:
                    out.append(1e3 * dt)
                time.sleep(max(0.0, period - dt))

    threads = [threading.Thread(target=run, args=(k,)) for k in range(clients)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    if errors:
        print(f"{len(errors)} of {len(out)} polls failed", file=sys.stderr)
    return out


def measure(url: str, args: argparse.Namespace) -> dict[str, Any]:
    t0 = time.perf_counter()
    token = build(url, args.conveyors, args.results)
    built = time.perf_counter() - t0
    port = _port()
    env = os.environ | {"OPENBLAS_NUM_THREADS": "1"}
    server = subprocess.Popen(
        [sys.executable, "-m", "chaintwin", "serve", "--db", url, "--port", str(port)],
        env=env,
        stderr=subprocess.DEVNULL,
    )
    base = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 60
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
            health = median_ms(c, "/api/v1/health", n)
            rows = {
                "GET /api/v1/conveyors": median_ms(c, "/api/v1/conveyors", n),
                "GET / (fleet page)": median_ms(c, "/", n),
                "GET .../recordings?limit=100": median_ms(
                    c, "/api/v1/conveyors/conveyor-007/recordings?limit=100", n
                ),
            }
        polled = polling(base, token, 50, 5.0, args.seconds)
        p99 = sorted(polled)[max(0, int(0.99 * len(polled)) - 1)]
    finally:
        server.terminate()
        server.wait(30)
    return {"built_s": built, "health_ms": health, "rows": rows, "p99_ms": p99, "n": len(polled)}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--conveyors", type=int, default=200)
    parser.add_argument("--results", type=int, default=10_000)
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--repeat", type=int, default=21)
    parser.add_argument("--postgres", help="an empty PostgreSQL database's URL")
    args = parser.parse_args()
    stores = {}
    with tempfile.TemporaryDirectory() as folder:
        stores["SQLite"] = measure(f"sqlite:///{folder}/bench.db", args)
    if args.postgres:
        stores["PostgreSQL"] = measure(args.postgres, args)
    print(
        f"{args.conveyors} conveyors x {args.results} results each; "
        "times are medians, ratio against GET /api/v1/health"
    )
    for name, m in stores.items():
        print(f"\n{name} (store built in {m['built_s']:.0f} s)")
        print(f"  {'GET /api/v1/health (reference)':34} {m['health_ms']:8.1f} ms   1.0x")
        for row, ms in m["rows"].items():
            print(f"  {row:34} {ms:8.1f} ms {ms / m['health_ms']:5.1f}x")
        print(
            f"  {'50 clients polling every 5 s, p99':34} {m['p99_ms']:8.1f} ms "
            f"{m['p99_ms'] / m['health_ms']:5.1f}x  ({m['n']} requests)"
        )
    print(json.dumps(stores, indent=1), file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
