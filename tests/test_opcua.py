"""OPC UA: the drive simulator (a real asyncua server) followed by the client.

One simulator serves the whole session (asyncua's ``Server.init`` takes about
4 s); it runs in an event loop on a background thread, beside the clients
each test starts. The simulator's counter carries on from test to test, so
every test works relative to the scope it publishes.
"""

from __future__ import annotations

import asyncio
import hashlib
import json
import logging
import re
import socket
import threading
import time
from collections.abc import Callable, Coroutine, Iterator
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
import pytest
from conftest import REFERENCE_PROFILE

from chaintwin.errors import ConnectorError, RecordingError
from chaintwin.live.drive_sim import DriveSim, Published
from chaintwin.live.opcua import (
    MAX_MESSAGE_BYTES,
    MAX_SCOPE_SAMPLES,
    DriveState,
    DriveStatus,
    OpcuaConfig,
    follow_drives,
    load_opcua_config,
    recording_from_scope,
)
from chaintwin.live.scope_layout import DEFAULT_NODES
from chaintwin.read.formats import read_recording
from chaintwin.read.profile import load_profile
from chaintwin.read.recording import Recording
from chaintwin.read.writer import format_recording, write_recording
from chaintwin.simulate.faults import Fault
from chaintwin.validate import inspect_recording

T = TypeVar("T")
PROFILE = load_profile(REFERENCE_PROFILE)
CONVEYOR = PROFILE.id


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class Loop:
    """An asyncio event loop on a background thread; tests hand it coroutines."""

    def __init__(self) -> None:
        self.loop = asyncio.new_event_loop()
        self.thread = threading.Thread(target=self.loop.run_forever, daemon=True)
        self.thread.start()

    def run(self, coro: Coroutine[Any, Any, T], timeout: float = 30.0) -> T:
        return asyncio.run_coroutine_threadsafe(coro, self.loop).result(timeout)

    def close(self) -> None:
        async def cancel_the_rest() -> None:
            rest = [t for t in asyncio.all_tasks() if t is not asyncio.current_task()]
            for t in rest:
                t.cancel()
            await asyncio.gather(*rest, return_exceptions=True)

        self.run(cancel_the_rest())
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(10)
        self.loop.close()


