"""The OPC UA server of the results, read by a real client (asyncua's).

One server serves the module (asyncua's ``Server.init`` takes seconds): it
runs Basic256Sha256 sign-and-encrypt (the default) with its own certificate,
made on first start in its certificate folder, in an event loop on a
background thread; every client connects with a certificate the test put in
its trust list (or one it did not) and a token of the store.
"""

from __future__ import annotations

import asyncio
import queue
import shutil
import socket
import threading
import time
import xml.etree.ElementTree as Et
from collections.abc import Coroutine, Iterator
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, TypeVar
from urllib.parse import unquote

import pytest
from conftest import REFERENCE_PROFILE, _free_port

from chaintwin.calibrating import calibrate
from chaintwin.diagnose.records import MonitorSettings
from chaintwin.ingest import ingest
from chaintwin.live.opcua_nodes import (
    DEVICE_HEALTH,
    NAMESPACE_URI,
    UNITS,
    conveyor_node_id,
    escape,
    node_id,
)
from chaintwin.read.profile import load_profile
from chaintwin.simulate.faults import Fault
from chaintwin.simulate.fleet import generate
from chaintwin.store.queries import fleet_rows
from chaintwin.store.store import Store
from chaintwin.store.verdicts import conveyor_verdict
from chaintwin.validate import load_recording
from chaintwin.web.access import create_token, revoke_token, verify_token

pytest.importorskip("asyncua")

from asyncua import Client, ua
from asyncua.crypto.security_policies import SecurityPolicyBasic256Sha256

from chaintwin.live.opcua_server import ResultsServer

T = TypeVar("T")
PROFILE = load_profile(REFERENCE_PROFILE)
HELD_BACK = 3
"""Recordings of the plant kept back, to be stored while clients watch."""


class Loop:
    """An asyncio event loop on a background thread."""

    def __init__(self) -> None:
        self.loop = asyncio.new_event_loop()
        self.thread = threading.Thread(target=self.loop.run_forever, daemon=True)
        self.thread.start()

    def run(self, coro: Coroutine[Any, Any, T], timeout: float = 60.0) -> T:
        return asyncio.run_coroutine_threadsafe(coro, self.loop).result(timeout)

    def close(self) -> None:
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(10)
        self.loop.close()


@dataclass
class Plant:
    url: str
    store: Store
    held: list[Path]
    token: str
    token_name: str


@pytest.fixture(scope="module")
def plant(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Plant]:
    """One conveyor over 5 days, friction rising from day 2; all but the last recordings
    ingested (a complete baseline of 5)."""
    folder = tmp_path_factory.mktemp("fleet")
    generate(
        PROFILE, folder, days=5, per_day=4, faults=[Fault("friction", 0.8)], onset_day=2, seed=5
    )
    url = f"sqlite:///{folder / 'plant.db'}"
    store = Store(url)
    recs = [
        load_recording(f, profile=PROFILE).recording
        for f in sorted((folder / "calibration").glob("*.csv"))
    ]
    store.put_calibration(calibrate(recs, PROFILE))
    files = sorted(folder.glob("*.csv"))
    ingest(
        [str(f) for f in files[:-HELD_BACK]],
        {PROFILE.id: PROFILE},
        store,
        settings=MonitorSettings(baseline_n=5),
        workers=1,
    )
    token = create_token(store, "scada", "viewer")
    yield Plant(url, store, files[-HELD_BACK:], token, "scada")
    store.close()


def _certificate(folder: Path, name: str) -> tuple[Path, Path, str]:
    from asyncua.crypto.cert_gen import setup_self_signed_certificate
    from cryptography.x509.oid import ExtendedKeyUsageOID

    uri = f"urn:chaintwin:test:{name}"
    cert, key = folder / f"{name}.der", folder / f"{name}.pem"
    asyncio.run(
        setup_self_signed_certificate(
            key,
            cert,
            uri,
            socket.gethostname(),
            [ExtendedKeyUsageOID.CLIENT_AUTH],
            {"organizationName": "chaintwin tests"},
        )
    )
    return cert, key, uri


@dataclass
class Running:
    server: ResultsServer
    loop: Loop
    endpoint: str
    cert_dir: Path
    trusted: tuple[Path, Path, str]
    stranger: tuple[Path, Path, str]
    updates: queue.Queue[tuple[str, float]]


