"""What monitoring is told and says: settings, the result of a recording, alarms, events.

Also the small conversions the health model's records share: unknown
values as NaN or None, times as ISO 8601 in UTC.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from datetime import UTC, datetime
from typing import Any

from chaintwin.errors import MonitorError

__all__ = [
    "EARLIEST_DATE",
    "LATEST_DATE",
    "LIFECYCLES",
    "NOT_COUNTED",
    "Acknowledgement",
    "Alarm",
    "Comment",
    "Event",
    "Evidence",
    "MonitorSettings",
    "RecordingResult",
    "SettingsGiven",
    "Shelving",
    "as_number",
    "date_in_span",
    "date_out_of_span",
    "finite_or_none",
    "iso_utc",
    "parse_time",
]

LIFECYCLES: tuple[str, ...] = (
    "unacknowledged",
    "acknowledged",
    "returned_unacknowledged",
    "shelved",
    "out_of_service",
    "closed",
)
"""An alarm's states in the words of ISA-18.2 (:meth:`Alarm.lifecycle`)."""

NOT_COUNTED: tuple[str, ...] = ("closed", "shelved", "out_of_service")
"""Lifecycles of alarms that neither fail scripts nor raise the health index."""


@dataclass(frozen=True, slots=True)
class MonitorSettings:
    """How a conveyor is monitored.

    Attributes
    ----------
    baseline_n : int
        Recordings in a baseline (and in a learned calibration).
    x, y : int
        An alarm needs ``x`` exceedances of a feature in the last ``y`` recordings.
    z_limit : float
        A feature exceeds more than this many robust baseline scales above
        its baseline (and more than its smallest relative change).
    """

    baseline_n: int = 20
    x: int = 3
    y: int = 10
    z_limit: float = 5.0
    residual: str = "inverse"
    """The model the residual features compare with: ``inverse`` (the rigid model
    driven by the measured speed) or ``closed-loop`` (the controller replica driven
    by the recorded set points, :mod:`chaintwin.identify.verification`)."""

    def __post_init__(self) -> None:
        if self.residual not in ("inverse", "closed-loop"):
            raise MonitorError(
                f"residual '{self.residual}' must be inverse or closed-loop", field="residual"
            )
        if self.baseline_n < 5:
            raise MonitorError(
                f"baseline_n {self.baseline_n} must be at least 5 recordings", field="baseline_n"
            )
        if not 1 <= self.x <= self.y:
            raise MonitorError(
                f"alarm_rule {self.x}/{self.y} needs 1 <= X <= Y", field="alarm_rule"
            )
        if not (math.isfinite(self.z_limit) and self.z_limit > 0):
            raise MonitorError(f"z_limit {self.z_limit} must be a positive number", field="z_limit")


@dataclass(frozen=True, slots=True)
class SettingsGiven:
    """Settings as a user gave them (None: not given), merged with stored ones.

    A state keeps the settings it was monitored with; options given again
    replace them, options left out keep them (and defaults apply to a new
    conveyor).
    """

    baseline_n: int | None = None
    x: int | None = None
    y: int | None = None
    z_limit: float | None = None
    residual: str | None = None

    def merged(self, stored: MonitorSettings | None) -> MonitorSettings:
        """The settings to use: given, else stored, else the defaults.

        Raises
        ------
        MonitorError
            When the result is not a valid setting.
        """
        base = stored or MonitorSettings()
        return MonitorSettings(
            baseline_n=base.baseline_n if self.baseline_n is None else self.baseline_n,
            x=base.x if self.x is None else self.x,
            y=base.y if self.y is None else self.y,
            z_limit=base.z_limit if self.z_limit is None else self.z_limit,
            residual=base.residual if self.residual is None else self.residual,
        )


