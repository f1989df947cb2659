"""Closed-loop simulation of a gearmotor-driven chain belt conveyor.

:func:`simulate` runs one plant through the drive's controller replica at
the controller cycle and returns a :class:`SimulationResult` (a result
object in the style of python-control's ``TimeResponseData``);
:func:`simulate_batch` runs many parameter sets with the same set points
(output-error fits, Monte Carlo, fleets) and returns a :class:`BatchResult`.

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
import threading
from collections.abc import Sequence
from dataclasses import dataclass

import numba
import numpy as np
import numpy.typing as npt

from chaintwin.errors import ModelError
from chaintwin.model.physics import G
from chaintwin.read.recording import FloatArray
from chaintwin.simulate import kernel as _k
from chaintwin.simulate.plant import PlantParameters
from chaintwin.simulate.setpoints import Setpoints

__all__ = ["BatchResult", "SimulationResult", "elastic_substeps", "simulate", "simulate_batch"]

BoolArray = npt.NDArray[np.bool_]
IntArray = npt.NDArray[np.int64]

_MAX_SUBSTEPS = 10_000

# numba's default (workqueue) threading layer must not be entered by two
# Python threads at once; simulate_batch serialises its parallel kernels.
_PARALLEL_LOCK = threading.Lock()


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


@dataclass(frozen=True, eq=False)
class BatchResult:
    """Many simulations with the same set points; arrays are ``(batch, n)``.

    ``time``, ``speed_setpoint`` and ``position_setpoint`` are read-only
    broadcast views (shared by all members). The simulated arrays are
    views of one ``(channel, n, batch)`` buffer, so a member's row is
    strided; use :func:`numpy.ascontiguousarray` if that matters. The
    ``belt_position_m``, ``sprocket_force_n``, ``load_torque_nm`` and
    ``loss_torque_nm`` arrays are only kept with ``full_output=True``
    (otherwise None).

    Parameters
    ----------
    time, speed_setpoint, position_setpoint : ndarray of float
        As in :class:`SimulationResult`, broadcast to ``(batch, n)``.
    torque_setpoint, torque, speed, position, belt_speed_m_s : ndarray of float
        As in :class:`SimulationResult`, ``(batch, n)``.
    belt_position_m, sprocket_force_n, load_torque_nm, loss_torque_nm : ndarray of float or None
        As in :class:`SimulationResult` with ``full_output=True``.
    parameters : tuple of PlantParameters
        The members' plants.
    setpoints : Setpoints
        The set points used.
    success : ndarray of bool
        Per member, False when it diverged.
    messages : tuple of str
        Per member.
    saturated_cycles : ndarray of int
        Per member, cycles at the torque limit.
    """

    time: FloatArray
    speed_setpoint: FloatArray
    position_setpoint: FloatArray
    torque_setpoint: FloatArray
    torque: FloatArray
    speed: FloatArray
    position: FloatArray
    belt_speed_m_s: FloatArray
    belt_position_m: FloatArray | None
    sprocket_force_n: FloatArray | None
    load_torque_nm: FloatArray | None
    loss_torque_nm: FloatArray | None
    parameters: tuple[PlantParameters, ...]
    setpoints: Setpoints
    success: BoolArray
    messages: tuple[str, ...]
    saturated_cycles: IntArray

    def __len__(self) -> int:
        return len(self.parameters)

    def member(self, index: int) -> SimulationResult:
        """Member ``index`` as a :class:`SimulationResult` (needs ``full_output=True``).

        Raises
        ------
        ModelError
            When the batch was run without ``full_output``.
        IndexError
            For an index out of range.
        """
        if (
            self.belt_position_m is None
            or self.sprocket_force_n is None
            or self.load_torque_nm is None
            or self.loss_torque_nm is None
        ):
            raise ModelError("batch result: member() needs simulate_batch(..., full_output=True)")
        i = range(len(self))[index]
        return SimulationResult(
            time=self.time[i],
            speed_setpoint=self.speed_setpoint[i],
            position_setpoint=self.position_setpoint[i],
            torque_setpoint=self.torque_setpoint[i],
            torque=self.torque[i],
            speed=self.speed[i],
            position=self.position[i],
            belt_position_m=self.belt_position_m[i],
            belt_speed_m_s=self.belt_speed_m_s[i],
            sprocket_force_n=self.sprocket_force_n[i],
            load_torque_nm=self.load_torque_nm[i],
            loss_torque_nm=self.loss_torque_nm[i],
            parameters=self.parameters[i],
            setpoints=self.setpoints,
            success=bool(self.success[i]),
            message=self.messages[i],
            saturated_cycles=int(self.saturated_cycles[i]),
        )


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


def _coefficients(
    p: PlantParameters,
    n_cycles: int,
    *,
    initial_motor_angle: float = 0.0,
    initial_belt_position_m: float = 0.0,
) -> FloatArray:
    c = np.zeros(_k.N_COEF, dtype=np.float64)
    dt = p.cycle_s
    tau = p.torque_time_constant_s
    if tau > 0.0:
        a_lag = -math.expm1(-dt / tau)
        b_lag = tau * a_lag / dt
    else:
        a_lag, b_lag = 1.0, 0.0
    c[_k.C_DT] = dt
    c[_k.C_KV] = p.position_gain_1_s
    c[_k.C_KP] = p.speed_gain_nm_s_rad
    c[_k.C_KP_TI] = p.speed_gain_nm_s_rad / p.speed_integral_time_s
    c[_k.C_TLIM] = p.torque_limit_nm
    c[_k.C_A_LAG] = a_lag
    c[_k.C_B_LAG] = b_lag
    c[_k.C_JD] = p.drive_inertia_kgm2
    c[_k.C_ETA] = p.efficiency
    c[_k.C_INV_ETA] = 1.0 / p.efficiency
    c[_k.C_BMA] = p.loss_constant_nm
    c[_k.C_BMB] = p.loss_viscous_nm_s_rad
    c[_k.C_BMC] = p.loss_quadratic_nm_s2_rad2
    c[_k.C_MASS] = p.moving_mass_kg
    c[_k.C_CARRIED] = p.carried_mass_kg
    c[_k.C_MU_G_COS] = p.friction * G * math.cos(p.incline_rad)
    c[_k.C_STATIC] = p.static_friction_ratio if p.stick_slip else 1.0
    c[_k.C_G_SIN] = G * math.sin(p.incline_rad)
    c[_k.C_KRV] = p.belt_speed_per_motor_speed
    c[_k.C_PITCH_R] = p.pitch_radius_m
    c[_k.C_RATIO] = p.ratio
    c[_k.C_TEETH] = float(p.teeth)
    c[_k.C_POLYGON] = 1.0 if p.polygon_active else 0.0
    c[_k.C_LOOP] = p.loop_length_m
    c[_k.C_STIFF] = p.belt_stiffness_n_m
    c[_k.C_DAMP] = p.belt_damping_n_s_m
    c[_k.C_OBS_POS] = p.obstruction_position_m
    c[_k.C_OBS_WIDTH] = p.obstruction_width_m
    c[_k.C_OBS_FORCE] = p.obstruction_force_n
    c[_k.C_IMP_PERIOD] = p.impulse_period_rad
    c[_k.C_IMP_WIDTH] = p.impulse_width_rad
    c[_k.C_IMP_AMP] = p.impulse_amplitude_nm
    step_k = -1
    if p.payload_step_time_s >= 0.0 and p.payload_step_kg != 0.0:
        step_k = max(0, math.ceil(p.payload_step_time_s / dt - 1e-9))
        if step_k >= n_cycles:
            step_k = -1
    c[_k.C_STEP_K] = float(step_k)
    c[_k.C_STEP_KG] = p.payload_step_kg
    c[_k.C_THETA0] = initial_motor_angle
    c[_k.C_X0] = initial_belt_position_m
    c[_k.C_NSUB] = float(elastic_substeps(p)) if p.elastic else 1.0
    c[_k.C_NRIP] = float(len(p.ripple_orders))
    c[_k.C_TAU] = tau
    return c


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


def _chunk_size(batch: int) -> int:
    threads = max(1, int(numba.get_num_threads()))
    per_thread = -(-batch // threads)
    return int(min(_k.LANES, max(8, -(-per_thread // 8) * 8)))


def _run_batch(
    coefs: FloatArray,
    members: tuple[PlantParameters, ...],
    idx_plain: IntArray,
    idx_general: IntArray,
    w_sp: FloatArray,
    p_sp: FloatArray,
    out: FloatArray,
    saturated: FloatArray,
    status: IntArray,
) -> None:
    """Fill ``out`` (Q, n, batch): plain members vectorised, the others one per thread."""
    n_q, n, batch = out.shape
    if idx_plain.size == batch:
        _k.batch_plain_kernel(coefs, w_sp, p_sp, _chunk_size(batch), out, saturated)
    elif idx_plain.size:
        sub = np.empty((n_q, n, idx_plain.size), dtype=np.float64)
        sat_sub = np.zeros(idx_plain.size, dtype=np.float64)
        _k.batch_plain_kernel(
            np.ascontiguousarray(coefs[idx_plain]),
            w_sp,
            p_sp,
            _chunk_size(idx_plain.size),
            sub,
            sat_sub,
        )
        out[:, :, idx_plain] = sub
        saturated[idx_plain] = sat_sub
    if idx_general.size:
        general = [members[i] for i in idx_general.tolist()]
        width = max(1, max(len(p.ripple_orders) for p in general))
        orders = np.zeros((len(general), width), dtype=np.float64)
        amps = np.zeros((len(general), width), dtype=np.float64)
        for row, p in enumerate(general):
            orders[row, : len(p.ripple_orders)] = p.ripple_orders
            amps[row, : len(p.ripple_amplitudes_nm)] = p.ripple_amplitudes_nm
        elastic = np.array([p.elastic for p in general], dtype=np.bool_)
        out_g = np.empty((len(general), _k.N_OUT, n), dtype=np.float64)
        st_g = np.zeros((len(general), 3), dtype=np.int64)
        _k.batch_general_kernel(
            np.ascontiguousarray(coefs[idx_general]), orders, amps, elastic, w_sp, p_sp, out_g, st_g
        )
        out[:, :, idx_general] = out_g[:, :n_q, :].transpose(1, 2, 0)
        status[idx_general] = st_g
        saturated[idx_general] = st_g[:, 2]


def _mark_diverged(out: FloatArray, idx_plain: IntArray, status: IntArray) -> None:
    """Plain members have no in-kernel check: a diverged one ends non-finite."""
    last = out[:, -1, :]
    finite_end = np.isfinite(last[_k.O_TORQUE]) & np.isfinite(last[_k.O_POSITION])
    for member in idx_plain.tolist():
        if not finite_end[member]:
            first_bad = np.flatnonzero(~np.isfinite(out[_k.O_POSITION, :, member]))
            status[member, 0] = 1
            status[member, 1] = int(first_bad[0]) if first_bad.size else out.shape[1] - 1


def simulate_batch(
    params: Sequence[PlantParameters],
    setpoints: Setpoints,
    *,
    full_output: bool = False,
) -> BatchResult:
    """Simulate many parameter sets with the same set points.

    Members with the plain rigid model (no realism switch, no fault; see
    :attr:`PlantParameters.is_plain_rigid`) run on a vectorised kernel
    (lanes across members, chunks across numba threads); the others run
    one per thread on the same kernels as :func:`simulate`. Every member
    gives the same numbers as :func:`simulate` with zero initial angle and
    belt position.

    Parameters
    ----------
    params : sequence of PlantParameters
        One per member, all at the set points' cycle.
    setpoints : Setpoints
        Shared by all members.
    full_output : bool
        Also keep belt position, sprocket force, load and loss torque
        (nearly doubles the memory written).

    Returns
    -------
    BatchResult

    Raises
    ------
    ModelError
        For an empty batch or a member whose cycle differs from the set
        points'.

    Notes
    -----
    The arithmetic runs at some 30 µs per member and 12 s cycle on two
    cores; writing the channels (5 × 8 bytes per cycle and member, fresh
    memory each call) dominates beyond that. Calls from several Python
    threads are serialised (numba's default threading layer is not
    re-entrant); :func:`simulate` releases the GIL and may run in threads.
    """
    members = tuple(params)
    if not members:
        raise ModelError("simulate_batch: give at least one parameter set")
    for i, p in enumerate(members):
        _check_cycle(p, setpoints, f"simulate_batch, member {i}")
    n = len(setpoints)
    batch = len(members)
    n_q = _k.N_OUT if full_output else _k.N_MAIN
    coefs = np.stack([_coefficients(p, n) for p in members])
    plain = np.array([p.is_plain_rigid for p in members], dtype=np.bool_)
    out = np.empty((n_q, n, batch), dtype=np.float64)
    saturated = np.zeros(batch, dtype=np.float64)
    status = np.zeros((batch, 3), dtype=np.int64)
    status[:, 1] = -1
    w_sp, p_sp = setpoints.speed, setpoints.position

    idx_plain = np.flatnonzero(plain)
    idx_general = np.flatnonzero(~plain)
    with _PARALLEL_LOCK:
        _run_batch(coefs, members, idx_plain, idx_general, w_sp, p_sp, out, saturated, status)
    _mark_diverged(out, idx_plain, status)
    status[:, 2] = saturated.astype(np.int64)
    out.flags.writeable = False

    def channel(q: int) -> FloatArray:
        view: FloatArray = out[q].T
        return view

    shared_t = np.broadcast_to(setpoints.time, (batch, n))
    shared_w = np.broadcast_to(setpoints.speed, (batch, n))
    shared_p = np.broadcast_to(setpoints.position, (batch, n))
    return BatchResult(
        time=shared_t,
        speed_setpoint=shared_w,
        position_setpoint=shared_p,
        torque_setpoint=channel(_k.O_TORQUE_SP),
        torque=channel(_k.O_TORQUE),
        speed=channel(_k.O_SPEED),
        position=channel(_k.O_POSITION),
        belt_speed_m_s=channel(_k.O_BELT_SPEED),
        belt_position_m=channel(_k.O_BELT_POSITION) if full_output else None,
        sprocket_force_n=channel(_k.O_FORCE) if full_output else None,
        load_torque_nm=channel(_k.O_LOAD) if full_output else None,
        loss_torque_nm=channel(_k.O_LOSS) if full_output else None,
        parameters=members,
        setpoints=setpoints,
        success=status[:, 0] == 0,
        messages=tuple(
            _message(int(s[0]), int(s[1]), int(s[2]), n, setpoints.cycle_s) for s in status
        ),
        saturated_cycles=status[:, 2].copy(),
    )
