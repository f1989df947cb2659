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

Every fault has one entry in the fault table (:class:`FaultType`,
:func:`fault_types`): the function that applies it to the plant, the features
it moves, the cause the diagnosis names and the end severity the evaluations
grow it to. The simulator, the probable causes
(:func:`chaintwin.diagnose.causes.explaining_causes`), the command line's
``--fault`` and the evaluation scripts read it from there;
:func:`register_fault` adds one (``docs/adding-a-fault.md``).
"""

from __future__ import annotations

import math
import zlib
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from chaintwin.errors import ModelError

if TYPE_CHECKING:  # the table is read by the command line at start: no plant imports
    from chaintwin.read.profile import ConveyorProfile
    from chaintwin.simulate.plant import PlantParameters

__all__ = [
    "BEARING_ORDER",
    "ELONGATION_IMPACT",
    "PAYLOAD_EVENT",
    "PAYLOAD_EVENT_CHANCE",
    "PAYLOAD_EVENT_FORCE",
    "PAYLOAD_EVENT_S",
    "SPROCKET_IMPACT",
    "SPROCKET_WIDTH",
    "Fault",
    "FaultType",
    "PlantEdit",
    "check_exclusive",
    "exclusive_groups",
    "expected_causes",
    "fault_names",
    "fault_type",
    "fault_types",
    "parse_fault",
    "parse_faults",
    "register_fault",
    "unregister_fault",
]

BEARING_ORDER = 3.57
"""Order (per motor revolution) of the simulated bearing defect line."""

BEARING_AMPLITUDE = 0.04
"""Bearing ripple amplitude per unit severity, share of nominal torque."""

GEAR_TOOTH_AMPLITUDE = 0.20
"""Gear tooth impulse per unit severity, share of nominal torque."""

OBSTRUCTION_WIDTH_M = 0.05
"""Belt travel over which an obstruction acts, m."""

OBSTRUCTION_PLACE = 0.37
"""Where on the belt loop the obstruction sits, share of the loop length."""

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

PAYLOAD_EVENT = "payload_event"
"""The fault drawn per recording (:func:`chaintwin.simulate.virtual.run_virtual`)."""

PAYLOAD_EVENT_CHANCE = 0.05
"""Probability that a recording holds a payload event."""

PAYLOAD_EVENT_FORCE = 1.0
"""Payload event force per unit severity, in units of the belt's rail friction."""

PAYLOAD_EVENT_S = (0.2, 1.0)
"""Range of a payload event's duration, s (drawn uniformly)."""


@dataclass(slots=True)
class PlantEdit:
    """A plant on its way to its faulty version: what the faults applied so far change.

    Parameters
    ----------
    profile : ConveyorProfile
        The conveyor.
    plant : PlantParameters
        The healthy plant (realism applied, no fault).
    nominal_torque_nm : float
        Nominal motor torque, N·m: the scale of the torque ripples and impulses.
    payload_step_time_s : float
        When a ``payload_step`` places its tray, s.
    rail_force_n : float
        The whole belt's rail friction of the healthy plant (μ·g·(m_b + m_t)), N.
    changes : dict of str to Any
        Fields of :class:`~chaintwin.simulate.plant.PlantParameters` to replace.
    mu : float
        Rail friction coefficient so far, 1.
    orders, amplitudes : list of float
        Torque ripple lines: orders per motor revolution and amplitudes, N·m.
    """

    profile: ConveyorProfile
    plant: PlantParameters
    nominal_torque_nm: float
    payload_step_time_s: float
    rail_force_n: float
    changes: dict[str, Any]
    mu: float
    orders: list[float] = field(default_factory=list)
    amplitudes: list[float] = field(default_factory=list)


ApplyFault = Callable[[PlantEdit, float], None]
"""Applies a fault of a severity (1) to a plant edit, in place."""