@pytest.fixture(scope="session")
def certs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A self-signed server certificate (made by the simulator) and a client one."""
    from asyncua.crypto.cert_gen import setup_self_signed_certificate
    from cryptography.x509.oid import ExtendedKeyUsageOID

    folder = tmp_path_factory.mktemp("pki")
    paths = {
        "server_cert": folder / "server.der",
        "server_key": folder / "server.pem",
        "client_cert": folder / "client.der",
        "client_key": folder / "client.pem",
    }
    asyncio.run(
        setup_self_signed_certificate(
            paths["client_key"],
            paths["client_cert"],
            "urn:chaintwin:client",
            socket.gethostname(),
            [ExtendedKeyUsageOID.CLIENT_AUTH],
            {"organizationName": "chaintwin tests"},
        )
    )
    return paths


@pytest.fixture(scope="session")
def ua_loop() -> Iterator[Loop]:
    loop = Loop()
    yield loop
    loop.close()


@pytest.fixture(scope="session")
def sim(ua_loop: Loop, certs: dict[str, Path]) -> Iterator[DriveSim]:
    drive = DriveSim(
        PROFILE,
        port=_free_port(),
        host="127.0.0.1",
        seed=11,
        faults=[Fault("bearing", 0.6)],
        onset=2,
        certificate=certs["server_cert"],
        private_key=certs["server_key"],
        users={"operator": "s3cret"},  # anonymous clients are welcome too
    )
    ua_loop.run(drive.start())
    yield drive
    ua_loop.run(drive.stop())


class Follower:
    """``follow_drives`` running in the loop, with what it submitted."""

    def __init__(self, loop: Loop, config: OpcuaConfig, status: DriveStatus | None = None) -> None:
        self.loop = loop
        self.got: list[tuple[str, Recording]] = []
        self.status = status or DriveStatus()

        async def submit(recording: Recording, key: str) -> None:
            self.got.append((key, recording))

        async def start() -> tuple[asyncio.Event, asyncio.Task[None]]:
            stop = asyncio.Event()
            return stop, asyncio.create_task(follow_drives(config, submit, stop, self.status))

        self.stop, self.task = loop.run(start())

    def received(self) -> list[str]:
        return [k for k, _ in self.got]

    def recording(self, key: str) -> Recording:
        return dict(self.got)[key]

    def close(self) -> None:
        async def stop() -> None:
            self.stop.set()
            await asyncio.wait_for(self.task, 10)

        self.loop.run(stop())


def wait_until(what: str, check: Callable[[], bool], timeout: float = 15.0) -> None:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if check():
            return
        time.sleep(0.02)
    raise AssertionError(f"timed out waiting for {what}")


def config_for(*drives: dict[str, Any]) -> OpcuaConfig:
    return OpcuaConfig.model_validate(
        {"drives": list(drives), "reconnect": {"initial_s": 0.1, "max_s": 0.4}}
    )


@pytest.fixture
def follower(ua_loop: Loop, sim: DriveSim) -> Iterator[Follower]:
    """A client following the simulator with the minimal configuration, connected."""
    f = Follower(ua_loop, config_for({"conveyor": CONVEYOR, "endpoint": sim.endpoint}))
    wait_until("the connection", lambda: f.status.drives[CONVEYOR].connected)
    wait_until(  # the scope already in the buffer (if any) is taken on connecting
        "the current scope",
        lambda: sim.counter == 0 or f.status.drives[CONVEYOR].last_counter == sim.counter,
    )
    yield f
    f.close()


def key_of(scope: Published) -> str:
    return f"opcua:{CONVEYOR}:{scope.counter}"


# ---------------------------------------------------------------- tests
def test_scope_arrives_as_the_virtual_run_and_a_dead_drive_stops_nothing(
    ua_loop: Loop, sim: DriveSim
) -> None:
    dead = f"opc.tcp://127.0.0.1:{_free_port()}"  # nothing listens there
    f = Follower(
        ua_loop,
        config_for(
            {"conveyor": "short-fast-03", "endpoint": dead},
            {"conveyor": CONVEYOR, "endpoint": sim.endpoint},
        ),
    )
    try:
        wait_until("the connection", lambda: f.status.drives[CONVEYOR].connected)
        scopes = [ua_loop.run(sim.publish_next()) for _ in range(3)]
        wait_until("the last scope", lambda: key_of(scopes[-1]) in f.received())
        scope = scopes[-1]
        got = f.recording(key_of(scope))
        want = scope.recording
        # the same metadata and channels, in the same units, as the virtual run
        assert got.metadata == want.metadata
        assert got.metadata.conveyor == CONVEYOR and got.metadata.recorded_at is not None
        assert list(got.channels) == list(want.channels)
        assert got.units == want.units
        for name in want.channels:
            np.testing.assert_allclose(got.channels[name], want.channels[name], rtol=1e-12)
        assert got.source == key_of(scope)
        # as a file it is byte for byte the file of the virtual run
        assert format_recording(got) == format_recording(want)
        # it passes validation like the original: the same warnings
        assert [w.code for w in inspect_recording(got, PROFILE).recording.warnings] == [
            w.code for w in inspect_recording(want, PROFILE).recording.warnings
        ]
        # the fault (onset 2 scopes, no ramp) is in the scopes from the third on
        assert scope.faults == {"bearing": 0.6 if scope.counter >= 3 else 0.0}
        # the dead drive is retried, and did not hold the live one back
        dead_state = f.status.drives["short-fast-03"]
        assert not dead_state.connected and dead_state.connects == 0
        assert dead_state.last_error and "\n" not in dead_state.last_error
        live = f.status.drives[CONVEYOR]
        assert live.connected and live.last_counter == scope.counter
        assert live.last_scope_at is not None and live.last_error is None
        health = json.loads(json.dumps(f.status.to_dict()))  # what the health endpoint shows
        assert health[CONVEYOR]["connected"] is True
        assert health[CONVEYOR]["last_counter"] == scope.counter
        assert health["short-fast-03"]["connected"] is False
        assert health["short-fast-03"]["last_error"] == dead_state.last_error
    finally:
        f.close()
    assert not f.status.drives[CONVEYOR].connected


def test_counter_gaps_are_counted_as_missed(
    ua_loop: Loop, sim: DriveSim, follower: Follower
) -> None:
    state = follower.status.drives[CONVEYOR]
    before, read_before = state.missed, state.scopes_read
    ua_loop.run(sim.stop())  # the drive goes away ...
    wait_until("the loss", lambda: not state.connected)
    scopes = [ua_loop.run(sim.publish_next()) for _ in range(3)]  # ... and records 3 scopes
    ua_loop.run(sim.start())
    wait_until("the newest scope", lambda: key_of(scopes[-1]) in follower.received())
    assert state.missed == before + 2
    assert (
        key_of(scopes[0]) not in follower.received()
        and key_of(scopes[1]) not in follower.received()
    )
    assert state.scopes_read == read_before + 1
    # and the next scope follows without a gap
    nxt = ua_loop.run(sim.publish_next())
    wait_until("the next scope", lambda: key_of(nxt) in follower.received())
    assert state.missed == before + 2


def test_a_quiet_drive_keeps_its_subscription_and_a_new_scope_arrives_at_once(
    ua_loop: Loop, sim: DriveSim, follower: Follower, caplog: pytest.LogCaptureFixture
) -> None:
    """Seconds without a scope are the normal case: the subscription (10 ms publishing,
    keep-alives every 10 s) is not taken for stale and recreated, and the next counter
    change is heard through it (no new connection)."""
    import logging

    caplog.set_level(logging.WARNING, logger="asyncua")
    caplog.set_level(logging.DEBUG, logger="chaintwin.live.opcua")  # asyncua's, one line each
    time.sleep(2.5)  # longer than asyncua's stale check (1 s) and than a scope's interval
    assert not [r for r in caplog.records if "stale" in r.getMessage()]
    state = follower.status.drives[CONVEYOR]
    scope = ua_loop.run(sim.publish_next())
    wait_until("the scope", lambda: key_of(scope) in follower.received())
    assert state.connects == 1 and state.connected


def test_a_restarted_service_given_its_last_counter_counts_the_gap(
    ua_loop: Loop, sim: DriveSim
) -> None:
    # the service's previous run took the scope now in the buffer, then stopped
    ua_loop.run(sim.publish_next())
    status = DriveStatus({CONVEYOR: DriveState(sim.endpoint, last_counter=sim.counter)})
    scopes = [ua_loop.run(sim.publish_next()) for _ in range(2)]  # while it was down
    f = Follower(ua_loop, config_for({"conveyor": CONVEYOR, "endpoint": sim.endpoint}), status)
    try:
        wait_until("the newest scope", lambda: key_of(scopes[-1]) in f.received())
        assert f.received() == [key_of(scopes[-1])]
        assert status.drives[CONVEYOR].missed == 1
    finally:
        f.close()
    # the same conveyor at another endpoint is another drive: its counter starts afresh
    moved = DriveStatus({CONVEYOR: DriveState("opc.tcp://elsewhere:4840", last_counter=1)})
    f = Follower(ua_loop, config_for({"conveyor": CONVEYOR, "endpoint": sim.endpoint}), moved)
    try:
        wait_until("the scope", lambda: key_of(scopes[-1]) in f.received())
        assert moved.drives[CONVEYOR].missed == 0
        assert moved.drives[CONVEYOR].endpoint == sim.endpoint
    finally:
        f.close()


def test_drive_that_disconnects_mid_read_is_reconnected(
    ua_loop: Loop, sim: DriveSim, follower: Follower
) -> None:
    from asyncua import ua

    state = follower.status.drives[CONVEYOR]
    connects, missed = state.connects, state.missed
    assert sim.server is not None
    torque = sim.node_id("Torque")
    fired = threading.Event()

    async def publish_and_break() -> Published:
        scope = await asyncio.to_thread(sim.simulate)
        await sim.publish(scope)
        assert sim.server is not None
        saved = sim.server.read_attribute_value(torque)

        def on_read(_nodeid: ua.NodeId, _attr: ua.AttributeIds) -> ua.DataValue:
            if not fired.is_set():  # the first read of the scope: the network breaks
                fired.set()
                sim.drop_connections()
                asyncio.get_running_loop().create_task(sim.stop())
            return saved

        sim.server.set_attribute_value_callback(torque, on_read)
        return scope

    scope = ua_loop.run(publish_and_break())
    wait_until("the read that breaks", fired.is_set)
    wait_until("the loss", lambda: not state.connected)
    assert key_of(scope) not in follower.received()
    time.sleep(0.3)  # a few reconnect attempts against a closed port
    assert state.last_error is not None and not state.connected
    ua_loop.run(sim.start())
    wait_until("the scope after reconnecting", lambda: key_of(scope) in follower.received())
    assert state.connects == connects + 1 and state.missed == missed
    assert format_recording(follower.recording(key_of(scope))) == format_recording(scope.recording)
    # and it carries on
    nxt = ua_loop.run(sim.publish_next())
    wait_until("the next scope", lambda: key_of(nxt) in follower.received())
    assert state.missed == missed and state.last_error is None


class _Collect(logging.Handler):
    """The records that reach the root logger's handlers (what a service's log shows:
    pytest's own capture also listens on loggers that do not propagate)."""

    def __init__(self) -> None:
        super().__init__(logging.DEBUG)
        self.records: list[logging.LogRecord] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.records.append(record)


