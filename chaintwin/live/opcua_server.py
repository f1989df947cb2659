"""The OPC UA server of the twin's results (read side): payload, health, forecasts.

``chaintwin serve --opcua-endpoint opc.tcp://HOST:PORT`` runs a
:class:`ResultsServer` beside the web server, fed from the same store: one
object per conveyor with its profile's data (``Identification``), its latest
results (``Monitoring``) and its NE 107 status (``DeviceHealth``), laid out
and named as :mod:`chaintwin.live.opcua_nodes` says. The server learns of
new results by a cheap poll of the store (:data:`POLL_S`): one row of
counters; only when they change, one small row per conveyor, and only the
conveyors whose health model, profile or forecasts changed are read again.

Security: the users are the store's tokens (user name = the token's name,
password = the token; every role may read, none may write); anonymous
access only when asked for. ``Basic256Sha256`` sign-and-encrypt with the
server's own certificate, made on first start in the certificate folder,
which also holds the trust list (``trusted/certs``: a client certificate
found there is accepted; one that is not is refused and copied to
``rejected/certs`` for an administrator to move).
"""

from __future__ import annotations

import asyncio
import contextlib
import hmac
import logging
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, Protocol, cast
from urllib.parse import urlparse

from asyncua import ua
from asyncua.common.utils import ServiceError
from asyncua.crypto.permission_rules import User, UserRole
from asyncua.server.server import Server
from asyncua.server.user_managers import UserManager
from asyncua.ua.attribute_ids import AttributeIds
from asyncua.ua.object_ids import ObjectIds
from asyncua.ua.status_codes import StatusCodes
from sqlalchemy import func, select
from sqlalchemy.orm import Session

from chaintwin.errors import ConnectorError
from chaintwin.store.queries import signature_columns
from chaintwin.store.schema import (
    AlarmRow,
    ConveyorRow,
    DerivedHealthRow,
    MonitorStateRow,
)
from chaintwin.store.store import Store

from .opcua_idle import quiet_session_watchdogs, quiet_subscriptions
from .opcua_nodes import (
    DEVICE_HEALTH,
    NAMESPACE_URI,
    ROOT,
    UNITS,
    ConveyorKey,
    ConveyorReader,
    Value,
    conveyor_node_id,
    node_id,
)
from .store_watch import StoreWatch

__all__ = [
    "POLL_S",
    "SECURITY",
    "CertificateFolder",
    "ResultsServer",
    "TokenUsers",
    "parse_endpoint",
]

log = logging.getLogger("chaintwin.live")

POLL_S = 0.5
"""How often the server asks the store whether anything changed, s."""

SECURITY = ("basic256sha256", "none")
"""``--opcua-security`` values."""

LEASE = "opcua-server"
"""The lease one ``serve`` process of a store holds while it runs the server."""

_VARIANT = {
    "double": ua.VariantType.Double,
    "int": ua.VariantType.Int64,
    "uint": ua.VariantType.UInt32,
    "string": ua.VariantType.String,
    "strings": ua.VariantType.String,
    "datetime": ua.VariantType.DateTime,
    "health": ua.VariantType.Int32,
}
_DATATYPE = {
    "double": ObjectIds.Double,
    "int": ObjectIds.Int64,
    "uint": ObjectIds.UInt32,
    "string": ObjectIds.String,
    "strings": ObjectIds.String,
    "datetime": ObjectIds.DateTime,
}


def parse_endpoint(endpoint: str) -> tuple[str, int]:
    """The host and port of an ``opc.tcp://HOST:PORT[/path]`` endpoint.

    Raises
    ------
    ConnectorError
        When it is not such an address, naming ``--opcua-endpoint``.
    """
    parsed = urlparse(endpoint)
    try:
        port = parsed.port
    except ValueError:
        port = None
    if parsed.scheme != "opc.tcp" or not parsed.hostname or port is None:
        raise ConnectorError(
            f"--opcua-endpoint {endpoint}: give opc.tcp://HOST:PORT (e.g. opc.tcp://0.0.0.0:4840)"
        )
    return parsed.hostname, port