@dataclass(frozen=True, slots=True)
class FaultType:
    """One entry of the fault table: a simulated fault from plant to diagnosis.

    Parameters
    ----------
    name : str
        What ``--fault NAME:SEVERITY`` calls it.
    apply : callable
        ``apply(edit, severity)``: what the simulator does to the plant
        (:class:`PlantEdit`, changed in place).
    cause : str or None
        The probable cause the diagnosis names for it (several faults may
        share one); None: no cause (an operating change, not a fault).
    moves : tuple of str
        The features it raises: a feature's name, or ``comb`` for every
        ``comb_<shaft>``, ``mode`` for every ``mode_<line>``, ``impulsive``
        for the impulsive features. A present cause explains the rise of a
        feature its faults move whose own cause is another
        (:func:`chaintwin.diagnose.causes.explaining_causes`).
    end_severity : float or None
        Severity the evaluations grow it to by their last recording; None:
        not evaluated.
    alarmed : bool
        The evaluations expect an alarm naming ``cause`` (False: an event of
        operation, reported and never alarmed).
    mechanism : str or None
        The plant mechanism it needs; two faults of one mechanism are
        refused together.
    torque_noise_gain : float
        Broadband torque noise grows by this × severity (share of the healthy noise).
    summary : str
        One line for help texts and docs.
    """

    name: str
    apply: ApplyFault
    cause: str | None
    moves: tuple[str, ...] = ()
    end_severity: float | None = None
    alarmed: bool = True
    mechanism: str | None = None
    torque_noise_gain: float = 0.0
    summary: str = ""

    @property
    def expected_cause(self) -> str | None:
        """The cause an evaluation expects an alarm to name, None for no alarm."""
        return self.cause if self.alarmed else None


def _friction(edit: PlantEdit, s: float) -> None:
    edit.mu *= 1.0 + s


def _lubrication(edit: PlantEdit, s: float) -> None:
    c = edit.changes
    c["loss_constant_nm"] *= 1.0 + 0.5 * s
    c["loss_viscous_nm_s_rad"] *= 1.0 + s
    c["loss_quadratic_nm_s2_rad2"] *= 1.0 + s


def _bearing(edit: PlantEdit, s: float) -> None:
    tn = edit.nominal_torque_nm
    edit.orders += [BEARING_ORDER, 2.0 * BEARING_ORDER]
    edit.amplitudes += [s * BEARING_AMPLITUDE * tn, 0.5 * s * BEARING_AMPLITUDE * tn]


def _gear_tooth(edit: PlantEdit, s: float) -> None:
    stages = edit.profile.gear.stages
    if stages and len(stages) >= 2:
        shaft_order = stages[0][0] / stages[0][1]
        teeth = stages[1][0]
    else:
        shaft_order = 1.0 / edit.plant.ratio
        teeth = 20
    period = 2.0 * math.pi / shaft_order
    edit.changes["impulse_period_rad"] = period
    edit.changes["impulse_width_rad"] = period / teeth
    edit.changes["impulse_amplitude_nm"] = s * GEAR_TOOTH_AMPLITUDE * edit.nominal_torque_nm


def _sprocket(edit: PlantEdit, s: float) -> None:
    plant = edit.plant
    if plant.teeth <= 0:
        return
    # one engagement per tooth: the motor turns ratio/z per tooth pass
    period = 2.0 * math.pi * plant.ratio / plant.teeth
    edit.changes["impulse_period_rad"] = period
    edit.changes["impulse_width_rad"] = SPROCKET_WIDTH * period
    edit.changes["impulse_amplitude_nm"] = s * SPROCKET_IMPACT * edit.nominal_torque_nm


def _obstruction(edit: PlantEdit, s: float) -> None:
    edit.changes["obstruction_position_m"] = OBSTRUCTION_PLACE * edit.plant.loop_length_m
    edit.changes["obstruction_width_m"] = OBSTRUCTION_WIDTH_M
    edit.changes["obstruction_force_n"] = s * edit.rail_force_n


