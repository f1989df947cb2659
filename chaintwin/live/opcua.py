"""Follow drives over OPC UA: each new scope in a drive's buffer becomes a recording.

The configuration file (docs/opcua.md) lists the drives::

    drives:
      - conveyor: white-belt-01
        endpoint: opc.tcp://127.0.0.1:4840

:func:`follow_drives` runs one task per drive: connect, subscribe to data
changes of the scope counter, and on each change read the channels and the
metadata in one Read request, build a :class:`~chaintwin.read.Recording`
with the file reader's own checks
(:func:`chaintwin.read.reader.recording_from_samples`), and hand it to ``submit``
with the source key ``opcua:<conveyor>:<counter>``. Counter gaps (scopes the
drive overwrote before they were read) are counted as ``missed``. A drive
that goes away is reconnected with exponential backoff; one drive down never
stops the others.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, Literal

import numpy as np
import yaml
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    field_validator,
    model_validator,
)

from chaintwin.errors import ChaintwinError, ConnectorError, RecordingError
from chaintwin.live.scope_layout import CHANNEL_KEYS, DEFAULT_NODES, unit_key
from chaintwin.read.files import read_limited, yaml_load
from chaintwin.read.profile import _format_validation_error
from chaintwin.read.reader import recording_from_samples
from chaintwin.read.recording import Recording
from chaintwin.units import accepted_units

__all__ = [
    "MAX_MESSAGE_BYTES",
    "MAX_SCOPE_SAMPLES",
    "DriveConfig",
    "DriveState",
    "DriveStatus",
    "OpcuaConfig",
    "ReconnectConfig",
    "Submit",
    "follow_drives",
    "load_opcua_config",
    "recording_from_scope",
]

from .sources import Submit

log = logging.getLogger("chaintwin.live.opcua")

MAX_SCOPE_SAMPLES = 2048
"""Most samples a drive's scope holds per channel; a longer array is refused unread."""

MAX_MESSAGE_BYTES = 8 * 1024 * 1024
"""Largest OPC UA message the client accepts, bytes (told to the drive when the
connection opens; a whole scope's Read answer is about 150 kB)."""

REQUIRED_NODES = ("counter", "sample_time", "speed", "torque")
"""``nodes`` keys a drive cannot do without (the others may be set to null)."""

_ENDPOINT = re.compile(r"^opc\.tcp://[^/\s:]+(:\d{1,5})?(/\S*)?$")
_NO_DATE = datetime(1601, 1, 2, tzinfo=UTC)  # OPC UA's null DateTime is 1601-01-01


