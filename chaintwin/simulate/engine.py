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
cycle that starts at ``time[k]``. :func:`simulate_batch` can keep every
``stride``-th cycle only (a scope with a sample time of ``stride`` controller
cycles, still no filter) and only some channels, which is what an
output-error fit against a scope recording needs.

Standstill
----------
While the belt is stuck (static friction holds it), ``load_torque_nm``
holds the whole drive torque (the static friction reacts to it),
``loss_torque_nm`` is 0 and ``sprocket_force_n`` the force that torque
would transmit; no power flows.
"""

from __future__ import annotations

import itertools
import math
import operator
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numba
import numpy as np
import numpy.typing as npt

from chaintwin._types import FloatArray
from chaintwin.errors import ModelError
from chaintwin.model.physics import G, chordal_radius_m
from chaintwin.simulate import kernel as _k
from chaintwin.simulate.plant import PlantParameters
from chaintwin.simulate.setpoints import Setpoints

__all__ = [
    "CHANNELS",
    "MAIN_CHANNELS",
    "BatchResult",
    "SimulationResult",
    "elastic_substeps",
    "simulate",
    "simulate_batch",
]

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


CHANNELS: tuple[str, ...] = (
    "torque_setpoint",
    "torque",
    "speed",
    "position",
    "belt_speed_m_s",
    "belt_position_m",
    "sprocket_force_n",
    "load_torque_nm",
    "loss_torque_nm",
)
"""Simulated channels of :class:`BatchResult`, in the kernels' row order."""

MAIN_CHANNELS: tuple[str, ...] = CHANNELS[:5]
"""What :func:`simulate_batch` keeps by default (without ``full_output``)."""

_CHANNEL_ROW = {name: row for row, name in enumerate(CHANNELS)}


