"""The virtual conveyor: the simulator plus what a real drive scope adds.

The identification model is rigid, noise-free and continuous. A real
recording is not, and tests that only fit the model to itself prove little.
The virtual conveyor therefore adds, each switchable in :class:`Realism`:

* an elastic belt (two-mass), stick-slip (static friction above kinetic),
  the polygon effect (chordal action) and gear-mesh torque ripple, inside
  the plant simulation;
* torque and speed measurement noise (the inverter's torque is a model
  estimate from the currents; the speed comes from an encoder);
* quantisation of the exported channels (0.1 rpm, 0.1 % torque, whole
  encoder increments);
* sampling without an anti-alias filter: the scope keeps every k-th
  controller cycle, so lines above the Nyquist frequency fold;
* scope limits: 2048 samples at the sample time, triggered a little before
  the move, so that a 1 ms scope holds only part of a 10 s cycle;
* exported units: rpm, % of nominal torque, encoder increments.

The torque set point carries the noise a drive's own speed measurement puts
into it (:func:`setpoint_noise`): encoder quantisation and speed-measurement
noise, through the speed filter, times the speed controller's gain, added to
the set point unfiltered and to the actual torque through the torque lag.

Simplifications: the exported channels' measurement noise is drawn apart
from the controller's (the scope's speed channel keeps its own draw), and
the controller's noise is added to the simulated torques afterwards, not fed
back through the plant (at the controller cycle the motor's inertia barely
moves with it).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, fields
from datetime import datetime
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.signal import lfilter

from chaintwin._types import FloatArray
from chaintwin.errors import ModelError
from chaintwin.physics import G
from chaintwin.read.profile import ConveyorProfile, ModelSpec
from chaintwin.read.recording import Metadata, Recording
from chaintwin.simulate.engine import SimulationResult, simulate
from chaintwin.simulate.faults import (
    PAYLOAD_EVENT,
    PAYLOAD_EVENT_CHANCE,
    PAYLOAD_EVENT_FORCE,
    PAYLOAD_EVENT_S,
    Fault,
    PlantEdit,
    check_exclusive,
    fault_type,
)
from chaintwin.simulate.plant import PlantParameters
from chaintwin.simulate.setpoints import Setpoints, from_arrays, trapezoid
from chaintwin.units import RPM_TO_RAD_S

__all__ = [
    "INCREMENTS_PER_REV",
    "Realism",
    "VirtualRun",
    "default_setpoints",
    "faulty_plant",
    "run_virtual",
    "setpoint_noise",
    "speed_filter_alpha",
]

INCREMENTS_PER_REV = 4096
"""Encoder increments per motor revolution of the virtual drive."""

GEAR_MESH_RIPPLE = 0.003
"""Healthy gear-mesh ripple amplitude, share of nominal torque."""


@dataclass(frozen=True, slots=True)
class Realism:
    """What the virtual conveyor adds to the rigid model; all on by default.

    Parameters
    ----------
    noise : bool
        Torque and speed measurement noise.
    quantisation : bool
        Export resolution: 0.1 rpm, 0.1 % torque (whole increments always).
    elastic : bool
        Two-mass elastic belt.
    stick_slip : bool
        Static friction above kinetic.
    polygon : bool
        Chordal action of the sprocket.
    gear_mesh : bool
        Torque ripple at the first stage's mesh order (needs ``gear.stages``).
    scope_limits : bool
        At most ``max_samples`` samples, trigger ``pretrigger_s`` before the move.
    position_offset : bool
        The scope's position channels start at an offset of their own in every
        recording, as drives export them: near zero in two recordings of three
        (the counter reset at the trigger), anywhere in the third. Positions
        are then not comparable across recordings.
    setpoint_noise : bool
        The speed controller's reaction to its own speed measurement
        (encoder quantisation and ``speed_noise_rpm``) in the torque set
        point and, through the torque lag, in the actual torque
        (:func:`setpoint_noise`).
    torque_noise : float
        Torque noise standard deviation, share of nominal torque.
    speed_noise_rpm : float
        Speed noise standard deviation, rpm.
    speed_filter_s : float
        Time constant of the drive's filter of the measured speed before
        the speed controller, s.
    speed_increments_per_rev : int
        Encoder counts per motor revolution the drive's speed measurement
        resolves: four edges of each of the encoder's lines (the scope
        exports the position in :data:`INCREMENTS_PER_REV`).
    max_samples : int
        Scope depth.
    pretrigger_s : float
        Time recorded before the move starts, s.
    """

    noise: bool = True
    quantisation: bool = True
    elastic: bool = True
    stick_slip: bool = True
    polygon: bool = True
    gear_mesh: bool = True
    scope_limits: bool = True
    position_offset: bool = True
    setpoint_noise: bool = True
    torque_noise: float = 0.004
    speed_noise_rpm: float = 0.8
    speed_filter_s: float = 0.002
    speed_increments_per_rev: int = 4 * INCREMENTS_PER_REV
    max_samples: int = 2048
    pretrigger_s: float = 0.2

    @classmethod
    def off(cls) -> Realism:
        """The rigid identification model, exported exactly (scope limits kept)."""
        return cls(
            noise=False,
            setpoint_noise=False,
            quantisation=False,
            elastic=False,
            stick_slip=False,
            polygon=False,
            gear_mesh=False,
        )

    def switches(self) -> dict[str, bool]:
        """The on/off switches by name."""
        return {f.name: getattr(self, f.name) for f in fields(self) if f.type in ("bool", bool)}


@dataclass(frozen=True, slots=True)
class VirtualRun:
    """A virtual recording and the truth behind it.

    Parameters
    ----------
    recording : Recording
        What the drive's scope would have exported (SI inside; export units
        in ``recording.units``).
    simulation : SimulationResult
        The simulation at every controller cycle (ground truth).
    plant : PlantParameters
        The plant simulated, faults applied.
    truth : dict
        JSON-ready ground truth: payload, faults, realism switches.
    """

    recording: Recording
    simulation: SimulationResult
    plant: PlantParameters
    truth: dict[str, Any] = field(default_factory=dict)


def _nominal_torque(profile: ConveyorProfile) -> float:
    if profile.motor.nominal_torque_nm is not None:
        return profile.motor.nominal_torque_nm
    limit = profile.torque_limit_nm
    if limit is None:
        raise ModelError(
            f"profile '{profile.id}': give motor.nominal_torque_nm or controller.torque_limit_nm "
            "to simulate it"
        )
    return limit / 3.0


def faulty_plant(
    profile: ConveyorProfile,
    *,
    payload_kg: float,
    faults: Sequence[Fault] = (),
    realism: Realism | None = None,
    model: ModelSpec | None = None,
    payload_step_time_s: float = -1.0,
    loss_scale: float = 1.0,
) -> PlantParameters:
    """Plant parameters of a profile with faults and realism applied.

    Parameters
    ----------
    profile : ConveyorProfile
        The conveyor.
    payload_kg : float
        Payload on the belt, kg.
    faults : sequence of Fault
        Faults with their severities (see :mod:`chaintwin.simulate.faults`).
    realism : Realism, optional
        Which plant-side realism to switch on (default: all).
    model : ModelSpec, optional
        Plant parameters (default: the profile's ``model:``, else typical values).
    payload_step_time_s : float
        When a ``payload_step`` fault places its tray, s.
    loss_scale : float
        Multiplies the gear losses BmA, BmB, BmC (temperature drift).
    """
    realism = realism or Realism()
    check_exclusive(f.name for f in faults if f.severity > 0.0)
    plant = PlantParameters.from_profile(profile, payload_kg=payload_kg, model=model)
    tn = _nominal_torque(profile)
    changes: dict[str, Any] = {
        "elastic": realism.elastic,
        "stick_slip": realism.stick_slip,
        "polygon": realism.polygon and plant.teeth > 0,
        "loss_constant_nm": plant.loss_constant_nm * loss_scale,
        "loss_viscous_nm_s_rad": plant.loss_viscous_nm_s_rad * loss_scale,
        "loss_quadratic_nm_s2_rad2": plant.loss_quadratic_nm_s2_rad2 * loss_scale,
    }
    edit = PlantEdit(
        profile=profile,
        plant=plant,
        nominal_torque_nm=tn,
        payload_step_time_s=payload_step_time_s,
        rail_force_n=plant.mu * G * (plant.belt_mass_kg + plant.tray_mass_kg),
        changes=changes,
        mu=plant.mu,
    )
    stages = profile.gear.stages
    if realism.gear_mesh and stages:
        edit.orders.append(float(stages[0][0]))  # first-stage mesh: pinion teeth per motor rev
        edit.amplitudes.append(GEAR_MESH_RIPPLE * tn)
    for fault in faults:
        fault_type(fault.name).apply(edit, fault.severity)
    changes["mu"] = edit.mu
    changes["ripple_orders"] = tuple(edit.orders)
    changes["ripple_amplitudes_nm"] = tuple(edit.amplitudes)
    return plant.replace(**changes)


def default_setpoints(
    profile: ConveyorProfile,
    *,
    duration_s: float,
    speed_rpm: float | None = None,
    ramp_s: float = 0.5,
    hold_s: float = 8.0,
    lead_s: float = 0.2,
    direction: int = 1,
) -> Setpoints:
    """A trapezoid move to nominal speed, padded with standstill to ``duration_s``.

    Parameters
    ----------
    profile : ConveyorProfile
        Supplies the nominal speed (1400 rpm when unknown) and controller cycle.
    duration_s : float
        Total time to cover, s.
    speed_rpm : float, optional
        Plateau speed, rpm.
    ramp_s, hold_s, lead_s : float
        Ramp time, time at constant speed and time before the move, s.
    direction : int
        +1 forward, -1 backward.
    """
    rpm = speed_rpm if speed_rpm is not None else (profile.motor.nominal_speed_rpm or 1400.0)
    w = rpm * RPM_TO_RAD_S
    tail = max(0.3, duration_s - lead_s - 2.0 * ramp_s - hold_s + 2.0 * profile.controller.cycle_s)
    return trapezoid(
        speed_rad_s=w,
        accel_rad_s2=w / ramp_s,
        hold_s=hold_s,
        direction=direction,
        lead_s=lead_s,
        tail_s=tail,
        cycle_s=profile.controller.cycle_s,
    )


SETPOINT_NOISE_STREAM = 35
"""Second key of the random stream of the controller's speed noise (beside the
run's seed), so that the other draws of a seeded run stay as they were."""


def _first_order(x: FloatArray, dt: float, tau: float) -> FloatArray:
    """``x`` through a first-order lag of time constant ``tau`` (s), exactly
    discretised at step ``dt`` (s), starting from 0; ``tau`` 0 passes it on."""
    if tau <= 0.0:
        return x.copy()
    alpha = 1.0 - math.exp(-dt / tau)
    return np.asarray(lfilter([alpha], [1.0, alpha - 1.0], x), dtype=np.float64)


def speed_filter_alpha(cycle_s: float, speed_filter_s: float) -> float:
    """Share of a new speed sample the drive's speed filter takes per cycle, 1."""
    return 1.0 if speed_filter_s <= 0.0 else 1.0 - math.exp(-cycle_s / speed_filter_s)


def setpoint_noise(
    position: FloatArray,
    setpoint: FloatArray,
    plant: PlantParameters,
    realism: Realism,
    rng: np.random.Generator,
) -> tuple[FloatArray, FloatArray]:
    """What the drive's own speed measurement adds to its torques, per controller cycle.

    The speed controller sees the motor speed as the encoder measures it:
    whole increments counted per cycle (``(N_k - N_(k-1))·inc/cycle``, a
    quantisation error of up to one increment per cycle) plus measurement
    noise of ``realism.speed_noise_rpm``, through the drive's speed filter
    (first order, ``realism.speed_filter_s``). Its proportional gain turns
    that into torque: the set point carries ``-Kp·n`` unfiltered, the actual
    torque the same through the torque lag. The integral part's share
    (``Kp/Ti`` per second) is left out: at the controller cycle it is two
    orders smaller. The drive's torque limit clips the set point after the
    controller: where the set point is held at the limit, its noise is cut
    off there too (a saturated set point stays flat).

    Parameters
    ----------
    position : FloatArray
        Motor angle at every controller cycle, rad.
    setpoint : FloatArray
        Torque set point without the noise at every controller cycle, N·m.
    plant : PlantParameters
        Controller cycle, speed gain and torque time constant.
    realism : Realism
        Speed noise and filter.
    rng : np.random.Generator
        The noise's random stream.

    Returns
    -------
    (FloatArray, FloatArray)
        Additions to the torque set point and to the actual torque, N·m.
    """
    dt = plant.cycle_s
    inc = 2.0 * math.pi / realism.speed_increments_per_rev
    counts = np.floor(position / inc)
    measured = np.empty_like(position)
    measured[1:] = np.diff(counts) * inc / dt - np.diff(position) / dt
    measured[0] = 0.0
    measured += rng.normal(0.0, realism.speed_noise_rpm * RPM_TO_RAD_S, position.shape)
    filtered = _first_order(measured, dt, realism.speed_filter_s)
    du = -plant.speed_gain_nm_s_rad * filtered
    limit = plant.torque_limit_nm
    du = np.clip(setpoint + du, -limit, limit) - setpoint
    return du, _first_order(du, dt, plant.torque_time_constant_s)


def _quantise(x: FloatArray, step: float) -> FloatArray:
    return np.round(x / step) * step


def _payload_event(
    faults: Sequence[Fault],
    plant: PlantParameters,
    setpoints: Setpoints,
    moving: npt.NDArray[np.intp],
    belt0: float,
    rng: np.random.Generator,
) -> tuple[float, float, float, float, float] | None:
    """A ``payload_event`` in this recording, or None.

    Drawn only when the fault is present (other recordings' random draws
    stay as they were). An item caught for a while is a resisting force
    over the stretch of belt that passes during the event.

    Returns
    -------
    (float, float, float, float, float) or None
        Start s, duration s, belt position where the stretch starts m, its
        length m, and the force N.
    """
    s = sum(f.severity for f in faults if f.name == PAYLOAD_EVENT)
    if s <= 0.0 or moving.size < 2 or rng.random() >= PAYLOAD_EVENT_CHANCE:
        return None
    t = setpoints.time
    t0, t1 = float(t[moving[0]]), float(t[moving[-1]])
    duration = min(float(rng.uniform(*PAYLOAD_EVENT_S)), 0.6 * (t1 - t0))
    if duration <= 0.0:
        return None
    start = float(rng.uniform(t0 + 0.2 * (t1 - t0), t1 - duration))
    krv = plant.belt_speed_per_motor_speed
    pos = setpoints.position
    ka, kb = np.searchsorted(t, [start, start + duration])
    kb = min(int(kb), pos.shape[0] - 1)
    xa = belt0 + krv * float(pos[int(ka)] - pos[0])
    xb = belt0 + krv * float(pos[kb] - pos[0])
    width = min(abs(xb - xa), plant.loop_length_m)
    rail = plant.mu * G * (plant.belt_mass_kg + plant.tray_mass_kg)
    return start, duration, min(xa, xb) % plant.loop_length_m, width, s * PAYLOAD_EVENT_FORCE * rail


def run_virtual(
    profile: ConveyorProfile,
    *,
    payload_kg: float = 0.0,
    sample_time_s: float = 0.006,
    faults: Sequence[Fault] = (),
    realism: Realism | None = None,
    seed: int | None = None,
    setpoints: Setpoints | None = None,
    speed_rpm: float | None = None,
    model: ModelSpec | None = None,
    recorded_at: datetime | None = None,
    calibration: bool = False,
    loss_scale: float = 1.0,
    initial_motor_angle: float | None = None,
    source: str = "<virtual>",
) -> VirtualRun:
    """Simulate one scope recording of the virtual conveyor.

    Parameters
    ----------
    profile : ConveyorProfile
        The conveyor.
    payload_kg : float
        Payload on the belt, kg.
    sample_time_s : float
        Scope sample time, s: a whole multiple of the controller cycle.
    faults : sequence of Fault
        Faults with severities.
    realism : Realism, optional
        What to add to the rigid model (default: everything).
    seed : int, optional
        Random seed (noise, sampling phase, belt position).
    setpoints : Setpoints, optional
        Speed/position set points at the controller cycle (default: a
        trapezoid to nominal speed, see :func:`default_setpoints`).
    speed_rpm : float, optional
        Plateau speed of the default trapezoid, rpm.
    model : ModelSpec, optional
        Plant parameters (default: the profile's ``model:``, else typical values).
    recorded_at : datetime, optional
        Written to the metadata.
    calibration : bool
        Write ``payload_kg`` to the metadata (a known reference load).
    loss_scale : float
        Multiplies the gear losses (temperature drift).
    initial_motor_angle : float, optional
        Absolute motor angle at the start, rad (default: random multi-turn).
    source : str
        Name given to the recording.

    Returns
    -------
    VirtualRun
    """
    realism = realism or Realism()
    if payload_kg < 0 or not math.isfinite(payload_kg):
        raise ModelError(f"payload {payload_kg!r} kg must be a number >= 0")
    cycle = profile.controller.cycle_s
    k = round(sample_time_s / cycle)
    if k < 1 or abs(k * cycle - sample_time_s) > 1e-9 * max(1.0, sample_time_s):
        raise ModelError(
            f"sample time {sample_time_s:g} s must be a whole multiple of the controller "
            f"cycle {cycle:g} s"
        )
    rng = np.random.default_rng(seed)
    scope_s = realism.max_samples * sample_time_s
    if setpoints is None:
        setpoints = default_setpoints(
            profile,
            duration_s=scope_s if realism.scope_limits else 10.0,
            speed_rpm=speed_rpm,
            lead_s=realism.pretrigger_s,
        )
    if realism.scope_limits:
        # the scope holds max_samples samples: simulate that long, padded with standstill
        need = realism.max_samples * k
        if setpoints.speed.shape[0] < need:
            pad = need - setpoints.speed.shape[0]
            speed = np.concatenate((setpoints.speed, np.zeros(pad)))
            setpoints = from_arrays(
                np.arange(need) * cycle,
                speed,
                np.concatenate((setpoints.position, np.full(pad, setpoints.position[-1]))),
                cycle_s=cycle,
            )
    # the step tray lands in the middle of the constant part of the move
    moving = np.flatnonzero(np.abs(setpoints.speed) > 0.99 * np.max(np.abs(setpoints.speed)))
    step_time = float(setpoints.time[moving[len(moving) // 2]]) if moving.size else -1.0
    plant = faulty_plant(
        profile,
        payload_kg=payload_kg,
        faults=faults,
        realism=realism,
        model=model,
        payload_step_time_s=step_time,
        loss_scale=loss_scale,
    )
    theta0 = (
        initial_motor_angle
        if initial_motor_angle is not None
        else float(rng.uniform(0.0, 2000.0 * 2.0 * math.pi))
    )
    belt0 = (theta0 * plant.belt_speed_per_motor_speed) % plant.loop_length_m
    event = _payload_event(faults, plant, setpoints, moving, belt0, rng)
    if event is not None:
        plant = plant.replace(
            obstruction_position_m=event[2],
            obstruction_width_m=event[3],
            obstruction_force_n=event[4],
        )
    sim = simulate(plant, setpoints, initial_motor_angle=theta0, initial_belt_position_m=belt0)
    if not sim.success:
        raise ModelError(f"simulation failed: {sim.message}")

    # the scope keeps every k-th controller cycle: no anti-alias filter
    phase = int(rng.integers(0, k)) if realism.noise else 0
    idx = np.arange(phase, sim.time.shape[0], k)
    if realism.scope_limits:
        idx = idx[: realism.max_samples]
    tn = _nominal_torque(profile)
    t: FloatArray = np.arange(idx.shape[0], dtype=np.float64) * sample_time_s
    w_sp = sim.speed_setpoint[idx]
    w = sim.speed[idx].copy()
    th_sp = sim.position_setpoint[idx].copy()
    th = sim.position[idx].copy()
    t_sp = sim.torque_setpoint[idx].copy()
    tq = sim.torque[idx].copy()
    if realism.setpoint_noise:
        stream = np.random.default_rng(
            None if seed is None else [seed & 0xFFFFFFFF, SETPOINT_NOISE_STREAM]
        )
        du, du_lagged = setpoint_noise(sim.position, sim.torque_setpoint, plant, realism, stream)
        t_sp = t_sp + du[idx]
        tq = tq + du_lagged[idx]
    if realism.noise:
        noise_scale = 1.0 + sum(
            f.severity * fault_type(f.name).torque_noise_gain
            for f in faults
            if fault_type(f.name).torque_noise_gain
        )
        tq = tq + rng.normal(0.0, realism.torque_noise * tn * noise_scale, tq.shape)
        w = w + rng.normal(0.0, realism.speed_noise_rpm * RPM_TO_RAD_S, w.shape)
    inc = 2.0 * math.pi / INCREMENTS_PER_REV
    if realism.position_offset and th.size:
        # the scope's counter: reset near the trigger, or anywhere
        start = th[0]
        offset = (
            float(rng.uniform(0.0, 2.0**31 * inc))
            if rng.random() < 1.0 / 3.0
            else float(rng.uniform(0.0, 50.0 * inc))
        )
        th = th - start + offset
        th_sp = th_sp - start + offset
    th = np.floor(th / inc) * inc  # encoders count whole increments
    th_sp = np.round(th_sp / inc) * inc
    pct = tn / 100.0
    if realism.quantisation:
        w_sp = _quantise(w_sp, 0.1 * RPM_TO_RAD_S)
        w = _quantise(w, 0.1 * RPM_TO_RAD_S)
        t_sp = _quantise(t_sp, 0.1 * pct)
        tq = _quantise(tq, 0.1 * pct)
    di = (np.abs(sim.speed_setpoint[idx]) > 0).astype(np.float64)
    channels: dict[str, FloatArray] = {
        "time": t,
        "speed_setpoint": w_sp,
        "speed": w,
        "position_setpoint": th_sp,
        "position": th,
        "torque_setpoint": t_sp,
        "torque": tq,
        "digital_inputs": di,
    }
    units = {
        "time": "s",
        "speed_setpoint": "rpm",
        "speed": "rpm",
        "position_setpoint": "inc",
        "position": "inc",
        "torque_setpoint": "%",
        "torque": "%",
        "digital_inputs": "-",
    }
    meta = Metadata(
        conveyor=profile.id,
        recorded_at=recorded_at,
        sample_time_s=sample_time_s,
        nominal_torque_nm=tn,
        increments_per_rev=float(INCREMENTS_PER_REV),
        payload_kg=payload_kg if calibration else None,
    )
    recording = Recording(
        source=source,
        channels=channels,
        units=units,
        headers={n: f"{n} [{u}]" for n, u in units.items()},
        metadata=meta,
    )
    truth: dict[str, Any] = {
        "conveyor": profile.id,
        "recorded_at": recorded_at.isoformat() if recorded_at else None,
        "payload_kg": payload_kg,
        "faults": {f.name: f.severity for f in faults},
        "loss_scale": loss_scale,
        "sample_time_s": sample_time_s,
        "realism": realism.switches(),
        "calibration": calibration,
        "friction": plant.mu,
        "payload_step_kg": plant.payload_step_kg,
        "payload_step_time_s": plant.payload_step_time_s if plant.payload_step_kg else None,
        "payload_event_s": None if event is None else [event[0], event[1]],
    }
    return VirtualRun(recording, sim, plant, truth)
