"""Benchmark: the live service over OPC UA, the whole chain and its OPC UA leg (a script).

**The whole chain** (the default): ``--drives`` (20) simulated drives in a
child process publish a scope every ``--interval`` (2 s); ``chaintwin serve
--no-web --opcua CONFIG`` in its own process follows them into a SQLite
store that holds each conveyor's calibration, and posts the alarms to a
webhook receiver in this process. The first drive turns faulty (friction)
after ``--onset`` scopes, which opens an alarm. All three processes share
the machine's 2 cores. Prints

1. reference: ``ingest()`` of one recording in this process (read,
   validate, weigh, monitor, store), the median of ``--ref-rounds``, at the
   start and again at the end of the run;
2. the chain: from a scope's trigger time (``recorded_at``, taken when the
   simulator starts the scope, a few milliseconds before its counter
   changes: the chain is over-estimated by that) to its result stored
   (``results.stored_at``): median, p95, max, and the p95's ratio to the
   reference (target: within 5x);
3. the alarm's notification: from the trigger of the scope that opened it
   to the webhook receiving it, and its ratio to the reference (target:
   within 2x more than the recordings', i.e. 10x), and from the result
   stored (its outbox row) to received;
4. scopes published, stored, the service's resident memory.

Beside 2., the service's own part (from the recording handed to ``submit``
to its result stored: spool file, queue, ingest; from the service's log),
the CPU the service and the drives used while followed, and the load
average.

``--leg-only`` times the OPC UA leg alone, as below.

**The OPC UA leg** (``--leg-only``): ``--drives`` (20) simulated drives
(:class:`chaintwin.live.drive_sim.DriveSim`, the reference conveyor
white-belt-01, one port each) run in a child process and publish a scope
every ``--interval`` (2 s), their phases spread over the interval as
unsynchronised drives are, for ``--seconds`` (60). This process follows them
with :func:`chaintwin.live.opcua.follow_drives` (one client task per drive)
and a ``submit`` that takes the recording and returns at once, so that what
is timed is the OPC UA leg alone: notification, one Read of the scope,
building the recording with the file reader's checks. Both processes share the
machine's 2 cores, as ``chaintwin demo --live`` does.

Prints:

1. reference: the library's ``ingest()`` of one recording into a SQLite
   store that holds the conveyor's calibration (read, validate, weigh,
   monitor, store), in this process after a warm-up: what the live service
   pays per recording; the median of ``--ref-rounds`` (3) recordings. Beside
   it, for the issue's wording ("the time ingest takes for one recording"),
   ``chaintwin ingest FILE --profiles DIR --db URL`` as a new process
   (interpreter start, imports, compilation), the median of as many;
2. the OPC UA leg: from a scope's trigger time (taken when the simulator
   starts simulating it, a few milliseconds before its counter changes: the
   leg is over-estimated by that) to the recording handed to ``submit``:
   median, p95 and maximum, and the p95's ratio to the reference (the
   issue's target for the whole chain, counter change to result stored, is
   a p95 within 5x the reference; this leg is the part before the ingest);
3. scopes published and read, counter gaps (missed) and refusals;
4. this process's resident memory at the start and the end of the run.

Run: ``.venv/bin/python benchmarks/bench_opcua.py [--drives 20] [--seconds 60]
[--leg-only]`` (starting the drives takes a few seconds each: asyncua builds
a server's standard address space).
"""

from __future__ import annotations

import argparse
import asyncio
import os
import re
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from datetime import UTC, datetime
from pathlib import Path

from chaintwin.identify.calibration import Calibration
from chaintwin.live.opcua import DriveStatus, OpcuaConfig, follow_drives
from chaintwin.read.profile import load_profile
from chaintwin.read.recording import Recording

PROFILE = Path(__file__).resolve().parents[1] / "chaintwin/examples/profiles/white-belt-01.yaml"


def rss_mb() -> float:
    """This process's resident set size, MB."""
    pages = int(Path("/proc/self/statm").read_text().split()[1])
    return pages * os.sysconf("SC_PAGE_SIZE") / 1e6


def conveyor_id(i: int) -> str:
    """The i-th simulated drive's conveyor id."""
    return f"belt-{i + 1:02d}"


def free_ports(n: int) -> list[int]:
    socks = []
    for _ in range(n):
        s = socket.socket()
        s.bind(("127.0.0.1", 0))
        socks.append(s)
    ports = [int(s.getsockname()[1]) for s in socks]
    for s in socks:
        s.close()
    return ports


