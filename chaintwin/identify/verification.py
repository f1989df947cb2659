"""Verification of the twin: the relative error (REP) of model against measurement.

The published method verifies its twin by running it beside the conveyor and
comparing simulated and measured speed and torque over whole recordings of
different movements (ramp, stairs, trapezoid, two accelerations, both
directions). This module computes that comparison.

REP series
----------
Per recording and channel (speed, torque)::

    REP(t) = 100 · (y_model(t) − y_measured(t)) / max|y_measured|   (%)

normalised by the channel's largest absolute value **in the recording**, not
pointwise (a pointwise relative error divides by zero at standstill). Its
mean, standard deviation (population) and largest absolute value are
reported over the moving samples of the recording (the phases of
:func:`~chaintwin.validate.phases.segment` that are not standstill: at
standstill static friction holds whatever torque the controller leaves, which
no model can know) and per movement phase.

Two models
----------
``closed-loop`` (the published method): the controller replica and the
rigid plant (:func:`chaintwin.simulate.simulate`) driven by the recording's
own speed and position set points, prepared as the output-error fit prepares
them (:func:`chaintwin.identify.closed_loop.prepare`); simulated speed and
torque are compared with the measured ones. The recording must start at rest.

``inverse``: the rigid model's torque computed from the measured speed
(:func:`chaintwin.model.rigid.model_torque`), the residual the monitoring
uses. It has no speed of its own (it is driven by the measured speed), so its
speed REP is null with that reason.

Parameters come from a calibration (``identify``/``calibrate``) or, without
one, from the profile's ``model:`` section (its nominal values; ModelSpec's
typical values when the profile has none); the result says which.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from itertools import pairwise
from typing import Any, Literal

import numpy as np

from chaintwin._types import FloatArray
from chaintwin.errors import EstimationError
from chaintwin.identify.calibration import Calibration
from chaintwin.identify.closed_loop import plant_of, prepare, sample_like
from chaintwin.model.rigid import model_torque
from chaintwin.read.profile import ConveyorProfile, ModelSpec
from chaintwin.read.recording import Recording
from chaintwin.simulate.engine import simulate
from chaintwin.validate.phases import Phase, segment

__all__ = [
    "RESIDUALS",
    "ChannelRep",
    "RepStats",
    "Residual",
    "TwinParameters",
    "Verification",
    "closed_loop_torque",
    "movement_label",
    "rep_series",
    "rep_stats",
    "twin_parameters",
    "verify_recording",
]

Residual = Literal["inverse", "closed-loop"]
RESIDUALS: tuple[Residual, ...] = ("inverse", "closed-loop")
"""The two models a recording can be verified against."""

MIN_SAMPLES = 4
"""Fewest samples a REP statistic is computed from."""

_TWO_SLOPES = 0.2
"""Relative difference of the set point's slope in the two halves of one ramp above
which the movement counts as having two accelerations."""


@dataclass(frozen=True, slots=True)
class TwinParameters:
    """The rigid model's parameters the twin is verified with.

    Parameters
    ----------
    mu : float
        Belt-on-rail friction coefficient, -.
    loss_constant_nm, loss_viscous_nm_s_rad, loss_quadratic_nm_s2_rad2 : float
        Gear losses BmA (Nm), BmB (Nm·s/rad), BmC (Nm·s²/rad²).
    drive_inertia_kgm2 : float
        Motor and gear inertia J_d at the motor shaft, kg·m².
    source : str
        ``"calibration"``, ``"profile"`` (the profile's ``model:`` section) or
        ``"typical"`` (ModelSpec's typical values: the profile has none).
    """

    mu: float
    loss_constant_nm: float
    loss_viscous_nm_s_rad: float
    loss_quadratic_nm_s2_rad2: float
    drive_inertia_kgm2: float
    source: str

    def rigid(self) -> dict[str, float]:
        """The names :func:`chaintwin.model.rigid.model_torque` reads."""
        return {
            "mu": self.mu,
            "BmA": self.loss_constant_nm,
            "BmB": self.loss_viscous_nm_s_rad,
            "BmC": self.loss_quadratic_nm_s2_rad2,
            "J_d": self.drive_inertia_kgm2,
        }

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: the parameters and their source."""
        return {
            "mu": self.mu,
            "BmA": self.loss_constant_nm,
            "BmB": self.loss_viscous_nm_s_rad,
            "BmC": self.loss_quadratic_nm_s2_rad2,
            "drive_inertia_kgm2": self.drive_inertia_kgm2,
            "source": self.source,
        }


def twin_parameters(
    profile: ConveyorProfile, calibration: Calibration | None = None
) -> TwinParameters:
    """The parameters to verify with: the calibration's, else the profile's nominal ones.

    Parameters
    ----------
    profile : ConveyorProfile
        The conveyor; its ``model:`` section is read only without a calibration.
    calibration : Calibration, optional
        Identified parameters (μ, BmA, BmB, BmC, J_d).
    """
    if calibration is not None:
        p = calibration.parameters
        return TwinParameters(
            mu=p["mu"],
            loss_constant_nm=p["BmA"],
            loss_viscous_nm_s_rad=p["BmB"],
            loss_quadratic_nm_s2_rad2=p["BmC"],
            drive_inertia_kgm2=p["J_d"],
            source="calibration",
        )
    spec = profile.model if profile.model is not None else ModelSpec()
    return TwinParameters(
        mu=spec.friction,
        loss_constant_nm=spec.loss_constant_nm,
        loss_viscous_nm_s_rad=spec.loss_viscous_nm_s_rad,
        loss_quadratic_nm_s2_rad2=spec.loss_quadratic_nm_s2_rad2,
        drive_inertia_kgm2=profile.motor.inertia_kgm2
        + profile.gear.inertia_kgm2
        + spec.unlisted_inertia_kgm2,
        source="profile" if profile.model is not None else "typical",
    )


@dataclass(frozen=True, slots=True)
class RepStats:
    """Mean, standard deviation and largest absolute value of a REP series, %."""

    mean_pct: float
    std_pct: float
    absmax_pct: float
    samples: int

    def to_dict(self) -> dict[str, float | int]:
        """``{"rep_mean_pct", "rep_std_pct", "rep_absmax_pct", "samples"}``."""
        return {
            "rep_mean_pct": self.mean_pct,
            "rep_std_pct": self.std_pct,
            "rep_absmax_pct": self.absmax_pct,
            "samples": self.samples,
        }


def rep_series(measured: FloatArray, model: FloatArray) -> FloatArray:
    """``100·(model − measured)/max|measured|`` per sample, %.

    Parameters
    ----------
    measured, model : FloatArray
        One channel of one recording, same shape and unit.

    Raises
    ------
    EstimationError
        When the shapes differ or the measured channel is zero (or not finite)
        everywhere: there is no scale to normalise by.
    """
    y = np.asarray(measured, dtype=np.float64)
    m = np.asarray(model, dtype=np.float64)
    if y.shape != m.shape:
        raise EstimationError(f"REP needs two series of one shape; got {y.shape} and {m.shape}")
    finite = y[np.isfinite(y)]
    scale = float(np.max(np.abs(finite))) if finite.size else 0.0
    if not scale > 0.0:
        raise EstimationError("the measured channel is zero everywhere; REP has no scale")
    out: FloatArray = 100.0 * (m - y) / scale
    return out


def rep_stats(series: FloatArray, index: np.ndarray | None = None) -> RepStats | None:
    """Statistics of a REP series over some samples (finite ones only).

    Returns None when fewer than :data:`MIN_SAMPLES` finite samples remain.
    """
    x = np.asarray(series, dtype=np.float64)
    if index is not None:
        x = x[index]
    x = x[np.isfinite(x)]
    if x.size < MIN_SAMPLES:
        return None
    return RepStats(
        mean_pct=float(x.mean()),
        std_pct=float(x.std()),
        absmax_pct=float(np.max(np.abs(x))),
        samples=int(x.size),
    )


@dataclass(frozen=True, slots=True)
class ChannelRep:
    """The REP of one channel of one recording.

    Parameters
    ----------
    series : FloatArray or None
        REP per sample, %; None when the channel cannot be compared.
    whole : RepStats or None
        Over the moving samples.
    reason : str or None
        Why ``series`` is None.
    """

    series: FloatArray | None
    whole: RepStats | None
    reason: str | None = None

    def to_dict(self) -> dict[str, Any]:
        """``{"rep_mean_pct", "rep_std_pct", "rep_absmax_pct"}`` (null with a reason)."""
        if self.whole is None:
            return {
                "rep_mean_pct": None,
                "rep_std_pct": None,
                "rep_absmax_pct": None,
                "reason": self.reason or "too few moving samples",
            }
        return self.whole.to_dict()


@dataclass(frozen=True)
class Verification:
    """One recording verified: REP of speed and torque, whole and per phase.

    Parameters
    ----------
    file : str
        The recording's source.
    residual : {"inverse", "closed-loop"}
        Which model was compared.
    movement : str
        What movement the recording holds (:func:`movement_label`).
    speed, torque : ChannelRep
        Over the moving samples.
    phases : list of dict
        Per moving phase: kind, direction, start and end time (s) and the
        speed and torque REP statistics (null when too short).
    parameters : TwinParameters
        What the model was run with.
    payload_kg : float
        Payload the model carried, kg.
    warnings : list of dict
        ``{"code", "message"}``: nominal parameters used, payload assumed.
    """

    file: str
    residual: Residual
    movement: str
    speed: ChannelRep
    torque: ChannelRep
    phases: list[dict[str, Any]]
    parameters: TwinParameters
    payload_kg: float
    warnings: list[dict[str, str]] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        """The ``verify --json`` object of this recording."""
        return {
            "file": self.file,
            "speed": self.speed.to_dict(),
            "torque": self.torque.to_dict(),
            "residual": self.residual,
            "movement": self.movement,
            "phases": self.phases,
            "parameters": self.parameters.to_dict(),
            "payload_kg": self.payload_kg,
            "warnings": self.warnings,
        }


def movement_label(phases: Sequence[Phase], time: FloatArray, setpoint: FloatArray) -> str:
    """Name the movement a recording holds, as the published verification table does.

    ``ramp`` (up and down without a constant part), ``trapezoid`` (up, hold,
    down), ``stairs`` (several constant levels in one move), ``two
    accelerations`` (one ramp whose slope changes by more than 20 % half way),
    with ``both directions`` when the recording runs forward and backward and
    ``backward`` when only backward; ``standstill`` when nothing moves.

    Parameters
    ----------
    phases : sequence of Phase
        The recording's phases.
    time : FloatArray
        Time per sample, s.
    setpoint : FloatArray
        The speed set point (or the speed), rad/s.
    """
    moving = [ph for ph in phases if ph.moving]
    if not moving:
        return "standstill"
    directions = {ph.direction for ph in moving if ph.direction != 0}
    constants = sum(1 for ph in moving if ph.kind == "constant")
    ramps = [ph for ph in moving if ph.kind in ("accelerate", "decelerate")]
    # a move: moving phases in one direction between standstills or reversals
    moves = int(phases[0].moving) + sum(
        1
        for prev, ph in pairwise(phases)
        if ph.moving and (not prev.moving or prev.direction != ph.direction)
    )
    if constants == 0:
        shape = "ramp"
    elif constants > max(1, moves):
        shape = "stairs"
    elif any(_two_slopes(time[ph.start : ph.stop], setpoint[ph.start : ph.stop]) for ph in ramps):
        shape = "two accelerations"
    else:
        shape = "trapezoid"
    if len(directions) > 1:
        return f"{shape}, both directions"
    if directions == {-1}:
        return f"{shape}, backward"
    return shape


def _two_slopes(t: FloatArray, w: FloatArray) -> bool:
    if t.size < 8:
        return False
    half = t.size // 2
    a = np.polyfit(t[:half], w[:half], 1)[0]
    b = np.polyfit(t[half:], w[half:], 1)[0]
    top = max(abs(a), abs(b))
    return bool(top > 0.0 and abs(a - b) > _TWO_SLOPES * top)


def closed_loop_torque(
    recording: Recording, profile: ConveyorProfile, params: TwinParameters, payload_kg: float
) -> FloatArray:
    """The closed loop's motor torque at the recording's samples, Nm.

    The controller replica and the rigid plant driven by the recording's set
    points (see the module notes); the residual ``monitor --residual
    closed-loop`` compares with.

    Raises
    ------
    EstimationError
        When the recording cannot be simulated (no speed set point, starts in
        motion, no motion).
    """
    return _closed_loop(recording, profile, params, payload_kg)[1]


def _closed_loop(
    recording: Recording, profile: ConveyorProfile, params: TwinParameters, payload_kg: float
) -> tuple[FloatArray, FloatArray]:
    """Simulated speed (rad/s) and torque (Nm) at the recording's samples."""
    prep = prepare(
        recording, profile, payload_kg, min_speed_share=0.01, skip_start_s=0.0, n_parameters=0
    )
    base = prep.base
    listed = base.motor_inertia_kgm2 + base.gear_inertia_kgm2
    # an identified loss slightly below zero (within its noise) is simulated as none:
    # the plant refuses negative losses
    values: Mapping[str, float] = {
        "mu": params.mu,
        "loss_constant_nm": max(params.loss_constant_nm, 0.0),
        "loss_viscous_nm_s_rad": max(params.loss_viscous_nm_s_rad, 0.0),
        "loss_quadratic_nm_s2_rad2": max(params.loss_quadratic_nm_s2_rad2, 0.0),
        "drive_inertia_scale": params.drive_inertia_kgm2 / listed,
    }
    plant = plant_of(base, values, (base.motor_inertia_kgm2, base.gear_inertia_kgm2))
    sim = simulate(plant, prep.setpoints, initial_motor_angle=prep.theta0)
    if not sim.success:
        raise EstimationError(
            f"{recording.source}: the closed-loop simulation failed: {sim.message}"
        )
    cycle = profile.controller.cycle_s
    return sample_like(sim.speed, prep, cycle), sample_like(sim.torque, prep, cycle)


def verify_recording(
    recording: Recording,
    profile: ConveyorProfile,
    *,
    calibration: Calibration | None = None,
    residual: Residual = "closed-loop",
    payload_kg: float | None = None,
) -> Verification:
    """Verify the twin against one recording: REP of speed and torque, whole and per phase.

    Parameters
    ----------
    recording : Recording
        Speed (rad/s), torque (Nm) and, for ``closed-loop``, the speed set
        point (and position set point) from rest.
    profile : ConveyorProfile
        The conveyor.
    calibration : Calibration, optional
        Identified parameters; default the profile's nominal ones (a warning
        ``nominal_parameters`` says so).
    residual : {"closed-loop", "inverse"}
        Which model (see the module notes).
    payload_kg : float, optional
        Payload, kg; default the recording's ``payload_kg`` metadata, else 0
        (a warning ``payload_assumed`` says so).

    Returns
    -------
    Verification

    Raises
    ------
    EstimationError
        When the recording cannot be compared (no motion, no set point for
        the closed loop, starts in motion, torque zero everywhere).
    """
    if residual not in RESIDUALS:
        raise EstimationError(f"residual '{residual}' is not one of {', '.join(RESIDUALS)}")
    warnings: list[dict[str, str]] = []
    params = twin_parameters(profile, calibration)
    if params.source != "calibration":
        what = (
            "the profile's model: section"
            if params.source == "profile"
            else "typical values (the profile has no model: section)"
        )
        warnings.append(
            {
                "code": "nominal_parameters",
                "message": f"no calibration given: the twin runs with {what}; give "
                "--calibration for the identified parameters",
            }
        )
    if payload_kg is None:
        payload_kg = recording.metadata.payload_kg
        if payload_kg is None:
            payload_kg = 0.0
            warnings.append(
                {
                    "code": "payload_assumed",
                    "message": "the recording has no payload_kg metadata: the model carries "
                    "0 kg; add '# payload_kg: <kg>' for a fair torque comparison",
                }
            )
    if not (math.isfinite(payload_kg) and payload_kg >= 0.0):
        raise EstimationError(f"payload_kg={payload_kg!r} must be a mass ≥ 0 kg")

    phases = segment(recording)
    moving_idx = [np.arange(ph.start, ph.stop) for ph in phases if ph.moving]
    if not moving_idx:
        raise EstimationError(f"{recording.source}: the conveyor does not move; nothing to verify")
    whole_idx = np.concatenate(moving_idx)

    if residual == "closed-loop":
        sim_speed, sim_torque = _closed_loop(recording, profile, params, payload_kg)
        speed_series: FloatArray | None = rep_series(recording.speed, sim_speed)
        speed_reason = None
    else:
        sim_torque = model_torque(recording, profile, params.rigid(), payload_kg)
        speed_series = None
        speed_reason = (
            "the inverse model is driven by the measured speed and has no speed of its own; "
            "use --residual closed-loop"
        )
    try:
        torque_series = rep_series(recording.torque, sim_torque)
    except EstimationError as exc:
        raise EstimationError(f"{recording.source}: torque: {exc}") from None

    speed = ChannelRep(
        speed_series,
        rep_stats(speed_series, whole_idx) if speed_series is not None else None,
        speed_reason,
    )
    torque = ChannelRep(torque_series, rep_stats(torque_series, whole_idx))
    per_phase: list[dict[str, Any]] = []
    for ph in phases:
        if not ph.moving:
            continue
        idx = np.arange(ph.start, ph.stop)
        s = rep_stats(speed_series, idx) if speed_series is not None else None
        q = rep_stats(torque_series, idx)
        per_phase.append(
            {
                **ph.to_dict(),
                "speed": s.to_dict() if s is not None else None,
                "torque": q.to_dict() if q is not None else None,
            }
        )
    setpoint = recording.channels.get("speed_setpoint")
    label = movement_label(
        phases,
        recording.time,
        np.asarray(setpoint if setpoint is not None else recording.speed, dtype=np.float64),
    )
    return Verification(
        file=recording.source,
        residual=residual,
        movement=label,
        speed=speed,
        torque=torque,
        phases=per_phase,
        parameters=params,
        payload_kg=float(payload_kg),
        warnings=warnings,
    )
