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
    "Acknowledgement",
    "Alarm",
    "Event",
    "MonitorSettings",
    "RecordingResult",
    "SettingsGiven",
    "as_number",
    "date_in_span",
    "date_out_of_span",
    "finite_or_none",
    "iso_utc",
    "parse_time",
]


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
class Alarm:
    """An alarm of a conveyor's health model (opened by the X-of-Y rule).

    Attributes
    ----------
    id : str
        Short unique id (``acknowledge`` takes it).
    conveyor, feature, cause : str
        Where, on which condition feature, and its probable cause.
    change : float or None
        The feature's latest relative change against its baseline, 1
        (None while unknown).
    since : str or None
        ISO time of the first exceedance in the window that opened it.
    opened_at, last_seen : str or None
        ISO times of the recording that opened it and of the last that met the rule.
    status : str
        ``open`` or ``closed``.
    acknowledged : Acknowledgement or None
        Set while open: it stays open but no longer fails ``--fail-on-alarm``.
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

    @property
    def is_open(self) -> bool:
        """Whether the alarm is open (acknowledged or not)."""
        return self.status == "open"

    def close(self, at: str | None, by: str) -> None:
        """Close the alarm at ISO time ``at`` for the reason ``by``."""
        self.status = "closed"
        self.closed_at = at
        self.closed_by = by

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (the form of state files, the store and ``monitor --json``)."""
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
        }
        if self.limit is not None:
            out["limit"] = self.limit
        if self.status == "closed":
            out["closed_at"] = self.closed_at
            out["closed_by"] = self.closed_by
        return out

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Alarm:
        """Inverse of :meth:`to_dict`.

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
        return cls(
            id=_text(data, "id"),
            conveyor=_text(data, "conveyor"),
            feature=_text(data, "feature"),
            cause=_text(data, "cause"),
            change=None if change is None else float(change),
            since=_text(data, "since", optional=True),
            opened_at=_text(data, "opened_at", optional=True),
            last_seen=_text(data, "last_seen", optional=True),
            status=status,
            acknowledged=None if ack is None else Acknowledgement.from_dict(ack),
            closed_at=data.get("closed_at"),
            closed_by=data.get("closed_by"),
            # alarms stored before rules and limits existed were statistical X-of-Y ones
            rule=str(data.get("rule", "x_of_y")),
            kind=str(data.get("kind", "statistical")),
            limit=None if data.get("limit") is None else float(data["limit"]),
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