@pytest.fixture
def root_log() -> Iterator[_Collect]:
    root = logging.getLogger()
    handler, level = _Collect(), root.level
    # a `chaintwin serve` run earlier in this process (setup_logging) leaves
    # "chaintwin.live" at INFO and not propagating: its debug lines would not get here
    live = logging.getLogger("chaintwin.live")
    saved = live.level, live.propagate, live.handlers
    live.setLevel(logging.NOTSET)
    live.propagate, live.handlers = True, []
    root.addHandler(handler)
    root.setLevel(logging.DEBUG)
    yield handler
    root.removeHandler(handler)
    root.setLevel(level)
    live.setLevel(saved[0])
    live.propagate, live.handlers = saved[1], saved[2]


def test_a_lost_drive_logs_one_line_without_traceback_and_reconnects_with_backoff(
    ua_loop: Loop, sim: DriveSim, follower: Follower, root_log: _Collect
) -> None:
    """The drive goes away for a while: one warning line (no asyncua traceback, no line
    per failed attempt), the attempts spaced by the capped exponential backoff, and
    the drive followed again once it is back."""
    state = follower.status.drives[CONVEYOR]
    connects = state.connects
    root_log.records.clear()
    sim.drop_connections()
    ua_loop.run(sim.stop())
    try:
        wait_until("the loss", lambda: not state.connected)
        # attempts after 0.1, 0.2, 0.4, 0.4 ... s (initial_s 0.1, max_s 0.4): several fail
        wait_until(
            "a few failed attempts",
            lambda: len([r for r in root_log.records if "attempt" in r.getMessage()]) >= 4,
        )
    finally:  # the drive is back for the tests after this one, whatever happened
        ua_loop.run(sim.start())
    wait_until("the reconnection", lambda: state.connected and state.connects == connects + 1)
    nxt = ua_loop.run(sim.publish_next())
    wait_until("the next scope", lambda: key_of(nxt) in follower.received())
    records = list(root_log.records)
    assert not [r for r in records if r.exc_info], "a traceback was logged"
    assert not [r for r in records if r.name.startswith("asyncua")]
    # asyncua's own account of the loss is there, one debug line
    crashed = [r.getMessage() for r in records if "Publish iteration crashed" in r.getMessage()]
    assert all(r.endswith("(ConnectionError: Connection is closed)") for r in crashed), crashed
    shown = [r for r in records if r.levelno >= logging.INFO]
    warnings = [r.getMessage() for r in shown if r.levelno >= logging.WARNING]
    assert len(warnings) == 1, warnings
    assert warnings[0].startswith(f"drive {CONVEYOR} ({sim.endpoint}): ")
    assert "\n" not in warnings[0]
    assert [r.getMessage() for r in shown if "connected" in r.getMessage()] == [
        f"drive {CONVEYOR} connected ({sim.endpoint})"
    ]
    # the attempts were spaced by the doubling delay, capped at max_s
    delays = [
        float(m.group(1))
        for r in records
        if (m := re.search(r"next attempt in ([0-9.]+) s", r.getMessage()))
    ]
    assert delays[:3] == [0.1, 0.2, 0.4] and set(delays[3:]) == {0.4}, delays