# ---------------------------------------------------------------- configuration
class ReconnectConfig(BaseModel):
    """Backoff between attempts to reach a drive that is away.

    The first retry waits ``initial_s``; each failed attempt doubles the wait,
    up to ``max_s``. A connection that was up resets it to ``initial_s``.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    initial_s: float = Field(1.0, gt=0, le=3600)
    max_s: float = Field(30.0, gt=0, le=3600)

    @model_validator(mode="after")
    def _ordered(self) -> ReconnectConfig:
        if self.max_s < self.initial_s:
            raise ValueError("max_s must be at least initial_s")
        return self


class DriveConfig(BaseModel):
    """One drive: where it is, how to log in, and where its scope buffer is.

    Parameters
    ----------
    conveyor : str
        The conveyor id (its profile's ``id``).
    endpoint : str
        ``opc.tcp://host:port[/path]``.
    security_policy : {"None", "Basic256Sha256"}, optional
        Default: no security.
    security_mode : {"Sign", "SignAndEncrypt"}, optional
        With Basic256Sha256; default ``SignAndEncrypt``.
    username, password : str, optional
        User name login (else anonymous).
    certificate, private_key : Path, optional
        The client's application certificate (DER or PEM) and private key
        (PEM), needed by Basic256Sha256; relative to the configuration file.
    server_certificate : Path, optional
        The drive's certificate: when given, only a drive presenting it is
        trusted; else the certificate the drive announces is used.
    application_uri : str
        The client's application URI; must match the certificate's URI.
    nodes : dict
        Node ids overriding the default layout's (``speed``,
        ``counter``, ``speed_unit``, ...); null drops an optional node.
    units : dict
        Channel → unit, for drives without unit nodes (overrides them).
    timeout_s : float
        Time a request to the drive may take, s.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    conveyor: str = Field(min_length=1)
    endpoint: str
    security_policy: Literal["None", "Basic256Sha256"] | None = None
    security_mode: Literal["Sign", "SignAndEncrypt"] | None = None
    username: str | None = None
    password: str | None = None
    certificate: Path | None = None
    private_key: Path | None = None
    server_certificate: Path | None = None
    application_uri: str = "urn:chaintwin:client"
    nodes: dict[str, str | None] = Field(default_factory=dict)
    units: dict[str, str] = Field(default_factory=dict)
    timeout_s: float = Field(4.0, gt=0, le=600)

    @field_validator("endpoint")
    @classmethod
    def _opc_tcp(cls, value: str) -> str:
        if not _ENDPOINT.match(value):
            raise ValueError(
                f"'{value}' is not an OPC UA endpoint; write opc.tcp://host[:port][/path], "
                "e.g. opc.tcp://10.0.4.21:4840"
            )
        return value

    @model_validator(mode="after")
    def _consistent(self) -> DriveConfig:
        secure = self.security_policy == "Basic256Sha256"
        if self.security_mode is not None and not secure:
            raise ValueError("security_mode needs security_policy: Basic256Sha256")
        if secure and (self.certificate is None or self.private_key is None):
            raise ValueError(
                "security_policy Basic256Sha256 needs the client's certificate and private_key"
            )
        if (self.certificate is None) != (self.private_key is None):
            raise ValueError("give both certificate and private_key, or neither")
        if self.password is not None and self.username is None:
            raise ValueError("password without username; add the username")
        for key, value in self.nodes.items():
            if key not in DEFAULT_NODES:
                raise ValueError(
                    f"nodes: unknown key '{key}'; use one of {', '.join(DEFAULT_NODES)}"
                )
            if value is None and key in REQUIRED_NODES:
                raise ValueError(f"nodes: '{key}' is required and cannot be null")
            if value is not None:
                _check_node_id(key, value)
        for channel, unit in self.units.items():
            if channel not in CHANNEL_KEYS:
                raise ValueError(
                    f"units: unknown channel '{channel}'; use one of {', '.join(CHANNEL_KEYS)}"
                )
            if unit not in accepted_units(channel):
                raise ValueError(
                    f"units: '{unit}' is not a unit of {channel}; "
                    f"use one of {', '.join(accepted_units(channel))}"
                )
        return self

    def node_ids(self) -> dict[str, str]:
        """Every node id to read, by ``nodes`` key: the defaults with the overrides."""
        merged: dict[str, str | None] = {**DEFAULT_NODES, **self.nodes}
        return {k: v for k, v in merged.items() if v is not None}