class TokenInfoLike(Protocol):
    """What the token check answers: the token's name and role."""

    @property
    def name(self) -> str:
        """The token's name (the OPC UA user name)."""

    @property
    def role(self) -> str:
        """The token's role (viewer, operator or admin)."""


TokenCheck = Callable[[Store, str], TokenInfoLike | None]
"""The active token matching a secret, or None: the web's token check
(``chaintwin.web.access.verify_token``), handed in by whoever starts the server
(the layers keep the live service below the web)."""


class TokenUsers(UserManager):
    """The store's tokens as OPC UA users: user name = token name, password = the token.

    Every active token may read (viewer, maintainer and admin alike: the
    server has nothing to write); an unknown, revoked or expired token, or a
    name that is not the token's, is refused (``BadUserAccessDenied``).
    Anonymous sessions only with ``anonymous``.
    """

    def __init__(
        self, store: Store, token_check: TokenCheck | None, anonymous: bool = False
    ) -> None:
        self.store = store
        self.token_check = token_check
        self.anonymous = anonymous
        self.refused = 0
        """Sessions refused so far."""

    def get_user(
        self,
        iserver: Any,
        username: str | None = None,
        password: str | None = None,
        certificate: Any = None,
    ) -> User | None:
        """The session's user, or None (refused)."""
        # ``certificate`` is the secure channel's client certificate (the server offers
        # no certificate user tokens): a session without user name and password is anonymous
        if not username and not password:
            if self.anonymous:
                return User(role=UserRole.User, name="anonymous")
            self.refused += 1
            return None
        if not username or not password:
            self.refused += 1
            return None
        if self.token_check is None:  # a server without users (the nodeset export)
            self.refused += 1
            return None
        try:
            info = self.token_check(self.store, str(password))
        except Exception as exc:  # the store is away: refused, and said why
            log.error("OPC UA login of %r: cannot check the token (%s)", username, exc)
            info = None
        if info is None or not hmac.compare_digest(info.name.encode(), str(username).encode()):
            self.refused += 1
            log.warning("OPC UA login refused for user %r", username)
            return None
        return User(role=UserRole.User, name=f"{info.name} ({info.role})")


class _ReadOnly:
    """What a session may call: browse, read, subscribe; no writes, calls or node changes."""

    def __init__(self) -> None:
        from asyncua.crypto.permission_rules import USER_TYPES

        barred = {
            ObjectIds.WriteRequest_Encoding_DefaultBinary,
            ObjectIds.CallRequest_Encoding_DefaultBinary,
        }
        self.allowed = {_ns0(t) for t in USER_TYPES if t not in barred}

    def check_validity(self, user: User, action_type_id: ua.NodeId, body: Any) -> bool:
        return user.role in (UserRole.User, UserRole.Admin) and action_type_id in self.allowed


@dataclass(frozen=True)
class CertificateFolder:
    """The server's certificate folder (``--opcua-cert-dir``).

    ``own/cert.der`` and ``own/private/key.pem`` (made on first start; the
    certificate renewed when expired), ``trusted/certs`` (client
    certificates, DER or PEM, that may connect), ``rejected/certs`` (those
    refused, for an administrator to move to ``trusted/certs``).
    """

    root: Path

    @property
    def cert(self) -> Path:
        return self.root / "own" / "cert.der"

    @property
    def key(self) -> Path:
        return self.root / "own" / "private" / "key.pem"

    @property
    def trusted(self) -> Path:
        return self.root / "trusted" / "certs"

    @property
    def rejected(self) -> Path:
        return self.root / "rejected" / "certs"

    def make(self) -> None:
        """Create the folders (the private key's readable by this user only).

        Raises
        ------
        ConnectorError
            When they cannot be created, naming the folder.
        """
        try:
            for d in (self.key.parent, self.trusted, self.rejected):
                d.mkdir(parents=True, exist_ok=True)
            self.key.parent.chmod(0o700)
        except OSError as exc:
            raise ConnectorError(
                f"--opcua-cert-dir {self.root}: cannot create it ({exc.strerror}); "
                "give a folder this user may write"
            ) from None


