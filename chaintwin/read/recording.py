"""The in-memory drive recording: SI channels, metadata and warnings.

A :class:`Recording` is what the reader produces and every later stage
consumes. Its arrays are SI on the motor side (s, rad/s, rad, Nm); the units
the file used are kept so a writer can produce the same format again.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from datetime import datetime
from typing import Any, Literal

import numpy as np
import numpy.typing as npt

from chaintwin._stats import median
from chaintwin._types import FloatArray

__all__ = [
    "WARNING_CODES",
    "Metadata",
    "Recording",
    "RecordingWarning",
]


WarningCode = Literal[
    "incomplete_cycle",
    "torque_saturated",
    "speed_windup",
    "no_motion",
    "irregular_sample_time",
    "payload_changed",
    "sample_time_mismatch",
    "profile_mismatch",
    "speed_not_following",
]

#: Every warning code chaintwin attaches, with when it is raised.
WARNING_CODES: Mapping[str, str] = {
    "incomplete_cycle": "the recording does not hold a whole movement (starts or ends in motion)",
    "torque_saturated": "the torque set point sits at the torque limit for a noticeable time",
    "speed_windup": "after a saturation the speed overshoots its set point (controllers wound up)",
    "no_motion": "the speed never leaves standstill",
    "irregular_sample_time": "the time steps are not uniform",
    "payload_changed": "(from weighing) the load changed during the movement",
    "sample_time_mismatch": "the metadata's sample_time_s disagrees with the time column",
    "profile_mismatch": "the recording's conveyor id is not the profile's id",
    "speed_not_following": "at constant set point the actual speed stays far from it",
}


@dataclass(frozen=True, slots=True)
class RecordingWarning:
    """A suspect but usable property of a recording, with a stable code.

    Parameters
    ----------
    code : str
        One of :data:`WARNING_CODES`.
    message : str
        What was seen, in words, with numbers.
    """

    code: str
    message: str

    def to_dict(self) -> dict[str, str]:
        """Return ``{"code": ..., "message": ...}`` for JSON output."""
        return {"code": self.code, "message": self.message}


@dataclass(frozen=True, slots=True)
class Metadata:
    """The ``# key: value`` lines of a recording, typed.

    Parameters
    ----------
    conveyor : str or None
        Conveyor id; matches a profile's ``id``.
    recorded_at : datetime or None
        When the scope was triggered, timezone-aware (UTC if no offset given).
    sample_time_s : float or None
        Nominal sample time, s.
    nominal_torque_nm : float or None
        Motor nominal torque, Nm (for ``%`` torque).
    increments_per_rev : float or None
        Encoder increments per motor revolution (for ``inc`` positions).
    payload_kg : float or None
        A known load on the belt, kg: on calibration recordings, and on
        recordings in operation with a known payload (zero tracking,
        :mod:`chaintwin.weigh.zero_tracking`).
    tray_kg : float or None
        Tray mass, kg; overrides the profile's ``tray_mass_kg``.
    extra : Mapping[str, str]
        Unknown keys, kept verbatim in file order.
    """

    conveyor: str | None = None
    recorded_at: datetime | None = None
    sample_time_s: float | None = None
    nominal_torque_nm: float | None = None
    increments_per_rev: float | None = None
    payload_kg: float | None = None
    tray_kg: float | None = None
    extra: Mapping[str, str] = field(default_factory=dict)


@dataclass(frozen=True, slots=True, eq=False)
class Recording:
    """One drive recording, SI on the motor side.

    Parameters
    ----------
    source : str
        The file as given (or a label for in-memory text).
    channels : Mapping[str, FloatArray]
        Channel name → samples. Canonical channels are in SI units
        (``time`` s, speeds rad/s, positions rad, torques Nm,
        ``digital_inputs`` as numbers); extra channels keep the file's values.
    units : Mapping[str, str]
        Channel name → unit as written in the file (``rpm``, ``%``, ...).
    headers : Mapping[str, str]
        Channel name → the header cell as written in the file.
    metadata : Metadata
        The metadata lines.
    warnings : tuple of RecordingWarning
        Suspect-but-usable findings; they travel to every later result.
    """

    source: str
    channels: Mapping[str, FloatArray]
    units: Mapping[str, str]
    headers: Mapping[str, str]
    metadata: Metadata
    warnings: tuple[RecordingWarning, ...] = ()
    memo: dict[str, Any] = field(init=False, default_factory=dict, repr=False, compare=False)
    """Quantities derived from the channels, once computed (the sample time, the
    acceleration: several steps of the pipeline ask for them); not copied by
    ``replace``, which may change the channels."""

    # ------------------------------------------------------------ accessors
    @property
    def time(self) -> FloatArray:
        """Time since the trigger, s."""
        return self.channels["time"]

    @property
    def speed(self) -> FloatArray:
        """Actual motor speed, rad/s."""
        return self.channels["speed"]

    @property
    def torque(self) -> FloatArray:
        """Actual motor torque, Nm."""
        return self.channels["torque"]

    @property
    def speed_setpoint(self) -> FloatArray | None:
        """Speed set point, rad/s, when recorded."""
        return self.channels.get("speed_setpoint")

    @property
    def position(self) -> FloatArray | None:
        """Actual motor position, rad (absolute, any offset), when recorded."""
        return self.channels.get("position")

    @property
    def position_setpoint(self) -> FloatArray | None:
        """Position set point, rad, when recorded."""
        return self.channels.get("position_setpoint")

    @property
    def torque_setpoint(self) -> FloatArray | None:
        """Torque set point of the speed controller, Nm, when recorded."""
        return self.channels.get("torque_setpoint")

    @property
    def digital_inputs(self) -> npt.NDArray[np.int64] | None:
        """Digital input bits as integers, when recorded."""
        di = self.channels.get("digital_inputs")
        return None if di is None else np.rint(di).astype(np.int64)

    @property
    def samples(self) -> int:
        """Number of samples."""
        return int(self.time.shape[0])

    @property
    def sample_time_s(self) -> float:
        """Sample time, s: the median time step of the time column."""
        ts = self.memo.get("sample_time_s")
        if ts is None:
            ts = self.memo["sample_time_s"] = median(np.diff(self.time))
        return float(ts)

    @property
    def duration_s(self) -> float:
        """Time from the first to the last sample, s."""
        return float(self.time[-1] - self.time[0])

    @property
    def extra_channels(self) -> tuple[str, ...]:
        """Names of the channels that are not canonical, in file order."""
        from chaintwin.units import CANONICAL_CHANNELS

        return tuple(n for n in self.channels if n not in CANONICAL_CHANNELS)

    def si_units(self) -> dict[str, str]:
        """Channel name → unit of the in-memory values (SI for canonical channels)."""
        from chaintwin.units import SI_UNITS

        return {n: SI_UNITS.get(n, self.units[n]) for n in self.channels}

    def with_warnings(self, *extra: RecordingWarning) -> Recording:
        """Return a copy with more warnings attached (duplicates by code+message dropped)."""
        seen = {(w.code, w.message) for w in self.warnings}
        new = [w for w in extra if (w.code, w.message) not in seen]
        return replace(self, warnings=(*self.warnings, *new))

    def has_warning(self, code: str) -> bool:
        """Return True when a warning with this code is attached."""
        return any(w.code == code for w in self.warnings)