class OpcuaConfig(BaseModel):
    """The drives to follow (``serve --opcua CONFIG.yaml``)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    drives: list[DriveConfig] = Field(min_length=1)
    reconnect: ReconnectConfig = Field(default_factory=ReconnectConfig)

    @model_validator(mode="after")
    def _unique(self) -> OpcuaConfig:
        seen: set[str] = set()
        for d in self.drives:
            if d.conveyor in seen:
                raise ValueError(f"conveyor '{d.conveyor}' is listed twice; list each drive once")
            seen.add(d.conveyor)
        return self


def _check_node_id(key: str, text: str) -> None:
    from asyncua import ua

    try:
        ua.NodeId.from_string(text)
    except Exception:
        raise ValueError(
            f"nodes: '{key}' is not a node id ({text!r}); write e.g. 'ns=2;s=Scope.Speed' "
            "or 'nsu=urn:...;i=1001'"
        ) from None


def load_opcua_config(path: Path) -> OpcuaConfig:
    """Read and check an OPC UA configuration file.

    Relative certificate paths are taken relative to the file's folder, and
    every certificate and key named must exist.

    Raises
    ------
    ConnectorError
        One line naming the file and the field, and what to do.
    """
    source = str(path)
    raw = read_limited(
        path, what="OPC UA configuration", error=lambda s, m: ConnectorError(f"{s}: {m}")
    )
    try:
        data = yaml_load(raw.decode("utf-8"))
    except UnicodeDecodeError:
        raise ConnectorError(f"{source}: not UTF-8 text; save it as UTF-8") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f", line {mark.line + 1}" if mark is not None else ""
        raise ConnectorError(f"{source}{where}: not valid YAML; fix the syntax") from None
    except RecursionError:
        raise ConnectorError(f"{source}: nested too deeply to be a configuration") from None
    if not isinstance(data, dict):
        raise ConnectorError(
            f"{source}: must be a YAML mapping with a 'drives' list (conveyor, endpoint per drive)"
        )
    try:
        config = OpcuaConfig.model_validate(data)
    except ValidationError as exc:
        raise ConnectorError(_format_validation_error(source, exc).replace("\n", " ")) from None
    base = Path(path).parent
    drives = []
    for i, d in enumerate(config.drives):
        files: dict[str, Any] = {}
        for name in ("certificate", "private_key", "server_certificate"):
            given: Path | None = getattr(d, name)
            if given is None:
                continue
            full = given if given.is_absolute() else base / given
            if not full.is_file():
                raise ConnectorError(
                    f"{source}: field 'drives.{i}.{name}': {full} is not a file; "
                    "give the path of the PEM or DER file",
                    field=f"drives.{i}.{name}",
                )
            files[name] = full
        drives.append(d.model_copy(update=files))
    return config.model_copy(update={"drives": drives})


# ---------------------------------------------------------------- state
@dataclass
class DriveState:
    """One drive as the service sees it (health, metrics).

    Parameters
    ----------
    endpoint : str
        The drive's endpoint URL.
    connected : bool
        A session is up.
    scopes_read : int
        Scopes read and handed to ``submit``.
    missed : int
        Scopes the drive overwrote before they were read (counter gaps).
    last_error : str or None
        The last connection or read problem, one line; None once connected.
    last_scope_at : datetime or None
        When the last scope was handed over, UTC.
    last_counter : int or None
        The drive's counter for the last scope taken; a restarted service
        given it again counts the gap since.
    connects : int
        Sessions opened (the first connection and every reconnection).
    refused : int
        Scopes that could not be made into a recording (``last_error`` says why).
    """

    endpoint: str
    connected: bool = False
    scopes_read: int = 0
    missed: int = 0
    last_error: str | None = None
    last_scope_at: datetime | None = None
    last_counter: int | None = None
    connects: int = 0
    refused: int = 0

    def to_dict(self) -> dict[str, Any]:
        """The state as JSON-ready values (times in ISO 8601), for the health endpoint."""
        return {
            "endpoint": self.endpoint,
            "connected": self.connected,
            "scopes_read": self.scopes_read,
            "missed": self.missed,
            "refused": self.refused,
            "connects": self.connects,
            "last_counter": self.last_counter,
            "last_error": self.last_error,
            "last_scope_at": None if self.last_scope_at is None else self.last_scope_at.isoformat(),
        }


@dataclass
class DriveStatus:
    """The drives followed, by conveyor id."""

    drives: dict[str, DriveState] = field(default_factory=dict)

    def to_dict(self) -> dict[str, dict[str, Any]]:
        """Each drive's :meth:`DriveState.to_dict` by conveyor id."""
        return {conveyor: state.to_dict() for conveyor, state in self.drives.items()}