def application_uri() -> str:
    """The server's application URI (also in its certificate)."""
    return f"urn:chaintwin:server:{socket.gethostname()}"


@dataclass
class _Known:
    key: tuple[Any, ...]
    values: dict[str, Value]


@dataclass
class ResultsServer:
    """The OPC UA server of the store's results.

    Parameters
    ----------
    store : Store
        The results store.
    endpoint : str
        ``opc.tcp://HOST:PORT`` to listen on.
    security : str
        ``basic256sha256`` (sign and encrypt; needs ``cert_dir``) or ``none``.
    cert_dir : Path or None
        The certificate folder (:class:`CertificateFolder`).
    anonymous : bool
        Let sessions in without a user.
    token_check : TokenCheck or None
        How a user name and password are checked against the store's tokens
        (None: no user gets in; anonymous sessions only with ``anonymous``).
    poll_s : float
        Seconds between two looks at the store.
    """

    store: Store
    endpoint: str
    security: str = "basic256sha256"
    cert_dir: Path | None = None
    anonymous: bool = False
    token_check: TokenCheck | None = None
    poll_s: float = POLL_S
    server: Server | None = None
    ns: int = 0
    users: TokenUsers | None = None
    on_update: Callable[[str], None] | None = None
    """Called with a conveyor id after its values were written (tests, benchmarks)."""
    ready: threading.Event = field(default_factory=threading.Event)
    """Set once the server listens (other threads may wait on it)."""
    published: threading.Event = field(default_factory=threading.Event)
    """Set once the conveyors the store held at the start are in the address space (the
    server listens before: clients see them appear)."""
    _known: dict[str, _Known] = field(default_factory=dict)
    _nodes: set[str] = field(default_factory=set)
    _owned: dict[str, list[ua.NodeId]] = field(default_factory=dict)
    """Per conveyor, the node ids made for it (its object first), for its removal."""
    _stamp: tuple[Any, ...] | None = None
    _trust_mtime: float = -1.0
    _trust: Any = None
    _reader: ConveyorReader = field(init=False)
    _watch: StoreWatch = field(init=False)
    _stamp_query: Any = None

    def __post_init__(self) -> None:
        self._reader = ConveyorReader(self.store)
        self._watch = StoreWatch(str(self.store.engine.url))
        if self.security not in SECURITY:
            raise ConnectorError(
                f"--opcua-security {self.security}: give one of {', '.join(SECURITY)}"
            )
        parse_endpoint(self.endpoint)
        if self.security != "none" and self.cert_dir is None:
            raise ConnectorError(
                "--opcua-security basic256sha256 needs --opcua-cert-dir DIR: the server's "
                "certificate is made there, and its trust list kept"
            )

    # ------------------------------------------------------------ set-up
    async def build(self) -> Server:
        """The asyncua server with its security and namespace, not yet listening."""
        self.users = TokenUsers(self.store, self.token_check, self.anonymous)
        server = Server(user_manager=self.users)
        await server.init()
        quiet_subscriptions(server)
        server.set_endpoint(self.endpoint)
        server.set_server_name("chaintwin results")
        server.product_uri = "urn:chaintwin"
        server.manufacturer_name = "chaintwin"
        await server.set_application_uri(application_uri())
        tokens: list[type] = [ua.UserNameIdentityToken]
        if self.anonymous:
            tokens.append(ua.AnonymousIdentityToken)
        server.set_identity_tokens(tokens)
        if self.security == "none":
            server.set_security_policy([ua.SecurityPolicyType.NoSecurity], _ReadOnly())  # type: ignore[arg-type]
        else:
            assert self.cert_dir is not None
            await self._certificates(server, CertificateFolder(self.cert_dir))
            server.set_security_policy(
                [ua.SecurityPolicyType.Basic256Sha256_SignAndEncrypt],
                _ReadOnly(),  # type: ignore[arg-type]
            )
        self.ns = await server.register_namespace(NAMESPACE_URI)
        root = ua.AddNodesItem()
        root.RequestedNewNodeId = _sid(ROOT, self.ns)
        root.BrowseName = ua.QualifiedName(ROOT, self.ns)
        root.NodeClass = ua.NodeClass.Object
        root.ParentNodeId = _ns0(ObjectIds.ObjectsFolder)
        root.ReferenceTypeId = _ns0(ObjectIds.Organizes)
        root.TypeDefinition = _ns0(ObjectIds.FolderType)
        attrs = ua.ObjectAttributes()
        attrs.DisplayName = ua.LocalizedText(ROOT)
        attrs.Description = ua.LocalizedText("Every conveyor of the chaintwin store")
        root.NodeAttributes = attrs
        self.server = server
        await self._add([root])
        from asyncua.common.structures104 import new_enum

        await new_enum(
            server,
            _sid(HEALTH_TYPE, self.ns),
            ua.QualifiedName(HEALTH_TYPE, self.ns),
            [n for n, _v in sorted(DEVICE_HEALTH_NAMES.items(), key=lambda nv: nv[1])],
        )
        return server

    async def _certificates(self, server: Server, folder: CertificateFolder) -> None:
        from asyncua.crypto.cert_gen import setup_self_signed_certificate
        from asyncua.crypto.validator import CertificateValidator, CertificateValidatorOptions
        from cryptography.x509.oid import ExtendedKeyUsageOID

        folder.make()
        try:
            await setup_self_signed_certificate(
                folder.key,
                folder.cert,
                application_uri(),
                socket.gethostname(),
                [ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH],
                {"organizationName": "chaintwin", "commonName": "chaintwin results"},
            )
            folder.key.chmod(0o600)
            await server.load_certificate(str(folder.cert))
            await server.load_private_key(str(folder.key))
        except (OSError, ValueError) as exc:
            raise ConnectorError(
                f"--opcua-cert-dir {folder.root}: cannot make or read the server's certificate "
                f"({exc}); remove own/ to have a new one made"
            ) from None
        checks = CertificateValidator(
            CertificateValidatorOptions.EXT_VALIDATION | CertificateValidatorOptions.PEER_CLIENT
        )  # time, application URI, key usage: the trust list is checked below

        async def validate(cert: Any, app: ua.ApplicationDescription) -> None:
            try:
                await checks.validate(cert, app)
                trust = await self._load_trust(folder)  # a certificate just trusted counts
                if trust is None or not trust.is_trusted(cert):
                    raise ServiceError(StatusCodes.BadCertificateUntrusted)
            except ServiceError as exc:
                _reject(folder, cert)
                log.warning(
                    "OPC UA client certificate of %s refused (%s); copied to %s: move it to %s "
                    "to trust it",
                    app.ApplicationUri,
                    ua.StatusCode(ua.UInt32(exc.code)).name,
                    folder.rejected,
                    folder.trusted,
                )
                raise

        server.set_certificate_validator(validate)

    async def _load_trust(self, folder: CertificateFolder) -> Any:
        """The trust list of ``trusted/certs``, read again when the folder changed (None:
        it holds no certificate, and none is trusted)."""
        from asyncua.crypto.truststore import TrustStore

        try:
            files = [p for p in folder.trusted.iterdir() if p.is_file()]
            mtime = max([folder.trusted.stat().st_mtime] + [p.stat().st_mtime for p in files])
        except OSError:
            files, mtime = [], -1.0
        if mtime != self._trust_mtime:
            trust = None
            if files:
                trust = TrustStore([folder.trusted], [])
                try:
                    await trust.load()
                except ValueError:  # no certificate could be read
                    trust = None
            self._trust, self._trust_mtime = trust, mtime
        return self._trust

    async def _add(self, items: list[ua.AddNodesItem]) -> None:
        assert self.server is not None
        session = self.server.iserver.isession
        for r in await session.add_nodes(items):
            r.StatusCode.check()

    # ------------------------------------------------------------ nodes
    def _object(self, parent: str | ua.NodeId, sid: str, name: str, description: str) -> Any:
        item = ua.AddNodesItem()
        item.RequestedNewNodeId = _sid(sid, self.ns)
        item.BrowseName = ua.QualifiedName(name, self.ns)
        item.NodeClass = ua.NodeClass.Object
        item.ParentNodeId = parent if isinstance(parent, ua.NodeId) else _sid(parent, self.ns)
        item.ReferenceTypeId = _ns0(
            ObjectIds.Organizes if sid.count("/") <= 1 else ObjectIds.HasComponent
        )
        item.TypeDefinition = _ns0(
            ObjectIds.BaseObjectType if sid.count("/") == 1 else ObjectIds.FolderType
        )
        attrs = ua.ObjectAttributes()
        attrs.DisplayName = ua.LocalizedText(name)
        attrs.Description = ua.LocalizedText(description)
        item.NodeAttributes = attrs
        self._nodes.add(sid)
        return item

    def _variable(self, parent: str, sid: str, name: str, value: Value) -> list[Any]:
        item = ua.AddNodesItem()
        item.RequestedNewNodeId = _sid(sid, self.ns)
        item.BrowseName = ua.QualifiedName(name, self.ns)
        item.NodeClass = ua.NodeClass.Variable
        item.ParentNodeId = _sid(parent, self.ns)
        item.ReferenceTypeId = _ns0(ObjectIds.HasComponent)
        analog = value.unit is not None and value.kind in ("double", "uint", "int")
        item.TypeDefinition = _ns0(
            ObjectIds.BaseAnalogType if analog else ObjectIds.BaseDataVariableType
        )
        attrs = ua.VariableAttributes()
        attrs.DisplayName = ua.LocalizedText(name)
        attrs.Description = ua.LocalizedText(value.description)
        attrs.DataType = (
            _sid(HEALTH_TYPE, self.ns) if value.kind == "health" else _ns0(_DATATYPE[value.kind])
        )
        if value.kind == "strings":
            attrs.ValueRank = ua.ValueRank.OneDimension
            attrs.ArrayDimensions = [0]
        else:
            attrs.ValueRank = ua.ValueRank.Scalar
        attrs.Value = _variant(value)
        attrs.AccessLevel = ua.AccessLevel.CurrentRead.mask
        attrs.UserAccessLevel = ua.AccessLevel.CurrentRead.mask
        attrs.WriteMask = 0
        attrs.UserWriteMask = 0
        item.NodeAttributes = attrs
        self._nodes.add(sid)
        items = [item]
        if analog:
            assert value.unit is not None
            unit = UNITS[value.unit]
            eu = ua.AddNodesItem()
            eu.RequestedNewNodeId = _sid(sid + "/EngineeringUnits", self.ns)
            eu.BrowseName = ua.QualifiedName("EngineeringUnits", 0)
            eu.NodeClass = ua.NodeClass.Variable
            eu.ParentNodeId = item.RequestedNewNodeId
            eu.ReferenceTypeId = _ns0(ObjectIds.HasProperty)
            eu.TypeDefinition = _ns0(ObjectIds.PropertyType)
            ea = ua.VariableAttributes()
            ea.DisplayName = ua.LocalizedText("EngineeringUnits")
            ea.DataType = _ns0(ObjectIds.EUInformation)
            ea.ValueRank = ua.ValueRank.Scalar
            ea.Value = ua.Variant(
                ua.EUInformation(
                    NamespaceUri="http://www.opcfoundation.org/UA/units/un/cefact",
                    UnitId=unit.unit_id,
                    DisplayName=ua.LocalizedText(unit.symbol),
                    Description=ua.LocalizedText(unit.name),
                )
            )
            ea.AccessLevel = ua.AccessLevel.CurrentRead.mask
            ea.UserAccessLevel = ua.AccessLevel.CurrentRead.mask
            eu.NodeAttributes = ea
            items.append(eu)
        return items

    def _conveyor_items(self, conveyor: str, values: dict[str, Value]) -> list[Any]:
        """The nodes a conveyor's values need that the server does not hold yet."""
        items: list[Any] = []
        base = conveyor_node_id(conveyor)
        if base not in self._nodes:
            items.append(self._object(ROOT, base, conveyor, f"Conveyor {conveyor}"))
        for path, value in values.items():
            parts = path.split("/")
            parent = base
            for part in parts[:-1]:
                sid = f"{parent}/{part}"
                if sid not in self._nodes:
                    items.append(self._object(parent, sid, part, _FOLDERS.get(part, part)))
                parent = sid
            sid = node_id(conveyor, path)
            if sid not in self._nodes:
                items += self._variable(parent, sid, parts[-1], value)
        return items

    async def publish(self, conveyor: str, values: dict[str, Value]) -> int:
        """Put a conveyor's values into the address space (new nodes made); returns how many
        values changed."""
        assert self.server is not None
        known = self._known.get(conveyor)
        items = self._conveyor_items(conveyor, values)
        if items:
            await self._add(items)
            self._owned.setdefault(conveyor, []).extend(i.RequestedNewNodeId for i in items)
        changed = 0
        stamp = cast(ua.DateTime, datetime.now(UTC))
        for path, value in values.items():
            if known is not None and known.values.get(path) == value:
                continue
            dv = _Written(
                _variant(value),
                StatusCode=ua.StatusCode(
                    ua.UInt32(
                        StatusCodes.Good if value.value is not None else StatusCodes.BadNoData
                    )
                ),
                SourceTimestamp=stamp,
                ServerTimestamp=stamp,
            )
            await self.server.write_attribute_value(_sid(node_id(conveyor, path), self.ns), dv)
            changed += 1
        return changed

    async def remove(self, conveyor: str) -> int:
        """Take a conveyor that left the store out of the address space; returns the nodes
        removed.

        Each monitored item of its values first gets a last data change with the status
        ``BadNodeIdUnknown`` (and no value): a subscribed client learns that the node is
        gone, and its subscription goes on with its other items.
        """
        assert self.server is not None
        aspace = self.server.iserver.aspace
        owned = self._owned.pop(conveyor, [])
        gone = ua.DataValue(
            ua.Variant(None, ua.VariantType.Null),
            StatusCode=ua.StatusCode(ua.UInt32(StatusCodes.BadNodeIdUnknown)),
            SourceTimestamp=cast(ua.DateTime, datetime.now(UTC)),
            ServerTimestamp=cast(ua.DateTime, datetime.now(UTC)),
        )
        for nid in owned:
            data = aspace.get(nid)
            attr = None if data is None else data.attributes.get(AttributeIds.Value)
            if attr is None or not attr.datachange_callbacks:
                continue
            await aspace.write_attribute_value(nid, AttributeIds.Value, gone)
            # the callbacks told; asyncua's delete would call them again, unawaited
            for handle in list(attr.datachange_callbacks):
                aspace.delete_datachange_callback(handle)
        session = self.server.iserver.isession
        items = []
        if owned:
            # the only reference to its nodes from outside them: the conveyors' folder's
            # (asyncua's DeleteTargetReferences would search every node of the server)
            ref = ua.DeleteReferencesItem()
            ref.SourceNodeId = _sid(ROOT, self.ns)
            ref.ReferenceTypeId = _ns0(ObjectIds.Organizes)
            ref.IsForward = True
            ref.TargetNodeId = owned[0]
            ref.DeleteBidirectional = False
            await session.delete_references([ref])
        for nid in reversed(owned):  # children before their parents
            item = ua.DeleteNodesItem()
            item.NodeId = nid
            item.DeleteTargetReferences = False
            items.append(item)
        if items:
            for code in await session.delete_nodes(ua.DeleteNodesParameters(items)):
                code.check()
        prefix = conveyor_node_id(conveyor)
        self._nodes = {n for n in self._nodes if n != prefix and not n.startswith(prefix + "/")}
        self._known.pop(conveyor, None)
        self._reader.forget(conveyor)
        return len(items)

    # ------------------------------------------------------------ the store
    def _stamp_now(self) -> tuple[Any, ...]:
        """A few numbers that change whenever anything the server shows may have changed."""
        if self._stamp_query is None:  # built once: the poll runs it twice a second
            self._stamp_query = select(
                *signature_columns(),
                select(func.max(DerivedHealthRow.computed_at)).scalar_subquery(),
            )
        with self.store.engine.connect() as c:
            return tuple(c.execute(self._stamp_query).one())

    def _keys(self) -> dict[str, ConveyorKey]:
        """Per conveyor: what its values depend on (profile, health model version, forecasts,
        open alarms)."""
        with Session(self.store.engine) as s:
            rows = s.execute(
                select(
                    ConveyorRow.id,
                    ConveyorRow.profile_sha256,
                    MonitorStateRow.version,
                    DerivedHealthRow.computed_at,
                )
                .outerjoin(MonitorStateRow, MonitorStateRow.conveyor_id == ConveyorRow.id)
                .outerjoin(DerivedHealthRow, DerivedHealthRow.conveyor_id == ConveyorRow.id)
            ).all()
            alarms = dict(
                s.execute(
                    select(AlarmRow.conveyor_id, func.count())
                    .where(AlarmRow.status != "closed")
                    .group_by(AlarmRow.conveyor_id)
                ).all()
            )
        return {str(r[0]): (r[1], r[2], r[3], alarms.get(r[0], 0)) for r in rows}

    def changed(self) -> tuple[list[tuple[str, tuple[Any, ...]]], list[str]]:
        """The conveyors whose values may have changed since the last look, and those that
        left the store (blocking I/O)."""
        stamp = self._stamp_now()
        if stamp == self._stamp:
            return [], []
        keys = self._keys()
        self._stamp = stamp
        gone = [c for c in self._owned if c not in keys]
        return [(c, k) for c, k in keys.items() if (self._known.get(c) or _NONE).key != k], gone

    def forget_looks(self) -> None:
        """Make the next :meth:`refresh` look at the store again in full: after a look
        that failed part-way, what was committed before it is not yet published (the
        store's change counter and stamp already moved past it)."""
        self._watch.close()
        self._stamp = None

    async def refresh(self) -> int:
        """Look at the store once; publish what changed, remove the conveyors that left it.
        Returns the conveyors updated or removed."""
        if self._stamp is not None and not self._watch.moved():
            return 0  # nothing committed since the last look (a SQLite store says so)
        changed, gone = await asyncio.to_thread(self.changed)
        done = 0
        for conveyor in gone:
            await self.remove(conveyor)
            log.info("OPC UA server: conveyor %s left the store; its nodes removed", conveyor)
            done += 1
            if self.on_update is not None:
                self.on_update(conveyor)
        for conveyor, key in changed:
            values = await asyncio.to_thread(self._reader.read, conveyor, key)
            if values is None:
                if conveyor in self._owned:  # gone between the two looks
                    await self.remove(conveyor)
                continue
            await self.publish(conveyor, values)
            self._known[conveyor] = _Known(key, values)
            done += 1
            if self.on_update is not None:
                self.on_update(conveyor)
        return done

    # ------------------------------------------------------------ running
    async def run(self, stop: asyncio.Event) -> None:
        """Serve until ``stop`` is set: build, listen, publish the store's conveyors (clients
        see them appear), poll."""
        server = await self.build()
        try:
            await server.start()
        except OSError as exc:
            raise ConnectorError(
                f"--opcua-endpoint {self.endpoint}: cannot listen ({exc.strerror or exc}); "
                "give a free port"
            ) from None
        quiet_session_watchdogs(server)
        log.info("OPC UA server at %s (%s)", self.endpoint, self.security)
        self.ready.set()
        try:
            started = time.perf_counter()
            count = await self.refresh()
            self.published.set()
            log.info(
                "OPC UA server: %d conveyors published in %.1f s",
                count,
                time.perf_counter() - started,
            )
            while not stop.is_set():
                # a plain sleep (a stop is seen within one poll): waiting on ``stop`` with a
                # timeout made a task and a timer twice a second
                await asyncio.sleep(self.poll_s)
                if stop.is_set():
                    break
                try:
                    await self.refresh()
                except Exception as exc:  # ours, or SQLAlchemy's: the store away for a moment
                    log.error("OPC UA server: cannot read the store (%s)", exc)
                    self.forget_looks()
        finally:
            self.ready.clear()
            self.published.clear()
            self._watch.close()
            await server.stop()