def test_a_scope_that_cannot_be_used_is_refused_and_said_why(ua_loop: Loop, sim: DriveSim) -> None:
    f = Follower(
        ua_loop,
        config_for(
            {"conveyor": "short-fast-03", "endpoint": sim.endpoint},  # the wrong drive
            {"conveyor": CONVEYOR, "endpoint": sim.endpoint, "nodes": {"speed": "ns=2;s=Nope"}},
        ),
    )
    try:
        states = f.status.drives
        wait_until(  # connected, and the scope in the buffer taken (refused) already
            "both connected",
            lambda: all(
                s.connected and (sim.counter == 0 or s.last_counter == sim.counter)
                for s in states.values()
            ),
        )
        refused = {k: s.refused for k, s in states.items()}
        scope = ua_loop.run(sim.publish_next())
        wait_until(
            "both refusals",
            lambda: all(s.last_counter == scope.counter for s in states.values()),
        )
        assert not f.got
        wrong, bad_node = states["short-fast-03"], states[CONVEYOR]
        assert wrong.last_error == (
            f"opcua:short-fast-03:{scope.counter}: the drive says it is conveyor '{CONVEYOR}', "
            "the configuration says 'short-fast-03'; correct the endpoint or conveyor in the "
            "configuration"
        )
        assert bad_node.last_error == (
            f"{key_of(scope)}: node 'speed' (ns=2;s=Nope) cannot be read (BadNodeIdUnknown); "
            "check 'nodes' in the configuration"
        )
        for name, state in states.items():  # refused, counted, and the session kept
            assert state.refused == refused[name] + 1
            assert state.connected and state.connects == 1 and state.scopes_read == 0
    finally:
        f.close()


def test_a_scope_longer_than_a_drive_holds_is_refused_in_one_line_and_the_next_taken(
    ua_loop: Loop, sim: DriveSim, follower: Follower
) -> None:
    """A drive's arrays are capped: 4096 samples are refused unread, the drive followed on."""
    import dataclasses

    state = follower.status.drives[CONVEYOR]
    base = sim.history[-1] if sim.history else ua_loop.run(sim.publish_next())
    wait_until("the current scope", lambda: state.last_counter == sim.counter)
    rec = base.recording
    long = dataclasses.replace(
        rec, channels={k: np.concatenate([v, v]) for k, v in rec.channels.items()}
    )
    assert len(long.channels["speed"]) == 2 * len(rec.channels["speed"]) > MAX_SCOPE_SAMPLES
    refused_before = state.refused
    counter = ua_loop.run(sim.publish(Published(sim.counter + 1, long, base.truth, base.faults)))
    wait_until("the long scope refused", lambda: state.last_counter == counter)
    first = next(k for k in ("speed_setpoint", "speed") if k in rec.channels)
    assert state.last_error == (
        f"{key_of(sim.history[-1])}: channel {first} holds {2 * len(rec.channels[first])} "
        f"samples, more than the {MAX_SCOPE_SAMPLES} a drive's scope holds; "
        f"check the drive's {first} node"
    )
    assert state.refused == refused_before + 1 and state.connected
    assert key_of(sim.history[-1]) not in follower.received()
    good = ua_loop.run(sim.publish_next())  # the next scope is taken as ever
    wait_until("the next scope", lambda: key_of(good) in follower.received())
    assert state.refused == refused_before + 1


def test_the_client_tells_the_drive_the_largest_message_it_takes() -> None:
    from chaintwin.live.opcua import DriveState, _Follower

    config = config_for({"conveyor": CONVEYOR, "endpoint": "opc.tcp://127.0.0.1:4840"})
    follower = _Follower(config.drives[0], config.reconnect, lambda *a: None, DriveState("x"))
    client = asyncio.run(follower._client())
    assert client.max_messagesize == MAX_MESSAGE_BYTES