@dataclass(frozen=True, eq=False)
class BatchResult:
    """Many simulations with the same set points; arrays are ``(batch, n_out)``.

    ``n_out = ceil(n/stride)`` columns, at cycles ``0, stride, 2·stride…``
    (all cycles with the default ``stride=1``). ``time``,
    ``speed_setpoint`` and ``position_setpoint`` are read-only broadcast
    views of the set points at those cycles (shared by all members). The
    simulated arrays are read-only views of one ``(channel, n_out, batch)``
    buffer, so a member's row is strided; use
    :func:`numpy.ascontiguousarray` if that matters.

    A simulated channel that was not asked for is None: by default the
    five of :data:`MAIN_CHANNELS` are kept, ``full_output=True`` keeps all
    nine of :data:`CHANNELS` and ``channels=`` exactly the ones named.
    :meth:`channel` returns a kept channel by name (typed without None).

    Parameters
    ----------
    time, speed_setpoint, position_setpoint : ndarray of float
        As in :class:`SimulationResult`, at the kept cycles, broadcast to
        ``(batch, n_out)``.
    torque_setpoint, torque, speed, position, belt_speed_m_s : ndarray of float or None
        As in :class:`SimulationResult`, ``(batch, n_out)``; None when not kept.
    belt_position_m, sprocket_force_n, load_torque_nm, loss_torque_nm : ndarray of float or None
        As in :class:`SimulationResult`; None when not kept (the default).
    parameters : tuple of PlantParameters
        The members' plants.
    setpoints : Setpoints
        The set points used (all cycles).
    success : ndarray of bool
        Per member, False when it diverged.
    messages : tuple of str
        Per member.
    saturated_cycles : ndarray of int
        Per member, cycles at the torque limit (over all cycles, kept or not).
    stride : int
        Every ``stride``-th controller cycle is kept.
    channels : tuple of str
        The kept channels (names from :data:`CHANNELS`).
    """

    time: FloatArray
    speed_setpoint: FloatArray
    position_setpoint: FloatArray
    torque_setpoint: FloatArray | None
    torque: FloatArray | None
    speed: FloatArray | None
    position: FloatArray | None
    belt_speed_m_s: FloatArray | None
    belt_position_m: FloatArray | None
    sprocket_force_n: FloatArray | None
    load_torque_nm: FloatArray | None
    loss_torque_nm: FloatArray | None
    parameters: tuple[PlantParameters, ...]
    setpoints: Setpoints
    success: BoolArray
    messages: tuple[str, ...]
    saturated_cycles: IntArray
    stride: int = 1
    channels: tuple[str, ...] = MAIN_CHANNELS

    def __len__(self) -> int:
        return len(self.parameters)

    def channel(self, name: str) -> FloatArray:
        """Kept channel ``name`` (one of :data:`CHANNELS`), ``(batch, n_out)``.

        Raises
        ------
        ModelError
            For an unknown name or a channel that was not kept.
        """
        if name not in _CHANNEL_ROW:
            raise ModelError(
                f"batch result: unknown channel {name!r}; channels are {', '.join(CHANNELS)}"
            )
        value: FloatArray | None = getattr(self, name)
        if value is None:
            raise ModelError(
                f"batch result: channel {name!r} was not kept; pass it in "
                "simulate_batch(..., channels=...) or use full_output=True"
            )
        return value

    def member(self, index: int) -> SimulationResult:
        """Member ``index`` as a :class:`SimulationResult`.

        Needs every channel at every cycle (``full_output=True``, stride 1).

        Raises
        ------
        ModelError
            When the batch was run without ``full_output`` or with a stride.
        IndexError
            For an index out of range.
        """
        if len(self.channels) != len(CHANNELS) or self.stride != 1:
            raise ModelError(
                "batch result: member() needs simulate_batch(..., full_output=True) with stride 1"
            )
        i = range(len(self))[index]
        return SimulationResult(
            time=self.time[i],
            speed_setpoint=self.speed_setpoint[i],
            position_setpoint=self.position_setpoint[i],
            torque_setpoint=self.channel("torque_setpoint")[i],
            torque=self.channel("torque")[i],
            speed=self.channel("speed")[i],
            position=self.channel("position")[i],
            belt_position_m=self.channel("belt_position_m")[i],
            belt_speed_m_s=self.channel("belt_speed_m_s")[i],
            sprocket_force_n=self.channel("sprocket_force_n")[i],
            load_torque_nm=self.channel("load_torque_nm")[i],
            loss_torque_nm=self.channel("loss_torque_nm")[i],
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


def _plain_terms(
    mass: float,
    carried: float,
    mu_g_cos: float,
    static: float,
    g_sin: float,
    k: float,
    dt: float,
    jd: float,
    eta: float,
    inv_eta: float,
    bma: float,
) -> list[float]:
    """Belt terms of the plain rigid model at the motor, layout ``C_M_RED0…C_BRKN0``.

    Python floats (no fused multiply-add), so :func:`simulate` and
    :func:`simulate_batch` feed their kernels the same bits.
    """
    m_red = mass * k * k
    fc = mu_g_cos * mass * k
    fs = fc * static
    fg = g_sin * carried * k
    hjm = dt / (jd + m_red * inv_eta)
    hjg = dt / (jd + m_red * eta)
    q_pos = fg + fs
    q_neg = fg - fs
    brk_pos = bma + q_pos * (inv_eta if q_pos > 0.0 else eta)
    brk_neg = q_neg * (inv_eta if q_neg < 0.0 else eta) - bma
    return [m_red, fc, fg, hjm, hjg, brk_pos, brk_neg]


def _coefficient_row(
    p: PlantParameters,
    n_cycles: int,
    initial_motor_angle: float = 0.0,
    initial_belt_position_m: float = 0.0,
) -> list[float]:
    """The kernels' coefficient vector (layout ``kernel.C_*``) as a list."""
    dt = p.cycle_s
    tau = p.torque_time_constant_s
    if tau > 0.0:
        a_lag = -math.expm1(-dt / tau)
        b_lag = tau * a_lag / dt
    else:
        a_lag, b_lag = 1.0, 0.0
    eta = p.efficiency
    inv_eta = 1.0 / eta
    jd = p.drive_inertia_kgm2
    bma = p.loss_constant_nm
    payload = p.payload_kg
    tray = p.tray_mass_kg
    mass = p.belt_mass_kg + tray + payload
    carried = tray + payload
    mu_g_cos = p.friction * G * math.cos(p.incline_rad)
    static = p.static_friction_ratio if p.stick_slip else 1.0
    g_sin = G * math.sin(p.incline_rad)
    krv = p.belt_speed_per_motor_speed
    step_kg = p.payload_step_kg
    step_k = -1
    if p.payload_step_time_s >= 0.0 and step_kg != 0.0:
        step_k = max(0, math.ceil(p.payload_step_time_s / dt - 1e-9))
        if step_k >= n_cycles:
            step_k = -1
    before = _plain_terms(mass, carried, mu_g_cos, static, g_sin, krv, dt, jd, eta, inv_eta, bma)
    if step_k >= 0:
        mass1 = mass + step_kg
        after = _plain_terms(
            mass1, carried + step_kg, mu_g_cos, static, g_sin, krv, dt, jd, eta, inv_eta, bma
        )
        step_scale = (jd + mass * krv * krv) / (jd + mass1 * krv * krv)
    else:
        after = before
        step_scale = 1.0
    teeth = p.teeth
    row = [
        dt,  # C_DT
        p.position_gain_1_s,  # C_KV
        p.speed_gain_nm_s_rad,  # C_KP
        p.speed_gain_nm_s_rad / p.speed_integral_time_s,  # C_KP_TI
        p.torque_limit_nm,  # C_TLIM
        a_lag,  # C_A_LAG
        b_lag,  # C_B_LAG
        jd,  # C_JD
        eta,  # C_ETA
        inv_eta,  # C_INV_ETA
        bma,  # C_BMA
        p.loss_viscous_nm_s_rad,  # C_BMB
        p.loss_quadratic_nm_s2_rad2,  # C_BMC
        mass,  # C_MASS
        carried,  # C_CARRIED
        mu_g_cos,  # C_MU_G_COS
        static,  # C_STATIC
        g_sin,  # C_G_SIN
        krv,  # C_KRV
        p.pitch_radius_m,  # C_PITCH_R
        p.ratio,  # C_RATIO
        float(teeth),  # C_TEETH
        1.0 if (p.polygon and teeth > 0) else 0.0,  # C_POLYGON
        p.loop_length_m,  # C_LOOP
        p.belt_stiffness_n_m,  # C_STIFF
        p.belt_damping_n_s_m,  # C_DAMP
        p.obstruction_position_m,  # C_OBS_POS
        p.obstruction_width_m,  # C_OBS_WIDTH
        p.obstruction_force_n,  # C_OBS_FORCE
        p.impulse_period_rad,  # C_IMP_PERIOD
        p.impulse_width_rad,  # C_IMP_WIDTH
        p.impulse_amplitude_nm,  # C_IMP_AMP
        float(step_k),  # C_STEP_K
        step_kg,  # C_STEP_KG
        initial_motor_angle,  # C_THETA0
        initial_belt_position_m,  # C_X0
        float(elastic_substeps(p)) if p.elastic else 1.0,  # C_NSUB
        float(len(p.ripple_orders)),  # C_NRIP
        tau,  # C_TAU
        *before,  # C_M_RED0 … C_BRKN0
        *after,  # C_M_RED1 … C_BRKN1
        step_scale,  # C_STEP_SCALE
    ]
    return row


def _plain_terms_array(
    mass: FloatArray,
    carried: FloatArray,
    mu_g_cos: FloatArray,
    static: FloatArray,
    g_sin: FloatArray,
    k: FloatArray,
    dt: FloatArray,
    jd: FloatArray,
    eta: FloatArray,
    inv_eta: FloatArray,
    bma: FloatArray,
) -> list[FloatArray]:
    """:func:`_plain_terms` for columns of members (the same operations)."""
    m_red = mass * k * k
    fc = mu_g_cos * mass * k
    fs = fc * static
    fg = g_sin * carried * k
    hjm = dt / (jd + m_red * inv_eta)
    hjg = dt / (jd + m_red * eta)
    q_pos = fg + fs
    q_neg = fg - fs
    brk_pos = bma + q_pos * np.where(q_pos > 0.0, inv_eta, eta)
    brk_neg = q_neg * np.where(q_neg < 0.0, inv_eta, eta) - bma
    return [m_red, fc, fg, hjm, hjg, brk_pos, brk_neg]


_RAW_FIELDS = (
    "cycle_s",
    "torque_time_constant_s",
    "position_gain_1_s",
    "speed_gain_nm_s_rad",
    "speed_integral_time_s",
    "torque_limit_nm",
    "motor_inertia_kgm2",
    "gear_inertia_kgm2",
    "efficiency",
    "loss_constant_nm",
    "loss_viscous_nm_s_rad",
    "loss_quadratic_nm_s2_rad2",
    "belt_mass_kg",
    "tray_mass_kg",
    "payload_kg",
    "friction",
    "incline_rad",
    "static_friction_ratio",
    "stick_slip",
    "pitch_radius_m",
    "ratio",
    "teeth",
    "polygon",
    "loop_length_m",
    "belt_stiffness_n_m",
    "belt_damping_n_s_m",
    "obstruction_position_m",
    "obstruction_width_m",
    "obstruction_force_n",
    "impulse_period_rad",
    "impulse_width_rad",
    "impulse_amplitude_nm",
    "payload_step_time_s",
    "payload_step_kg",
    "elastic",
)
_raw_fields = operator.attrgetter(*_RAW_FIELDS)
_ripple_orders = operator.attrgetter("ripple_orders")


def _lag_terms(dt: float, tau: float) -> tuple[float, ...]:
    if tau > 0.0:
        a_lag = -math.expm1(-dt / tau)
        return a_lag, tau * a_lag / dt
    return 1.0, 0.0


def _incline_terms(incline: float) -> tuple[float, ...]:
    return math.cos(incline), math.sin(incline)


def _krv_term(pitch_r: float, teeth: float, ratio: float) -> tuple[float, ...]:
    return (chordal_radius_m(pitch_r, int(teeth)) / ratio,)


def _per_distinct(
    fn: Callable[..., tuple[float, ...]], *columns: FloatArray
) -> tuple[FloatArray, ...]:
    """``fn`` of each member's arguments (one column each), once per distinct tuple."""
    size = columns[0].size
    if all(c.min() == c.max() for c in columns):  # the usual case: shared by all
        key = tuple(float(c[0]) for c in columns)
        return tuple(np.full(size, v, dtype=np.float64) for v in fn(*key))
    keys = list(zip(*(c.tolist() for c in columns), strict=True))
    table = {key: fn(*key) for key in set(keys)}
    values = np.array([table[key] for key in keys], dtype=np.float64)
    return tuple(values.T)


def _coefficient_matrix(
    members: Sequence[PlantParameters], n_cycles: int
) -> tuple[FloatArray, BoolArray]:
    """Coefficient rows of many members at once, and which are plain rigid.

    The same numbers as stacking :func:`_coefficient_row` (zero initial
    angle and belt position), bit for bit: the same IEEE operations in the
    same order, column by column (transcendental functions once per
    distinct argument, with :mod:`math` as there). For a batch it costs
    about half as much Python time; what remains is mostly reading the
    members' fields.
    """
    batch = len(members)
    n_raw = len(_RAW_FIELDS)
    raw = np.fromiter(
        itertools.chain.from_iterable(map(_raw_fields, members)),
        dtype=np.float64,
        count=batch * n_raw,
    ).reshape(batch, n_raw)
    (
        dt,
        tau,
        kv,
        kp,
        ti,
        tlim,
        j_motor,
        j_gear,
        eta,
        bma,
        bmb,
        bmc,
        belt,
        tray,
        payload,
        friction,
        incline,
        static_ratio,
        stick_slip,
        pitch_r,
        ratio,
        teeth,
        polygon,
        loop,
        stiff,
        damp,
        obs_pos,
        obs_w,
        obs_f,
        imp_period,
        imp_w,
        imp_amp,
        step_t,
        step_kg,
        elastic,
    ) = raw.T
    c = np.empty((batch, _k.N_COEF), dtype=np.float64)
    # transcendental terms with math, once per distinct argument
    a_lag, b_lag = _per_distinct(_lag_terms, dt, tau)
    cos_b, sin_b = _per_distinct(_incline_terms, incline)
    (krv,) = _per_distinct(_krv_term, pitch_r, teeth, ratio)
    inv_eta = 1.0 / eta
    jd = j_motor + j_gear
    mass = belt + tray + payload
    carried = tray + payload
    mu_g_cos = friction * G * cos_b
    static = np.where(stick_slip != 0.0, static_ratio, 1.0)
    g_sin = G * sin_b
    step_k = np.where(
        (step_t >= 0.0) & (step_kg != 0.0), np.maximum(0.0, np.ceil(step_t / dt - 1e-9)), -1.0
    )
    step_k = np.where(step_k >= n_cycles, -1.0, step_k)
    stepped = step_k >= 0.0
    n_rip = np.fromiter(map(len, map(_ripple_orders, members)), dtype=np.float64, count=batch)
    c[:, _k.C_DT] = dt
    c[:, _k.C_KV] = kv
    c[:, _k.C_KP] = kp
    c[:, _k.C_KP_TI] = kp / ti
    c[:, _k.C_TLIM] = tlim
    c[:, _k.C_A_LAG] = a_lag
    c[:, _k.C_B_LAG] = b_lag
    c[:, _k.C_JD] = jd
    c[:, _k.C_ETA] = eta
    c[:, _k.C_INV_ETA] = inv_eta
    c[:, _k.C_BMA] = bma
    c[:, _k.C_BMB] = bmb
    c[:, _k.C_BMC] = bmc
    c[:, _k.C_MASS] = mass
    c[:, _k.C_CARRIED] = carried
    c[:, _k.C_MU_G_COS] = mu_g_cos
    c[:, _k.C_STATIC] = static
    c[:, _k.C_G_SIN] = g_sin
    c[:, _k.C_KRV] = krv
    c[:, _k.C_PITCH_R] = pitch_r
    c[:, _k.C_RATIO] = ratio
    c[:, _k.C_TEETH] = teeth
    c[:, _k.C_POLYGON] = np.where((polygon != 0.0) & (teeth > 0.0), 1.0, 0.0)
    c[:, _k.C_LOOP] = loop
    c[:, _k.C_STIFF] = stiff
    c[:, _k.C_DAMP] = damp
    c[:, _k.C_OBS_POS] = obs_pos
    c[:, _k.C_OBS_WIDTH] = obs_w
    c[:, _k.C_OBS_FORCE] = obs_f
    c[:, _k.C_IMP_PERIOD] = imp_period
    c[:, _k.C_IMP_WIDTH] = imp_w
    c[:, _k.C_IMP_AMP] = imp_amp
    c[:, _k.C_STEP_K] = step_k
    c[:, _k.C_STEP_KG] = step_kg
    c[:, _k.C_THETA0] = 0.0
    c[:, _k.C_X0] = 0.0
    c[:, _k.C_NSUB] = 1.0
    for i in np.flatnonzero(elastic != 0.0).tolist():
        c[i, _k.C_NSUB] = float(elastic_substeps(members[i]))
    c[:, _k.C_NRIP] = n_rip
    c[:, _k.C_TAU] = tau
    before = _plain_terms_array(
        mass, carried, mu_g_cos, static, g_sin, krv, dt, jd, eta, inv_eta, bma
    )
    mass1 = mass + step_kg
    after = _plain_terms_array(
        mass1, carried + step_kg, mu_g_cos, static, g_sin, krv, dt, jd, eta, inv_eta, bma
    )
    scale = (jd + mass * krv * krv) / (jd + mass1 * krv * krv)
    first = _k.C_M_RED0
    for j, (b, a) in enumerate(zip(before, after, strict=True)):
        c[:, first + j] = b
        c[:, _k.C_M_RED1 + j] = np.where(stepped, a, b)
    c[:, _k.C_STEP_SCALE] = np.where(stepped, scale, 1.0)
    plain = ~(
        (elastic != 0.0)
        | (c[:, _k.C_POLYGON] != 0.0)
        | (n_rip > 0.0)
        | (imp_amp != 0.0)
        | ((obs_w > 0.0) & (obs_f > 0.0))
    )
    return c, plain


def _coefficients(
    p: PlantParameters,
    n_cycles: int,
    *,
    initial_motor_angle: float = 0.0,
    initial_belt_position_m: float = 0.0,
) -> FloatArray:
    """The kernels' coefficient vector (layout ``kernel.C_*``)."""
    return np.array(
        _coefficient_row(p, n_cycles, initial_motor_angle, initial_belt_position_m),
        dtype=np.float64,
    )


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


def _batch_channels(channels: Sequence[str] | None, full_output: bool) -> tuple[str, ...]:
    if channels is None:
        return CHANNELS if full_output else MAIN_CHANNELS
    if full_output:
        raise ModelError("simulate_batch: give either channels= or full_output=True, not both")
    if isinstance(channels, str):
        channels = (channels,)
    names = tuple(channels)
    unknown = [c for c in names if c not in _CHANNEL_ROW]
    if unknown:
        raise ModelError(
            f"simulate_batch: unknown channel(s) {', '.join(map(repr, unknown))}; "
            f"channels are {', '.join(CHANNELS)}"
        )
    if not names:
        raise ModelError("simulate_batch: channels= names no channel; give at least one")
    if len(set(names)) != len(names):
        raise ModelError(f"simulate_batch: channels {names} name a channel twice")
    return names


def _batch_buffer(out: FloatArray | None, shape: tuple[int, int, int]) -> FloatArray:
    if out is None:
        return np.empty(shape, dtype=np.float64)
    if (
        not isinstance(out, np.ndarray)
        or out.dtype != np.float64
        or out.shape != shape
        or not out.flags.c_contiguous
        or not out.flags.writeable
    ):
        got = f"{out.dtype} {out.shape}" if isinstance(out, np.ndarray) else type(out).__name__
        raise ModelError(
            f"simulate_batch: out= must be a writeable C-contiguous float64 array of shape "
            f"{shape} (channels, ceil(cycles/stride), members); got {got}"
        )
    return out


def _run_batch(
    coefs: FloatArray,
    members: tuple[PlantParameters, ...],
    idx_plain: IntArray,
    idx_general: IntArray,
    w_sp: FloatArray,
    p_sp: FloatArray,
    stride: int,
    rows: IntArray,
    out: FloatArray,
    status: IntArray,
) -> None:
    """Fill ``out`` (Q, n_out, batch) and ``status`` (batch, 3).

    Plain members run vectorised (diverged ones again on the scalar kernel,
    which tells where and NaN-fills as :func:`simulate` does), the others
    one per thread.
    """
    n_q, n_out, batch = out.shape
    n = w_sp.size
    # the vectorised kernel shares one cycle time; members whose cycle differs
    # in the last bits (within the 1e-9 tolerance) run as a group of their own
    cycles = coefs[idx_plain, _k.C_DT]
    for cycle in np.unique(cycles).tolist():
        idx = idx_plain[cycles == cycle]
        whole = idx.size == batch
        sub = out if whole else np.empty((n_q, n_out, idx.size), dtype=np.float64)
        sat = np.zeros(idx.size, dtype=np.float64)
        bad = np.zeros(idx.size, dtype=np.bool_)
        _k.batch_plain_kernel(
            coefs if whole else np.ascontiguousarray(coefs[idx]),
            w_sp,
            p_sp,
            _chunk_size(idx.size),
            stride,
            rows,
            sub,
            sat,
            bad,
        )
        if not whole:
            out[:, :, idx] = sub
        status[idx, 2] = sat.astype(np.int64)
        if bad.any():
            one = np.empty((_k.N_OUT, n), dtype=np.float64)
            for member in idx[bad].tolist():
                res = _k.plain_kernel(coefs[member], w_sp, p_sp, one)
                status[member] = res
                out[:, :, member] = one[rows, ::stride]
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
        out[:, :, idx_general] = out_g[:, rows, ::stride].transpose(1, 2, 0)
        status[idx_general] = st_g


def simulate_batch(
    params: Sequence[PlantParameters],
    setpoints: Setpoints,
    *,
    stride: int = 1,
    channels: Sequence[str] | None = None,
    full_output: bool = False,
    out: FloatArray | None = None,
) -> BatchResult:
    """Simulate many parameter sets with the same set points.

    Members with the plain rigid model (no realism switch, no fault; see
    :attr:`PlantParameters.is_plain_rigid`) run on a vectorised kernel
    (lanes across members, chunks across numba threads); the others run
    one per thread on the same kernels as :func:`simulate`. Every member
    gives the same numbers as :func:`simulate` with zero initial angle and
    belt position, at the kept cycles.

    Parameters
    ----------
    params : sequence of PlantParameters
        One per member, all at the set points' cycle.
    setpoints : Setpoints
        Shared by all members.
    stride : int
        Keep every ``stride``-th controller cycle (0, stride, 2·stride…),
        as a drive scope with a sample time of ``stride`` cycles samples
        (no filtering); the simulation itself still runs every cycle. The
        arrays get ``ceil(n/stride)`` columns.
    channels : sequence of str, optional
        Keep exactly these channels (names from :data:`CHANNELS`, e.g.
        ``("torque", "speed")`` for an output-error fit; one name alone is
        one channel), in this order; the others are None in the result.
        Default: the five of :data:`MAIN_CHANNELS`.
    full_output : bool
        Keep all nine channels (instead of ``channels``).
    out : ndarray, optional
        Buffer to write into, float64, C-contiguous, shape ``(channels
        kept, ceil(n/stride), len(params))``, channel rows in the order of
        ``channels`` (or :data:`MAIN_CHANNELS`, :data:`CHANNELS`); the
        result's arrays are read-only views of it (``out[q].T``). Reusing
        one buffer across calls saves allocating and page-faulting fresh
        memory for large outputs, but each call then overwrites the arrays
        of the previous result.

    Returns
    -------
    BatchResult

    Raises
    ------
    ModelError
        For an empty batch, a member whose cycle differs from the set
        points', a stride below 1, unknown or repeated channel names,
        ``channels`` together with ``full_output``, or an unsuitable ``out``.

    Notes
    -----
    Costs per member and 12 s cycle (12 001 controller cycles) of the
    plain rigid model, batch 256, on two cores (see
    ``benchmarks/bench_simulate.py``): some 20 µs of arithmetic, 2-6 µs of
    Python (packing the parameters, single-threaded), and writing the
    channels, 8 bytes per kept cycle, channel and member. The default output
    (five channels at every cycle, 480 kB per member) is bound by memory
    bandwidth (over 100 µs); torque and speed at a 6-cycle stride (32 kB)
    add a few µs. Calls from several Python threads are serialised (numba's
    default threading layer is not re-entrant); :func:`simulate` releases
    the GIL and may run in threads.
    """
    members = tuple(params)
    if not members:
        raise ModelError("simulate_batch: give at least one parameter set")
    if isinstance(stride, bool) or not isinstance(stride, (int, np.integer)) or stride < 1:
        raise ModelError(f"simulate_batch: stride must be a whole number ≥ 1 (got {stride!r})")
    stride = int(stride)
    names = _batch_channels(channels, full_output)
    n = len(setpoints)
    batch = len(members)
    coefs, plain = _coefficient_matrix(members, n)
    cycles = coefs[:, _k.C_DT]
    off = np.flatnonzero(np.abs(cycles - setpoints.cycle_s) > 1e-9 * cycles)
    if off.size:
        i = int(off[0])
        _check_cycle(members[i], setpoints, f"simulate_batch, member {i}")
    n_out = -(-n // stride)
    rows = np.array([_CHANNEL_ROW[c] for c in names], dtype=np.int64)
    buf = _batch_buffer(out, (len(names), n_out, batch))
    status = np.zeros((batch, 3), dtype=np.int64)
    status[:, 1] = -1
    idx_plain = np.flatnonzero(plain)
    idx_general = np.flatnonzero(~plain)
    with _PARALLEL_LOCK:
        _run_batch(
            coefs,
            members,
            idx_plain,
            idx_general,
            setpoints.speed,
            setpoints.position,
            stride,
            rows,
            buf,
            status,
        )
    view = buf.view()
    view.flags.writeable = False
    kept: dict[str, FloatArray] = {name: view[r].T for r, name in enumerate(names)}
    text: dict[tuple[int, int, int], str] = {}
    messages = []
    for s in status.tolist():
        key = (s[0], s[1], s[2])
        if key not in text:
            text[key] = _message(s[0], s[1], s[2], n, setpoints.cycle_s)
        messages.append(text[key])

    def shared(a: FloatArray) -> FloatArray:
        return np.broadcast_to(a[::stride], (batch, n_out))

    return BatchResult(
        time=shared(setpoints.time),
        speed_setpoint=shared(setpoints.speed),
        position_setpoint=shared(setpoints.position),
        torque_setpoint=kept.get("torque_setpoint"),
        torque=kept.get("torque"),
        speed=kept.get("speed"),
        position=kept.get("position"),
        belt_speed_m_s=kept.get("belt_speed_m_s"),
        belt_position_m=kept.get("belt_position_m"),
        sprocket_force_n=kept.get("sprocket_force_n"),
        load_torque_nm=kept.get("load_torque_nm"),
        loss_torque_nm=kept.get("loss_torque_nm"),
        parameters=members,
        setpoints=setpoints,
        success=status[:, 0] == 0,
        messages=tuple(messages),
        saturated_cycles=status[:, 2].copy(),
        stride=stride,
        channels=names,
    )