@pytest.fixture(scope="module")
def running(plant: Plant, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Running]:
    folder = tmp_path_factory.mktemp("pki")
    trusted = _certificate(folder, "hmi")
    stranger = _certificate(folder, "stranger")
    cert_dir = folder / "server"
    (cert_dir / "trusted" / "certs").mkdir(parents=True)
    shutil.copy(trusted[0], cert_dir / "trusted" / "certs" / "hmi.der")
    endpoint = f"opc.tcp://127.0.0.1:{_free_port()}"
    updates: queue.Queue[tuple[str, float]] = queue.Queue()
    server = ResultsServer(
        plant.store,
        endpoint,
        cert_dir=cert_dir,
        token_check=verify_token,
        on_update=lambda c: updates.put((c, time.time())),
    )
    loop = Loop()
    stop = asyncio.Event()
    task = asyncio.run_coroutine_threadsafe(server.run(stop), loop.loop)
    assert server.published.wait(120) or task.result(0), "the server did not start"
    yield Running(server, loop, endpoint, cert_dir, trusted, stranger, updates)
    loop.loop.call_soon_threadsafe(stop.set)
    task.result(30)
    loop.close()


async def _client(
    run: Running, user: str | None, password: str | None, cert: tuple[Path, Path, str] | None
) -> Client:
    client = Client(run.endpoint, timeout=10)
    if cert is not None:
        client.application_uri = cert[2]
        await client.set_security(
            SecurityPolicyBasic256Sha256,
            certificate=str(cert[0]),
            private_key=str(cert[1]),
            mode=ua.MessageSecurityMode.SignAndEncrypt,
        )
    if user is not None:
        client.set_user(user)
    if password is not None:
        client.set_password(password)
    return client


def _nid(ns: int, text: str) -> ua.NodeId:
    return ua.NodeId(ua.String(text), ua.Int16(ns))


# ------------------------------------------------------------------ node ids (no server)
def test_node_ids_escape_the_conveyor_id_and_read_back() -> None:
    for cid in ("line-1", "hall 2/line;3", "Förder%band", "a.b_c~d"):
        nid = conveyor_node_id(cid)
        assert nid.count("/") == 1  # the id's own slashes are escaped
        assert unquote(nid.split("/", 1)[1]) == cid
        assert node_id(cid, "Monitoring/Payload") == f"Conveyors/{escape(cid)}/Monitoring/Payload"
    assert escape("hall 2/line;3") == "hall%202%2Fline%3B3"
    assert escape("a.b_c~d-1") == "a.b_c~d-1"


def test_unit_ids_are_the_unece_codes_as_opc_ua_packs_them() -> None:
    # OPC 10000-8: "KGM" -> 0x4B << 16 | 0x47 << 8 | 0x4D
    assert UNITS["kg"].unit_id == 0x4B474D == 4933453
    assert UNITS["d"].unit_id == (ord("D") << 16) | (ord("A") << 8) | ord("Y")
    assert UNITS["deg"].unit_id == (ord("D") << 8) | ord("D")


def test_an_empty_trust_list_trusts_no_one_and_a_new_certificate_counts_at_once(
    plant: Plant, tmp_path: Path
) -> None:
    from asyncua.crypto.uacrypto import load_certificate

    from chaintwin.live.opcua_server import CertificateFolder

    folder = CertificateFolder(tmp_path / "pki")
    folder.make()
    server = ResultsServer(plant.store, "opc.tcp://127.0.0.1:4840", cert_dir=folder.root)
    assert asyncio.run(server._load_trust(folder)) is None  # nothing trusted, no error
    cert_path, _key, _uri = _certificate(tmp_path, "panel")
    cert = asyncio.run(load_certificate(cert_path))
    shutil.copy(cert_path, folder.trusted / "panel.der")
    trust = asyncio.run(server._load_trust(folder))
    assert trust is not None and trust.is_trusted(cert)