@pytest.mark.slow
def test_a_scope_read_twice_is_stored_once(ua_loop: Loop, sim: DriveSim, tmp_path: Path) -> None:
    from chaintwin.ingest.pipeline import ingest
    from chaintwin.store import Store

    scope = ua_loop.run(sim.publish_next())
    reads: list[Recording] = []
    for _ in range(2):  # two services (or one restarted) each read the scope in the buffer
        f = Follower(ua_loop, config_for({"conveyor": CONVEYOR, "endpoint": sim.endpoint}))
        try:
            wait_until("the scope", lambda f=f: key_of(scope) in f.received())  # type: ignore[misc]
            reads.append(f.recording(key_of(scope)))
        finally:
            f.close()
    files = []
    for i, rec in enumerate(reads):  # as the service hands them to ingest
        files.append(write_recording(rec, tmp_path / f"read{i}.csv"))
    digests = {hashlib.sha256(p.read_bytes()).hexdigest() for p in files}
    assert len(digests) == 1  # the store's content hash: the same content
    with Store(f"sqlite:///{tmp_path / 'store.db'}") as store:
        first = ingest([str(files[0])], {CONVEYOR: PROFILE}, store)
        second = ingest([str(files[1])], {CONVEYOR: PROFILE}, store)
        assert first.refused == 0 and first.duplicates == 0
        assert second.duplicates == 1 and second.processed == 0
        assert store.counts()["recordings"] == 1
        assert store.known(digests) == digests
    # and a file of it reads back to the scope
    again = read_recording(files[0], profile=PROFILE)
    assert again.metadata == scope.recording.metadata


def test_basic256sha256_sign_and_encrypt(
    ua_loop: Loop, sim: DriveSim, certs: dict[str, Path], tmp_path: Path
) -> None:
    from asyncua import ua

    secure = {
        "conveyor": CONVEYOR,
        "endpoint": sim.endpoint,
        "security_policy": "Basic256Sha256",
        "security_mode": "SignAndEncrypt",
        "certificate": str(certs["client_cert"]),
        "private_key": str(certs["client_key"]),
        "server_certificate": str(certs["server_cert"]),
    }
    f = Follower(ua_loop, config_for(secure))
    try:
        wait_until("the secure connection", lambda: f.status.drives[CONVEYOR].connected)
        # the drive's side of the connection: signed and encrypted with Basic256Sha256
        assert sim.server is not None and sim.server.bserver is not None
        policies = {
            (
                c.processor._connection.security_policy.URI,
                c.processor._connection.security_policy.Mode,
            )
            for c in sim.server.bserver.clients
        }
        assert policies == {
            (
                "http://opcfoundation.org/UA/SecurityPolicy#Basic256Sha256",
                ua.MessageSecurityMode.SignAndEncrypt,
            )
        }
        scope = ua_loop.run(sim.publish_next())
        wait_until("the scope", lambda: key_of(scope) in f.received())
        assert format_recording(f.recording(key_of(scope))) == format_recording(scope.recording)
    finally:
        f.close()
    # pinned to another certificate than the drive's: refused, and said why
    wrong = {**secure, "server_certificate": str(certs["client_cert"]), "timeout_s": 1.0}
    f = Follower(ua_loop, config_for(wrong))
    try:
        wait_until("the refusal", lambda: f.status.drives[CONVEYOR].last_error is not None)
        state = f.status.drives[CONVEYOR]
        assert not state.connected and state.connects == 0 and not f.got
    finally:
        f.close()


def test_faults_grow_from_the_onset_counted_in_scopes() -> None:
    drive = DriveSim(PROFILE, faults=[Fault("bearing", 0.8)], onset=3, ramp=4)
    assert [drive.severities(k)[0].severity for k in range(9)] == pytest.approx(
        [0.0, 0.0, 0.0, 0.0, 0.2, 0.4, 0.6, 0.8, 0.8]
    )
    step = DriveSim(PROFILE, faults=[Fault("bearing", 0.8)], onset=2)
    assert [step.severities(k)[0].severity for k in range(4)] == [0.0, 0.0, 0.8, 0.8]


@pytest.mark.slow
def test_a_running_drive_simulates_each_scope_before_its_trigger(ua_loop: Loop) -> None:
    """run() simulates the next scope during the interval: a scope triggers when it is
    published, so a slow simulation is not in the time from trigger to counter change."""
    from datetime import UTC, datetime

    drive = DriveSim(PROFILE, port=_free_port(), host="127.0.0.1", interval_s=0.5, seed=3)
    slow = drive.simulate
    simulated: list[int] = []

    def simulate(when: datetime | None = None) -> Published:
        time.sleep(0.3)  # a loaded machine
        simulated.append(drive.counter)
        return slow(when)

    drive.simulate = simulate  # type: ignore[method-assign]
    published: list[tuple[Published, datetime]] = []
    ua_loop.run(
        drive.run(
            asyncio.Event(),
            count=3,
            on_publish=lambda scope: published.append((scope, datetime.now(UTC))),
        ),
        timeout=60,
    )
    assert [scope.counter for scope, _ in published] == [1, 2, 3]
    assert simulated[:3] == [0, 1, 2]  # each simulated after the one before it was published
    for scope, at in published[1:]:  # the first was simulated when asked for
        trigger = scope.recording.metadata.recorded_at
        assert trigger is not None and (at - trigger).total_seconds() < 0.2


def test_user_login(ua_loop: Loop, sim: DriveSim) -> None:
    login = {"conveyor": CONVEYOR, "endpoint": sim.endpoint, "username": "operator"}
    f = Follower(ua_loop, config_for({**login, "password": "s3cret"}))
    try:
        wait_until("the login", lambda: f.status.drives[CONVEYOR].connected)
        scope = ua_loop.run(sim.publish_next())
        wait_until("the scope", lambda: key_of(scope) in f.received())
    finally:
        f.close()
    f = Follower(ua_loop, config_for({**login, "password": "wrong"}))
    try:
        wait_until("the refusal", lambda: f.status.drives[CONVEYOR].last_error is not None)
        state = f.status.drives[CONVEYOR]
        assert "BadUserAccessDenied" in (state.last_error or "")
        assert not state.connected and state.connects == 0 and not f.got
    finally:
        f.close()


