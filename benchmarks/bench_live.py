"""Benchmark: the live service following watched folders (a script, not a test).

Scenario: ``--sources`` conveyors (20), each writing a recording
into its own sub-folder of one watched folder every ``--interval`` seconds
(2), for ``--seconds`` (60; an hour for the memory check). ``chaintwin serve
--no-web --watch DROP --settle-s S`` runs in its own process. It prints

1. reference: ``ingest`` of one recording (one conveyor, warm: the median of
   ``--reference`` calls in this process; and the first, cold call);
2. the latency of each recording from its file being complete plus the
   settle time to its result stored (``results.stored_at``): median, p95,
   max, and p95's ratio to the reference (target: within 3x);
3. the alarm's notification: one conveyor turns faulty after ``--onset``
   recordings (a friction rise); the time from the result that opened the
   alarm stored (its outbox row) to the notification received by a webhook
   receiver in this process, and its ratio to the reference (target: within
   2x more than the recording's own latency);
4. recordings written and stored, and the service's resident memory (RSS)
   after start and at the end (target: flat).

``--memory`` samples the service's resident size every ``--memory-every``
seconds (10) and prints it every minute, with the growth per minute after
the warm-up (``--warmup-s``, a least-squares line through the samples),
and the service's own account of its memory every minute
(``CHAINTWIN_MEMORY_LOG``: glibc's heap in use and free, SQLite's, Python's
blocks, the store's open connections).
``--tracemalloc`` traces the service's allocations
(``CHAINTWIN_TRACEMALLOC_DIR``: slower, larger), takes a snapshot after the
warm-up and another at the end, and prints the 15 lines whose allocations
grew the most in between, and the tracebacks of the top three.

Run: ``.venv/bin/python benchmarks/bench_live.py [--seconds 3600] [--postgres URL]
[--memory] [--tracemalloc]``.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from datetime import UTC, datetime
from pathlib import Path

import psutil
from sqlalchemy import select
from webhook_receiver import start_receiver

from chaintwin.calibrating.procedure import calibrate
from chaintwin.identify.calibration import Calibration
from chaintwin.ingest.pipeline import ingest
from chaintwin.read.profile import ConveyorProfile, load_profile
from chaintwin.simulate.faults import Fault
from chaintwin.simulate.fleet import generate
from chaintwin.store.schema import OutboxRow, RecordingRow, ResultRow
from chaintwin.store.store import Store
from chaintwin.validate import load_recording

ROOT = Path(__file__).resolve().parents[1]
PROFILE = ROOT / "chaintwin/examples/profiles/white-belt-01.yaml"

_AT = re.compile(r"^# recorded_at: .*$", re.MULTILINE)
_CONVEYOR = re.compile(r"^# conveyor: .*$", re.MULTILINE)


def conveyor_copy(base: ConveyorProfile, cal: Calibration, cid: str) -> Calibration:
    """The calibration of a conveyor like ``base`` under another id."""
    prof = base.model_copy(update={"id": cid})
    data = cal.to_dict()
    data |= {
        "conveyor": cid,
        "profile": prof.model_dump(mode="json"),
        "profile_sha256": prof.content_hash(),
    }
    return Calibration.from_dict(data, f"bench {cid}")


def as_conveyor(text: str, cid: str, at: datetime) -> str:
    """A recording's text for conveyor ``cid`` recorded at ``at`` (a new content)."""
    text = _CONVEYOR.sub(f"# conveyor: {cid}", text, count=1)
    return _AT.sub(f"# recorded_at: {at.strftime('%Y-%m-%dT%H:%M:%S.%fZ')}", text, count=1)


def pct(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, round(q * (len(ordered) - 1)))]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sources", type=int, default=20)
    ap.add_argument("--interval", type=float, default=2.0)
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--settle-s", type=float, default=2.0)
    ap.add_argument("--reference", type=int, default=5)
    ap.add_argument("--onset", type=int, default=22, help="Recordings before belt-00 turns faulty.")
    ap.add_argument("--postgres", help="PostgreSQL URL of an empty database (default: SQLite)")
    ap.add_argument("--memory", action="store_true", help="Report the service's memory over time.")
    ap.add_argument("--memory-every", type=float, default=10.0, help="RSS sample interval, s.")
    ap.add_argument(
        "--tracemalloc",
        action="store_true",
        help="Trace the service's allocations; print the growth between warm-up and end.",
    )
    ap.add_argument(
        "--warmup-s",
        type=float,
        default=None,
        help="Memory growth is counted from here, s (default: a fifth of the run, at most 120).",
    )
    args = ap.parse_args()
    if args.warmup_s is None:
        args.warmup_s = min(120.0, args.seconds / 5)

    work = Path(tempfile.mkdtemp(prefix="chaintwin-bench-live-"))
    try:
        run(args, work)
    finally:
        shutil.rmtree(work, ignore_errors=True)