# ------------------------------------------------------------------ a real client
def test_browse_read_values_units_and_health(plant: Plant, running: Running) -> None:
    row = next(r for r in fleet_rows(plant.store) if r["id"] == PROFILE.id)
    judged = conveyor_verdict(plant.store, PROFILE.id)

    async def read() -> dict[str, Any]:
        client = await _client(running, plant.token_name, plant.token, running.trusted)
        async with client:
            ns = await client.get_namespace_index(NAMESPACE_URI)
            objects = client.nodes.objects
            root = await objects.get_child([f"{ns}:Conveyors"])
            names = [(await c.read_browse_name()).Name for c in await root.get_children()]
            base = conveyor_node_id(PROFILE.id)
            conveyor = client.get_node(_nid(ns, base))
            parts = [(await c.read_browse_name()).Name for c in await conveyor.get_children()]
            payload = client.get_node(_nid(ns, node_id(PROFILE.id, "Monitoring/Payload")))
            eu = await (await payload.get_child(["0:EngineeringUnits"])).read_value()
            features = client.get_node(_nid(ns, node_id(PROFILE.id, "Monitoring/Features")))
            feats = [(await f.read_browse_name()).Name for f in await features.get_children()]
            health = client.get_node(_nid(ns, node_id(PROFILE.id, "DeviceHealth")))

            async def value(path: str) -> Any:
                return await client.get_node(_nid(ns, node_id(PROFILE.id, path))).read_value()

            return {
                "names": names,
                "parts": parts,
                "payload": await payload.read_value(),
                "eu": eu,
                "feats": feats,
                "health": await health.read_value(),
                "health_type": await health.read_data_type(),
                "health_text": await value("Monitoring/Health"),
                "ratio": await value("Identification/GearRatio"),
                "tlf": await value("Monitoring/Tlf"),
                "expected": await value("Monitoring/Features/friction/Expected"),
                "limit": await value("Monitoring/Features/friction/Limit"),
                "friction": await value("Monitoring/Features/friction/Value"),
                "at": await value("Monitoring/LastRecordedAt"),
                "ns": ns,
            }

    got = running.loop.run(read())
    assert got["names"] == [PROFILE.id]
    assert {"Identification", "Monitoring", "DeviceHealth", "DeviceHealthSince"} <= set(
        got["parts"]
    )
    # the values are the store's (the fleet's rows and the verdict read the same way)
    assert got["payload"] == pytest.approx(row["payload_kg"], rel=1e-12)
    assert got["tlf"] == pytest.approx(row["tlf"], rel=1e-12)
    assert got["at"] == datetime.fromisoformat(row["last_recorded_at"])
    assert got["eu"].UnitId == UNITS["kg"].unit_id and got["eu"].DisplayName.Text == "kg"
    assert got["health"] == DEVICE_HEALTH[judged.ne107]
    assert got["health_type"] == _nid(got["ns"], "DeviceHealthEnumeration")
    assert got["health_text"] == judged.health
    assert got["ratio"] == PROFILE.gear.ratio
    assert "friction" in got["feats"]
    assert got["expected"] < got["limit"]  # the baseline band
    assert got["friction"] > 0.0


def test_a_new_recording_reaches_a_subscribed_client(plant: Plant, running: Running) -> None:
    """Subscribe to the payload and the recording time; store a recording; its values arrive."""
    changes: queue.Queue[tuple[str, Any, float]] = queue.Queue()

    class Handler:
        def datachange_notification(self, node: Any, val: Any, data: Any) -> None:
            changes.put((node.nodeid.Identifier.rsplit("/", 1)[-1], val, time.time()))

    state: dict[str, Any] = {}

    async def subscribe() -> None:
        client = await _client(running, plant.token_name, plant.token, running.trusted)
        await client.connect()
        ns = await client.get_namespace_index(NAMESPACE_URI)
        sub = await client.create_subscription(100, Handler())
        nodes = [
            client.get_node(_nid(ns, node_id(PROFILE.id, p)))
            for p in ("Monitoring/Payload", "Monitoring/LastRecordedAt")
        ]
        await sub.subscribe_data_change(nodes)
        state["client"] = client

    running.loop.run(subscribe())
    try:
        first = {changes.get(timeout=30)[0] for _ in range(2)}  # the initial values
        assert first == {"Payload", "LastRecordedAt"}
        latencies = []
        for path in plant.held[:2]:
            ingest([str(path)], {PROFILE.id: PROFILE}, plant.store, workers=1)
            row = next(r for r in fleet_rows(plant.store) if r["id"] == PROFILE.id)
            committed = _stored_at(plant.store)
            seen: dict[str, tuple[Any, float]] = {}
            while set(seen) != {"Payload", "LastRecordedAt"}:
                name, val, at = changes.get(timeout=60)
                seen[name] = (val, at)
            assert seen["Payload"][0] == pytest.approx(row["payload_kg"], rel=1e-12)
            want = datetime.fromisoformat(row["last_recorded_at"])
            assert seen["LastRecordedAt"][0] == want
            latencies.append(seen["Payload"][1] - committed)
        print(f"commit to data change: {', '.join(f'{s:.2f}' for s in latencies)} s")
    finally:
        running.loop.run(state["client"].disconnect())