# ---------------------------------------------------------------- configuration
def test_minimal_config_loads_with_the_default_layout(tmp_path: Path) -> None:
    path = tmp_path / "opcua.yaml"
    path.write_text(
        "drives:\n  - conveyor: white-belt-01           # a comment\n"
        "    endpoint: opc.tcp://127.0.0.1:4840\n"
    )
    config = load_opcua_config(path)
    (drive,) = config.drives
    assert drive.conveyor == "white-belt-01" and drive.security_policy is None
    assert drive.node_ids() == DEFAULT_NODES
    assert config.reconnect.initial_s == 1.0 and config.reconnect.max_s == 30.0


def test_config_paths_are_relative_to_the_file(tmp_path: Path) -> None:
    (tmp_path / "pki").mkdir()
    for name in ("c.der", "k.pem"):
        (tmp_path / "pki" / name).write_bytes(b"x")
    path = tmp_path / "opcua.yaml"
    path.write_text(
        "drives:\n  - conveyor: a\n    endpoint: opc.tcp://drive-a:4840\n"
        "    security_policy: Basic256Sha256\n    certificate: pki/c.der\n"
        "    private_key: pki/k.pem\n    nodes: {torque: 'ns=3;s=Drive.Torque', position: null}\n"
    )
    (drive,) = load_opcua_config(path).drives
    assert drive.certificate == tmp_path / "pki" / "c.der"
    ids = drive.node_ids()
    assert ids["torque"] == "ns=3;s=Drive.Torque" and "position" not in ids


@pytest.mark.parametrize(
    ("text", "field"),
    [
        ("drives:\n  - conveyor: a\n    endpoint: http://drive:4840\n", "drives.0.endpoint"),
        ("drives:\n  - endpoint: opc.tcp://drive:4840\n", "drives.0.conveyor"),
        ("drives:\n  - conveyor: a\n    endpoint: opc.tcp://d:1\n    speed: 3\n", "drives.0.speed"),
        (
            "drives:\n  - conveyor: a\n    endpoint: opc.tcp://d:1\n"
            "    security_policy: Basic256Sha256\n",
            "drives.0",
        ),
        (
            "drives:\n  - conveyor: a\n    endpoint: opc.tcp://d:1\n    nodes: {counter: null}\n",
            "drives.0",
        ),
        (
            "drives:\n  - conveyor: a\n    endpoint: opc.tcp://d:1\n    nodes: {speed: 'ns=;x'}\n",
            "drives.0",
        ),
        (
            "drives:\n  - conveyor: a\n    endpoint: opc.tcp://d:1\n    units: {speed: furlong}\n",
            "drives.0",
        ),
        (
            "drives:\n  - conveyor: a\n    endpoint: opc.tcp://d:1\n"
            "  - conveyor: a\n    endpoint: opc.tcp://d:2\n",
            "(top level)",
        ),
        ("drives: []\n", "drives"),
        ("reconnect: {initial_s: 0}\ndrives: []\n", "reconnect.initial_s"),
        (
            "drives:\n  - conveyor: a\n    endpoint: opc.tcp://d:1\n    certificate: no.der\n"
            "    private_key: no.pem\n",
            "drives.0.certificate",
        ),
    ],
)
def test_bad_config_is_one_line_naming_the_field(tmp_path: Path, text: str, field: str) -> None:
    path = tmp_path / "opcua.yaml"
    path.write_text(text)
    with pytest.raises(ConnectorError) as info:
        load_opcua_config(path)
    message = str(info.value)
    assert "\n" not in message
    assert message.startswith(f"{path}: ")
    assert f"field '{field}" in message


@pytest.mark.parametrize(
    ("text", "needle"),
    [("drives: [\n", "line"), ("- just a list\n", "mapping"), ("", "mapping")],
)
def test_config_that_is_not_a_mapping_is_refused(tmp_path: Path, text: str, needle: str) -> None:
    path = tmp_path / "opcua.yaml"
    path.write_text(text)
    with pytest.raises(ConnectorError, match=needle):
        load_opcua_config(path)
    with pytest.raises(ConnectorError, match="cannot be read"):
        load_opcua_config(tmp_path / "missing.yaml")


# ---------------------------------------------------------------- a scope's values → a recording
def _values(n: int = 64) -> dict[str, Any]:
    t = np.arange(n)
    return {
        "conveyor_id": CONVEYOR,
        "sample_time": 0.006,
        "nominal_torque": 2.5,
        "speed": (100.0 * np.sin(t / 10.0)).tolist(),
        "speed_unit": "rpm",
        "torque": (10.0 * np.cos(t / 10.0)).tolist(),
        "torque_unit": "%",
    }