# ---------------------------------------------------------------- a scope → a recording
def recording_from_scope(
    values: Mapping[str, Any],
    *,
    conveyor: str,
    source: str,
    units: Mapping[str, str] | None = None,
) -> Recording:
    """Build a recording from the values read from a drive's scope buffer.

    The scope's metadata and header are written as a file's head and the
    samples taken as numbers (:func:`~chaintwin.read.reader.recording_from_samples`:
    the file reader's own checks, without printing and parsing every
    sample), so a recording read over OPC UA passes the same checks, with
    the same refusals, and carries the same metadata, units and values as a
    file of it printed exactly.

    Parameters
    ----------
    values : Mapping[str, Any]
        ``nodes`` key → value read (channels as sequences of numbers in
        their unit, ``sample_time`` in s, ``trigger_time`` a datetime,
        ``<channel>_unit`` strings, ...). Missing keys are absent nodes.
    conveyor : str
        The conveyor id of the configuration.
    source : str
        Name of the recording (``opcua:<conveyor>:<counter>``).
    units : Mapping[str, str], optional
        Channel → unit, over the unit nodes.

    Raises
    ------
    RecordingError
        Naming the source and what is wrong with the scope.
    """
    drive_id = values.get("conveyor_id")
    if isinstance(drive_id, str) and drive_id.strip() and drive_id.strip() != conveyor:
        raise RecordingError(
            source,
            f"the drive says it is conveyor '{drive_id.strip()}', the configuration says "
            f"'{conveyor}'; correct the endpoint or conveyor in the configuration",
        )
    dt = _number(values.get("sample_time"))
    if dt is None or dt <= 0:
        raise RecordingError(
            source,
            f"sample time {values.get('sample_time')!r} is not a positive number of seconds; "
            "check the drive's sample time node",
        )
    lines = [f"# conveyor: {conveyor}"]
    when = values.get("trigger_time")
    if isinstance(when, datetime):
        when = when if when.tzinfo is not None else when.replace(tzinfo=UTC)
        if when > _NO_DATE:
            lines.append(f"# recorded_at: {when.astimezone(UTC).isoformat()}")
    lines.append(f"# sample_time_s: {dt!r}")
    for key, meta in (
        ("nominal_torque", "nominal_torque_nm"),
        ("increments_per_rev", "increments_per_rev"),
    ):
        number = _number(values.get(key))
        if number is not None and number > 0:
            lines.append(f"# {meta}: {number!r}")
    header = ["time [s]"]
    columns: list[np.ndarray] = []
    for key in CHANNEL_KEYS:
        samples = values.get(key)
        if samples is None or len(samples) == 0:
            continue
        if len(samples) > MAX_SCOPE_SAMPLES:
            raise RecordingError(
                source,
                f"channel {key} holds {len(samples)} samples, more than the "
                f"{MAX_SCOPE_SAMPLES} a drive's scope holds; check the drive's {key} node",
            )
        unit = (units or {}).get(key) or values.get(unit_key(key)) or ""
        if not isinstance(unit, str) or not unit.strip():
            raise RecordingError(
                source,
                f"channel {key} has no unit; give it in the drive's {unit_key(key)} node "
                f"or in the configuration's units ({', '.join(accepted_units(key))})",
            )
        try:
            column = np.asarray(samples, dtype=np.float64)
        except (TypeError, ValueError):
            raise RecordingError(source, f"channel {key} does not hold numbers") from None
        if column.ndim != 1:
            raise RecordingError(source, f"channel {key} is not a one-dimensional array")
        if columns and column.shape[0] != columns[0].shape[0]:
            raise RecordingError(
                source,
                f"channel {key} holds {column.shape[0]} samples, the channels before it "
                f"{columns[0].shape[0]}; every channel of a scope has the same length",
            )
        header.append(f"{key} [{unit.strip()}]")
        columns.append(column)
    if not columns:
        raise RecordingError(source, "the scope holds no samples; is the drive recording?")
    n = columns[0].shape[0]
    table = np.column_stack([np.arange(n, dtype=np.float64) * dt, *columns])
    # the head goes through the file reader's parsing, the numbers as they are
    head = "\n".join(lines) + "\n" + ",".join(header) + "\n"
    return recording_from_samples(head, table, source)


def _number(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    v = float(value)
    return v if math.isfinite(v) else None


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0]}" if text else type(exc).__name__


class _OneLine(logging.Handler):
    """asyncua's records as one debug line each on the service's logger.

    asyncua logs a lost connection with tracebacks of its own (e.g. "Publish
    iteration crashed; retrying in 1s" with a ``ConnectionError``) and
    warnings while a session is torn down; the follower says what happened
    in one line of its own, so these are kept for debugging only, without
    their tracebacks (the exception's one-line reason instead).
    """

    def emit(self, record: logging.LogRecord) -> None:
        """Log ``record`` again as one debug line on ``chaintwin.live``."""
        try:
            text = record.getMessage().strip().splitlines()
            message = text[0] if text else ""
            if record.exc_info and record.exc_info[1] is not None:
                message += f" ({_one_line(record.exc_info[1])})"
            log.debug("asyncua %s: %s", record.name, message, extra={"asyncua": record.levelname})
        except Exception:  # a logging handler never raises
            self.handleError(record)


