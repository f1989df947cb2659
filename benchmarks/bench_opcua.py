"""Benchmark: the OPC UA leg of the live service (a script, not a test).

Scenario (issue 21): ``--drives`` (20) simulated drives
(:class:`chaintwin.live.drive_sim.DriveSim`, the reference conveyor
white-belt-01, one port each) run in a child process and publish a scope
every ``--interval`` (2 s), their phases spread over the interval as
unsynchronised drives are, for ``--seconds`` (60). This process follows them
with :func:`chaintwin.live.opcua.follow_drives` (one client task per drive)
and a ``submit`` that takes the recording and returns at once, so that what
is timed is the OPC UA leg alone: notification, one Read of the scope,
building the recording through the file reader. Both processes share the
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

Run: ``.venv/bin/python benchmarks/bench_opcua.py [--drives 20] [--seconds 60]``
(starting the drives takes about 4 s each: asyncua builds a server's
standard address space).
"""

from __future__ import annotations

import argparse
import asyncio
import os
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from datetime import UTC, datetime
from pathlib import Path

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
async def serve(ports: list[int], interval: float) -> None:
    """Run one DriveSim per port until SIGTERM; print ``ready`` once all listen."""
    from chaintwin.live.drive_sim import DriveSim

    profile = load_profile(PROFILE)
    sims = [
        DriveSim(
            profile.model_copy(update={"id": conveyor_id(i)}),
            port=p,
            host="127.0.0.1",
            interval_s=interval,
            seed=i,
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
def reference_ingest(rounds: int) -> tuple[float, float]:
    """Median times of ingesting one recording into a store with a calibration, s.

    Returns
    -------
    (float, float)
        ``chaintwin ingest`` as a new process, and ``ingest()`` in this process.
    """
    import logging

    from chaintwin.identify.calibrating import calibrate
    from chaintwin.simulate.fleet import generate
    from chaintwin.store import Store
    from chaintwin.store.ingest import ingest
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
        store = Store(url)
        try:
            store.put_calibration(cal)
            inproc = []
            for k, f in enumerate(files[: rounds + 1]):
                t0 = time.perf_counter()
                summary = ingest([f], {profile.id: profile}, store, workers=1)
                if k > 0:  # the first one compiles and warms up
                    inproc.append(time.perf_counter() - t0)
                assert summary.refused == 0, summary.refusals
        finally:
            store.close()
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
    parser.add_argument("--serve", type=str, default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.serve is not None:
        asyncio.run(serve([int(p) for p in args.serve.split(",")], args.interval))
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
    latencies, status = asyncio.run(follow(ports, args.seconds))
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
        f"{args.seconds:g} s (drives started in {started:.0f} s)"
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