def _stored_at(store: Store) -> float:
    from sqlalchemy import select
    from sqlalchemy.orm import Session

    from chaintwin.store.schema import ResultRow

    with Session(store.engine) as s:
        newest = s.scalar(select(ResultRow.stored_at).order_by(ResultRow.id.desc()).limit(1))
    return datetime.fromisoformat(str(newest)).astimezone(UTC).timestamp()


def test_a_conveyor_added_to_the_store_appears_without_restart(
    plant: Plant, running: Running
) -> None:
    odd = PROFILE.model_copy(update={"id": "hall 2/line;3"})
    plant.store.put_profile(odd)

    async def find() -> list[str]:
        client = await _client(running, plant.token_name, plant.token, running.trusted)
        async with client:
            ns = await client.get_namespace_index(NAMESPACE_URI)
            node = client.get_node(_nid(ns, node_id(odd.id, "Identification/ConveyorId")))
            name = await node.read_value()
            root = await client.nodes.objects.get_child([f"{ns}:Conveyors"])
            names = [(await c.read_browse_name()).Name for c in await root.get_children()]
            return [name, *names]

    while True:  # the server looks every POLL_S; wait on its update of that conveyor
        conveyor, _at = running.updates.get(timeout=30)
        if conveyor == odd.id:
            break
    got = running.loop.run(find())
    assert got[0] == odd.id
    assert odd.id in got[1:] and PROFILE.id in got[1:]