def _rail_obstacle(edit: PlantEdit, s: float) -> None:
    # where on the loop the tray that hits it sits: any place, per conveyor
    place = (zlib.crc32(edit.profile.id.encode()) % 1000) / 1000.0
    edit.changes["obstruction_position_m"] = place * edit.plant.loop_length_m
    edit.changes["obstruction_width_m"] = OBSTACLE_WIDTH_M
    edit.changes["obstruction_force_n"] = s * OBSTACLE_FORCE * edit.rail_force_n


def _elongation(edit: PlantEdit, s: float) -> None:
    plant = edit.plant
    eps = s * ELONGATION_PER_SEVERITY
    edit.changes["pitch_radius_m"] = plant.pitch_radius_m * (1.0 + eps)
    edit.changes["loop_length_m"] = plant.loop_length_m * (1.0 + eps)
    edit.changes["polygon"] = plant.teeth > 0
    edit.mu *= 1.0 + 2.0 * eps
    if plant.teeth > 0:
        # the longer pitch no longer seats on the tooth flank: each link
        # lands and drops on engagement, an impact once per tooth pass
        tooth_pass = plant.teeth / plant.ratio
        for h in (1, 2, 3):
            edit.orders.append(h * tooth_pass)
            edit.amplitudes.append(s * ELONGATION_IMPACT * edit.nominal_torque_nm / h)


def _payload_step(edit: PlantEdit, s: float) -> None:
    edit.changes["payload_step_time_s"] = edit.payload_step_time_s
    edit.changes["payload_step_kg"] = s * PAYLOAD_STEP_KG


def _per_recording(edit: PlantEdit, s: float) -> None:
    """Nothing on the plant: the event is drawn per recording by the simulator."""


_IMPULSE_TRAIN = "impulse train"
_BELT_PLACE = "resisting place on the belt"

_TABLE: dict[str, FaultType] = {}


def register_fault(fault: FaultType) -> FaultType:
    """Add a fault type to the table (``docs/adding-a-fault.md``).

    Raises
    ------
    ModelError
        When a fault of that name is registered already.
    """
    if fault.name in _TABLE:
        raise ModelError(f"fault '{fault.name}' is registered already; give it another name")
    if not fault.name or ":" in fault.name:
        raise ModelError(f"fault name {fault.name!r} must be non-empty and hold no ':'")
    _TABLE[fault.name] = fault
    return fault


def unregister_fault(name: str) -> None:
    """Remove a registered fault type (tests that register a toy one)."""
    _TABLE.pop(name, None)