def run(args: argparse.Namespace, work: Path) -> None:
    base = load_profile(PROFILE)
    print("generating recordings ...", file=sys.stderr)
    generate(base, work / "base", days=1, per_day=args.reference + 6, seed=3)
    texts = [p.read_text() for p in sorted((work / "base").glob("*.csv"))]
    generate(
        base,
        work / "faulty",
        days=1,
        per_day=6,
        faults=[Fault("friction", 1.0)],
        seed=4,
        calibration=False,
    )
    faulty = [p.read_text() for p in sorted((work / "faulty").glob("*.csv"))]
    cal_recs = [
        load_recording(p, profile=base).recording
        for p in sorted((work / "base" / "calibration").glob("*.csv"))
    ]
    cal = calibrate(cal_recs, base)
    url = args.postgres or f"sqlite:///{work / 'plant.db'}"
    store = Store(url)
    ids = [f"belt-{k:02d}" for k in range(args.sources)]
    for cid in [*ids, "reference"]:
        store.put_calibration(conveyor_copy(base, cal, cid))

    # 1. the reference: ingest of one recording, in this process
    ref_dir = work / "reference"
    ref_dir.mkdir()
    ref_profile = {"reference": base.model_copy(update={"id": "reference"})}
    times: list[float] = []
    for k in range(args.reference + 1):
        path = ref_dir / f"ref-{k}.csv"
        path.write_text(as_conveyor(texts[k % len(texts)], "reference", datetime.now(UTC)))
        t = time.perf_counter()
        summary = ingest([str(path)], ref_profile, store, workers=1)
        times.append(time.perf_counter() - t)
        assert summary.processed == 1, summary.to_dict()
    cold, warm = times[0], statistics.median(times[1:])
    store.close()

    # 2. the service, following one folder with a sub-folder per conveyor
    drop = work / "drop"
    for cid in ids:
        (drop / cid).mkdir(parents=True)
    hook, received = start_receiver()  # when each notification arrived
    (work / "notify.key").write_text("bench-secret\n")
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", PYTHONPATH=str(ROOT))
    traces = work / "tracemalloc"
    if args.tracemalloc:
        traces.mkdir()
        env["CHAINTWIN_TRACEMALLOC_DIR"] = str(traces)
    if args.memory:
        env["CHAINTWIN_MEMORY_LOG"] = "1"  # the service logs its heap every minute
    log = (work / "serve.log").open("wb")
    proc = subprocess.Popen(
        [
            sys.executable, "-m", "chaintwin", "serve", "--db", url, "--no-web",
            "--watch", str(drop), "--settle-s", str(args.settle_s),
            "--order-window-s", "0",  # the pipeline's latency, without the order window
            "--notify-url", f"http://127.0.0.1:{hook.server_address[1]}/hook",
            "--notify-secret-file", str(work / "notify.key"),
        ],
        stderr=log, stdout=subprocess.DEVNULL, env=env,
    )  # fmt: skip
    log.close()
    deadline = time.monotonic() + 120
    while "following " + str(drop) not in (work / "serve.log").read_text():
        if proc.poll() is not None or time.monotonic() > deadline:
            sys.exit(f"the service did not start: {(work / 'serve.log').read_text()[-2000:]}")
        time.sleep(0.1)
    rss_start = psutil.Process(proc.pid).memory_info().rss

    written: dict[str, float] = {}  # file -> wall time complete, s since the epoch
    lock = threading.Lock()
    stop = threading.Event()

    def publish(k: int, cid: str) -> None:
        n = 0
        start = time.monotonic() + k * args.interval / len(ids)  # spread over the interval
        while not stop.is_set():
            wait = start + n * args.interval - time.monotonic()
            if wait > 0 and stop.wait(wait):
                return
            name = drop / cid / f"{cid}-{n:05d}.csv"
            bad = k == 0 and n >= args.onset
            source = faulty[n % len(faulty)] if bad else texts[n % len(texts)]
            text = as_conveyor(source, cid, datetime.now(UTC))
            part = name.with_suffix(".csv.part")
            part.write_text(text)
            part.rename(name)  # complete now
            with lock:
                written[str(name)] = time.time()
            n += 1

    print(
        f"{len(ids)} sources every {args.interval:g} s for {args.seconds:g} s ...",
        file=sys.stderr,
    )
    threads = [threading.Thread(target=publish, args=(k, c)) for k, c in enumerate(ids)]
    for t in threads:
        t.start()
    service = psutil.Process(proc.pid)
    rss: list[float] = []  # the service's resident size every tenth of the run, MB
    samples: list[tuple[float, float]] = []  # (s since the start, RSS MB) with --memory
    begun = time.monotonic()
    every = min(args.memory_every, args.seconds / 10)
    marks = [begun + args.seconds * (k + 1) / 10 for k in range(10)]
    snapped = False
    while marks:
        now = time.monotonic()
        if args.tracemalloc and not snapped and now - begun >= args.warmup_s:
            os.kill(proc.pid, signal.SIGUSR1)  # the snapshot after the warm-up
            snapped = True
        if now >= marks[0]:
            marks.pop(0)
            rss.append(service.memory_info().rss / 2**20)
        if args.memory:
            samples.append((now - begun, service.memory_info().rss / 2**20))
        time.sleep(max(0.0, min(every, (marks[0] if marks else now) - time.monotonic())))
    stop.set()
    for t in threads:
        t.join()
    # the last ones: settle plus their ingest
    store = Store(url)
    deadline = time.monotonic() + args.settle_s + 60
    while True:
        with store.engine.connect() as c:
            n = len(list(c.execute(select(RecordingRow.id).where(RecordingRow.file.in_(written)))))
        if n >= len(written) or time.monotonic() > deadline:
            break
        time.sleep(0.5)
    time.sleep(2.0)  # the last notifications
    rss_end = psutil.Process(proc.pid).memory_info().rss
    growth = ""
    if args.tracemalloc:
        os.kill(proc.pid, signal.SIGUSR1)  # the snapshot at the end
        deadline = time.monotonic() + 300
        while not (traces / "snapshot-1.tracemalloc").exists() and time.monotonic() < deadline:
            time.sleep(0.5)
        time.sleep(2.0)  # written whole
        growth = tracemalloc_growth(traces, args.warmup_s, args.seconds)
    proc.terminate()
    code = proc.wait(60)
    # the reference again, on the store as the run left it (larger)
    after: list[float] = []
    for k in range(args.reference):
        path = ref_dir / f"ref-end-{k}.csv"
        path.write_text(as_conveyor(texts[k % len(texts)], "reference", datetime.now(UTC)))
        t = time.perf_counter()
        ingest([str(path)], ref_profile, store, workers=1)
        after.append(time.perf_counter() - t)
    warm_end = statistics.median(after)
    with store.engine.connect() as c:
        rows = c.execute(
            select(RecordingRow.file, ResultRow.stored_at).join(
                ResultRow, ResultRow.recording_id == RecordingRow.id
            )
        ).all()
        made = {r.id: r.created_at for r in c.execute(select(OutboxRow)).all()}
    store.close()
    hook.shutdown()
    notified = [
        received[i] - datetime.fromisoformat(at).timestamp()
        for i, at in made.items()
        if i in received
    ]
    latency = [
        datetime.fromisoformat(at).timestamp() - written[f] - args.settle_s
        for f, at in rows
        if f in written and at is not None
    ]
    if not latency:
        sys.exit("nothing was stored: see the service's log")
    p50, p95 = statistics.median(latency), pct(latency, 0.95)
    db = "PostgreSQL" if args.postgres else "SQLite"
    print(f"bench_live: {len(ids)} sources every {args.interval:g} s, {args.seconds:g} s, {db}")
    print(f"  reference ingest of one recording: {warm * 1000:.0f} ms warm (median of "
          f"{args.reference}), {cold * 1000:.0f} ms cold (first call)")  # fmt: skip
    print(f"  stored {len(latency)} of {len(written)} written; settle {args.settle_s:g} s")
    print(f"  latency complete+settle -> stored: median {p50 * 1000:.0f} ms, p95 "
          f"{p95 * 1000:.0f} ms, max {max(latency) * 1000:.0f} ms")  # fmt: skip
    print(f"  reference again at the end (store of {len(rows)} results): "
          f"{warm_end * 1000:.0f} ms")  # fmt: skip
    print(f"  p95 / reference (warm, start): {p95 / warm:.2f}x (target <= 3x); "
          f"/ reference (end): {p95 / warm_end:.2f}x; "
          f"/ reference (cold): {p95 / cold:.2f}x")  # fmt: skip
    if notified:
        worst = max(notified)
        print(f"  notifications: {len(notified)} of {len(made)} received; outbox -> received "
              f"max {worst * 1000:.0f} ms, {worst / warm:.2f}x the reference (target <= 2x "
              f"more than the recording's p95: {(p95 + worst) / p95:.2f}x of it)")  # fmt: skip
    else:
        print(f"  notifications: no alarm opened (belt-00 turns faulty after {args.onset} "
              f"recordings, {args.onset * args.interval:g} s; run longer)")  # fmt: skip
    print(f"  service RSS: {rss_start / 2**20:.0f} MB after start, "
          f"{rss_end / 2**20:.0f} MB at the end; exit code on SIGTERM {code}")  # fmt: skip
    print(f"  RSS every {args.seconds / 10:g} s: {' '.join(f'{m:.0f}' for m in rss)} MB")
    if args.memory:
        print(memory_report(samples, args.warmup_s, rss_start / 2**20, rss_end / 2**20))
        logged = [
            line.split("memory: ", 1)[1]
            for line in (work / "serve.log").read_text().splitlines()
            if "memory: rss" in line
        ]
        print("  the service's own log each minute (MB; before/after handing free heap back):")
        for line in logged:
            print(f"    {line}")
    if growth:
        print(growth)


