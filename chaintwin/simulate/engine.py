"""Closed-loop simulation of a gearmotor-driven chain belt conveyor.

:func:`simulate` runs one plant through the drive's controller replica at
the controller cycle and returns a :class:`SimulationResult` (a result
object in the style of python-control's ``TimeResponseData``).

Sampling
--------
State channels (speed, position, torque, belt speed and position) are the
instantaneous values at ``time[k] = k·cycle_s``, as a drive scope samples
them (no anti-alias filter). Force-like channels (``sprocket_force_n``,
``load_torque_nm``, ``loss_torque_nm``) hold the value in effect over the
cycle that starts at ``time[k]``.

Standstill
----------
While the belt is stuck (static friction holds it), ``load_torque_nm``
holds the whole drive torque (the static friction reacts to it),
``loss_torque_nm`` is 0 and ``sprocket_force_n`` the force that torque
would transmit; no power flows.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from chaintwin._types import FloatArray
from chaintwin.errors import ModelError
from chaintwin.physics import G
from chaintwin.simulate import _kernel as _k
from chaintwin.simulate.plant import PlantParameters
from chaintwin.simulate.setpoints import Setpoints

__all__ = [
    "SimulationResult",
    "elastic_substeps",
    "simulate",
]

_MAX_SUBSTEPS = 10_000


# ----------------------------------------------------------------- results
@dataclass(frozen=True, eq=False)
class SimulationResult:
    """The simulated drive channels at every controller cycle.

    Parameters
    ----------
    time : ndarray of float
        ``k·cycle_s``, s.
    speed_setpoint : ndarray of float
        Speed set point, rad/s.
    position_setpoint : ndarray of float
        Position set point, rad, in the frame of ``position`` (the set
        points' position plus the initial motor angle).
    torque_setpoint : ndarray of float
        Speed controller output after the limit, Nm.
    torque : ndarray of float
        Actual motor torque (after the delay and lag), Nm.
    speed : ndarray of float
        Motor speed, rad/s.
    position : ndarray of float
        Motor angle, rad (starts at the initial motor angle).
    belt_position_m : ndarray of float
        Belt-side position, m (starts at the initial belt position).
    belt_speed_m_s : ndarray of float
        Belt speed, m/s.
    sprocket_force_n : ndarray of float
        Force the sprocket exerts on the belt, N (``∫F·v dt`` is the net
        mechanical work delivered to the belt, gear losses excluded).
    load_torque_nm : ndarray of float
        Belt load referred to the motor including the efficiency of the
        power flow, plus disturbance torques, Nm (inertia excluded).
    loss_torque_nm : ndarray of float
        Gear/motor losses BmA·sign(ω) + BmB·ω + BmC·ω·|ω|, Nm.
    parameters : PlantParameters
        The plant simulated.
    setpoints : Setpoints
        The set points used.
    success : bool
        False when the simulation diverged (non-finite state).
    message : str
        What happened, for people.
    saturated_cycles : int
        Cycles in which the torque set point sat at the torque limit.
    """

    time: FloatArray
    speed_setpoint: FloatArray
    position_setpoint: FloatArray
    torque_setpoint: FloatArray
    torque: FloatArray
    speed: FloatArray
    position: FloatArray
    belt_position_m: FloatArray
    belt_speed_m_s: FloatArray
    sprocket_force_n: FloatArray
    load_torque_nm: FloatArray
    loss_torque_nm: FloatArray
    parameters: PlantParameters
    setpoints: Setpoints
    success: bool
    message: str
    saturated_cycles: int = 0

    def __len__(self) -> int:
        return int(self.time.size)


# ------------------------------------------------------------------ packing
def elastic_substeps(params: PlantParameters) -> int:
    """Plant sub-steps per controller cycle used by the elastic model.

    Chosen so that the belt mode advances at most 0.1 rad and the damper
    at most 0.5 of its explicit stability limit per sub-step (at least 2).

    Raises
    ------
    ModelError
        When that would need more than 10 000 sub-steps (a belt far too
        stiff for the controller cycle).
    """
    r = params.chordal_radius_m
    m1 = params.drive_inertia_kgm2 * (params.ratio / r) ** 2
    m2 = min(params.moving_mass_kg, params.moving_mass_kg + params.payload_step_kg)
    inv = 1.0 / m1 + 1.0 / m2
    omega_hi = math.sqrt(params.belt_stiffness_n_m * inv)
    rate = params.belt_damping_n_s_m * inv
    dt = params.cycle_s
    n = max(2, math.ceil(dt * omega_hi / 0.1), math.ceil(dt * rate / 0.5))
    if n > _MAX_SUBSTEPS:
        raise ModelError(
            f"plant parameters: the belt (k = {params.belt_stiffness_n_m:.3g} N/m) is too stiff "
            f"for a {dt * 1e3:.3g} ms cycle ({n} sub-steps); lower belt_stiffness_n_m or use "
            "the rigid model"
        )
    return n


_TERMS = ("m_red", "fc", "fg", "hjm", "hjg", "brkp", "brkn")  # order of _kernel.belt_terms
_TERMS_BEFORE = tuple(f"{name}0" for name in _TERMS)
_TERMS_AFTER = tuple(f"{name}1" for name in _TERMS)


def _coefficients(
    p: PlantParameters,
    n_cycles: int,
    *,
    initial_motor_angle: float = 0.0,
    initial_belt_position_m: float = 0.0,
) -> FloatArray:
    """The kernels' coefficient vector (layout :data:`_kernel.COEFFICIENTS`)."""
    dt = p.cycle_s
    tau = p.torque_time_constant_s
    if tau > 0.0:
        a_lag = -math.expm1(-dt / tau)
        b_lag = tau * a_lag / dt
    else:
        a_lag, b_lag = 1.0, 0.0
    # the kernels use η where the belt drives the motor and 1/η where the motor drives
    eta = p.back_efficiency or p.efficiency
    inv_eta = 1.0 / p.efficiency
    jd = p.drive_inertia_kgm2
    bma = p.loss_constant_nm
    payload = p.payload_kg
    tray = p.tray_mass_kg
    mass = p.belt_mass_kg + tray + payload
    carried = tray + payload
    mu_g_cos = p.mu * G * math.cos(p.incline_rad)
    static = p.static_friction_ratio if p.stick_slip else 1.0
    g_sin = G * math.sin(p.incline_rad)
    krv = p.belt_speed_per_motor_speed
    step_kg = p.payload_step_kg
    step_k = -1
    if p.payload_step_time_s >= 0.0 and step_kg != 0.0:
        step_k = max(0, math.ceil(p.payload_step_time_s / dt - 1e-9))
        if step_k >= n_cycles:
            step_k = -1
    before = _k.belt_terms(mass, carried, mu_g_cos, static, g_sin, krv, dt, jd, eta, inv_eta, bma)
    if step_k >= 0:
        mass1 = mass + step_kg
        after = _k.belt_terms(
            mass1, carried + step_kg, mu_g_cos, static, g_sin, krv, dt, jd, eta, inv_eta, bma
        )
        step_scale = (jd + mass * krv * krv) / (jd + mass1 * krv * krv)
    else:
        after = before
        step_scale = 1.0
    teeth = p.teeth
    values = {
        "dt": dt,
        "kv": p.position_gain_1_s,
        "kp": p.speed_gain_nm_s_rad,
        "kp_ti": p.speed_gain_nm_s_rad / p.speed_integral_time_s,
        "tlim": p.torque_limit_nm,
        "a_lag": a_lag,
        "b_lag": b_lag,
        "jd": jd,
        "eta": eta,
        "inv_eta": inv_eta,
        "bma": bma,
        "bmb": p.loss_viscous_nm_s_rad,
        "bmc": p.loss_quadratic_nm_s2_rad2,
        "mass": mass,
        "carried": carried,
        "mu_g_cos": mu_g_cos,
        "static": static,
        "g_sin": g_sin,
        "krv": krv,
        "pitch_r": p.pitch_radius_m,
        "ratio": p.ratio,
        "teeth": float(teeth),
        "polygon": 1.0 if (p.polygon and teeth > 0) else 0.0,
        "loop": p.loop_length_m,
        "stiff": p.belt_stiffness_n_m,
        "damp": p.belt_damping_n_s_m,
        "obs_pos": p.obstruction_position_m,
        "obs_width": p.obstruction_width_m,
        "obs_force": p.obstruction_force_n,
        "imp_period": p.impulse_period_rad,
        "imp_width": p.impulse_width_rad,
        "imp_amp": p.impulse_amplitude_nm,
        "step_k": float(step_k),
        "step_kg": step_kg,
        "theta0": initial_motor_angle,
        "x0": initial_belt_position_m,
        "nsub": float(elastic_substeps(p)) if p.elastic else 1.0,
        "nrip": float(len(p.ripple_orders)),
        "tau": tau,
        "step_scale": step_scale,
        "stribeck_v": p.stribeck_speed_m_s if p.stick_slip else 0.0,
    }
    values.update(zip(_TERMS_BEFORE, before, strict=True))
    values.update(zip(_TERMS_AFTER, after, strict=True))
    return _k.pack(values)


def _check_cycle(params: PlantParameters, setpoints: Setpoints, where: str) -> None:
    if abs(params.cycle_s - setpoints.cycle_s) > 1e-9 * params.cycle_s:
        raise ModelError(
            f"{where}: the set points are at a {setpoints.cycle_s * 1e3:.6g} ms cycle but the "
            f"plant's controller runs at {params.cycle_s * 1e3:.6g} ms; build the set points "
            "with cycle_s=params.cycle_s"
        )


def _message(status: int, failed: int, saturated: int, n: int, cycle_s: float) -> str:
    if status != 0:
        return (
            f"diverged: non-finite state at cycle {failed} (t = {failed * cycle_s:.4g} s); "
            "check the controller gains and plant parameters"
        )
    text = f"simulated {n} cycles"
    if saturated:
        text += f"; torque set point at the limit in {saturated} cycles"
    return text


def _readonly(a: FloatArray) -> FloatArray:
    a.flags.writeable = False
    return a


# -------------------------------------------------------------- simulation
def simulate(
    params: PlantParameters,
    setpoints: Setpoints,
    *,
    initial_motor_angle: float = 0.0,
    initial_belt_position_m: float = 0.0,
) -> SimulationResult:
    """Simulate the closed loop (controller replica + plant) over the set points.

    Parameters
    ----------
    params : PlantParameters
        The plant, controller and realism switches.
    setpoints : Setpoints
        Speed and position set points at ``params.cycle_s``.
    initial_motor_angle : float
        Motor angle at ``t = 0``, rad (the position controller tracks the
        set point relative to it).
    initial_belt_position_m : float
        Belt position at ``t = 0``, m (matters for the obstruction).

    Returns
    -------
    SimulationResult

    Raises
    ------
    ModelError
        When the set points' cycle differs from ``params.cycle_s`` or the
        elastic model would need too many sub-steps.

    Notes
    -----
    Starts at rest: speed 0, torque 0, controller integral 0, belt spring
    relaxed.
    """
    _check_cycle(params, setpoints, "simulate")
    if not (math.isfinite(initial_motor_angle) and math.isfinite(initial_belt_position_m)):
        raise ModelError("simulate: the initial motor angle and belt position must be finite")
    n = len(setpoints)
    coef = _coefficients(
        params,
        n,
        initial_motor_angle=initial_motor_angle,
        initial_belt_position_m=initial_belt_position_m,
    )
    orders = np.asarray(params.ripple_orders, dtype=np.float64)
    amps = np.asarray(params.ripple_amplitudes_nm, dtype=np.float64)
    out = np.empty((_k.N_OUT, n), dtype=np.float64)
    # the controller tracks the set point relative to the initial angle
    position_setpoint = (
        _readonly(setpoints.position + initial_motor_angle)
        if initial_motor_angle != 0.0
        else setpoints.position
    )
    w_sp, p_sp = setpoints.speed, position_setpoint
    if params.is_plain_rigid:
        status, failed, saturated = _k.plain_kernel(coef, w_sp, p_sp, out)
    elif params.elastic:
        status, failed, saturated = _k.elastic_kernel(coef, orders, amps, w_sp, p_sp, out)
    else:
        status, failed, saturated = _k.rigid_kernel(coef, orders, amps, w_sp, p_sp, out)
    out.flags.writeable = False
    return SimulationResult(
        time=setpoints.time,
        speed_setpoint=setpoints.speed,
        position_setpoint=position_setpoint,
        torque_setpoint=out[_k.O_TORQUE_SP],
        torque=out[_k.O_TORQUE],
        speed=out[_k.O_SPEED],
        position=out[_k.O_POSITION],
        belt_position_m=out[_k.O_BELT_POSITION],
        belt_speed_m_s=out[_k.O_BELT_SPEED],
        sprocket_force_n=out[_k.O_FORCE],
        load_torque_nm=out[_k.O_LOAD],
        loss_torque_nm=out[_k.O_LOSS],
        parameters=params,
        setpoints=setpoints,
        success=int(status) == 0,
        message=_message(int(status), int(failed), int(saturated), n, params.cycle_s),
        saturated_cycles=int(saturated),
    )