# ---------------------------------------------------------------- the drives (child process)
async def serve(ports: list[int], interval: float, onset: int | None = None) -> None:
    """Run one DriveSim per port until SIGTERM; print ``ready`` once all listen.

    With ``onset``, the first drive's friction rises to its full fault after
    that many scopes (an alarm for the notification's timing).
    """
    from chaintwin.live.drive_sim import DriveSim
    from chaintwin.simulate.faults import Fault

    profile = load_profile(PROFILE)
    sims = [
        DriveSim(
            profile.model_copy(update={"id": conveyor_id(i)}),
            port=p,
            host="127.0.0.1",
            interval_s=interval,
            seed=i,
            faults=[Fault("friction", 1.0)] if onset is not None and i == 0 else (),
            onset=onset or 0,
        )
        for i, p in enumerate(ports)
    ]
    for sim in sims:
        await sim.start()
    await asyncio.to_thread(sims[0].simulate)  # compile the kernels before the clock starts
    stop = asyncio.Event()
    asyncio.get_running_loop().add_signal_handler(signal.SIGTERM, stop.set)
    print("ready", flush=True)

    async def one(i: int) -> None:
        await asyncio.sleep(i * interval / len(sims))  # unsynchronised drives
        await sims[i].run(stop)

    await asyncio.gather(*(one(i) for i in range(len(sims))))
    print(f"published {sum(s.counter for s in sims)}", flush=True)


# ---------------------------------------------------------------- the reference
class Reference:
    """``ingest()`` of one recording into a store with the conveyor's calibration,
    in this process, timed (the chain's reference, measured in the same run)."""

    def __init__(self, work: Path, rounds: int) -> None:
        from chaintwin.calibrating.procedure import calibrate
        from chaintwin.simulate.fleet import generate
        from chaintwin.store import Store
        from chaintwin.validate import load_recording

        self.profile = load_profile(PROFILE)
        self.rounds = rounds
        folder = work / "reference"
        generate(self.profile, folder, days=1, per_day=2 * rounds + 2, seed=3)
        cal_files = sorted((folder / "calibration").glob("*.csv"))
        self.calibration = calibrate(
            [load_recording(p, profile=self.profile).recording for p in cal_files], self.profile
        )
        self.files = sorted(str(p) for p in folder.glob("*.csv"))
        self.store = Store(f"sqlite:///{work}/reference.db")
        self.store.put_calibration(self.calibration)
        self.used = 0

    def time(self, warm_up: bool) -> float:
        """The median time of ``rounds`` ingests of one recording, s."""
        from chaintwin.ingest.pipeline import ingest

        times = []
        for k in range(self.rounds + (1 if warm_up else 0)):
            f = self.files[self.used]
            self.used += 1
            t0 = time.perf_counter()
            summary = ingest([f], {self.profile.id: self.profile}, self.store, workers=1)
            if k > 0 or not warm_up:  # the first one compiles and warms up
                times.append(time.perf_counter() - t0)
            assert summary.refused == 0, summary.refusals
        return statistics.median(times)


def conveyor_calibration(base: Calibration, cid: str) -> Calibration:
    """The calibration of a conveyor like ``base`` under another id."""
    from chaintwin.identify.calibration import Calibration

    prof = load_profile(PROFILE).model_copy(update={"id": cid})
    data = base.to_dict() | {
        "conveyor": cid,
        "profile": prof.model_dump(mode="json"),
        "profile_sha256": prof.content_hash(),
    }
    return Calibration.from_dict(data, f"bench {cid}")


def start_drives(ports: list[int], interval: float, onset: int | None) -> subprocess.Popen[str]:
    """The drives' child process, once all listen."""
    root = Path(__file__).resolve().parents[1]
    env = {**os.environ, "PYTHONPATH": str(root), "OPENBLAS_NUM_THREADS": "1"}
    cmd = [sys.executable, __file__, "--serve", ",".join(map(str, ports))]
    cmd += ["--interval", str(interval)]
    if onset is not None:
        cmd += ["--onset", str(onset)]
    child = subprocess.Popen(
        cmd, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, env=env
    )
    assert child.stdout is not None
    line = child.stdout.readline()
    if line.strip() != "ready":
        raise SystemExit(f"the drives did not start: {line!r}")
    return child


