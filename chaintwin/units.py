"""Canonical channels, the units the data contract accepts, and SI conversion.

Everything inside chaintwin is SI on the motor side: s, rad, rad/s, Nm.
Conversion happens here, at the edge, and nowhere else.

Two units need a number from outside the column: ``inc`` needs the encoder's
``increments_per_rev`` and ``%`` needs the motor's ``nominal_torque_nm``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final

__all__ = [
    "CANONICAL_CHANNELS",
    "REQUIRED_CHANNELS",
    "RPM_TO_RAD_S",
    "SI_UNITS",
    "ChannelSpec",
    "G",
    "UnitContext",
    "accepted_units",
    "from_si_factor",
    "to_si_factor",
]

RPM_TO_RAD_S: Final = 2.0 * math.pi / 60.0

G: Final = 9.81
"""Gravitational acceleration, m/s² (the one value every module uses)."""


@dataclass(frozen=True, slots=True)
class ChannelSpec:
    """A canonical channel of a drive recording.

    Parameters
    ----------
    name : str
        Canonical name (``speed``, ``torque``, ...).
    quantity : str
        What it measures, for messages.
    si_unit : str
        The unit it has inside chaintwin.
    units : tuple of str
        The units the data contract accepts for it.
    """

    name: str
    quantity: str
    si_unit: str
    units: tuple[str, ...]


_SPECS: Final = (
    ChannelSpec("time", "time", "s", ("s", "ms")),
    ChannelSpec("speed_setpoint", "speed", "rad/s", ("rad/s", "rpm", "1/min")),
    ChannelSpec("speed", "speed", "rad/s", ("rad/s", "rpm", "1/min")),
    ChannelSpec("position_setpoint", "position", "rad", ("rad", "rev", "inc")),
    ChannelSpec("position", "position", "rad", ("rad", "rev", "inc")),
    ChannelSpec("torque_setpoint", "torque", "Nm", ("Nm", "%")),
    ChannelSpec("torque", "torque", "Nm", ("Nm", "%")),
    ChannelSpec("digital_inputs", "bits", "-", ("-",)),
)

#: Canonical channel name → its specification, in the contract's order.
CANONICAL_CHANNELS: Final[dict[str, ChannelSpec]] = {s.name: s for s in _SPECS}

#: Channels without which a recording is refused.
REQUIRED_CHANNELS: Final = ("time", "speed", "torque")

#: Canonical channel name → SI unit used inside chaintwin.
SI_UNITS: Final[dict[str, str]] = {s.name: s.si_unit for s in _SPECS}


@dataclass(frozen=True, slots=True)
class UnitContext:
    """Numbers some units need to be converted.

    Parameters
    ----------
    increments_per_rev : float or None
        Encoder increments per motor revolution, for ``inc``.
    nominal_torque_nm : float or None
        Motor nominal torque in Nm, for ``%``.
    """

    increments_per_rev: float | None = None
    nominal_torque_nm: float | None = None


def accepted_units(channel: str) -> tuple[str, ...]:
    """Return the units the data contract accepts for a canonical channel."""
    return CANONICAL_CHANNELS[channel].units


def to_si_factor(channel: str, unit: str, context: UnitContext) -> float:
    """Return the factor that converts ``channel`` values in ``unit`` to SI.

    Parameters
    ----------
    channel : str
        Canonical channel name.
    unit : str
        One of :func:`accepted_units` for ``channel``.
    context : UnitContext
        Supplies ``increments_per_rev`` and ``nominal_torque_nm``.

    Returns
    -------
    float
        Multiply the column by this to get SI values.

    Raises
    ------
    KeyError
        If the unit is not accepted for the channel.
    ValueError
        If the unit needs a number the context does not hold; the message
        names the metadata key.
    """
    if unit not in CANONICAL_CHANNELS[channel].units:
        raise KeyError(unit)
    if unit in ("s", "rad/s", "rad", "Nm", "-"):
        return 1.0
    if unit == "ms":
        return 1e-3
    if unit in ("rpm", "1/min"):
        return RPM_TO_RAD_S
    if unit == "rev":
        return 2.0 * math.pi
    if unit == "inc":
        if context.increments_per_rev is None:
            raise ValueError("increments_per_rev")
        return 2.0 * math.pi / context.increments_per_rev
    if unit == "%":
        if context.nominal_torque_nm is None:
            raise ValueError("nominal_torque_nm")
        return context.nominal_torque_nm / 100.0
    raise KeyError(unit)  # pragma: no cover - guarded by the table above


def from_si_factor(channel: str, unit: str, context: UnitContext) -> float:
    """Return the factor that converts SI values of ``channel`` to ``unit``.

    The inverse of :func:`to_si_factor`, with the same errors.
    """
    return 1.0 / to_si_factor(channel, unit, context)
