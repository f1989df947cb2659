"""A simulated drive: an OPC UA server publishing the virtual conveyor's scopes.

:class:`DriveSim` serves one drive's scope buffer in the default layout
(:mod:`chaintwin.live.scope_layout`, docs/opcua.md) and publishes a new
recording of the virtual conveyor (:func:`chaintwin.simulate.virtual.run_virtual`)
every interval, as ``chaintwin generate`` makes them: a payload drawn from a
range, the gear losses drifting with temperature, the motor angle carried
from one scope to the next, and faults growing from an onset counted in
recordings. Each scope's channels and metadata are written first and the
counter last, so that a client that sees the counter change reads a whole
scope.

Several simulators run in one process (tests, ``chaintwin demo --live``),
each on its own port. ``Server.init`` of asyncua takes about 4 s; a
simulator's network side can be stopped and started again
(:meth:`DriveSim.stop`, :meth:`DriveSim.start`) without it.
"""

from __future__ import annotations

import asyncio
import collections
import contextlib
import dataclasses
import hmac
import logging
import math
import socket
from collections.abc import Callable, Mapping, Sequence
from datetime import UTC, datetime
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np
from asyncua import ua
from asyncua.crypto.permission_rules import User, UserRole
from asyncua.server.server import Server
from asyncua.server.user_managers import UserManager

from chaintwin.errors import ConnectorError, ModelError
from chaintwin.live.scope_layout import CHANNEL_KEYS, NAMESPACE_URI, OBJECT_NAME
from chaintwin.read.profile import ConveyorProfile, ModelSpec
from chaintwin.read.recording import Recording
from chaintwin.simulate.faults import Fault
from chaintwin.simulate.fleet import _loss_scale, fault_severity
from chaintwin.simulate.virtual import Realism, run_virtual
from chaintwin.units import UnitContext, from_si_factor

__all__ = ["APPLICATION_URI", "DriveSim", "Published"]

log = logging.getLogger("chaintwin.live.drive_sim")

APPLICATION_URI = "urn:chaintwin:drive-sim"
"""The simulator's OPC UA application URI (its certificate must carry it)."""

_NULL_TIME = datetime(1601, 1, 1, tzinfo=UTC)  # OPC UA's "no date"
_EPOCH = datetime(2026, 1, 1, tzinfo=UTC)  # origin of the loss drift's phase


class Published:
    """One scope the simulator published: its counter, recording and ground truth.

    Parameters
    ----------
    counter : int
        The counter value it was published with.
    recording : Recording
        The recording, SI inside, as ``chaintwin simulate`` would write it.
    truth : dict
        The simulation's ground truth (payload, faults, loss scale, ...).
    faults : dict
        Every fault's severity in this scope.
    """

    __slots__ = ("counter", "faults", "recording", "truth")

    def __init__(
        self,
        counter: int,
        recording: Recording,
        truth: dict[str, object],
        faults: dict[str, float],
    ) -> None:
        self.counter = counter
        self.recording = recording
        self.truth = truth
        self.faults = faults


