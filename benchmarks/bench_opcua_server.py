"""Benchmark: the OPC UA server of the results under load (a script, not a test).

Scenario: a store of ``--conveyors`` conveyors (200), each with a complete
baseline, features and stored forecasts (one virtual conveyor's recordings
ingested for real, its health model and forecasts copied to the others
under their own ids and profiles: their ``Value`` nodes stay empty, as they
hold no recording, every other node is filled); ``chaintwin serve
--no-web --opcua-endpoint`` in its own process (Basic256Sha256
sign-and-encrypt, a token user, the client certificate trusted); a second
process of ``--clients`` asyncua clients (20), each subscribed to
``Payload``, ``HealthIndex``, ``DeviceHealth`` and ``LastRecordedAt`` of
every conveyor (publishing every 0.5 s). After a warm-up, this script
stores ``--recordings`` new recordings of the real conveyor, one every
``--interval`` s, by ``ingest`` in this process, and prints

1. the serving process's CPU seconds per stored recording (its user+system
   time over the ingest window, divided by the recordings; its idle polling
   counted), one ingest's CPU seconds (this process's, per recording) and
   their ratio (target at most 0.2);
2. the commit-to-client latency: from each result's ``stored_at`` to its
   ``LastRecordedAt`` data change reaching each client: median, p99, max
   (target p99 at most 2 s);
3. the serving process's resident memory after the warm-up, sampled every
   5 s, and its slope (least squares, MB/min; target at most 0.1 over an
   hour: run ``--minutes 60`` for that, the default run is a few minutes).

``--clients N`` sets the number of subscribed clients (0: none, the serving
process's own work alone) and ``--security none`` serves and connects
without encryption (the token user's password then crosses in clear: for
measuring what encryption costs, not for a plant), so a sweep of both gives
the fixed and the per-client cost of a recording.

``--idle-s S`` keeps the server idle with its clients for S s after the
warm-up and prints its CPU rate (with ``--profile``, that window is the one
profiled); ``--recordings 0`` stops there.

Run: ``.venv/bin/python benchmarks/bench_opcua_server.py`` (about 5 minutes
on a 2-core machine: the simulation, the ingest of the history, the
server's start, the run).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import resource
import shutil
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
PATHS = (
    "Monitoring/Payload",
    "Monitoring/HealthIndex",
    "DeviceHealth",
    "Monitoring/LastRecordedAt",
)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _cpu_s(pid: int) -> float:
    """User + system CPU seconds of a process (Linux /proc)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    return float("nan")


def _own_cpu_s() -> float:
    own = resource.getrusage(resource.RUSAGE_SELF)
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def _slope_mb_min(samples: list[tuple[float, float]]) -> float:
    if len(samples) < 3:
        return float("nan")
    t = [s[0] / 60.0 for s in samples]
    m = [s[1] for s in samples]
    tm, mm = statistics.fmean(t), statistics.fmean(m)
    den = sum((x - tm) ** 2 for x in t)
    return sum((x - tm) * (y - mm) for x, y in zip(t, m, strict=True)) / den


# ---------------------------------------------------------------- the clients' process
def clients_child(
    endpoint: str, count: int, conveyors: list[str], cert: str, key: str, security: str
) -> None:
    """``count`` clients subscribed to every conveyor's values; one JSON line per
    ``LastRecordedAt`` change of the first conveyor (client, value, arrival time).
    ``security`` is the server's ``--opcua-security`` (``none``: no certificate)."""
    from asyncua import Client, ua
    from asyncua.crypto.security_policies import SecurityPolicyBasic256Sha256

    from chaintwin.live.opcua_nodes import NAMESPACE_URI, node_id

    user, token = os.environ["BENCH_USER"], os.environ["BENCH_TOKEN"]
    watched = node_id(conveyors[0], "Monitoring/LastRecordedAt")

    class Handler:
        def __init__(self, k: int) -> None:
            self.k = k

        def datachange_notification(self, node: Any, val: Any, data: Any) -> None:
            if node.nodeid.Identifier == watched and val is not None:
                line = {"client": self.k, "value": val.isoformat(), "t": time.time()}
                print(json.dumps(line), flush=True)

    async def one(k: int) -> Client:
        # a loaded machine answers late: asyncua's watchdog gives the server 1 s by default
        client = Client(endpoint, timeout=120, watchdog_intervall=30.0)
        client.application_uri = "urn:chaintwin:bench"
        if security != "none":
            await client.set_security(
                SecurityPolicyBasic256Sha256, certificate=cert, private_key=key,
                mode=ua.MessageSecurityMode.SignAndEncrypt,
            )  # fmt: skip
        client.set_user(user)
        client.set_password(token)
        await client.connect()
        ns = await client.get_namespace_index(NAMESPACE_URI)
        sub = await client.create_subscription(500, Handler(k))
        nodes = [
            client.get_node(ua.NodeId(ua.String(node_id(c, p)), ua.Int16(ns)))
            for c in conveyors
            for p in PATHS
        ]
        for i in range(0, len(nodes), 200):
            await sub.subscribe_data_change(nodes[i : i + 200])
        return client

    async def main() -> None:
        clients = [await one(k) for k in range(count)]
        print(json.dumps({"ready": len(clients)}), flush=True)
        stop = asyncio.Event()
        asyncio.get_running_loop().add_signal_handler(signal.SIGTERM, stop.set)
        await stop.wait()
        for c in clients:
            await c.disconnect()

    asyncio.run(main())


