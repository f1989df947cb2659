"""Benchmark: ingest throughput against the cost of reading, scaling, PostgreSQL, memory.

A script, not a test: every figure is a ratio against a reference measured
in the same run (the machine drifts by 10 % and more between runs), and
nothing is asserted on time.

Scenario: the reference conveyor white-belt-01, ``--recordings`` virtual
recordings (16 a day, payload 10-40 kg, seasonal and daily loss drift, a
friction rise from day 4; :func:`chaintwin.simulate.fleet.generate`), one
calibration from its calibration runs (setup, not timed), each timed ingest
into a fresh store holding that calibration, ``baseline_n=20``, BLAS pinned
to one thread. Rows (best of ``--rounds`` rounds, the configurations
interleaved in each round):

1. reference: ``load_recording`` (read + validate, segmentation included,
   what ``bench_read`` times) of every file, in this process;
2. the full pipeline as ``ingest`` runs it (read, validate, weigh, features,
   impacts, health model, store) with ``workers=1``: in this process, one
   core, SQLite. Target: at most 3x row 1 per recording;
3. the same with 2 local worker processes (the fork server's); target: at
   least 1.8x the throughput of row 2;
4. a Dask cluster of separate processes: ``dask scheduler`` and ``dask
   worker --nworkers 1 --nthreads 1`` started as commands, the ingest given
   the scheduler's address (``ingest --scheduler``); with one worker
   process, then with a second one joined (4a), against row 2 and against
   each other;
5. PostgreSQL: row 2 into a throwaway PostgreSQL server of this run
   (``initdb`` + ``pg_ctl`` on a free port; skipped, and said so, without
   the binaries); target: at most 1.3x row 2 per recording;
6. memory: peak resident size (``ru_maxrss``) of a new process that ingests
   2,000 and 20,000 distinct recordings with ``workers=1`` (``--memory``):
   the ``--recordings`` files and copies of them dated later (each copy
   shifted by the span of the series, so every file has its own content
   hash and the series goes on in time; the samples repeat). Target: flat.

Beside the table: the largest relative difference of every stored number
(and whether statuses, alarms and warnings are the same) between the stores
of rows 3-5 and row 2's.

Run: ``python benchmarks/bench_throughput.py`` (400 recordings, the memory
rows at 2,000 and 20,000: about 10 minutes and 2.5 GB of temporary files);
a short run: ``--recordings 160 --rounds 2 --memory 500``.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import re  # noqa: E402
import resource  # noqa: E402
import shutil  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from collections.abc import Iterator  # noqa: E402
from contextlib import contextmanager  # noqa: E402
from datetime import datetime, timedelta  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

from chaintwin.calibrating.procedure import calibrate  # noqa: E402
from chaintwin.cli.demo_cmd import examples_dir  # noqa: E402
from chaintwin.diagnose.records import MonitorSettings  # noqa: E402
from chaintwin.identify.calibration import Calibration  # noqa: E402
from chaintwin.ingest.pipeline import ingest  # noqa: E402
from chaintwin.read.profile import ConveyorProfile, load_profile  # noqa: E402
from chaintwin.simulate.faults import Fault  # noqa: E402
from chaintwin.simulate.fleet import generate  # noqa: E402
from chaintwin.store.store import Store  # noqa: E402
from chaintwin.testing.postgres import free_port, postgres_binaries, throwaway_postgres  # noqa: E402
from chaintwin.validate.checks import load_recording  # noqa: E402

PROFILE = examples_dir() / "profiles" / "white-belt-01.yaml"
PER_DAY = 16
ONSET_DAY = 4
SEED = 3
BASELINE_N = 20
TARGET_RATIO = 3.0
TARGET_SCALING = 1.8
TARGET_PG = 1.3


# ---------------------------------------------------------------- helpers


def _leaves(value: Any, path: str = "") -> Iterator[tuple[str, Any]]:
    if isinstance(value, dict):
        for k, v in value.items():
            if k not in ("stored_at", "id"):
                yield from _leaves(v, f"{path}/{k}")
    elif isinstance(value, list):
        yield f"{path}#len", len(value)
        for k, v in enumerate(value):
            yield from _leaves(v, f"{path}[{k}]")
    else:
        yield path, value


def compare_stores(a: Store, b: Store) -> tuple[float, bool]:
    """(largest relative difference of the stored results' numbers, texts the same)."""
    la = dict(_leaves([a.results(), [x.to_dict() for x in a.alarms()]]))
    lb = dict(_leaves([b.results(), [x.to_dict() for x in b.alarms()]]))
    if la.keys() != lb.keys():
        return math.inf, False
    worst, same = 0.0, True
    for key, x in la.items():
        y = lb[key]
        if isinstance(x, bool) or not isinstance(x, int | float):
            same = same and x == y
            continue
        if not isinstance(y, int | float) or isinstance(y, bool):
            same = False
            continue
        if x == y or (math.isnan(x) and math.isnan(y)):
            continue
        d = abs(x - y) / max(abs(x), abs(y)) if math.isfinite(x - y) else math.inf
        worst = max(worst, d)
    return worst, same


@contextmanager
def postgres_server() -> Iterator[str | None]:
    """A throwaway PostgreSQL server on a free port (None without its binaries)."""
    bindir = postgres_binaries()
    if bindir is None:
        yield None
        return
    with throwaway_postgres(bindir, prefix="chaintwin-bench-pg-") as url:
        yield url


def _new_pg_database(base: str, name: str) -> str:
    import psycopg

    with psycopg.connect(base, autocommit=True) as c:
        c.execute(f'CREATE DATABASE "{name}"')
    return base.rsplit("/", 1)[0] + f"/{name}"


class DaskCluster:
    """``dask scheduler`` and ``dask worker`` processes started as commands."""

    def __init__(self, log: Path) -> None:
        self.port = free_port()
        self.address = f"tcp://127.0.0.1:{self.port}"
        self.log = log
        self.procs: list[subprocess.Popen[bytes]] = []
        exe = Path(sys.executable).with_name("dask")
        self.exe = str(exe)
        self._start(
            [
                self.exe,
                "scheduler",
                "--host",
                "127.0.0.1",
                "--port",
                str(self.port),
                "--no-dashboard",
            ]
        )

    def _start(self, cmd: list[str]) -> None:
        with self.log.open("ab") as out:
            self.procs.append(subprocess.Popen(cmd, stdout=out, stderr=out))

    def add_worker(self) -> None:
        """One more worker process (one thread), waited for until the scheduler has it."""
        from distributed import Client

        self._start(
            [
                self.exe,
                "worker",
                self.address,
                "--nworkers",
                "1",
                "--nthreads",
                "1",
                "--no-dashboard",
                "--memory-limit",
                "0",
            ]
        )
        with Client(self.address, timeout="30s") as client:  # type: ignore[no-untyped-call]
            client.wait_for_workers(len(self.procs) - 1, timeout=60)  # all but the scheduler

    def close(self) -> None:
        for p in reversed(self.procs):
            p.terminate()
        for p in reversed(self.procs):
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                p.kill()


# ---------------------------------------------------------------- memory rows


def copies(src: list[str], folder: Path, count: int) -> list[str]:
    """``count`` distinct recordings: the given ones, then copies dated later.

    Copy ``k`` of the series has its ``recorded_at`` shifted by ``k`` times
    the series' span (and a day), so the files differ in content and go on
    in time.
    """
    folder.mkdir(parents=True, exist_ok=True)
    texts = [Path(f).read_text() for f in src]
    stamp = re.compile(r"^# recorded_at: (\S+)$", re.M)
    times = [datetime.fromisoformat(stamp.search(t).group(1)) for t in texts]  # type: ignore[union-attr]
    span = max(times) - min(times) + timedelta(days=1)
    out: list[str] = []
    k = 0
    while len(out) < count:
        for text, at in zip(texts, times, strict=True):
            if len(out) >= count:
                break
            when = at + k * span
            path = folder / f"white-belt-01-{when.strftime('%Y%m%dT%H%M%S')}.csv"
            path.write_text(
                stamp.sub(f"# recorded_at: {when.strftime('%Y-%m-%dT%H:%M:%SZ')}", text, count=1)
            )
            out.append(str(path))
        k += 1
    return out


def rss_child(folder: Path, cal_file: Path, db: Path) -> None:
    """In a new process: ingest every file of ``folder`` with one worker; print JSON."""
    prof = load_profile(PROFILE)
    cal = Calibration.from_dict(json.loads(cal_file.read_text()), str(cal_file))
    store = Store(f"sqlite:///{db}")
    store.put_calibration(cal)
    files = sorted(str(p) for p in folder.glob("*.csv"))
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    t0 = time.perf_counter()
    summary = ingest(
        files, {prof.id: prof}, store, settings=MonitorSettings(baseline_n=BASELINE_N), workers=1
    )
    seconds = time.perf_counter() - t0
    store.close()
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    status = Path("/proc/self/status")
    found = re.search(r"^VmRSS:\s+(\d+) kB", status.read_text(), re.M) if status.exists() else None
    now = int(found.group(1)) if found else 0
    print(
        json.dumps(
            {
                "files": len(files),
                "processed": summary.processed,
                "seconds": seconds,
                "peak_rss_mb": peak / 1024,
                "rss_before_mb": before / 1024,
                "rss_after_mb": now / 1024,
            }
        )
    )


# ---------------------------------------------------------------- main


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--recordings", type=int, default=400, help="recordings of rows 1-5")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument(
        "--memory", default="2000,20000", help="recordings of the memory rows ('' for none)"
    )
    parser.add_argument("--no-dask", action="store_true", help="leave out row 4")
    parser.add_argument("--no-postgres", action="store_true", help="leave out row 5")
    parser.add_argument("--rss-child", nargs=3, type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.rss_child:
        rss_child(*args.rss_child)
        return
    t_start = time.perf_counter()
    prof = load_profile(PROFILE)
    profiles: dict[str, ConveyorProfile] = {prof.id: prof}
    settings = MonitorSettings(baseline_n=BASELINE_N)
    memory = [int(x) for x in args.memory.split(",") if x.strip()]
    notes: list[str] = []
    with tempfile.TemporaryDirectory(prefix="bench_throughput_") as tmp_name:
        tmp = Path(tmp_name)
        folder = tmp / "recordings"
        t0 = time.perf_counter()
        generate(
            prof,
            folder,
            days=-(-args.recordings // PER_DAY),
            per_day=PER_DAY,
            faults=[Fault("friction", 0.3)],
            onset_day=ONSET_DAY,
            seed=SEED,
        )
        files = sorted(str(p) for p in folder.glob("*.csv"))[: args.recordings]
        n = len(files)
        cal_files = sorted((folder / "calibration").glob("*.csv"))
        cal = calibrate([load_recording(p, profile=prof).recording for p in cal_files], prof)
        t_gen = time.perf_counter() - t0
        serial = 0
        kept: dict[str, Store] = {}

        def run(label: str, url: str, **kw: Any) -> float:
            store = Store(url)
            store.put_calibration(cal)
            t0 = time.perf_counter()
            summary = ingest(files, profiles, store, settings=settings, **kw)
            seconds = time.perf_counter() - t0
            if summary.processed != n:
                notes.append(f"CHECK FAILED: {label}: {summary.processed} of {n} processed")
            if label not in kept:
                kept[label] = store  # the first round's store, for the comparison
            else:
                store.close()
            return seconds

        def sqlite_url() -> str:
            nonlocal serial
            serial += 1
            return f"sqlite:///{tmp / f's{serial}.db'}"

        # warm-up: numba (compiled or loaded), the fork server, first-use caches
        warm = Store(f"sqlite:///{tmp / 'warm.db'}")
        warm.put_calibration(cal)
        ingest(files[:8], profiles, warm, settings=MonitorSettings(baseline_n=5), workers=2)
        ingest(files[8:16], profiles, warm, settings=MonitorSettings(baseline_n=5), workers=1)
        warm.close()

        times: dict[str, list[float]] = {}

        def note(key: str, seconds: float) -> None:
            times.setdefault(key, []).append(seconds)

        with postgres_server() as pg:
            if pg is None and not args.no_postgres:
                notes.append("row 5 not measured: no PostgreSQL server binaries (initdb, pg_ctl)")
            use_pg = pg is not None and not args.no_postgres
            for rnd in range(args.rounds):
                order = ["read", "w1", "w2", "pg"]
                if rnd % 2:
                    order.reverse()
                for key in order:
                    if key == "read":
                        t0 = time.perf_counter()
                        for f in files:
                            load_recording(f, profile=prof)
                        note(key, time.perf_counter() - t0)
                    elif key == "w1":
                        note(key, run(key, sqlite_url(), workers=1))
                    elif key == "w2":
                        note(key, run(key, sqlite_url(), workers=2))
                    elif use_pg:
                        assert pg is not None
                        url = _new_pg_database(pg, f"bench{rnd}")
                        note(key, run(key, url, workers=1))
            if not args.no_dask:
                cluster = DaskCluster(tmp / "dask.log")
                try:
                    for workers in (1, 2):
                        cluster.add_worker()
                        # the new worker process loads numba's code and fills its caches
                        warm = Store(f"sqlite:///{tmp / f'warm-dask{workers}.db'}")
                        warm.put_calibration(cal)
                        ingest(
                            files[:16], profiles, warm, settings=settings, scheduler=cluster.address
                        )
                        warm.close()
                        for _ in range(args.rounds):
                            note(
                                f"dask{workers}",
                                run(f"dask{workers}", sqlite_url(), scheduler=cluster.address),
                            )
                finally:
                    cluster.close()
            diffs = {
                label: compare_stores(kept["w1"], store)
                for label, store in kept.items()
                if label != "w1"
            }
            for store in kept.values():
                store.close()

        # memory rows: a new process each, so that its peak is its own
        rss: dict[int, dict[str, Any]] = {}
        if memory:
            cal_path = tmp / "cal.json"
            cal_path.write_text(json.dumps(cal.to_dict()))
            for count in memory:
                where = tmp / f"mem{count}"
                copies(files, where, count)
                done = subprocess.run(
                    [
                        sys.executable,
                        __file__,
                        "--rss-child",
                        str(where),
                        str(cal_path),
                        str(tmp / f"mem{count}.db"),
                    ],
                    capture_output=True,
                    text=True,
                    check=False,
                )
                try:
                    rss[count] = json.loads(done.stdout.strip().splitlines()[-1])
                except (json.JSONDecodeError, IndexError):
                    notes.append(f"CHECK FAILED: memory row {count}: {done.stderr[-400:]}")
                shutil.rmtree(where)
                for p in tmp.glob(f"mem{count}.db*"):
                    p.unlink()

    # ---------------------------------------------------------------- report
    best = {k: min(v) for k, v in times.items()}
    ref = best["read"] / n
    print(
        f"chaintwin ingest throughput, {prof.id}: {n} recordings "
        f"({n // PER_DAY} days x {PER_DAY}, 2048 samples at 6 ms, friction rise from day "
        f"{ONSET_DAY}), baseline_n={BASELINE_N}; best of {args.rounds} rounds; "
        f"os.cpu_count()={os.cpu_count()}; load average {os.getloadavg()[0]:.2f}; "
        f"setup {t_gen:.0f} s"
    )
    head = f"{'what':62s} {'ms/rec':>8s} {'rec/s':>8s} {'ratio':>7s}"
    print(head)
    print("-" * len(head))

    def row(label: str, key: str, against: str = "read") -> None:
        if key not in best:
            return
        per = best[key] / n
        print(f"{label:62s} {per * 1e3:8.2f} {1 / per:8.1f} {per / (best[against] / n):7.2f}")

    row("1. read + validate (load_recording) [reference]", "read")
    row("2. ingest, 1 worker, SQLite (full pipeline) / row 1", "w1")
    row("3. ingest, 2 local workers / row 1", "w2")
    row("4. ingest, Dask cluster, 1 worker process / row 1", "dask1")
    row("   4a. Dask cluster, 2 worker processes / row 1", "dask2")
    row("5. ingest, 1 worker, PostgreSQL / row 1", "pg")
    print()
    r2 = best["w1"] / n / ref
    print(
        f"full pipeline / read+validate per recording, 1 worker: {r2:.2f}x; target at most "
        f"{TARGET_RATIO:g}x: {'MET' if r2 <= TARGET_RATIO else 'NOT MET'}"
    )
    s2 = best["w1"] / best["w2"]
    print(
        f"2 local workers / 1 worker (throughput): {s2:.2f}x; target at least "
        f"{TARGET_SCALING:g}x: {'MET' if s2 >= TARGET_SCALING else 'NOT MET'}"
    )
    if "dask2" in best:
        sd = best["w1"] / best["dask2"]
        print(
            f"Dask cluster, 2 worker processes / 1 local worker: {sd:.2f}x "
            f"({'MET' if sd >= TARGET_SCALING else 'NOT MET'}); 2 / 1 Dask worker processes: "
            f"{best['dask1'] / best['dask2']:.2f}x"
        )
    if "pg" in best:
        rp = best["pg"] / best["w1"]
        print(
            f"PostgreSQL / SQLite per recording (1 worker): {rp:.2f}x; target at most "
            f"{TARGET_PG:g}x: {'MET' if rp <= TARGET_PG else 'NOT MET'}"
        )
    for label, (worst, same) in diffs.items():
        print(
            f"stored results of {label} against 1 worker: largest relative difference "
            f"{worst:.3g}; statuses, alarms and warnings {'the same' if same else 'DIFFER'}"
        )
    for count, got in rss.items():
        print(
            f"memory: {got['processed']} of {count} distinct recordings ingested with 1 worker "
            f"in a new process: peak resident size {got['peak_rss_mb']:.0f} MB "
            f"({got['rss_before_mb']:.0f} MB before the ingest, {got['rss_after_mb']:.0f} MB "
            "resident after it), "
            f"{got['seconds'] / count * 1e3:.2f} ms per recording"
        )
    if len(rss) >= 2:
        lo, hi = min(rss), max(rss)
        grow = rss[hi]["peak_rss_mb"] / rss[lo]["peak_rss_mb"]
        print(f"memory: peak at {hi} / peak at {lo}: {grow:.2f}x")
    for line in notes:
        print(line)
    print(f"total run time {time.perf_counter() - t_start:.0f} s")


if __name__ == "__main__":
    main()