for _entry in (
    FaultType(
        "friction",
        _friction,
        "friction",
        moves=("friction",),
        end_severity=0.5,
        summary="rail friction coefficient × (1 + s)",
    ),
    FaultType(
        "lubrication",
        _lubrication,
        "lubrication",
        moves=("speed_loss",),
        end_severity=1.0,
        summary="speed-dependent gear losses × (1 + s), constant loss × (1 + s/2)",
    ),
    FaultType(
        "bearing",
        _bearing,
        "bearing",
        moves=("residual_std", "unexplained_peak", "mode"),
        end_severity=0.5,
        torque_noise_gain=1.0,
        summary="torque ripple at order 3.57 and its 2nd harmonic, broadband noise × (1 + s)",
    ),
    FaultType(
        "gear_tooth",
        _gear_tooth,
        "gear",
        moves=("comb", "residual_std", "unexplained_peak", "mode", "impulsive"),
        end_severity=0.5,
        mechanism=_IMPULSE_TRAIN,
        summary="one impulse per revolution of the second stage's pinion",
    ),
    FaultType(
        "obstruction",
        _obstruction,
        "obstruction",
        moves=(
            "friction",
            "residual_std",
            "unexplained_peak",
            "comb",
            "mode",
            "impulsive",
            "impact_hits_per_rev",
        ),
        end_severity=0.5,
        mechanism=_BELT_PLACE,
        summary="a resisting force over 50 mm of belt travel, once per belt revolution",
    ),
    FaultType(
        "elongation",
        _elongation,
        "elongation",
        moves=("tooth_pass", "friction", "residual_std", "mode"),
        end_severity=1.0,
        summary="chain pitch longer by s × 3 %, engagement impacts at the tooth pass",
    ),
    FaultType(
        "payload_step",
        _payload_step,
        None,
        moves=("payload_kg",),
        summary="a tray of s × 20 kg placed on the moving belt",
    ),
    FaultType(
        "rail_obstacle",
        _rail_obstacle,
        "obstruction",
        moves=(
            "friction",
            "residual_std",
            "unexplained_peak",
            "comb",
            "mode",
            "impulsive",
            "impact_hits_per_rev",
        ),
        end_severity=1.0,
        mechanism=_BELT_PLACE,
        summary="an obstacle on the rail one tray hits once per belt revolution",
    ),
    FaultType(
        "sprocket",
        _sprocket,
        "sprocket",
        moves=(
            "sprocket_comb",
            "tooth_pass",
            "friction",
            "residual_std",
            "unexplained_peak",
            "comb",
            "mode",
            "impulsive",
        ),
        end_severity=1.0,
        mechanism=_IMPULSE_TRAIN,
        summary="a resisting impulse once per tooth engagement of a worn drive sprocket",
    ),
    FaultType(
        PAYLOAD_EVENT,
        _per_recording,
        "payload_event",
        moves=("impulsive",),
        end_severity=1.0,
        alarmed=False,
        mechanism=_BELT_PLACE,
        summary="an item caught for 0.2-1.0 s in one recording of twenty",
    ),
):
    register_fault(_entry)


def fault_types() -> tuple[FaultType, ...]:
    """Every registered fault type, in the order registered."""
    return tuple(_TABLE.values())


def fault_names() -> tuple[str, ...]:
    """The names of every fault the virtual conveyor can inject."""
    return tuple(_TABLE)


def fault_type(name: str) -> FaultType:
    """The table entry of a fault.

    Raises
    ------
    ModelError
        Naming the unknown fault and the accepted names.
    """
    try:
        return _TABLE[name]
    except KeyError:
        raise ModelError(f"unknown fault '{name}'; use one of {', '.join(fault_names())}") from None


def expected_causes() -> dict[str, str]:
    """Fault name to the cause an evaluation expects its alarm to name (alarmed faults only)."""
    return {t.name: t.cause for t in fault_types() if t.cause is not None and t.alarmed}


def exclusive_groups() -> tuple[tuple[str, ...], ...]:
    """Faults that share one mechanism of the plant: at most one of each group at a time."""
    groups: dict[str, list[str]] = {}
    for t in fault_types():
        if t.mechanism is not None:
            groups.setdefault(t.mechanism, []).append(t.name)
    return tuple(tuple(g) for g in groups.values())


@dataclass(frozen=True, slots=True)
class Fault:
    """A fault and its severity (dimensionless, see the module table)."""

    name: str
    severity: float

    def __post_init__(self) -> None:
        fault_type(self.name)
        if not math.isfinite(self.severity) or self.severity < 0.0 or self.severity > 10.0:
            raise ModelError(
                f"fault '{self.name}' severity {self.severity!r} must be a number from 0 to 10"
            )

    def __str__(self) -> str:
        return f"{self.name}:{self.severity:g}"

    @property
    def kind(self) -> FaultType:
        """Its entry of the fault table."""
        return fault_type(self.name)


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
    """Refuse two faults that need the same mechanism of the plant (:func:`exclusive_groups`).

    Raises
    ------
    ModelError
        Naming the two faults.
    """
    given = set(names)
    for group in exclusive_groups():
        both = [n for n in group if n in given]
        if len(both) > 1:
            raise ModelError(
                f"faults {' and '.join(both)} cannot be simulated together (one plant "
                f"mechanism for {', '.join(group)}); give one of them"
            )