# ---------------------------------------------------------------- the profiled server
def serve_profiled(out: str, argv: list[str]) -> None:
    """``chaintwin serve`` with yappi (CPU clock, every thread) at hand: SIGUSR1 starts it
    (the start of the measured window), SIGUSR2 stops it and writes the functions' own and
    cumulative CPU time to ``out`` (the end of it)."""
    import yappi

    from chaintwin.cli import main as cli_main

    def clear(*_: Any) -> None:
        yappi.start(builtins=True, profile_threads=True)

    def dump(*_: Any) -> None:
        yappi.stop()
        stats = yappi.get_func_stats()
        lines = []
        for key in ("tsub", "ttot"):
            stats.sort(key, "desc")
            lines.append(f"# by {key}: ncall tsub ttot  function (file:line)")
            for f in list(stats)[:60]:
                lines.append(
                    f"{f.ncall:9d} {f.tsub:8.3f} {f.ttot:8.3f}  {f.name} "
                    f"({Path(f.module).name}:{f.lineno})"
                )
        threads = yappi.get_thread_stats()
        lines.append("# threads: name ttot")
        lines += [f"{t.name} {t.ttot:.3f}" for t in threads]
        Path(out).write_text("\n".join(lines) + "\n")

    signal.signal(signal.SIGUSR1, clear)
    signal.signal(signal.SIGUSR2, dump)
    yappi.set_clock_type("cpu")
    sys.argv = ["chaintwin", *argv]
    cli_main()


