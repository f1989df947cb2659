"""What monitoring is told and says: its settings and its result for one recording.

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
    "MonitorSettings",
    "RecordingResult",
    "SettingsGiven",
    "as_number",
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

    def __post_init__(self) -> None:
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
    features: dict[str, float | None] = field(default_factory=dict)
    exceeded: list[str] = field(default_factory=list)
    warnings: list[dict[str, str]] = field(default_factory=list)
    error: str | None = None

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
            "warnings": self.warnings,
            "conveyor": self.conveyor,
            "status": self.status,
            "uncertainty_kg": self.uncertainty_kg,
            "features": self.features,
            "exceeded": self.exceeded,
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> RecordingResult:
        """Inverse of :meth:`to_dict` (for results kept in a state)."""
        return cls(**{k: v for k, v in data.items() if k in cls.__dataclass_fields__})


def as_number(x: float | None) -> float:
    """NaN for an unknown value (None, as a state file stores it)."""
    return float("nan") if x is None else float(x)


def finite_or_none(x: float | None) -> float | None:
    """None for an unknown or non-finite value, else the float."""
    return None if x is None or not math.isfinite(x) else float(x)


def iso_utc(t: datetime | None) -> str | None:
    """ISO 8601 in UTC, so that times from plants in other zones compare as strings."""
    return None if t is None else t.astimezone(UTC).isoformat()


def parse_time(text: str | None) -> datetime | None:
    """A stored ISO time, None when absent or unreadable."""
    try:
        return None if text is None else datetime.fromisoformat(text)
    except (TypeError, ValueError):
        return None