@dataclass
class RecordingResult:
    """What monitoring says about one recording (``monitor --json`` object)."""

    file: str
    conveyor: str
    recorded_at: str | None
    status: str
    """``learning`` (calibration being learned), ``baseline`` (part of the
    baseline), ``monitored``, ``duplicate`` or ``refused``."""
    alarm: bool = False
    causes: list[dict[str, Any]] = field(default_factory=list)
    payload_kg: float | None = None
    uncertainty_kg: float | None = None
    tlf: float | None = None
    """Transport loss factor from the work at the sprocket (:mod:`chaintwin.weigh.tlf`)."""
    features: dict[str, float | None] = field(default_factory=dict)
    exceeded: list[str] = field(default_factory=list)
    warnings: list[dict[str, str]] = field(default_factory=list)
    error: str | None = None
    impacts: list[dict[str, Any]] = field(default_factory=list)
    """Torque impacts of the recording (:mod:`chaintwin.diagnose.impacts`)."""
    tlf_motor_shaft: float | None = None
    """Transport loss factor from the work at the motor shaft (the published definition)."""
    loss_drift: dict[str, float] | None = None
    """The relative loss drift the payload was weighed with: ``{mean, sigma}``."""
    since_known_run_s: float | None = None
    """Time since the conveyor's last recording with a known payload, s (zero tracking)."""

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready; a refused recording gives ``file`` and ``error`` only."""
        if self.error is not None:
            return {"file": self.file, "error": self.error}
        return {
            "file": self.file,
            "recorded_at": self.recorded_at,
            "alarm": self.alarm,
            "causes": self.causes,
            "payload_kg": self.payload_kg,
            "tlf": self.tlf,
            "tlf_motor_shaft": self.tlf_motor_shaft,
            "warnings": self.warnings,
            "conveyor": self.conveyor,
            "status": self.status,
            "uncertainty_kg": self.uncertainty_kg,
            "features": self.features,
            "exceeded": self.exceeded,
            "impacts": self.impacts,
            "loss_drift": self.loss_drift,
            "since_known_run_s": self.since_known_run_s,
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> RecordingResult:
        """Inverse of :meth:`to_dict` (for results kept in a state)."""
        return cls(**{k: v for k, v in data.items() if k in cls.__dataclass_fields__})


def _text(data: dict[str, Any], key: str, *, optional: bool = False) -> Any:
    """``data[key]`` checked to be a string (or None when ``optional``)."""
    value = data[key]
    if not (isinstance(value, str) or (optional and value is None)):
        raise TypeError(f"'{key}' must be a string, not {type(value).__name__}")
    return value


@dataclass(frozen=True, slots=True)
class Acknowledgement:
    """Who acknowledged an alarm, why and when (ISO time, UTC)."""

    by: str
    why: str
    at: str

    def to_dict(self) -> dict[str, str]:
        """JSON-ready."""
        return {"by": self.by, "why": self.why, "at": self.at}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Acknowledgement:
        """Inverse of :meth:`to_dict`; KeyError or TypeError when damaged."""
        return cls(by=_text(data, "by"), why=_text(data, "why"), at=_text(data, "at"))


@dataclass(slots=True)
class Evidence:
    """A feature that exceeded with an alarm's cause: what the alarm rests on.

    Attributes
    ----------
    feature : str
        The condition feature.
    kind : str
        ``statistical`` (against the baseline) or ``limit`` (an absolute limit).
    value : float or None
        Its latest value that met the rule (feature units; None when unknown).
    z : float or None
        Its distance from the baseline then, in robust baseline scales (None
        for a limit, or when unknown).
    since : str or None
        ISO time of its first exceedance in the window that made it join.
    """

    feature: str
    kind: str = "statistical"
    value: float | None = None
    z: float | None = None
    since: str | None = None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        return {
            "feature": self.feature,
            "kind": self.kind,
            "value": self.value,
            "z": self.z,
            "since": self.since,
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Evidence:
        """Inverse of :meth:`to_dict`; KeyError, TypeError or ValueError when damaged."""
        value, z = data.get("value"), data.get("z")
        return cls(
            feature=_text(data, "feature"),
            kind=str(data.get("kind", "statistical")),
            value=None if value is None else float(value),
            z=None if z is None else float(z),
            since=_text(data, "since", optional=True),
        )


@dataclass(frozen=True, slots=True)
class Comment:
    """A comment on an alarm: who wrote what, when (ISO time, UTC)."""

    by: str
    at: str
    text: str

    def to_dict(self) -> dict[str, str]:
        """JSON-ready."""
        return {"by": self.by, "at": self.at, "text": self.text}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Comment:
        """Inverse of :meth:`to_dict`; KeyError or TypeError when damaged."""
        return cls(by=_text(data, "by"), at=_text(data, "at"), text=_text(data, "text"))


@dataclass(frozen=True, slots=True)
class Shelving:
    """An alarm set aside for a time: who, why, when and until when (ISO, UTC)."""

    by: str
    why: str
    at: str
    until: str

    def to_dict(self) -> dict[str, str]:
        """JSON-ready."""
        return {"by": self.by, "why": self.why, "at": self.at, "until": self.until}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Shelving:
        """Inverse of :meth:`to_dict`; KeyError or TypeError when damaged."""
        return cls(
            by=_text(data, "by"),
            why=_text(data, "why"),
            at=_text(data, "at"),
            until=_text(data, "until"),
        )


def _later(a: str | None, b: datetime) -> bool:
    """Whether ISO time ``a`` is after ``b`` (False when ``a`` is absent or unreadable)."""
    t = parse_time(a)
    if t is None:
        return False
    if t.tzinfo is None:
        t = t.replace(tzinfo=UTC)
    return t > b


@dataclass(slots=True)
class Alarm:
    """An alarm of a conveyor's health model: one probable cause, its evidence.

    A conveyor has at most one open alarm per probable cause; every feature
    that exceeds with that cause is part of its ``evidence``.

    Attributes
    ----------
    id : str
        Short unique id (``acknowledge`` takes it).
    conveyor, feature, cause : str
        Where, the lead feature (the one that opened it) and the probable cause.
    change : float or None
        The lead feature's latest relative change against its baseline, 1
        (None while unknown).
    since : str or None
        ISO time of the first exceedance in the window that opened it.
    opened_at, last_seen : str or None
        ISO times of the recording that opened it and of the last that met the rule.
    status : str
        ``open`` or ``closed``.
    acknowledged : Acknowledgement or None
        Set while open: someone has seen it; it stays open (and counts) until it closes.
    closed_at, closed_by : str or None
        When and by what (quiet recordings, a maintenance event) it closed.
    rule : str
        The rule that raised it: ``x_of_y`` (X exceedances in the last Y
        recordings) or ``immediate`` (the first exceedance).
    kind : str
        ``statistical`` (against the baseline) or ``limit`` (an absolute limit
        of the profile's ``limits:``).
    limit : float or None
        The absolute limit exceeded (feature units), for ``kind`` ``limit``.
    evidence : list of Evidence
        Every feature that exceeded with its cause, the lead first.
    active : bool
        Whether the last judged recording met the rule of one of its features
        (False: its features are back in band, it closes once they stay so).
    shelved : Shelving or None
        Set aside until ``shelved.until`` (it then returns by itself).
    out_of_service_until : str or None
        Its conveyor is out of service until then (ISO time; no end: None
        with ``out_of_service`` set).
    out_of_service : bool
        Its conveyor is out of service.
    comments : list of Comment
        Comments, oldest first.
    merged : list of str
        Ids of alarms of the same cause grouped into this one (they still
        name it: :func:`~chaintwin.diagnose.alarms.group_by_cause`).
    """

    id: str
    conveyor: str
    feature: str
    cause: str
    change: float | None
    since: str | None
    opened_at: str | None
    last_seen: str | None
    status: str = "open"
    acknowledged: Acknowledgement | None = None
    closed_at: str | None = None
    closed_by: str | None = None
    rule: str = "x_of_y"
    kind: str = "statistical"
    limit: float | None = None
    evidence: list[Evidence] = field(default_factory=list)
    active: bool = True
    shelved: Shelving | None = None
    out_of_service: bool = False
    out_of_service_until: str | None = None
    comments: list[Comment] = field(default_factory=list)
    merged: list[str] = field(default_factory=list)

    def answers_to(self, alarm_id: str) -> bool:
        """Whether ``alarm_id`` names this alarm (its id, or one grouped into it)."""
        return alarm_id == self.id or alarm_id in self.merged

    @property
    def is_open(self) -> bool:
        """Whether the alarm is open (acknowledged or not)."""
        return self.status == "open"

    def close(self, at: str | None, by: str) -> None:
        """Close the alarm at ISO time ``at`` for the reason ``by``."""
        self.status = "closed"
        self.closed_at = at
        self.closed_by = by

    def is_shelved(self, now: datetime | None = None) -> bool:
        """Whether it is shelved at ``now`` (default: the clock); a shelf ends by itself."""
        if self.shelved is None:
            return False
        return _later(self.shelved.until, now or datetime.now(UTC))

    def is_out_of_service(self, now: datetime | None = None) -> bool:
        """Whether its conveyor is out of service at ``now`` (default: the clock)."""
        if not self.out_of_service:
            return False
        until = self.out_of_service_until
        return until is None or _later(until, now or datetime.now(UTC))

    def lifecycle(self, now: datetime | None = None) -> str:
        """Its state in ISA-18.2's words at ``now`` (default: the clock): one of :data:`LIFECYCLES`.

        ``closed`` (ISA's "normal"), else ``out_of_service`` while its
        conveyor is, else ``shelved`` until the shelf ends, else
        ``acknowledged``, ``unacknowledged`` (active) or
        ``returned_unacknowledged`` (its features back in band).
        """
        if not self.is_open:
            return "closed"
        if self.is_out_of_service(now):
            return "out_of_service"
        if self.is_shelved(now):
            return "shelved"
        if self.acknowledged is not None:
            return "acknowledged"
        return "unacknowledged" if self.active else "returned_unacknowledged"

    def counts(self, now: datetime | None = None) -> bool:
        """Whether it counts as a standing alarm: open, neither shelved nor out of service."""
        return self.lifecycle(now) not in NOT_COUNTED

    def to_dict(self, now: datetime | None = None) -> dict[str, Any]:
        """JSON-ready (the form of state files, the store and ``monitor --json``).

        ``lifecycle`` is its state at ``now`` (default: the clock).
        """
        out: dict[str, Any] = {
            "id": self.id,
            "conveyor": self.conveyor,
            "feature": self.feature,
            "cause": self.cause,
            "change": self.change,
            "since": self.since,
            "opened_at": self.opened_at,
            "last_seen": self.last_seen,
            "status": self.status,
            "acknowledged": None if self.acknowledged is None else self.acknowledged.to_dict(),
            "rule": self.rule,
            "kind": self.kind,
            "lifecycle": self.lifecycle(now),
            "evidence": [e.to_dict() for e in self.evidence],
            "active": self.active,
            "shelved_until": None if self.shelved is None else self.shelved.until,
            "shelved": None if self.shelved is None else self.shelved.to_dict(),
            "out_of_service": self.out_of_service,
            "out_of_service_until": self.out_of_service_until,
            "comments": [c.to_dict() for c in self.comments],
        }
        if self.merged:
            out["merged"] = list(self.merged)
        if self.limit is not None:
            out["limit"] = self.limit
        if self.status == "closed":
            out["closed_at"] = self.closed_at
            out["closed_by"] = self.closed_by
        return out

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Alarm:
        """Inverse of :meth:`to_dict` (``lifecycle`` is worked out again, not read).

        Raises
        ------
        KeyError, TypeError, ValueError
            When the record is damaged.
        """
        status = _text(data, "status")
        if status not in ("open", "closed"):
            raise ValueError(f"alarm status '{status}' is neither open nor closed")
        change = data["change"]
        ack = data.get("acknowledged")
        shelved = data.get("shelved")
        feature = _text(data, "feature")
        kind = str(data.get("kind", "statistical"))
        since = _text(data, "since", optional=True)
        evidence = [Evidence.from_dict(e) for e in data.get("evidence") or []]
        if not evidence:  # alarms stored before evidence existed rest on their feature
            evidence = [Evidence(feature, kind, None, None, since)]
        return cls(
            id=_text(data, "id"),
            conveyor=_text(data, "conveyor"),
            feature=feature,
            cause=_text(data, "cause"),
            change=None if change is None else float(change),
            since=since,
            opened_at=_text(data, "opened_at", optional=True),
            last_seen=_text(data, "last_seen", optional=True),
            status=status,
            acknowledged=None if ack is None else Acknowledgement.from_dict(ack),
            closed_at=data.get("closed_at"),
            closed_by=data.get("closed_by"),
            # alarms stored before rules and limits existed were statistical X-of-Y ones
            rule=str(data.get("rule", "x_of_y")),
            kind=kind,
            limit=None if data.get("limit") is None else float(data["limit"]),
            evidence=evidence,
            active=bool(data.get("active", True)),
            shelved=None if shelved is None else Shelving.from_dict(shelved),
            out_of_service=bool(data.get("out_of_service", False)),
            out_of_service_until=_text(data, "out_of_service_until", optional=True)
            if "out_of_service_until" in data
            else None,
            comments=[Comment.from_dict(c) for c in data.get("comments") or []],
            merged=[str(m) for m in data.get("merged") or []],
        )


@dataclass(slots=True)
class Event:
    """A maintenance event: recordings after ``at`` form a new baseline.

    Attributes
    ----------
    id : str
        Short unique id.
    kind : str
        One of :data:`~chaintwin.diagnose.state.MAINTENANCE_KINDS`.
    at : str
        ISO time (UTC) the work was done.
    by, why : str
        Who did it and why.
    recorded : str
        ISO time it was entered.
    applied : bool
        Whether monitoring has restarted its baseline for it.
    """

    id: str
    kind: str
    at: str
    by: str
    why: str
    recorded: str
    applied: bool = False

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        return {
            "id": self.id,
            "kind": self.kind,
            "at": self.at,
            "by": self.by,
            "why": self.why,
            "recorded": self.recorded,
            "applied": self.applied,
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Event:
        """Inverse of :meth:`to_dict`; KeyError or TypeError when damaged."""
        applied = data["applied"]
        if not isinstance(applied, bool):
            raise TypeError("'applied' must be true or false")
        return cls(
            id=_text(data, "id"),
            kind=_text(data, "kind"),
            at=_text(data, "at"),
            by=_text(data, "by"),
            why=_text(data, "why"),
            recorded=_text(data, "recorded"),
            applied=applied,
        )


def as_number(x: float | None) -> float:
    """NaN for an unknown value (None, as a state file stores it)."""
    return float("nan") if x is None else float(x)


def finite_or_none(x: float | None) -> float | None:
    """None for an unknown or non-finite value, else the float."""
    return None if x is None or not math.isfinite(x) else float(x)


def iso_utc(t: datetime | None) -> str | None:
    """ISO 8601 in UTC, so that times from plants in other zones compare as strings."""
    return None if t is None else t.astimezone(UTC).isoformat()


EARLIEST_DATE = datetime(1970, 1, 1, tzinfo=UTC)
"""The earliest time a user may give (maintenance, recordings' times)."""

LATEST_DATE = datetime(2200, 1, 1, tzinfo=UTC)
"""The latest time a user may give: later ones are typing mistakes, and years
past 9999 cannot be written in ISO 8601 once a time zone moves them."""


def date_out_of_span(at: datetime) -> str | None:
    """Why ``at`` is refused (outside :data:`EARLIEST_DATE`..:data:`LATEST_DATE`), or None.

    A time without a time zone is taken as UTC.
    """
    when = at if at.tzinfo is not None else at.replace(tzinfo=UTC)
    try:
        inside = EARLIEST_DATE <= when <= LATEST_DATE
    except OverflowError:  # year 1 or 9999 moved out of range by its time zone
        inside = False
    if inside:
        return None
    return (
        f"{at.isoformat()} is outside {EARLIEST_DATE.date()}..{LATEST_DATE.date()}; "
        "give a time in that span"
    )


def date_in_span(at: datetime | None) -> datetime | None:
    """``at`` as it is, for a pydantic validator (an API body's time field).

    Raises
    ------
    ValueError
        Outside :data:`EARLIEST_DATE`..:data:`LATEST_DATE` (:func:`date_out_of_span`).
    """
    refused = None if at is None else date_out_of_span(at)
    if refused is not None:
        raise ValueError(refused)
    return at


def parse_time(text: str | None) -> datetime | None:
    """A stored ISO time, None when absent or unreadable."""
    try:
        return None if text is None else datetime.fromisoformat(text)
    except (TypeError, ValueError):
        return None
