"""Faults of the virtual conveyor, each on a documented dimensionless scale.

A fault is given as ``NAME:SEVERITY`` (``--fault friction:0.2``). Severity 0
is healthy; the scales are chosen so that 1.0 is a clearly developed fault
that a maintenance engineer would act on.

==============  ==============================================================
name            what severity s does to the plant
==============  ==============================================================
friction        rail friction coefficient × (1 + s): friction:0.2 = +20 %
lubrication     gear-unit lubrication loss: speed-dependent losses BmB and BmC
                × (1 + s), constant loss BmA × (1 + s/2)
bearing         rotor bearing defect: torque ripple at the non-integer order
                3.57 of motor speed (outer-race pass of a 9-ball bearing) with
                amplitude s × 4 % of nominal torque, plus its second harmonic
                at half that, plus broadband torque noise × (1 + s)
gear_tooth      a damaged tooth on the second gear stage's pinion: one impulse
                per revolution of that shaft, s × 20 % of nominal torque, one
                tooth mesh wide
obstruction     a local obstruction on the rail at one place of the belt loop:
                a resisting force of s × the whole belt's rail friction
                (μ·g·(m_b + m_t)) over 50 mm of belt travel, once per belt
                revolution
elongation      chain elongation (wear of pins and bushes): pitch longer by
                s × 3 % (3 % is a usual replacement limit); the chain rides
                higher on the sprocket (radius × (1 + ε)), the polygon effect
                is on, articulation friction rises: μ × (1 + 2ε), and the
                links no longer seat on the tooth flanks: an engagement impact
                once per tooth pass, torque ripple at the tooth-pass order z/i
                and its 2nd and 3rd harmonic of s × 2 % of nominal torque / h
payload_step    a tray of s × 20 kg is placed on the moving belt at the middle
                of the constant-speed run
rail_obstacle   an obstacle fixed to the rail (a bent guide, a screw head) that
                one tray hits once per belt revolution: a resisting force of
                s × 3 × the whole belt's rail friction over 10 mm of travel,
                at a place of the loop that differs per conveyor
sprocket        a worn drive sprocket (hooked, thinned teeth): the chain snaps
                off each tooth as it leaves it, a resisting impulse once per
                tooth engagement of s × 15 % of nominal torque over 15 % of
                the tooth pitch (the tooth-pass order z/i); no friction or
                radius change (that is ``elongation``)
payload_event   an item caught between a tray and a guide for part of a
                cycle: in a recording with probability 0.05, a resisting force
                of s × the whole belt's rail friction over 0.2-1.0 s of
                travel at a random time of the constant-speed run (a drag, not
                a knock); nothing in the other recordings
==============  ==============================================================

A plant has one impulse train (``gear_tooth`` or ``sprocket``) and one
resisting place on the belt (``obstruction``, ``rail_obstacle`` or
``payload_event``): two faults that need the same one are refused together.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

from chaintwin.errors import ModelError

__all__ = [
    "BEARING_ORDER",
    "ELONGATION_IMPACT",
    "EXCLUSIVE",
    "FAULT_NAMES",
    "PAYLOAD_EVENT_CHANCE",
    "PAYLOAD_EVENT_FORCE",
    "PAYLOAD_EVENT_S",
    "SPROCKET_IMPACT",
    "SPROCKET_WIDTH",
    "Fault",
    "check_exclusive",
    "parse_fault",
    "parse_faults",
]

FAULT_NAMES = (
    "friction",
    "lubrication",
    "bearing",
    "gear_tooth",
    "obstruction",
    "elongation",
    "payload_step",
    "rail_obstacle",
    "sprocket",
    "payload_event",
)
"""Every fault the virtual conveyor can inject."""

BEARING_ORDER = 3.57
"""Order (per motor revolution) of the simulated bearing defect line."""

BEARING_AMPLITUDE = 0.04
"""Bearing ripple amplitude per unit severity, share of nominal torque."""

GEAR_TOOTH_AMPLITUDE = 0.20
"""Gear tooth impulse per unit severity, share of nominal torque."""

OBSTRUCTION_WIDTH_M = 0.05
"""Belt travel over which an obstruction acts, m."""

OBSTACLE_WIDTH_M = 0.01
"""Belt travel over which a rail obstacle acts, m."""

OBSTACLE_FORCE = 3.0
"""Rail obstacle force per unit severity, in units of the belt's rail friction."""