def _quiet_asyncua() -> None:
    """Route asyncua's loggers through :class:`_OneLine` (once per process)."""
    logger = logging.getLogger("asyncua")
    if not any(isinstance(h, _OneLine) for h in logger.handlers):
        logger.addHandler(_OneLine())
    logger.propagate = False


# ---------------------------------------------------------------- following drives
async def follow_drives(
    config: OpcuaConfig, submit: Submit, stop: asyncio.Event, status: DriveStatus
) -> None:
    """Follow every configured drive until ``stop`` is set.

    One task per drive; a drive that is down, refuses the login or serves
    bad scopes is retried with backoff and never stops the others.
    ``status.drives`` (by conveyor id) is kept up to date; an entry already
    there for the same endpoint is carried on (its ``last_counter`` counts
    the gap since: a service that keeps it across restarts counts the
    scopes it missed while down).

    Parameters
    ----------
    config : OpcuaConfig
        The drives (:func:`load_opcua_config`).
    submit : Submit
        Called with each recording read and its source key
        ``opcua:<conveyor>:<counter>``.
    stop : asyncio.Event
        Set to stop: each drive's session is closed and the function returns.
    status : DriveStatus
        Updated in place.
    """
    followers = []
    for drive in config.drives:
        state = status.drives.get(drive.conveyor)
        if state is None or state.endpoint != drive.endpoint:  # another drive: counted afresh
            state = DriveState(drive.endpoint)
            status.drives[drive.conveyor] = state
        followers.append(_Follower(drive, config.reconnect, submit, state))
    tasks = [asyncio.create_task(f.run(stop), name=f"opcua:{f.drive.conveyor}") for f in followers]
    try:
        await asyncio.gather(*tasks)
    finally:
        for t in tasks:
            t.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)


class _Lost(Exception):
    """The connection to a drive was lost."""


class _Handler:
    """asyncua subscription handler: counter changes and status changes into a queue."""

    def __init__(self, events: asyncio.Queue[tuple[str, Any]]) -> None:
        self.events = events

    def datachange_notification(self, node: Any, val: Any, data: Any) -> None:
        self.events.put_nowait(("counter", val))

    def status_change_notification(self, status: Any) -> None:
        self.events.put_nowait(("lost", f"subscription status {status}"))