def chain(args: argparse.Namespace) -> None:
    """The whole chain: drives -> ``chaintwin serve --opcua`` -> store -> webhook."""
    import shutil

    import psutil
    from sqlalchemy import select
    from webhook_receiver import start_receiver

    from chaintwin.store import Store
    from chaintwin.store.schema import OutboxRow, RecordingRow, ResultRow

    work = Path(tempfile.mkdtemp(prefix="chaintwin-bench-opcua-"))
    try:
        print("reference and calibrations ...", file=sys.stderr)
        ref = Reference(work, args.ref_rounds)
        ref_start = ref.time(warm_up=True)
        url = f"sqlite:///{work}/plant.db"
        store = Store(url)
        cids = [conveyor_id(i) for i in range(args.drives)]
        for cid in cids:
            store.put_calibration(conveyor_calibration(ref.calibration, cid))
        store.close()

        hook, received = start_receiver()  # when each notification arrived
        (work / "notify.key").write_text("bench-secret\n")

        print(f"starting {args.drives} drives ...", file=sys.stderr)
        ports = free_ports(args.drives)
        t0 = time.perf_counter()
        drives = start_drives(ports, args.interval, args.onset)
        started = time.perf_counter() - t0
        config = work / "drives.yaml"
        config.write_text(
            "drives:\n"
            + "".join(
                f"  - conveyor: {cid}\n    endpoint: opc.tcp://127.0.0.1:{p}\n"
                for cid, p in zip(cids, ports, strict=True)
            )
        )
        root = Path(__file__).resolve().parents[1]
        env = {**os.environ, "PYTHONPATH": str(root), "OPENBLAS_NUM_THREADS": "1"}
        log_path = work / "serve.log"
        with log_path.open("wb") as log:
            service = subprocess.Popen(
                [
                    sys.executable, "-m", "chaintwin", "serve", "--no-web", "--db", url,
                    "--opcua", str(config),
                    "--notify-url", f"http://127.0.0.1:{hook.server_address[1]}/hook",
                    "--notify-secret-file", str(work / "notify.key"),
                ],
                stdout=subprocess.DEVNULL, stderr=log, env=env,
            )  # fmt: skip
        deadline = time.monotonic() + 120
        while log_path.read_text().count(" connected (") < args.drives:
            if service.poll() is not None or time.monotonic() > deadline:
                drives.terminate()
                raise SystemExit(f"the service did not connect: {log_path.read_text()[-2000:]}")
            time.sleep(0.2)
        ps = psutil.Process(service.pid)
        sims = psutil.Process(drives.pid)
        rss_start = ps.memory_info().rss / 2**20
        begun = datetime.now(UTC)
        load_start = os.getloadavg()[0]
        cpu_start = (sum(ps.cpu_times()[:2]), sum(sims.cpu_times()[:2]), time.monotonic())
        print(f"following for {args.seconds:g} s ...", file=sys.stderr)
        rss = []
        for _ in range(10):
            time.sleep(args.seconds / 10)
            rss.append(ps.memory_info().rss / 2**20)
        followed = time.monotonic() - cpu_start[2]
        cpu_service = (sum(ps.cpu_times()[:2]) - cpu_start[0]) / followed
        cpu_drives = (sum(sims.cpu_times()[:2]) - cpu_start[1]) / followed
        load_end = os.getloadavg()[0]
        drives.send_signal(signal.SIGTERM)
        tail = drives.stdout.read() if drives.stdout else ""
        drives.wait(30)
        published = int(tail.split()[-1]) if tail.strip() else -1
        time.sleep(3.0)  # the last results and notifications
        rss_end = ps.memory_info().rss / 2**20
        service.send_signal(signal.SIGTERM)
        code = service.wait(60)
        log_text = log_path.read_text()
        hook.shutdown()
        ref_end = ref.time(warm_up=False)
        ref.store.close()

        store = Store(url)
        with store.engine.connect() as c:
            rows = c.execute(
                select(RecordingRow.file, RecordingRow.recorded_at, ResultRow.stored_at).join(
                    ResultRow, ResultRow.recording_id == RecordingRow.id
                )
            ).all()
            outbox = c.execute(select(OutboxRow.id, OutboxRow.at, OutboxRow.created_at)).all()
        store.close()
        warm_from = begun.timestamp() + 5.0  # the scopes taken on connecting are older
        latency = []
        timed = []
        for f, at, stored_at in rows:
            if at is None or stored_at is None:
                continue
            trig = datetime.fromisoformat(at).timestamp()
            if trig >= warm_from:
                latency.append(datetime.fromisoformat(stored_at).timestamp() - trig)
                timed.append(str(f))
        if not latency:
            raise SystemExit(f"nothing was stored: {log_path.read_text()[-2000:]}")
        latency.sort()
        p50, p95 = statistics.median(latency), latency[int(0.95 * (len(latency) - 1))]
        # the service's own part: from the recording handed to submit to its result stored,
        # of the scopes timed above
        logged = {
            m[1]: float(m[2]) for m in re.finditer(r"stored (opcua://\S+) in ([0-9.]+) s", log_text)
        }
        handed = sorted(logged[f] for f in timed if f in logged)
        named = sum(1 for f, _a, _s in rows if str(f).startswith("opcua://"))
        print(
            f"bench_opcua, the whole chain: {args.drives} drives, a scope every "
            f"{args.interval:g} s each, {args.seconds:g} s (drives started in {started:.0f} s)"
        )
        print(
            f"  1. reference ingest() of one recording: {ref_start * 1e3:.0f} ms at the start, "
            f"{ref_end * 1e3:.0f} ms at the end (medians of {args.ref_rounds})"
        )
        print(
            f"  2. counter change -> result stored: median {p50 * 1e3:.0f} ms, p95 "
            f"{p95 * 1e3:.0f} ms, max {latency[-1] * 1e3:.0f} ms over {len(latency)} scopes; "
            f"p95 / reference {p95 / ref_start:.2f}x (start), {p95 / ref_end:.2f}x (end) "
            "(target <= 5x)"
        )
        if handed:
            print(
                f"     of which submit -> result stored (spool file, queue, ingest): median "
                f"{statistics.median(handed) * 1e3:.0f} ms, p95 "
                f"{handed[int(0.95 * (len(handed) - 1))] * 1e3:.0f} ms"
            )
        print(
            f"     CPU while followed: service {cpu_service:.2f} cores, drives {cpu_drives:.2f} "
            f"cores; load average (1 min) {load_start:.2f} at the start, {load_end:.2f} at the end"
        )
        lines = []
        for oid, at, created in outbox:
            if oid not in received or at is None:
                continue
            whole = received[oid] - datetime.fromisoformat(at).timestamp()
            tail_s = received[oid] - datetime.fromisoformat(created).timestamp()
            lines.append(
                f"  3. notification {oid}: counter change -> received {whole * 1e3:.0f} ms "
                f"({whole / ref_start:.2f}x the reference, target <= 10x; "
                f"{whole / p95:.2f}x the recordings' p95, target <= 2x); result stored -> "
                f"received {tail_s * 1e3:.0f} ms"
            )
        print("\n".join(lines) if lines else f"  3. no alarm opened ({len(outbox)} in the outbox)")
        print(
            f"  4. published {published}, stored {len(rows)} (named opcua://: {named}); "
            f"service RSS {rss_start:.0f} MB after connecting, {rss_end:.0f} MB at the end "
            f"({' '.join(f'{m:.0f}' for m in rss)}); exit code on SIGTERM {code}"
        )
    finally:
        shutil.rmtree(work, ignore_errors=True)