def test_a_look_at_the_store_that_fails_is_repeated_until_it_publishes(
    plant: Plant, running: Running, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A commit seen while the store cannot be read (locked for a moment) is published at a
    later look, with no further commit to wake the watch."""
    failed = threading.Event()
    keys = running.server._keys

    def locked_once() -> Any:
        if not failed.is_set():
            failed.set()
            raise OSError("database is locked")
        return keys()

    monkeypatch.setattr(running.server, "_keys", locked_once)
    late = PROFILE.model_copy(update={"id": "late-line-9"})
    plant.store.put_profile(late)  # the only commit: its look fails once
    assert failed.wait(30)
    while True:
        conveyor, _at = running.updates.get(timeout=30)
        if conveyor == late.id:
            break


def test_a_conveyor_deleted_from_the_store_leaves_and_its_monitored_items_end(
    plant: Plant, running: Running, caplog: pytest.LogCaptureFixture
) -> None:
    """A conveyor deleted from the store: each subscribed value gets a last data change with
    BadNodeIdUnknown, its nodes go (browse, read), the subscription goes on, its items are
    deleted without error, and the server logs no error doing it."""
    from sqlalchemy import delete
    from sqlalchemy.orm import Session

    from chaintwin.store.schema import ConveyorRow

    doomed = PROFILE.model_copy(update={"id": "line-to-go"})
    plant.store.put_profile(doomed)
    while running.updates.get(timeout=30)[0] != doomed.id:  # it appeared
        pass
    changes: queue.Queue[tuple[str, int]] = queue.Queue()

    class Handler:
        def datachange_notification(self, node: Any, val: Any, data: Any) -> None:
            code = data.monitored_item.Value.StatusCode.value
            changes.put((str(node.nodeid.Identifier), code))

    paths = ("Identification/ConveyorId", "Monitoring/Payload")
    state: dict[str, Any] = {}

    async def subscribe() -> None:
        client = await _client(running, plant.token_name, plant.token, running.trusted)
        await client.connect()
        ns = await client.get_namespace_index(NAMESPACE_URI)
        sub = await client.create_subscription(100, Handler())
        nodes = [client.get_node(_nid(ns, node_id(doomed.id, p))) for p in paths]
        nodes.append(client.get_node(_nid(ns, node_id(PROFILE.id, "Monitoring/Health"))))
        state.update(client=client, ns=ns, sub=sub, handles=await sub.subscribe_data_change(nodes))

    async def after() -> tuple[list[str], ua.StatusCode, int]:
        client, ns, sub = state["client"], state["ns"], state["sub"]
        root = await client.nodes.objects.get_child([f"{ns}:Conveyors"])
        names = [(await c.read_browse_name()).Name for c in await root.get_children()]
        read = await client.uaclient.read_attributes(
            [_nid(ns, node_id(doomed.id, "Identification/ConveyorId"))], ua.AttributeIds.Value
        )
        await sub.unsubscribe(state["handles"][:2])  # the gone items end without error
        again = await sub.subscribe_data_change(  # the subscription goes on
            client.get_node(_nid(ns, node_id(PROFILE.id, "Monitoring/Payload")))
        )
        return names, read[0].StatusCode, again

    running.loop.run(subscribe())
    try:
        first = {changes.get(timeout=30)[0] for _ in range(3)}  # the initial values
        gone = {node_id(doomed.id, p) for p in paths}
        assert first == gone | {node_id(PROFILE.id, "Monitoring/Health")}
        caplog.set_level("WARNING")
        caplog.clear()  # what the server logs from here on
        with Session(plant.store.engine) as s, s.begin():
            s.execute(delete(ConveyorRow).where(ConveyorRow.id == doomed.id))
        while running.updates.get(timeout=30)[0] != doomed.id:  # the server took it out
            pass
        last: dict[str, int] = {}
        while set(last) != gone:
            name, code = changes.get(timeout=30)
            if name in gone:
                last[name] = code
        assert set(last.values()) == {ua.StatusCodes.BadNodeIdUnknown}
        names, code, again = running.loop.run(after())
        assert doomed.id not in names and PROFILE.id in names
        assert code.value == ua.StatusCodes.BadNodeIdUnknown
        assert again > 0
        assert not [r for r in caplog.records if r.levelno >= 30], caplog.text
        assert not any(n.startswith(conveyor_node_id(doomed.id)) for n in running.server._nodes)
    finally:
        running.loop.run(state["client"].disconnect())


def test_values_read_again_in_part_agree_with_a_full_read(plant: Plant) -> None:
    """The reader that keeps a conveyor's parts (its health model without its history)
    gives the values a full read gives, when only the forecasts' key changed."""
    from chaintwin.live.opcua_nodes import ConveyorReader, read_conveyor

    server = ResultsServer(plant.store, "opc.tcp://127.0.0.1:4840", security="none")
    key = server._keys()[PROFILE.id]
    reader = ConveyorReader(plant.store)
    full = read_conveyor(plant.store, PROFILE.id)
    assert full is not None and any(p.startswith("Monitoring/Features/") for p in full)
    assert reader.read(PROFILE.id, key) == full
    kept = reader._parts[PROFILE.id]
    assert kept.state is not None and kept.state.history == []  # the history not kept
    again = (key[0], key[1], "a later refit", key[3])  # only the forecasts' time differs
    assert reader.read(PROFILE.id, again) == full


@pytest.mark.parametrize(
    ("user", "password"),
    [
        ("scada", "ct_not-the-token"),  # a wrong token
        ("someone-else", None),  # the right token under another name
        (None, None),  # anonymous
    ],
)
def test_a_user_without_a_valid_token_is_refused(
    plant: Plant, running: Running, user: str | None, password: str | None
) -> None:
    given = plant.token if password is None and user is not None else password
    refused_before = running.server.users.refused if running.server.users else 0

    async def connect() -> None:
        client = await _client(running, user, given, running.trusted)
        async with client:
            pass

    with pytest.raises((ua.UaStatusCodeError, ua.UaError)) as err:
        running.loop.run(connect())
    assert "BadUserAccessDenied" in repr(err.value) or "BadIdentityToken" in repr(err.value)
    if user is not None:
        assert running.server.users is not None
        assert running.server.users.refused == refused_before + 1


def test_a_revoked_token_is_refused_at_once(plant: Plant, running: Running) -> None:
    token = create_token(plant.store, "leaving", "admin")

    async def connect() -> bool:
        client = await _client(running, "leaving", token, running.trusted)
        async with client:
            return True

    assert running.loop.run(connect())
    revoke_token(plant.store, "leaving")
    with pytest.raises(ua.UaStatusCodeError, match="BadUserAccessDenied"):
        running.loop.run(connect())


def test_no_session_may_write(plant: Plant, running: Running) -> None:
    async def write() -> None:
        client = await _client(running, plant.token_name, plant.token, running.trusted)
        async with client:
            ns = await client.get_namespace_index(NAMESPACE_URI)
            node = client.get_node(_nid(ns, node_id(PROFILE.id, "Monitoring/Payload")))
            await node.write_value(ua.DataValue(ua.Variant(1.0, ua.VariantType.Double)))

    with pytest.raises(ua.UaStatusCodeError, match="BadUserAccessDenied"):
        running.loop.run(write())


def test_an_untrusted_client_certificate_is_refused_until_trusted(
    plant: Plant, running: Running
) -> None:
    async def connect() -> str:
        client = await _client(running, plant.token_name, plant.token, running.stranger)
        async with client:
            ns = await client.get_namespace_index(NAMESPACE_URI)
            node = client.get_node(_nid(ns, node_id(PROFILE.id, "Identification/ConveyorId")))
            return str(await node.read_value())

    rejected = running.cert_dir / "rejected" / "certs"
    before = set(rejected.glob("*.der"))
    with pytest.raises((ua.UaStatusCodeError, ua.UaError, ConnectionError, TimeoutError)):
        running.loop.run(connect())
    new = set(rejected.glob("*.der")) - before
    assert len(new) == 1  # kept for an administrator to trust
    assert new.pop().read_bytes() == running.stranger[0].read_bytes()
    # the administrator moves it to the trust list: it connects, no restart
    shutil.copy(running.stranger[0], running.cert_dir / "trusted" / "certs" / "stranger.der")
    assert running.loop.run(connect()) == PROFILE.id


def test_the_server_made_its_own_certificate_and_offers_only_basic256sha256(
    running: Running,
) -> None:
    own = running.cert_dir / "own"
    assert (own / "cert.der").stat().st_size > 0
    assert (own / "private" / "key.pem").stat().st_mode & 0o077 == 0  # the owner's only

    async def endpoints() -> list[Any]:
        return list(await Client(running.endpoint, timeout=10).connect_and_get_server_endpoints())

    found = running.loop.run(endpoints())
    assert {(e.SecurityPolicyUri.rsplit("#", 1)[-1], e.SecurityMode) for e in found} == {
        ("Basic256Sha256", ua.MessageSecurityMode.SignAndEncrypt)
    }
    tokens = {t.TokenType for e in found for t in e.UserIdentityTokens}
    assert tokens == {ua.UserTokenType.UserName}  # anonymous is off


# ------------------------------------------------------------------ the command line
def test_nodeset_export_holds_every_conveyor_node_with_its_units(
    plant: Plant, running: Running, tmp_path: Path
) -> None:
    from chaintwin.cli.app import main

    out = tmp_path / "chaintwin.xml"
    assert main(["opcua", "nodeset", "--db", plant.url, "--out", str(out)]) == 0
    ns = {"u": "http://opcfoundation.org/UA/2011/03/UANodeSet.xsd"}
    root = Et.parse(out).getroot()
    assert [u.text for u in root.findall("u:NamespaceUris/u:Uri", ns)] == [NAMESPACE_URI]
    ids = {el.get("NodeId") for el in root if el.get("NodeId")}
    for cid in plant.store.conveyors():
        assert f"ns=1;s={node_id(cid, 'Monitoring/Payload')}" in ids
        assert f"ns=1;s={node_id(cid, 'DeviceHealth')}" in ids
    unit = root.find(
        f"u:UAVariable[@NodeId='ns=1;s={node_id(PROFILE.id, 'Monitoring/Payload')}"
        "/EngineeringUnits']",
        ns,
    )
    assert unit is not None
    assert str(UNITS["kg"].unit_id) in Et.tostring(unit, encoding="unicode")


def test_serve_refuses_a_bad_opcua_endpoint_naming_the_option(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    from chaintwin.cli.app import main

    db = f"sqlite:///{tmp_path / 'x.db'}"
    code = main(["serve", "--db", db, "--no-web", "--opcua-endpoint", "http://host:4840"])
    err = capsys.readouterr().err
    assert code == 2 and "--opcua-endpoint http://host:4840" in err and "opc.tcp://" in err
    code = main(
        ["serve", "--db", db, "--no-web", "--opcua-endpoint", "opc.tcp://h:4840",
         "--opcua-security", "sign"]
    )  # fmt: skip
    err = capsys.readouterr().err
    assert code == 2 and "--opcua-security sign" in err


def _wait_for_line(log: Path, text: str, proc: Any, seconds: float = 120.0) -> bool:
    """Whether ``text`` appears in the log before the process ends (or ``seconds`` pass)."""
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        if text in log.read_text(errors="replace"):
            return True
        if proc.poll() is not None:
            return text in log.read_text(errors="replace")
        time.sleep(0.2)
    return False


@pytest.mark.slow
def test_serve_runs_one_opcua_server_per_store_and_another_takes_over(
    plant: Plant, tmp_path: Path
) -> None:
    """Two ``serve`` processes on one store: one serves OPC UA (the lease); when it stops
    the other takes over. ``--opcua-security none`` with anonymous access, as asked for."""
    import os
    import signal
    import subprocess
    import sys

    root = Path(__file__).resolve().parents[1]
    env = dict(os.environ, PYTHONPATH=str(root), OPENBLAS_NUM_THREADS="1")
    ports = [_free_port(), _free_port()]
    procs, logs = [], []
    for k, port in enumerate(ports):
        log = tmp_path / f"serve-{k}.log"
        logs.append(log)
        with log.open("wb") as err:
            procs.append(
                subprocess.Popen(
                    [
                        sys.executable,
                        "-m",
                        "chaintwin",
                        "serve",
                        "--db",
                        plant.url,
                        "--no-web",
                        "--lease-s",
                        "3",
                        "--opcua-endpoint",
                        f"opc.tcp://127.0.0.1:{port}",
                        "--opcua-security",
                        "none",
                        "--opcua-allow-anonymous",
                    ],
                    stdout=subprocess.DEVNULL,
                    stderr=err,
                    env=env,
                    cwd=tmp_path,
                )
            )

    async def conveyor_id(port: int) -> str:
        async with Client(f"opc.tcp://127.0.0.1:{port}", timeout=10) as client:
            ns = await client.get_namespace_index(NAMESPACE_URI)
            node = client.get_node(_nid(ns, node_id(PROFILE.id, "Identification/ConveyorId")))
            return str(await node.read_value())

    try:
        up = [
            _wait_for_line(log, "conveyors published in", p, 0.1)
            for log, p in zip(logs, procs, strict=True)
        ]
        while not any(up):
            up = [
                _wait_for_line(log, "conveyors published in", p, 1)
                for log, p in zip(logs, procs, strict=True)
            ]
            assert all(p.poll() is None for p in procs), [log.read_text() for log in logs]
        first = up.index(True)
        other = 1 - first
        assert asyncio.run(conveyor_id(ports[first])) == PROFILE.id
        assert "OPC UA server at" not in logs[other].read_text()  # it stands by
        procs[first].send_signal(signal.SIGTERM)
        assert procs[first].wait(60) == 0
        assert _wait_for_line(logs[other], "conveyors published in", procs[other])
        assert asyncio.run(conveyor_id(ports[other])) == PROFILE.id
    finally:
        for p in procs:
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
                try:
                    p.wait(60)
                except subprocess.TimeoutExpired:
                    p.kill()
                    p.wait(10)


# ------------------------------------------------------------------ quiet while idle
def test_an_idle_subscription_sleeps_yet_sends_its_keep_alives_and_wakes_for_a_change(
    plant: Plant, running: Running
) -> None:
    """asyncua's loop wakes every publishing interval; the patched one only when a value
    is queued or the keep-alive is due, and the keep-alives still come in time."""
    from chaintwin.live.opcua_idle import QuietSubscription, QuietSubscriptionService

    assert running.server.server is not None
    iserver = running.server.server.iserver
    assert isinstance(iserver.subscription_service, QuietSubscriptionService)
    changes: queue.Queue[Any] = queue.Queue()
    keep_alives = threading.Semaphore(0)
    calls: list[float] = []

    class Handler:
        def datachange_notification(self, node: Any, val: Any, data: Any) -> None:
            changes.put(val)

    state: dict[str, Any] = {}
    nid = node_id(PROFILE.id, "Monitoring/Payload")

    async def subscribe() -> None:
        client = await _client(running, plant.token_name, plant.token, running.trusted)
        await client.connect()
        state["client"] = client
        ns = await client.get_namespace_index(NAMESPACE_URI)
        params = ua.CreateSubscriptionParameters(
            RequestedPublishingInterval=50,  # ms: a keep-alive every 10 intervals, 0.5 s
            RequestedLifetimeCount=300,
            RequestedMaxKeepAliveCount=10,
            MaxNotificationsPerPublish=0,
            PublishingEnabled=True,
            Priority=0,
        )
        sub = await client.create_subscription(params, Handler())
        await sub.subscribe_data_change(client.get_node(_nid(ns, nid)))
        internal = iserver.subscription_service.subscriptions[sub.subscription_id]
        state["internal"], state["ns"] = internal, ns

    running.loop.run(subscribe())
    try:
        internal = state["internal"]
        assert isinstance(internal, QuietSubscription)
        changes.get(timeout=30)  # the initial value

        async def watch() -> None:
            publish, send = internal.publish_results, internal.pub_result_callback

            async def counted(requestdata: Any = None) -> bool:
                calls.append(time.monotonic())
                return bool(await publish(requestdata))

            async def sent(result: ua.PublishResult, *rest: Any) -> None:
                if not result.NotificationMessage.NotificationData:
                    keep_alives.release()
                await send(result, *rest)

            internal.publish_results, internal.pub_result_callback = counted, sent

        running.loop.run(watch())
        for _ in range(3):
            assert keep_alives.acquire(timeout=60), "no keep-alive on an idle subscription"
        # asyncua's loop: 10 calls per keep-alive (30 in all); the quiet one: one each (and a
        # few more should a Publish request be late: it then ticks until one comes)
        assert len(calls) < 15, f"{len(calls)} wake-ups for 3 keep-alives"

        before = len(calls)
        sentinel = 1234.5

        async def write(value: float | None) -> None:
            assert running.server.server is not None
            kind = ua.VariantType.Null if value is None else ua.VariantType.Double
            dv = ua.DataValue(ua.Variant(value, kind))
            await running.server.server.write_attribute_value(_nid(state["ns"], nid), dv)

        known = running.server._known[PROFILE.id].values["Monitoring/Payload"].value
        running.loop.run(write(sentinel))
        try:
            assert changes.get(timeout=30) == sentinel
            # woken by the value: one publish at the next interval (and at most a keep-alive)
            assert len(calls) - before <= 2
        finally:
            running.loop.run(write(known))
    finally:
        running.loop.run(state["client"].disconnect())


def test_the_session_watchdogs_of_connected_clients_are_quiet(
    plant: Plant, running: Running
) -> None:
    from chaintwin.live.opcua_idle import WATCHDOG_S

    async def look() -> list[float]:
        client = await _client(running, plant.token_name, plant.token, running.trusted)
        await client.connect()
        try:
            assert running.server.server is not None
            bserver = running.server.server.bserver
            assert bserver is not None
            return [p.processor._watchdog_interval for p in bserver.clients if p.processor]
        finally:
            await client.disconnect()

    intervals = running.loop.run(look())
    assert intervals and all(i == WATCHDOG_S for i in intervals)


def test_the_store_watch_sees_another_connection_s_commit_and_only_then(
    tmp_path: Path,
) -> None:
    import sqlite3

    from chaintwin.live.store_watch import StoreWatch

    db = tmp_path / "w.db"
    with sqlite3.connect(db) as c:
        c.execute("PRAGMA journal_mode=WAL")
        c.execute("CREATE TABLE t (x INTEGER)")
    watch = StoreWatch(f"sqlite:///{db}")
    assert watch.moved()  # the first look
    assert not watch.moved()
    with sqlite3.connect(db) as c:
        c.execute("INSERT INTO t VALUES (1)")
    assert watch.moved()
    assert not watch.moved()
    watch.close()
    assert StoreWatch("postgresql://u@h/db").moved()  # another database: always asked
    assert StoreWatch(f"sqlite:///{tmp_path / 'missing' / 'x.db'}").moved()


def test_the_asyncua_pin_is_the_range_the_idle_patches_are_tested_against() -> None:
    import importlib.metadata
    import re
    import tomllib

    from chaintwin.live.opcua_idle import TESTED

    root = Path(__file__).resolve().parents[1]
    live = tomllib.loads((root / "pyproject.toml").read_text())["project"]["optional-dependencies"]
    pin = next(d for d in live["live"] if d.startswith("asyncua"))
    low, high = TESTED
    assert pin == f"asyncua>={low[0]}.{low[1]},<{high[0]}.{high[1]}"
    installed = tuple(int(x) for x in re.findall(r"\d+", importlib.metadata.version("asyncua"))[:2])
    assert low <= installed < high  # the patches apply here (the tests above use them)