class DriveSim:
    """An OPC UA server that publishes a virtual conveyor's scope recordings.

    Parameters
    ----------
    profile : ConveyorProfile
        The conveyor; its id is published as ``ConveyorId``.
    port : int
        TCP port to listen on.
    host : str
        Address to listen on (``0.0.0.0``: every interface).
    interval_s : float
        Time between two scopes, s (:meth:`run`).
    faults : sequence of Fault
        Faults at their full severity.
    onset : int
        Scopes (0-based, counted from the first this simulator publishes)
        before the faults start to grow.
    ramp : int
        Scopes over which a fault grows from 0 to its full severity after
        the onset; 0: full severity from the onset on.
    seed : int
        Random seed: the same seed publishes the same recordings.
    sample_time_s : float
        The scope's sample time, s.
    payload_range_kg : (float, float)
        Payload drawn uniformly from this range for each scope, kg.
    drift : float
        Amplitude of the gear losses' temperature drift (0.05 = ±5 %).
    realism : Realism, optional
        Default: everything on.
    model : ModelSpec, optional
        Plant parameters (default: the profile's ``model:``, else typical values).
    certificate, private_key : Path, optional
        The server's certificate (DER or PEM) and private key (PEM). With
        them the server also offers Basic256Sha256 (Sign, SignAndEncrypt);
        files that do not exist are created (a self-signed certificate for
        :data:`APPLICATION_URI`).
    users : Mapping[str, str], optional
        User name → password of the users who may log in.
    anonymous : bool
        Whether a client may connect without logging in.
    """

    def __init__(
        self,
        profile: ConveyorProfile,
        *,
        port: int = 4840,
        host: str = "0.0.0.0",
        interval_s: float = 2.0,
        faults: Sequence[Fault] = (),
        onset: int = 0,
        ramp: int = 0,
        seed: int = 0,
        sample_time_s: float = 0.006,
        payload_range_kg: tuple[float, float] = (10.0, 40.0),
        drift: float = 0.05,
        realism: Realism | None = None,
        model: ModelSpec | None = None,
        certificate: Path | None = None,
        private_key: Path | None = None,
        users: Mapping[str, str] | None = None,
        anonymous: bool = True,
    ) -> None:
        if not (math.isfinite(interval_s) and interval_s > 0):
            raise ModelError(
                f"interval {interval_s!r} s must be a positive number", field="interval_s"
            )
        if onset < 0:
            raise ModelError(f"onset {onset} must be 0 or more (scopes)", field="onset")
        if ramp < 0:
            raise ModelError(f"ramp {ramp} must be 0 or more (scopes)", field="ramp")
        if not 0 < port < 65536:
            raise ModelError(f"port {port} must be from 1 to 65535", field="port")
        if (certificate is None) != (private_key is None):
            raise ConnectorError(
                "give both a certificate and a private key, or neither", field="certificate"
            )
        lo, hi = payload_range_kg
        if not 0.0 <= lo <= hi:
            raise ModelError(f"payload range {lo}-{hi} kg must satisfy 0 <= low <= high")
        self.profile = profile
        self.port = port
        self.host = host
        self.interval_s = interval_s
        self.faults = tuple(faults)
        self.onset = onset
        self.ramp = ramp
        self.sample_time_s = sample_time_s
        self.payload_range_kg = (lo, hi)
        self.drift = drift
        self.realism = realism or Realism()
        self.model = model
        self.certificate = certificate
        self.private_key = private_key
        self.users = dict(users or {})
        self.anonymous = anonymous
        if not anonymous and not self.users:
            raise ConnectorError("without anonymous login give at least one user", field="users")
        self.server: Server | None = None
        self.namespace_index = 0
        self.counter = 0
        self.running = False
        self.history: collections.deque[Published] = collections.deque(maxlen=32)
        """The last scopes published, newest last."""
        self._rng = np.random.default_rng(seed)
        self._angle = float(self._rng.uniform(0.0, 1000.0 * 2.0 * math.pi))
        self._nodes: dict[str, ua.NodeId] = {}
        self._prepared: Published | None = None

    # ---------------------------------------------------------------- lifecycle
    @property
    def endpoint(self) -> str:
        """The endpoint URL a client on this machine connects to."""
        host = "127.0.0.1" if self.host in ("0.0.0.0", "") else self.host
        return f"opc.tcp://{host}:{self.port}"

    def node_id(self, name: str) -> ua.NodeId:
        """The node id of a node of the layout by name (``Counter``, ``Speed.Unit``)."""
        return ua.NodeId(ua.String(f"{OBJECT_NAME}.{name}"), ua.Int16(self.namespace_index))

    async def init(self) -> None:
        """Build the server and its address space (about 4 s: asyncua's own nodes)."""
        if self.server is not None:
            return
        server = Server(user_manager=_Users(self.users, self.anonymous))
        await server.init()
        server.set_endpoint(f"opc.tcp://{self.host}:{self.port}")
        server.set_server_name(f"chaintwin drive-sim {self.profile.id}")
        await server.set_application_uri(APPLICATION_URI)
        policies = [ua.SecurityPolicyType.NoSecurity]
        if self.certificate is not None and self.private_key is not None:
            await _ensure_certificate(self.certificate, self.private_key)
            await server.load_certificate(str(self.certificate))
            await server.load_private_key(str(self.private_key))
            policies += [
                ua.SecurityPolicyType.Basic256Sha256_Sign,
                ua.SecurityPolicyType.Basic256Sha256_SignAndEncrypt,
            ]
        server.set_security_policy(policies)
        tokens: list[type] = [ua.AnonymousIdentityToken] if self.anonymous else []
        if self.users:
            tokens.append(ua.UserNameIdentityToken)
        server.set_identity_tokens(tokens)
        idx = await server.register_namespace(NAMESPACE_URI)
        self.namespace_index = idx
        scope = await server.nodes.objects.add_object(
            ua.NodeId(ua.String(OBJECT_NAME), ua.Int16(idx)), ua.QualifiedName(OBJECT_NAME, idx)
        )

        async def variable(name: str, value: object, vtype: ua.VariantType) -> None:
            parent = scope
            if "." in name:
                parent = server.get_node(self.node_id(name.rsplit(".", 1)[0]))
            nid = self.node_id(name)
            await parent.add_variable(
                nid, ua.QualifiedName(name.rsplit(".", 1)[-1], idx), ua.Variant(value, vtype)
            )
            self._nodes[name] = nid

        tn = self.profile.nominal_torque_nm
        await variable("ConveyorId", self.profile.id, ua.VariantType.String)
        await variable("TriggerTime", _NULL_TIME, ua.VariantType.DateTime)
        await variable("SampleTime", self.sample_time_s, ua.VariantType.Double)
        await variable("NominalTorque", float(tn) if tn else 0.0, ua.VariantType.Double)
        await variable("IncrementsPerRev", 0.0, ua.VariantType.Double)
        for node in CHANNEL_KEYS.values():
            await variable(node, [], ua.VariantType.Double)
            await variable(f"{node}.Unit", "", ua.VariantType.String)
        await variable("Counter", 0, ua.VariantType.UInt32)
        self.server = server

    async def start(self) -> None:
        """Listen on the port (after :meth:`init`, which it calls if needed)."""
        await self.init()
        assert self.server is not None
        if self.running:
            return
        try:
            await self.server.start()
        except OSError as exc:
            raise ConnectorError(
                f"drive-sim cannot listen on {self.host}:{self.port} ({exc.strerror or exc}); "
                "choose another --port",
                field="port",
            ) from None
        self.running = True
        log.info("drive-sim %s listening on %s", self.profile.id, self.endpoint)

    async def stop(self) -> None:
        """Stop listening and drop every connection; the address space is kept."""
        if self.server is not None and self.running:
            self.running = False
            await self.server.stop()

    def drop_connections(self) -> None:
        """Abort every client connection at once, as a network break does (synchronous)."""
        if self.server is None:
            return
        for transport in list(self.server.iserver.asyncio_transports):
            transport.abort()

    async def __aenter__(self) -> DriveSim:
        await self.start()
        return self

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        await self.stop()

    # ---------------------------------------------------------------- scopes
    def severities(self, k: int) -> list[Fault]:
        """Every fault's severity at the ``k``-th scope (0-based)."""
        if k < self.onset:
            return [Fault(f.name, 0.0) for f in self.faults]
        step = min(k, self.onset + self.ramp)
        days = self.onset + self.ramp + 1
        return [Fault(f.name, fault_severity(f, step, days, self.onset)) for f in self.faults]

    def simulate(self, when: datetime | None = None) -> Published:
        """Simulate the next scope (CPU-bound: run it in a thread); not yet published.

        Parameters
        ----------
        when : datetime, optional
            Trigger time (default: now, to the millisecond).
        """
        if when is None:
            when = _now_ms()
        k = self.counter
        severities = self.severities(k)
        active = [f for f in severities if f.severity > 0.0]
        lo, hi = self.payload_range_kg
        payload = float(self._rng.uniform(lo, hi))
        t_days = (when - _EPOCH).total_seconds() / 86400.0
        run = run_virtual(
            self.profile,
            payload_kg=payload,
            sample_time_s=self.sample_time_s,
            faults=active,
            realism=self.realism,
            seed=int(self._rng.integers(2**31)),
            model=self.model,
            recorded_at=when,
            loss_scale=_loss_scale(t_days, self.drift),
            initial_motor_angle=self._angle,
            source=f"drive-sim:{self.profile.id}:{k + 1}",
        )
        # unrecorded moves between scopes advance the belt
        self._angle = float(run.simulation.position[-1]) + float(self._rng.uniform(0, 5000.0))
        faults = {f.name: f.severity for f in severities}
        return Published(k + 1, run.recording, {**run.truth, "faults": faults}, faults)

    async def publish(self, scope: Published) -> int:
        """Write a scope into the buffer: channels and metadata first, the counter last.

        Returns
        -------
        int
            The new counter value.
        """
        await self.init()
        server = self.server
        assert server is not None
        rec = scope.recording
        meta = rec.metadata
        context = UnitContext(
            increments_per_rev=meta.increments_per_rev, nominal_torque_nm=meta.nominal_torque_nm
        )
        when = meta.recorded_at or datetime.now(UTC)

        def value(v: object, vtype: ua.VariantType) -> ua.DataValue:
            return ua.DataValue(
                ua.Variant(v, vtype),
                SourceTimestamp=_ua_time(when),
                ServerTimestamp=_ua_time(datetime.now(UTC)),
            )

        writes: list[tuple[str, ua.DataValue]] = []
        for key, node in CHANNEL_KEYS.items():
            if key in rec.channels:
                unit = rec.units[key]
                samples = rec.channels[key] * from_si_factor(key, unit, context)
                writes.append((node, value(samples.tolist(), ua.VariantType.Double)))
                writes.append((f"{node}.Unit", value(unit, ua.VariantType.String)))
            else:
                writes.append((node, value([], ua.VariantType.Double)))
                writes.append((f"{node}.Unit", value("", ua.VariantType.String)))
        writes += [
            ("ConveyorId", value(meta.conveyor or self.profile.id, ua.VariantType.String)),
            ("TriggerTime", value(when, ua.VariantType.DateTime)),
            ("SampleTime", value(meta.sample_time_s or rec.sample_time_s, ua.VariantType.Double)),
            ("NominalTorque", value(meta.nominal_torque_nm or 0.0, ua.VariantType.Double)),
            ("IncrementsPerRev", value(meta.increments_per_rev or 0.0, ua.VariantType.Double)),
        ]
        for name, dv in writes:
            await server.write_attribute_value(self._nodes[name], dv)
        counter = scope.counter
        await server.write_attribute_value(
            self._nodes["Counter"], value(counter, ua.VariantType.UInt32)
        )
        self.counter = counter
        self.history.append(scope)
        return counter

    def prepare(self) -> None:
        """Simulate the next scope now (CPU-bound), to be published by :meth:`publish_next`.

        Fails early on settings the simulation refuses (a sample time that is
        not a whole multiple of the controller cycle, ...) and compiles the
        simulator's kernels before the server starts. The scope's trigger time
        is set again when it is published.
        """
        self._prepared = self.simulate()

    async def publish_next(self) -> Published:
        """Simulate the next scope (in a thread) and publish it."""
        scope = self._prepared
        self._prepared = None
        if scope is None:
            scope = await asyncio.to_thread(self.simulate)
        else:  # simulated ahead: it triggers now
            stamp = _now_ms()
            meta = dataclasses.replace(scope.recording.metadata, recorded_at=stamp)
            rec = dataclasses.replace(scope.recording, metadata=meta)
            truth = {**scope.truth, "recorded_at": stamp.isoformat()}
            scope = Published(scope.counter, rec, truth, scope.faults)
        await self.publish(scope)
        return scope

    async def run(
        self,
        stop: asyncio.Event,
        *,
        count: int | None = None,
        on_publish: Callable[[Published], None] | None = None,
    ) -> None:
        """Listen and publish a scope every interval until ``stop`` is set, then stop.

        Each scope is simulated during the interval before it (:meth:`prepare`)
        and triggers when it is published, as a drive's counter changes when its
        scope is complete: the simulation's time is not a client's latency.

        Parameters
        ----------
        stop : asyncio.Event
            Set to stop.
        count : int, optional
            Stop by itself after this many scopes (and one more interval, so
            that clients can read the last one).
        on_publish : callable, optional
            Called with each scope once it is published.
        """
        await self.start()
        loop = asyncio.get_running_loop()
        due = loop.time()
        published = 0
        ahead: asyncio.Future[None] | None = None

        async def simulate_ahead(delay: float) -> None:
            # half an interval after a scope, once its clients have read it: the next
            # scope is simulated then, and triggers when it is published
            await asyncio.sleep(delay)
            await asyncio.to_thread(self.prepare)

        try:
            while not stop.is_set():
                if count is not None and published >= count:
                    break
                if ahead is not None:
                    await ahead
                    ahead = None
                scope = await self.publish_next()
                published += 1
                if on_publish is not None:
                    on_publish(scope)
                log.info(
                    "drive-sim %s published scope %d (%s)",
                    self.profile.id,
                    scope.counter,
                    ", ".join(f"{k}:{v:g}" for k, v in scope.faults.items()) or "healthy",
                )
                due += self.interval_s
                now = loop.time()
                if due < now:  # simulating took longer than the interval: skip ahead
                    due = now
                if count is None or published < count:
                    ahead = asyncio.ensure_future(simulate_ahead((due - now) / 2))
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(stop.wait(), timeout=due - now)
        finally:
            if ahead is not None:
                ahead.cancel()
                with contextlib.suppress(asyncio.CancelledError, Exception):
                    await ahead  # a scope not published: its failure is nobody's
            await self.stop()