class _Follower:
    """Follows one drive: sessions, reconnects with backoff, scopes into recordings."""

    WATCHDOG_S = 1.0
    """How often asyncua checks that the drive still answers, s."""

    SESSION_TIMEOUT_MS = 600_000
    """How long a drive keeps a session whose client has gone, ms (asyncua's server maximum)."""

    PUBLISHING_INTERVAL_MS = 10.0
    """The subscription's publishing interval, ms. The counter changes once a scope, so
    a short interval costs no more notifications, only the drive's timer; 100 ms cost
    a scope 50 ms on average before the client heard of its counter. (0, the drive's
    fastest, makes asyncua's server send no keep-alives, and asyncua's client then
    recreates the subscription as stale every second between scopes.)"""

    KEEPALIVE_COUNT = 1000
    """Publishing intervals without a change before the drive sends a keep-alive (10 s):
    asyncua's client takes a subscription that heard nothing for 1.5 times that as
    stale and recreates it."""

    LIFETIME_COUNT = 10_000
    """Publishing intervals without a Publish request before the drive drops the
    subscription (at least three keep-alives, OPC UA Part 4, 5.13.2)."""

    def __init__(
        self, drive: DriveConfig, reconnect: ReconnectConfig, submit: Submit, state: DriveState
    ) -> None:
        self.drive = drive
        self.reconnect = reconnect
        self.submit = submit
        self.state = state
        self._up = False

    async def run(self, stop: asyncio.Event) -> None:
        """Follow the drive until ``stop``: sessions, and between them the backoff.

        The first failure of an outage (the drive lost, or not reached at
        start) is one warning line; the failed attempts after it, until a
        session is up again, are logged at debug level (the health endpoint
        shows the last error). The delay between attempts doubles from
        ``reconnect.initial_s`` up to ``reconnect.max_s``.
        """
        _quiet_asyncua()
        delay = self.reconnect.initial_s
        said = False  # the current outage has been logged
        while not stop.is_set():
            try:
                await self._session(stop)
            except asyncio.CancelledError:
                raise
            except Exception as exc:  # any failure of one drive: log, back off, retry
                reason = _one_line(exc)
                self.state.last_error = reason
                if self._up:  # it was connected: a new outage, the backoff starts again
                    delay = self.reconnect.initial_s
                    said = False
                extra = {"source": f"opcua:{self.drive.conveyor}", "reason": reason}
                if not said:
                    log.warning(
                        "drive %s (%s): %s; reconnecting with backoff, next attempt in %.1f s",
                        self.drive.conveyor,
                        self.drive.endpoint,
                        reason,
                        delay,
                        extra=extra,
                    )
                    said = True
                else:
                    log.debug(
                        "drive %s (%s): attempt failed (%s); next attempt in %.1f s",
                        self.drive.conveyor,
                        self.drive.endpoint,
                        reason,
                        delay,
                        extra=extra,
                    )
            finally:
                self.state.connected = False
            if stop.is_set():
                break
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(stop.wait(), timeout=delay)
            delay = min(delay * 2.0, self.reconnect.max_s)

    async def _client(self) -> Any:
        from asyncua import ua
        from asyncua.client.client import Client
        from asyncua.crypto.security_policies import SecurityPolicyBasic256Sha256

        d = self.drive
        client = Client(d.endpoint, timeout=d.timeout_s, watchdog_intervall=self.WATCHDOG_S)
        client.application_uri = d.application_uri
        client.session_timeout = self.SESSION_TIMEOUT_MS
        # the largest answer taken: the drive is told so, and asyncua refuses larger ones
        client.max_messagesize = MAX_MESSAGE_BYTES
        client.name = client.description = f"chaintwin ({d.conveyor})"
        if d.username is not None:
            client.set_user(d.username)
            if d.password is not None:
                client.set_password(d.password)
        if d.security_policy == "Basic256Sha256":
            assert d.certificate is not None and d.private_key is not None
            mode = (
                ua.MessageSecurityMode.Sign
                if d.security_mode == "Sign"
                else ua.MessageSecurityMode.SignAndEncrypt
            )
            await client.set_security(
                SecurityPolicyBasic256Sha256,
                certificate=str(d.certificate),
                private_key=str(d.private_key),
                server_certificate=None
                if d.server_certificate is None
                else str(d.server_certificate),
                mode=mode,
            )
        return client

    async def _resolve(self, client: Any) -> dict[str, Any]:
        """The node ids to read, with namespace URIs turned into the drive's indices."""
        from asyncua import ua

        namespaces: list[str] | None = None
        nodes: dict[str, Any] = {}
        for key, text in self.drive.node_ids().items():
            nid = ua.NodeId.from_string(text)
            uri = getattr(nid, "NamespaceUri", None)
            if uri:
                if namespaces is None:
                    namespaces = list(await client.get_namespace_array())
                if uri not in namespaces:
                    raise ConnectorError(
                        f"drive {self.drive.conveyor}: the drive has no namespace '{uri}' "
                        f"(node '{key}'); give the node ids of its scope buffer in 'nodes'",
                        field="nodes",
                    )
                nid = ua.NodeId(nid.Identifier, ua.Int16(namespaces.index(uri)), nid.NodeIdType)
            nodes[key] = client.get_node(nid)
        return nodes

    async def _session(self, stop: asyncio.Event) -> None:
        """One session: connect, subscribe, take scopes; returns when stop is set."""
        from asyncua import ua

        self._up = False
        client = await self._client()
        events: asyncio.Queue[tuple[str, Any]] = asyncio.Queue()

        async def lost(exc: Exception) -> None:
            events.put_nowait(("lost", _one_line(exc)))

        client.connection_lost_callback = lost
        stopper = asyncio.create_task(stop.wait())
        try:
            await client.connect()
            nodes = await self._resolve(client)
            params = ua.CreateSubscriptionParameters(
                RequestedPublishingInterval=self.PUBLISHING_INTERVAL_MS,
                RequestedLifetimeCount=self.LIFETIME_COUNT,
                RequestedMaxKeepAliveCount=self.KEEPALIVE_COUNT,
                MaxNotificationsPerPublish=10_000,
                PublishingEnabled=True,
                Priority=0,
            )
            sub = await client.create_subscription(params, _Handler(events))
            await sub.subscribe_data_change(nodes["counter"])
            self._up = True
            self.state.connected = True
            self.state.connects += 1
            self.state.last_error = None
            log.info(
                "drive %s connected (%s)",
                self.drive.conveyor,
                self.drive.endpoint,
                extra={"source": f"opcua:{self.drive.conveyor}"},
            )
            while True:
                getter = asyncio.create_task(events.get())
                await asyncio.wait({getter, stopper}, return_when=asyncio.FIRST_COMPLETED)
                if not getter.done():
                    getter.cancel()
                    return
                kind, value = getter.result()
                # only the newest counter matters: older scopes are overwritten already
                while not events.empty():
                    kind2, value2 = events.get_nowait()
                    if kind != "lost":
                        kind, value = kind2, value2
                if kind == "lost":
                    raise _Lost(f"connection lost ({value})")
                if not isinstance(value, int) or value == self.state.last_counter:
                    continue
                if value == 0:  # no scope yet (a new or restarted drive): counted from here
                    self.state.last_counter = 0
                else:
                    await self._take(client, nodes)
        finally:
            stopper.cancel()
            self.state.connected = False
            # the drive may be gone already: then there is nothing to close
            with contextlib.suppress(Exception):
                await asyncio.wait_for(client.disconnect(), timeout=2.0)

    async def _take(self, client: Any, nodes: dict[str, Any]) -> None:
        """Read the scope (one Read request) and hand it over as a recording."""
        keys = list(nodes)
        values = await client.read_attributes([nodes[k] for k in keys])
        read: dict[str, Any] = {}
        unreadable: list[str] = []
        for key, dv in zip(keys, values, strict=True):
            good = dv.StatusCode is None or dv.StatusCode.is_good()
            if good and dv.Value is not None:
                read[key] = dv.Value.Value
            elif key in REQUIRED_NODES:
                status = dv.StatusCode.name if dv.StatusCode is not None else "no value"
                unreadable.append(
                    f"'{key}' ({nodes[key].nodeid.to_string()}) cannot be read ({status})"
                )
        if "counter" not in read:
            raise ConnectorError(
                f"drive {self.drive.conveyor}: node {'; node '.join(unreadable)}; "
                "check 'nodes' in the configuration",
                field="nodes",
            )
        counter = read.get("counter")
        if not isinstance(counter, int) or counter <= 0:
            return
        st = self.state
        conveyor = self.drive.conveyor
        if st.last_counter is not None:
            if counter == st.last_counter:
                return
            if counter < st.last_counter:
                log.info(
                    "drive %s: counter went back from %d to %d (drive restarted?)",
                    conveyor,
                    st.last_counter,
                    counter,
                    extra={"source": f"opcua:{conveyor}"},
                )
            elif counter > st.last_counter + 1:
                gap = counter - st.last_counter - 1
                st.missed += gap
                log.warning(
                    "drive %s: %d scope(s) missed (counter %d after %d): overwritten "
                    "in the drive before they were read",
                    conveyor,
                    gap,
                    counter,
                    st.last_counter,
                    extra={"source": f"opcua:{conveyor}", "missed": gap},
                )
        key = f"opcua:{conveyor}:{counter}"
        try:
            if unreadable:
                raise ConnectorError(
                    f"{key}: node {'; node '.join(unreadable)}; check 'nodes' in the configuration",
                    field="nodes",
                )
            recording = await asyncio.to_thread(
                recording_from_scope, read, conveyor=conveyor, source=key, units=self.drive.units
            )
        except ChaintwinError as exc:  # the scope cannot be used: counted, said, not retried
            st.refused += 1
            st.last_error = str(exc).splitlines()[0]
            st.last_counter = counter
            log.warning("refused %s", st.last_error, extra={"source": key, "reason": st.last_error})
            return
        await self.submit(recording, key)
        st.scopes_read += 1
        st.last_counter = counter
        st.last_scope_at = datetime.now(UTC)