_NONE = _Known((), {})


class _Written(ua.DataValue):
    """A value the server writes and never changes afterwards: its own deep copy.

    asyncua copies each value written once per monitored item of its node
    (``copy.deepcopy``, against a caller changing it later): with 20 clients
    watching a value that was most of the serving process's work per
    recording. Every write makes a new one; none is changed once written.
    """

    __slots__ = ()

    def __deepcopy__(self, memo: dict[int, Any]) -> _Written:
        return self


HEALTH_TYPE = "DeviceHealthEnumeration"
"""The string node id of the server's copy of OPC 10000-100's ``DeviceHealthEnumeration``
(same names and values; the DI namespace itself is not loaded)."""

DEVICE_HEALTH_NAMES = {k.upper(): v for k, v in DEVICE_HEALTH.items()}

_FOLDERS = {
    "Identification": "What the conveyor's profile says (modelled after OPC 40001-1 "
    "Identification; not a conformant MachineIdentificationType)",
    "Monitoring": "The latest results, the health index and the remaining life",
    "Features": "Each monitored condition feature with its baseline band",
}


def _ns0(i: int) -> ua.NodeId:
    """A node id of OPC UA's own namespace."""
    return ua.NodeId(ua.Int32(i))


def _sid(text: str, ns: int) -> ua.NodeId:
    """A string node id of namespace ``ns``."""
    return ua.NodeId(ua.String(text), ua.Int16(ns))