# ---------------------------------------------------------------- the store
def build_store(work: Path, conveyors: int, history: int, extra: int) -> tuple[str, list[Path]]:
    """A store of ``conveyors`` conveyors; returns its URL and the recordings kept back."""
    from sqlalchemy import select
    from sqlalchemy.orm import Session

    from chaintwin.calibrating import calibrate
    from chaintwin.diagnose.records import MonitorSettings
    from chaintwin.ingest import ingest
    from chaintwin.read.profile import load_profile
    from chaintwin.simulate.faults import Fault
    from chaintwin.simulate.fleet import generate
    from chaintwin.store.schema import DerivedHealthRow, MonitorStateRow
    from chaintwin.store.store import Store
    from chaintwin.validate import load_recording

    profile = load_profile(ROOT / "chaintwin" / "examples" / "profiles" / "white-belt-01.yaml")
    folder = work / "fleet"
    per_day = 8
    days = max(4, -(-(history + extra) // per_day))
    t0 = time.perf_counter()
    generate(
        profile, folder, days=days, per_day=per_day, faults=[Fault("friction", 0.6)],
        onset_day=days // 2, seed=7,
    )  # fmt: skip
    files = sorted(folder.glob("*.csv"))
    url = f"sqlite:///{work / 'plant.db'}"
    store = Store(url)
    recs = [
        load_recording(f, profile=profile).recording
        for f in sorted((folder / "calibration").glob("*.csv"))
    ]
    store.put_calibration(calibrate(recs, profile))
    ingest(
        [str(f) for f in files[:history]], {profile.id: profile}, store,
        settings=MonitorSettings(baseline_n=5), workers=1,
    )  # fmt: skip
    with Session(store.engine) as s:
        state = s.get(MonitorStateRow, profile.id)
        derived = s.get(DerivedHealthRow, profile.id)
        assert state is not None and derived is not None, "no health model or forecasts"
        state_doc, derived_row = dict(state.state), derived
        derived_cols = {
            c: getattr(derived_row, c) for c in ("inputs", "latest", "computed_at", "content")
        }
    for k in range(1, conveyors):
        clone = profile.model_copy(update={"id": f"{profile.id}-{k:03d}"})
        store.put_profile(clone)
        doc = dict(state_doc, conveyor=clone.id, profile_sha256=clone.content_hash())
        now = datetime.now(UTC).isoformat()
        with Session(store.engine) as s, s.begin():
            s.add(MonitorStateRow(conveyor_id=clone.id, state=doc, updated_at=now, version=1))
            s.add(DerivedHealthRow(conveyor_id=clone.id, **derived_cols))
    with Session(store.engine) as s:
        n = len(s.execute(select(MonitorStateRow.conveyor_id)).all())
    store.close()
    print(
        f"store: {n} conveyors with health models ({history} recordings ingested, "
        f"{time.perf_counter() - t0:.0f} s to build)",
        flush=True,
    )
    return url, files[history : history + extra]


# ---------------------------------------------------------------- the run
def run(args: argparse.Namespace, work: Path) -> None:
    from asyncua.crypto.cert_gen import setup_self_signed_certificate
    from cryptography.x509.oid import ExtendedKeyUsageOID
    from sqlalchemy import select
    from sqlalchemy.orm import Session

    from chaintwin.ingest import ingest
    from chaintwin.read.profile import load_profile
    from chaintwin.store.schema import ResultRow
    from chaintwin.store.store import Store
    from chaintwin.web.access import create_token

    pristine, held_list = work / "plant-before-run.db", work / "held.json"
    if args.keep is not None and pristine.exists() and held_list.exists():  # built before
        shutil.copy(pristine, work / "plant.db")
        for side in ("plant.db-wal", "plant.db-shm"):
            (work / side).unlink(missing_ok=True)
        url, held = (
            f"sqlite:///{work / 'plant.db'}",
            [Path(p) for p in json.loads(held_list.read_text())],
        )
        held = held[: args.recordings]
        print(f"store: the one built before in {work}", flush=True)
    else:
        # a kept store holds back at least 40 recordings for later runs
        extra = max(args.recordings, 40) if args.keep is not None else args.recordings
        url, held = build_store(work, args.conveyors, args.history, extra)
        if args.keep is not None:  # kept for the next run with the same --keep
            import sqlite3

            with sqlite3.connect(work / "plant.db") as src, sqlite3.connect(pristine) as dst:
                src.backup(dst)
            held_list.write_text(json.dumps([str(p) for p in held]))
        held = held[: args.recordings]
    profile = load_profile(ROOT / "chaintwin" / "examples" / "profiles" / "white-belt-01.yaml")
    store = Store(url)
    user = f"bench-{int(time.time())}"  # a store kept from an earlier run has its own
    token = create_token(store, user, "viewer")
    pki = work / "pki"
    (pki / "trusted" / "certs").mkdir(parents=True, exist_ok=True)
    cert, key = work / "client.der", work / "client.pem"
    asyncio.run(
        setup_self_signed_certificate(
            key, cert, "urn:chaintwin:bench", socket.gethostname(),
            [ExtendedKeyUsageOID.CLIENT_AUTH], {"organizationName": "bench"},
        )
    )  # fmt: skip
    shutil.copy(cert, pki / "trusted" / "certs" / "bench.der")
    endpoint = f"opc.tcp://127.0.0.1:{_free_port()}"
    env = dict(os.environ, PYTHONPATH=str(ROOT), OPENBLAS_NUM_THREADS="1")
    log = work / "serve.log"
    serve = ["serve", "--db", url, "--no-web", "--opcua-endpoint", endpoint,
             "--opcua-cert-dir", str(pki), "--opcua-security", args.security]  # fmt: skip
    head = [sys.executable, "-m", "chaintwin"]
    if args.profile is not None:
        head = [sys.executable, __file__, "--serve-profiled", str(args.profile.resolve())]
    server = subprocess.Popen(
        [*head, *serve],
        stdout=subprocess.DEVNULL, stderr=log.open("wb"), env=env, cwd=work,
    )  # fmt: skip
    clients = None
    try:
        t0 = time.perf_counter()
        while "OPC UA server at" not in log.read_text(errors="replace"):
            if server.poll() is not None:
                raise SystemExit(f"serve ended: {log.read_text()[-2000:]}")
            time.sleep(0.5)
        listening = time.perf_counter() - t0
        while "conveyors published in" not in log.read_text(errors="replace"):
            if server.poll() is not None:
                raise SystemExit(f"serve ended: {log.read_text()[-2000:]}")
            time.sleep(0.5)
        print(
            f"server: listening after {listening:.1f} s, every conveyor published after "
            f"{time.perf_counter() - t0:.1f} s",
            flush=True,
        )
        ids = [profile.id] + [f"{profile.id}-{k:03d}" for k in range(1, args.conveyors)]
        (work / "ids.json").write_text(json.dumps(ids))
        clients = subprocess.Popen(
            [sys.executable, __file__, "--clients-child", endpoint, str(args.clients),
             str(work / "ids.json"), str(cert), str(key), args.security],
            stdout=subprocess.PIPE, stderr=(work / "clients.log").open("wb"), text=True,
            env=dict(env, BENCH_USER=user, BENCH_TOKEN=token),
        )  # fmt: skip
        arrivals: list[dict[str, Any]] = []
        ready = threading.Event()

        def read() -> None:
            assert clients is not None and clients.stdout is not None
            for line in clients.stdout:
                doc = json.loads(line)
                if "ready" in doc:
                    ready.set()
                else:
                    arrivals.append(doc)

        threading.Thread(target=read, daemon=True).start()
        t0 = time.perf_counter()
        while not ready.wait(1.0):
            if clients.poll() is not None:
                raise SystemExit(f"clients ended: {(work / 'clients.log').read_text()[-2000:]}")
        items = args.clients * args.conveyors * len(PATHS)
        print(
            f"clients: {args.clients} subscribed to {items} monitored items in all "
            f"after {time.perf_counter() - t0:.1f} s",
            flush=True,
        )
        idle0, idle_t0 = _cpu_s(server.pid), time.perf_counter()
        time.sleep(args.warmup_s)
        idle_rate = (_cpu_s(server.pid) - idle0) / (time.perf_counter() - idle_t0)
        if args.idle_s > 0:  # the idle server alone: its rate, profiled with --profile
            if args.profile is not None:
                server.send_signal(signal.SIGUSR1)
            idle0, idle_t0 = _cpu_s(server.pid), time.perf_counter()
            time.sleep(args.idle_s)
            long_rate = (_cpu_s(server.pid) - idle0) / (time.perf_counter() - idle_t0)
            if args.profile is not None:
                server.send_signal(signal.SIGUSR2)
                time.sleep(5.0)  # the profile written before the next window starts
            print(
                f"idle: {long_rate:.4f} CPU s/s over {args.idle_s:g} s with the clients "
                f"connected and no recording (the warm-up's: {idle_rate:.4f})",
                flush=True,
            )
        memory: list[tuple[float, float]] = []
        start = time.perf_counter()
        stop_sampling = threading.Event()

        def sample() -> None:
            while not stop_sampling.wait(5.0):
                memory.append((time.perf_counter() - start, _rss_mb(server.pid)))

        memory.append((0.0, _rss_mb(server.pid)))
        sampler = threading.Thread(target=sample, daemon=True)
        sampler.start()
        if args.profile is not None and args.idle_s <= 0:
            server.send_signal(signal.SIGUSR1)
        served0 = _cpu_s(server.pid)
        ingest_cpu = 0.0
        stored: list[str] = []
        wall0 = time.perf_counter()
        for k, path in enumerate(held):
            due = wall0 + k * args.interval
            time.sleep(max(0.0, due - time.perf_counter()))
            c0 = _own_cpu_s()
            ingest([str(path)], {profile.id: profile}, store, workers=1)
            ingest_cpu += _own_cpu_s() - c0
            with Session(store.engine) as s:
                row = s.execute(
                    select(ResultRow.recorded_at, ResultRow.stored_at)
                    .where(ResultRow.conveyor_id == profile.id)
                    .order_by(ResultRow.id.desc())
                    .limit(1)
                ).one()
            stored.append(f"{row.recorded_at}|{row.stored_at}")
        time.sleep(max(args.interval, 3.0))  # the last data changes arrive
        served = _cpu_s(server.pid) - served0
        window = time.perf_counter() - wall0
        if args.profile is not None and args.idle_s <= 0:
            server.send_signal(signal.SIGUSR2)
        # the rest of the memory run, without ingest
        while time.perf_counter() - start < args.minutes * 60.0:
            time.sleep(1.0)
        stop_sampling.set()
        sampler.join(10)
    finally:
        for proc in (clients, server):
            if proc is not None and proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
                try:
                    proc.wait(60)
                except subprocess.TimeoutExpired:
                    proc.kill()
        store.close()
    n = len(held)
    if n == 0:
        return
    per_served, per_ingest = served / n, ingest_cpu / n
    per_work = (served - idle_rate * window) / n
    print(
        f"\n1. CPU per stored recording ({n} recordings in {window:.0f} s): serving process "
        f"{per_served:.3f} s, one ingest {per_ingest:.3f} s; ratio {per_served / per_ingest:.3f} "
        f"(target <= 0.2). Of it, the serving process's idle rate with the clients connected "
        f"({idle_rate:.4f} CPU s/s over the {args.warmup_s:g} s warm-up, no recording) times "
        f"the window: {idle_rate * window / n:.3f} s; above idle {per_work:.3f} s per recording, "
        f"ratio {per_work / per_ingest:.3f}"
    )
    times = {}
    for text in stored:
        recorded, at = text.split("|")
        times[datetime.fromisoformat(recorded).astimezone(UTC)] = (
            datetime.fromisoformat(at).astimezone(UTC).timestamp()
        )
    lat = []
    for a in arrivals:
        when = datetime.fromisoformat(a["value"]).astimezone(UTC)
        if when in times:
            lat.append(a["t"] - times[when])
    lat.sort()
    want = n * args.clients
    if lat:
        p99 = lat[min(len(lat) - 1, round(0.99 * (len(lat) - 1)))]
        print(
            f"2. commit to data change ({len(lat)} of {want} expected notifications): median "
            f"{statistics.median(lat):.2f} s, p99 {p99:.2f} s, max {lat[-1]:.2f} s "
            "(target p99 <= 2 s)"
        )
    else:
        print(f"2. commit to data change: none of {want} notifications arrived")
    warm = [m for m in memory if m[0] >= 0.0]
    print(
        f"3. serving process memory: {warm[0][1]:.1f} MB after warm-up, {warm[-1][1]:.1f} MB "
        f"after {warm[-1][0] / 60:.1f} min; slope {_slope_mb_min(warm):+.3f} MB/min over "
        f"{len(warm)} samples (target <= 0.1 over an hour; this run: {args.minutes:g} min)"
    )


def main() -> None:
    if len(sys.argv) > 1 and sys.argv[1] == "--clients-child":
        endpoint, count, ids, cert, key, security = sys.argv[2:8]
        sys.path.insert(0, str(ROOT))
        clients_child(endpoint, int(count), json.loads(Path(ids).read_text()), cert, key, security)
        return
    if len(sys.argv) > 1 and sys.argv[1] == "--serve-profiled":
        sys.path.insert(0, str(ROOT))
        serve_profiled(sys.argv[2], sys.argv[3:])
        return
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--conveyors", type=int, default=200)
    ap.add_argument("--clients", type=int, default=20)
    ap.add_argument("--history", type=int, default=12, help="recordings ingested before")
    ap.add_argument("--recordings", type=int, default=30, help="recordings stored in the run")
    ap.add_argument("--interval", type=float, default=3.0, help="s between two recordings")
    ap.add_argument("--warmup-s", type=float, default=20.0)
    ap.add_argument("--minutes", type=float, default=3.0, help="length of the memory run")
    ap.add_argument(
        "--profile", type=Path,
        help="run the server under yappi and write its profile of the ingest window here",
    )  # fmt: skip
    ap.add_argument(
        "--idle-s", type=float, default=0.0,
        help="after the warm-up, this long with no recording: the idle rate printed, and "
        "profiled instead of the ingest window with --profile",
    )  # fmt: skip
    ap.add_argument(
        "--security", choices=("basic256sha256", "none"), default="basic256sha256",
        help="the server's --opcua-security and the clients' (none: no certificate)",
    )  # fmt: skip
    ap.add_argument("--keep", type=Path, help="work here and keep it (default: a temp folder)")
    args = ap.parse_args()
    if args.keep is not None:
        args.keep.mkdir(parents=True, exist_ok=True)
        run(args, args.keep)
        return
    with tempfile.TemporaryDirectory(prefix="bench-opcua-") as tmp:
        run(args, Path(tmp))


if __name__ == "__main__":
    main()