def test_recording_from_scope_converts_units_and_checks_like_the_reader() -> None:
    rec = recording_from_scope(_values(), conveyor=CONVEYOR, source="opcua:x:1")
    assert rec.units == {"time": "s", "speed": "rpm", "torque": "%"}
    np.testing.assert_allclose(rec.time[:3], [0.0, 0.006, 0.012])
    np.testing.assert_allclose(rec.torque[0], 0.10 * 2.5)  # 10 % of 2.5 Nm
    assert rec.metadata.recorded_at is None  # no trigger time node: none, as in a file
    bad = [
        ({"conveyor_id": "other-belt"}, "other-belt"),
        ({"sample_time": 0.0}, "sample time"),
        ({"speed_unit": ""}, "no unit"),
        ({"torque": [1.0] * 10}, "same length"),
        ({"speed": [float("nan")] * 64}, "finite"),
        ({"speed": [1.0] * 10, "torque": [1.0] * 10}, "at least 32"),
        ({"nominal_torque": 0.0}, "nominal_torque_nm"),
    ]
    for change, needle in bad:
        with pytest.raises(RecordingError, match=needle) as info:
            recording_from_scope({**_values(), **change}, conveyor=CONVEYOR, source="opcua:x:1")
        assert str(info.value).startswith("opcua:x:1")


def _scope_text(values: dict[str, Any], conveyor: str) -> str:
    """The scope as the client used to build it: a file of it, every number printed exactly."""
    from datetime import UTC

    lines = [f"# conveyor: {conveyor}"]
    if "trigger_time" in values:
        lines.append(f"# recorded_at: {values['trigger_time'].astimezone(UTC).isoformat()}")
    lines.append(f"# sample_time_s: {float(values['sample_time'])!r}")
    for key, meta in (
        ("nominal_torque", "nominal_torque_nm"),
        ("increments_per_rev", "increments_per_rev"),
    ):
        if values.get(key):
            lines.append(f"# {meta}: {float(values[key])!r}")
    header, columns = ["time [s]"], []
    for key in (
        "speed_setpoint",
        "speed",
        "position_setpoint",
        "position",
        "torque_setpoint",
        "torque",
        "digital_inputs",
    ):
        if values.get(key):
            header.append(f"{key} [{values[f'{key}_unit']}]")
            columns.append(np.asarray(values[key], dtype=np.float64))
    n = len(columns[0])
    table = np.column_stack([np.arange(n) * float(values["sample_time"]), *columns])
    rows = "\n".join(",".join(f"{v:.17g}" for v in row) for row in table.tolist())
    return "\n".join(lines) + "\n" + ",".join(header) + "\n" + rows + "\n"


def _published_values(scope: Published) -> dict[str, Any]:
    """What the client reads from a drive that published ``scope`` (its own units)."""
    from chaintwin.units import UnitContext, from_si_factor

    rec, meta = scope.recording, scope.recording.metadata
    context = UnitContext(
        increments_per_rev=meta.increments_per_rev, nominal_torque_nm=meta.nominal_torque_nm
    )
    values: dict[str, Any] = {
        "counter": scope.counter,
        "conveyor_id": meta.conveyor,
        "trigger_time": meta.recorded_at,
        "sample_time": meta.sample_time_s or rec.sample_time_s,
        "nominal_torque": meta.nominal_torque_nm or 0.0,
        "increments_per_rev": meta.increments_per_rev or 0.0,
    }
    for key, unit in rec.units.items():
        if key != "time":
            values[key] = (rec.channels[key] * from_si_factor(key, unit, context)).tolist()
            values[f"{key}_unit"] = unit
    return values


def test_recording_from_scope_equals_the_file_of_it_and_refuses_alike(sim: DriveSim) -> None:
    """The arrays read from a drive become the recording the file reader makes of the
    same scope printed exactly: same samples, units, headers, metadata; and a bad scope
    is refused with the same one line (one code path for the checks)."""
    from datetime import UTC, datetime

    from chaintwin.read.reader import parse_recording

    values = _published_values(sim.simulate())
    key = "opcua:x:1"
    direct = recording_from_scope(values, conveyor=CONVEYOR, source=key)
    via_file = parse_recording(_scope_text(values, CONVEYOR), key)
    assert direct.metadata == via_file.metadata and direct.metadata.recorded_at is not None
    assert direct.units == via_file.units and direct.headers == via_file.headers
    assert list(direct.channels) == list(via_file.channels)
    for name, column in via_file.channels.items():
        np.testing.assert_array_equal(direct.channels[name], column)  # bit for bit
    assert len(direct.channels) == 8 and direct.channels["speed"].shape == (2048,)

    speed = np.asarray(values["speed"])
    bad_rows = speed.copy()
    bad_rows[40] = np.inf
    bad = [
        {"speed": bad_rows.tolist()},  # a sample that is not finite: its line is named
        {"speed_unit": "furlongs"},  # no unit of speed
        {"sample_time": 0.5},  # no drive scope samples that slowly
        {"torque": (np.asarray(values["torque"]) * 1e3).tolist()},  # torque beyond 10x nominal
        {"trigger_time": datetime(2300, 1, 1, tzinfo=UTC)},  # the drive's clock is off
        {k: values[k][:20] for k in values if isinstance(values[k], list)},  # too short
    ]
    for change in bad:
        scope = {**values, **change}
        with pytest.raises(RecordingError) as from_file:
            parse_recording(_scope_text(scope, CONVEYOR), key)
        with pytest.raises(RecordingError) as from_arrays:
            recording_from_scope(scope, conveyor=CONVEYOR, source=key)
        assert str(from_arrays.value) == str(from_file.value)
        assert "\n" not in str(from_arrays.value) and str(from_arrays.value).startswith(key)