class _Users(UserManager):
    """Who may log in: the given users by password, and anonymous clients when allowed."""

    def __init__(self, users: Mapping[str, str], anonymous: bool) -> None:
        self.users = users
        self.anonymous = anonymous

    def get_user(
        self,
        iserver: Any,
        username: str | None = None,
        password: str | None = None,
        certificate: Any = None,
    ) -> User | None:
        if username is None:
            return User(role=UserRole.User) if self.anonymous else None
        known = self.users.get(username)
        if known is None or password is None:
            return None
        if not hmac.compare_digest(known.encode(), password.encode()):
            return None
        return User(role=UserRole.User, name=username)


def _now_ms() -> datetime:
    """Now, UTC, to the millisecond (a scope's trigger time)."""
    now = datetime.now(UTC)
    return now.replace(microsecond=now.microsecond // 1000 * 1000)


def _ua_time(when: datetime) -> ua.DateTime:
    """A datetime as asyncua's DateTime type (the same instant)."""
    return ua.DateTime.fromtimestamp(when.timestamp(), tz=UTC)


async def _ensure_certificate(certificate: Path, private_key: Path) -> None:
    """Create a self-signed certificate and key for :data:`APPLICATION_URI` when missing."""
    if certificate.is_file() and private_key.is_file():
        return
    from asyncua.crypto.cert_gen import setup_self_signed_certificate
    from cryptography.x509.oid import ExtendedKeyUsageOID

    try:
        await setup_self_signed_certificate(
            private_key,
            certificate,
            APPLICATION_URI,
            socket.gethostname(),
            [ExtendedKeyUsageOID.SERVER_AUTH],
            {"organizationName": "chaintwin"},
        )
    except OSError as exc:
        raise ConnectorError(
            f"{exc.filename or certificate}: cannot write the certificate "
            f"({exc.strerror or exc}); give a writable path",
            field="certificate",
        ) from None