def memory_report(
    samples: list[tuple[float, float]], warmup_s: float, start_mb: float, end_mb: float
) -> str:
    """``--memory``: RSS every minute, and its growth after the warm-up (MB/min)."""
    lines = [f"  memory: RSS {start_mb:.1f} MB after start, {end_mb:.1f} MB at the end"]
    minute = [
        m
        for k, (t, m) in enumerate(samples)
        if k == 0 or int(t // 60) > int(samples[k - 1][0] // 60)
    ]
    lines.append("  RSS each minute: " + " ".join(f"{m:.0f}" for m in minute) + " MB")
    late = [(t, m) for t, m in samples if t >= warmup_s]
    if len(late) >= 3:
        tm = statistics.fmean(t for t, _ in late)
        mm = statistics.fmean(m for _, m in late)
        slope = sum((t - tm) * (m - mm) for t, m in late) / sum((t - tm) ** 2 for t, _ in late)
        lines.append(
            f"  growth after the warm-up ({warmup_s:g} s): {slope * 60:+.3f} MB/min "
            f"(least squares over {len(late)} samples; {late[0][1]:.1f} -> {late[-1][1]:.1f} MB)"
        )
    return "\n".join(lines)


def tracemalloc_growth(folder: Path, warmup_s: float, seconds: float) -> str:
    """``--tracemalloc``: the 15 lines whose allocations grew most between the snapshots."""
    import tracemalloc

    first = tracemalloc.Snapshot.load(str(folder / "snapshot-0.tracemalloc"))
    last = tracemalloc.Snapshot.load(str(folder / "snapshot-1.tracemalloc"))
    ignore = [tracemalloc.Filter(False, tracemalloc.__file__)]
    first, last = first.filter_traces(ignore), last.filter_traces(ignore)
    total = sum(s.size for s in last.statistics("filename")) - sum(
        s.size for s in first.statistics("filename")
    )
    lines = [
        f"  tracemalloc: traced memory grew {total / 2**20:+.2f} MB between {warmup_s:g} s "
        f"and the end ({seconds:g} s); the top 15 lines:"
    ]
    for stat in last.compare_to(first, "lineno")[:15]:
        frame = stat.traceback[0]
        lines.append(
            f"    {stat.size_diff / 2**10:+9.1f} KiB {stat.count_diff:+7d} blocks  "
            f"{frame.filename}:{frame.lineno}"
        )
    lines.append("  the top three's tracebacks (innermost last):")
    for stat in last.compare_to(first, "traceback")[:3]:
        lines.append(f"    {stat.size_diff / 2**10:+.1f} KiB in {stat.count_diff:+d} blocks:")
        lines.extend(f"      {line}" for line in stat.traceback.format())
    return "\n".join(lines)


if __name__ == "__main__":
    main()