ELONGATION_PER_SEVERITY = 0.03
"""Chain pitch elongation per unit severity (3 % at severity 1)."""

ELONGATION_IMPACT = 0.02
"""Tooth-pass engagement impact per unit elongation severity, share of nominal torque."""

PAYLOAD_STEP_KG = 20.0
"""Mass placed on the moving belt per unit severity, kg."""

SPROCKET_IMPACT = 0.15
"""Worn-sprocket impulse per unit severity, share of nominal torque."""

SPROCKET_WIDTH = 0.15
"""Worn-sprocket impulse width, share of the tooth pitch (motor angle per tooth pass)."""

PAYLOAD_EVENT_CHANCE = 0.05
"""Probability that a recording holds a payload event."""

PAYLOAD_EVENT_FORCE = 1.0
"""Payload event force per unit severity, in units of the belt's rail friction."""

PAYLOAD_EVENT_S = (0.2, 1.0)
"""Range of a payload event's duration, s (drawn uniformly)."""

EXCLUSIVE = (
    ("gear_tooth", "sprocket"),
    ("obstruction", "rail_obstacle", "payload_event"),
)
"""Faults that share one mechanism of the plant: at most one of each group at a time."""


@dataclass(frozen=True, slots=True)
class Fault:
    """A fault and its severity (dimensionless, see the module table)."""

    name: str
    severity: float

    def __post_init__(self) -> None:
        if self.name not in FAULT_NAMES:
            raise ModelError(f"unknown fault '{self.name}'; use one of {', '.join(FAULT_NAMES)}")
        if not math.isfinite(self.severity) or self.severity < 0.0 or self.severity > 10.0:
            raise ModelError(
                f"fault '{self.name}' severity {self.severity!r} must be a number from 0 to 10"
            )

    def __str__(self) -> str:
        return f"{self.name}:{self.severity:g}"


def parse_fault(text: str) -> Fault:
    """Parse ``NAME:SEVERITY`` (e.g. ``bearing:0.5``).

    Raises
    ------
    ModelError
        Naming the text and the accepted names.
    """
    name, sep, value = text.partition(":")
    name = name.strip()
    if not sep:
        raise ModelError(f"fault '{text}' must be NAME:SEVERITY, e.g. friction:0.2")
    try:
        severity = float(value)
    except ValueError:
        raise ModelError(
            f"fault '{text}': severity '{value}' is not a number (e.g. friction:0.2)"
        ) from None
    return Fault(name, severity)


def parse_faults(texts: Iterable[str]) -> tuple[Fault, ...]:
    """Parse several ``NAME:SEVERITY`` texts; a name given twice is refused."""
    faults = tuple(parse_fault(t) for t in texts)
    names = [f.name for f in faults]
    for n in names:
        if names.count(n) > 1:
            raise ModelError(f"fault '{n}' is given twice; give each fault once")
    check_exclusive(names)
    return faults


def check_exclusive(names: Iterable[str]) -> None:
    """Refuse two faults that need the same mechanism of the plant (:data:`EXCLUSIVE`).

    Raises
    ------
    ModelError
        Naming the two faults.
    """
    given = set(names)
    for group in EXCLUSIVE:
        both = [n for n in group if n in given]
        if len(both) > 1:
            raise ModelError(
                f"faults {' and '.join(both)} cannot be simulated together (one plant "
                f"mechanism for {', '.join(group)}); give one of them"
            )