def reference_ingest(rounds: int) -> tuple[float, float]:
    """Median times of ingesting one recording into a store with a calibration, s.

    Returns
    -------
    (float, float)
        ``chaintwin ingest`` as a new process, and ``ingest()`` in this process.
    """
    import logging

    from chaintwin.calibrating.procedure import calibrate
    from chaintwin.ingest.pipeline import ingest
    from chaintwin.simulate.fleet import generate
    from chaintwin.store import Store
    from chaintwin.validate import load_recording

    logging.getLogger("chaintwin").setLevel(logging.ERROR)
    profile = load_profile(PROFILE)
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "gen"
        generate(profile, folder, days=1, per_day=2 * rounds + 1, seed=3)
        cal_files = sorted((folder / "calibration").glob("*.csv"))
        cal = calibrate([load_recording(p, profile=profile).recording for p in cal_files], profile)
        files = sorted(str(p) for p in folder.glob("*.csv"))
        profiles = Path(tmp) / "profiles"
        profiles.mkdir()
        (profiles / "white-belt-01.yaml").write_bytes(PROFILE.read_bytes())
        url = f"sqlite:///{tmp}/ref.db"
        with Store(url) as store:
            store.put_calibration(cal)
            inproc = []
            for k, f in enumerate(files[: rounds + 1]):
                t0 = time.perf_counter()
                summary = ingest([f], {profile.id: profile}, store, workers=1)
                if k > 0:  # the first one compiles and warms up
                    inproc.append(time.perf_counter() - t0)
                assert summary.refused == 0, summary.refusals
        cli = []
        env = {**os.environ, "PYTHONPATH": str(PROFILE.parents[3])}
        for f in files[rounds + 1 : 2 * rounds + 1]:
            t0 = time.perf_counter()
            cmd = [sys.executable, "-m", "chaintwin", "ingest", f, "--profiles", str(profiles)]
            subprocess.run(
                [*cmd, "--db", url, "--workers", "1"],
                check=True,
                capture_output=True,
                env=env,
            )
            cli.append(time.perf_counter() - t0)
    return statistics.median(cli), statistics.median(inproc)