def _variant(value: Value) -> ua.Variant:
    if value.value is None:
        return ua.Variant(None, ua.VariantType.Null)
    if value.kind == "strings":
        return ua.Variant(list(value.value), ua.VariantType.String)
    return ua.Variant(value.value, _VARIANT[value.kind])


def _reject(folder: CertificateFolder, cert: Any) -> None:
    """Copy a refused client certificate to ``rejected/certs`` (DER, named by its thumbprint)."""
    from cryptography.hazmat.primitives import hashes
    from cryptography.hazmat.primitives.serialization import Encoding

    with contextlib.suppress(OSError, ValueError):
        name = cert.fingerprint(hashes.SHA1()).hex()  # OPC UA's thumbprint
        (folder.rejected / f"{name}.der").write_bytes(cert.public_bytes(Encoding.DER))


async def export_nodeset(store: Store, out: Path, *, values: bool = False) -> int:
    """Write the namespace the server would publish for ``store`` as NodeSet2 XML.

    The server is built as ``serve`` builds it (not listening) with every
    conveyor of the store, and its namespace (:data:`NAMESPACE_URI`) written
    to ``out``. ``values``: the variables' current values too (the
    engineering units are always written: they describe the nodes).

    Returns
    -------
    int
        The nodes written.

    Raises
    ------
    ConnectorError
        When ``out`` cannot be written.
    """
    from asyncua.common.ua_utils import get_nodes_of_namespace
    from asyncua.common.xmlexporter import XmlExporter

    results = ResultsServer(store, "opc.tcp://127.0.0.1:4840", security="none")
    server = await results.build()
    await results.refresh()
    nodes = await get_nodes_of_namespace(server, [NAMESPACE_URI])
    exporter = XmlExporter(server, export_values=values)
    await exporter.build_etree(nodes)  # type: ignore[no-untyped-call]
    try:
        await exporter.write_xml(str(out))  # type: ignore[no-untyped-call]
    except OSError as exc:
        raise ConnectorError(f"--out {out}: cannot write it ({exc.strerror})") from None
    return len(nodes)