# ---------------------------------------------------------------- the command
@pytest.mark.slow
def test_drive_sim_command_serves_the_minimal_config_and_stops_on_sigterm(
    ua_loop: Loop, tmp_path: Path
) -> None:
    import os
    import signal
    import subprocess
    import sys

    port = _free_port()
    root = Path(__file__).resolve().parents[1]
    env = {**os.environ, "PYTHONPATH": str(root), "PYTHONUNBUFFERED": "1"}
    args = [sys.executable, "-m", "chaintwin", "drive-sim", "--profile", str(REFERENCE_PROFILE)]
    args += ["--port", str(port), "--interval", "0.3", "--fault", "friction:0.3", "--onset", "1"]
    proc = subprocess.Popen(
        args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, cwd=tmp_path
    )
    try:
        assert proc.stdout is not None
        lines = [proc.stdout.readline() for _ in range(3)]
        assert lines[0].startswith(f"drive-sim {CONVEYOR} on opc.tcp://0.0.0.0:{port}")
        assert lines[1].startswith("scope 1 at ") and lines[1].endswith("faults: friction:0\n")
        assert lines[2].startswith("scope 2 at ") and lines[2].endswith("faults: friction:0.3\n")
        config = tmp_path / "opcua.yaml"  # the minimal configuration, as documented
        config.write_text(
            f"drives:\n  - conveyor: {CONVEYOR}\n    endpoint: opc.tcp://127.0.0.1:{port}\n"
        )
        f = Follower(ua_loop, load_opcua_config(config))
        try:
            wait_until("a scope", lambda: bool(f.got))
            key, rec = f.got[0]
            assert key.startswith(f"opcua:{CONVEYOR}:")
            assert rec.metadata.conveyor == CONVEYOR and rec.samples == 2048
            assert not inspect_recording(rec, PROFILE).recording.has_warning("profile_mismatch")
        finally:
            f.close()
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(15) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        for stream in (proc.stdout, proc.stderr):
            if stream is not None:
                stream.close()


def test_drive_sim_command_refuses_bad_options(capsys: pytest.CaptureFixture[str]) -> None:
    from chaintwin.cli.app import main

    base = ["drive-sim", "--profile", str(REFERENCE_PROFILE)]
    assert main([*base, "--fault", "rust:1"]) == 2
    assert "unknown fault 'rust'" in capsys.readouterr().err
    assert main([*base, "--certificate", "c.der"]) == 2
    assert "--private-key" in capsys.readouterr().err
    assert main([*base, "--port", "0"]) == 2
    # refused before the server starts: the first scope is simulated first
    assert main([*base, "--sample-time", "0.0055"]) == 2
    assert "whole multiple of the controller cycle" in capsys.readouterr().err


@pytest.mark.slow
def test_serve_follows_a_drive_over_opcua_and_stores_its_scopes(
    ua_loop: Loop, sim: DriveSim, tmp_path: Path
) -> None:
    """``chaintwin serve --no-web --opcua CONFIG`` against the simulator, end to end."""
    import os
    import signal
    import subprocess
    import sys

    from sqlalchemy import func, select
    from sqlalchemy.orm import Session

    from chaintwin.store.engine import engine_for
    from chaintwin.store.schema import RecordingRow
    from chaintwin.store.store import Store

    url = f"sqlite:///{tmp_path / 'live.db'}"
    Store(url).close()
    config = tmp_path / "drives.yaml"
    config.write_text(f"drives:\n  - conveyor: {CONVEYOR}\n    endpoint: {sim.endpoint}\n")
    profiles = tmp_path / "profiles"
    profiles.mkdir()
    (profiles / "p.yaml").write_text(Path(REFERENCE_PROFILE).read_text())
    root = Path(__file__).resolve().parents[1]
    env = dict(os.environ, PYTHONPATH=str(root), OPENBLAS_NUM_THREADS="1")
    log = tmp_path / "serve.log"

    def stored() -> int:
        engine = engine_for(url)
        with Session(engine) as s:
            n = int(s.scalar(select(func.count()).select_from(RecordingRow)) or 0)
        engine.dispose()
        return n

    args = ["serve", "--no-web", "--db", url, "--profiles", str(profiles), "--opcua", str(config)]
    with log.open("wb") as err:
        proc = subprocess.Popen(
            [sys.executable, "-m", "chaintwin", *args],
            stdout=subprocess.DEVNULL,
            stderr=err,
            env=env,
        )
    try:
        before = stored()
        end = time.monotonic() + 60
        # the scope in the buffer is taken on connecting, then each new one
        while stored() < before + 2:
            assert proc.poll() is None, log.read_text()[-2000:]
            assert time.monotonic() < end, log.read_text()[-2000:]
            ua_loop.run(sim.publish_next())
            time.sleep(1.0)
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(30) == 0, log.read_text()[-2000:]
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
    assert f"{CONVEYOR} at {sim.endpoint}" in log.read_text()
    # stored under the drive's stable name, not the spool file it passed through
    engine = engine_for(url)
    with Session(engine) as s:
        files = list(s.scalars(select(RecordingRow.file)))
    engine.dispose()
    assert files and all(re.fullmatch(rf"opcua://{CONVEYOR}/\d+", f) for f in files), files
    results = Store(url).results(CONVEYOR)
    assert {r["file"] for r in results} <= set(files)
    assert "chaintwin-spool-" not in log.read_text()