# ---------------------------------------------------------------- the clients (this process)
async def follow(ports: list[int], seconds: float) -> tuple[list[float], DriveStatus]:
    config = OpcuaConfig.model_validate(
        {
            "drives": [
                {"conveyor": conveyor_id(i), "endpoint": f"opc.tcp://127.0.0.1:{p}"}
                for i, p in enumerate(ports)
            ]
        }
    )
    latencies: list[float] = []
    warm_until = time.monotonic() + 5.0  # the scopes taken on connecting are not timed

    async def submit(recording: Recording, key: str) -> None:
        when = recording.metadata.recorded_at
        if when is not None and time.monotonic() > warm_until:
            latencies.append((datetime.now(UTC) - when).total_seconds())

    stop = asyncio.Event()
    status = DriveStatus()
    task = asyncio.create_task(follow_drives(config, submit, stop, status))
    end = time.monotonic() + seconds
    while (left := end - time.monotonic()) > 0:
        await asyncio.sleep(min(left, seconds / 10))
        RSS.append(rss_mb())
    stop.set()
    await task
    return latencies, status


RSS: list[float] = []
"""This process's resident memory, MB, sampled ten times over the run."""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--drives", type=int, default=20)
    parser.add_argument("--interval", type=float, default=2.0)
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--ref-rounds", type=int, default=3)
    parser.add_argument(
        "--onset", type=int, default=None, help="Scopes before the first drive turns faulty."
    )
    parser.add_argument("--leg-only", action="store_true", help="Time the OPC UA leg alone.")
    parser.add_argument("--serve", type=str, default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.serve is not None:
        asyncio.run(serve([int(p) for p in args.serve.split(",")], args.interval, args.onset))
        return
    if not args.leg_only:
        if args.onset is None:  # the baseline (20 scopes), then a few to open the alarm
            args.onset = 22
        chain(args)
        return

    ref, inproc = reference_ingest(args.ref_rounds)
    ports = free_ports(args.drives)
    root = Path(__file__).resolve().parents[1]
    env = {**os.environ, "PYTHONPATH": str(root)}
    t0 = time.perf_counter()
    child = subprocess.Popen(
        [
            sys.executable,
            __file__,
            "--serve",
            ",".join(map(str, ports)),
            "--interval",
            str(args.interval),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
        env=env,
    )
    assert child.stdout is not None
    line = child.stdout.readline()
    if line.strip() != "ready":
        raise SystemExit(f"the drives did not start: {line!r}")
    started = time.perf_counter() - t0
    rss_start = rss_mb()
    load_start = os.getloadavg()[0]
    latencies, status = asyncio.run(follow(ports, args.seconds))
    load_end = os.getloadavg()[0]
    rss_end = rss_mb()
    child.send_signal(signal.SIGTERM)
    tail = child.stdout.read()
    child.wait(30)
    published = int(tail.split()[-1]) if tail.strip() else -1

    latencies.sort()
    p95 = latencies[int(0.95 * (len(latencies) - 1))] if latencies else float("nan")
    p50 = statistics.median(latencies) if latencies else float("nan")
    states = status.drives.values()
    print(
        f"OPC UA leg: {args.drives} drives, a scope every {args.interval:g} s each, "
        f"{args.seconds:g} s (drives started in {started:.0f} s; load average "
        f"{load_start:.2f} at the start, {load_end:.2f} at the end)"
    )
    print(f"{'':44s}{'ms':>10s}{'ratio':>8s}")
    rows = [
        ("1. reference: ingest() of one recording", inproc),
        ("   chaintwin ingest (a new process), one", ref),
        ("2. trigger -> recording handed over, median", p50),
        ("   p95", p95),
    ]
    for label, seconds in rows:
        print(f"{label:44s}{seconds * 1e3:10.1f}{seconds / inproc:8.2f}")
    print(f"{'   max':44s}{latencies[-1] * 1e3 if latencies else float('nan'):10.1f}")
    print(
        f"3. published {published}, read {sum(s.scopes_read for s in states)} "
        f"({len(latencies)} timed), missed {sum(s.missed for s in states)}, "
        f"refused {sum(s.refused for s in states)}, reconnections "
        f"{sum(max(s.connects - 1, 0) for s in states)}"
    )
    print(f"   p95 / chaintwin ingest: {p95 / ref:.3f}")
    print(
        f"4. resident memory of this process: {rss_start:.0f} MB at the start, "
        f"{rss_end:.0f} MB at the end (over the run: {', '.join(f'{m:.0f}' for m in RSS)})"
    )


if __name__ == "__main__":
    main()
