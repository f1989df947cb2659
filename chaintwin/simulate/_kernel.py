"""Compiled (numba) kernels of the closed-loop conveyor simulator.

Internal: :mod:`chaintwin.simulate.engine` packs a
:class:`~chaintwin.simulate.plant.PlantParameters` into a coefficient vector
(layout ``C_*`` below) and calls these kernels; outputs are rows ``O_*`` of
a ``(N_OUT, n)`` array, one column per controller cycle.

One controller cycle ``k`` (time ``t_k = k·dt``)
-----------------------------------------------
1. Sample speed ω_k and angle θ_k; position P + speed PI with clamping
   anti-windup gives the torque set point u_k (``controller``).
2. The motor torque follows ``1/(1 + sτ)`` driven by the set point of the
   *previous* cycle, u_{k-1} (one cycle of delay), solved exactly over the
   cycle: ``T_{k+1} = T_k + (1 - e^{-dt/τ})·(u_{k-1} - T_k)``; the plant
   sees the exact mean torque over the cycle (over each sub-step when
   sub-stepping).
3. The plant advances one cycle (rigid: one step; elastic: ``n_sub``
   semi-implicit Euler sub-steps).

Power-flow cases (which efficiency applies)
-------------------------------------------
Rigid model: with ``f = F·r/i`` (belt resistance at the motor, ideal gear),
``M = m·r²/i²`` and ``A`` the motor torque net of motor/gear losses, the
gear carries ``Q = f + M·α`` (ideal). Motoring (power motor → belt,
``Q·ω > 0``) the motor supplies ``Q/η`` so ``(J_d + M/η)·α = A − f/η``;
generating (belt drives motor) it supplies ``Q·η`` so
``(J_d + M·η)·α = A − f·η``. Solving both, ``Q`` has the sign of
``f·J_d + M·A`` in either case, so that sign decides the case without
iteration (``rigid_core``). Elastic model: the spring force ``F_k`` at the
sprocket rim is the gear's output load; motoring while ``F_k·ω ≥ 0``
(torque ``F_k·ρ/(i·η)``), else generating (``F_k·ρ·η/i``).

Coulomb friction at standstill
------------------------------
A speed that would cross zero within a step, or that decays below a tiny
band (1e-6 rad/s), is set to exactly zero ("stuck"). While stuck, the drive
torque must exceed the breakaway level (static friction, with the efficiency
of the power flow that motion would have) in one direction to move;
otherwise the speed stays at zero. This holds the belt without chattering
while the drive holds position.

The plain rigid model
---------------------
The identification model (rigid, no realism switch, no fault) runs in
:func:`plain_kernel`, a lean twin of :func:`rigid_kernel`: it takes its belt
terms precomputed from the coefficients (``M_RED0`` …, computed in Python
by :func:`belt_terms` once per run) and is compiled without floating-point
contraction (``_EXACT``), fused multiply-adds written out (:func:`fma`), so
that its numbers do not depend on how LLVM fuses operations.

Coefficient layout
------------------
:data:`COEFFICIENTS` is the one table of the coefficient vector: name,
meaning and unit of each entry, in order. The index constants ``C_*`` are
made from it (one :func:`_coef` call per row) and :func:`pack` builds a
vector from values given by name, checking that every entry is given once.

The kernels, their shared pieces and the layout stay in this one module
although it is long: numba's on-disk cache is invalidated only when the
file of the cached function changes (not the files of functions it
inlines) and it freezes module-level constants such as ``C_*`` at compile
time, so a kernel in another file could run stale pieces or indices.
"""

from __future__ import annotations

import math
import operator
from collections.abc import Callable, Mapping
from typing import Any, cast

import numpy as np
from llvmlite import ir as llvm_ir  # type: ignore[import-untyped]
from numba import njit, types
from numba.extending import intrinsic

from chaintwin._types import FloatArray
from chaintwin.errors import ModelError

__all__ = [
    "COEFFICIENTS",
    "N_COEF",
    "N_OUT",
    "belt_terms",
    "elastic_kernel",
    "pack",
    "plain_extra",
    "plain_kernel",
    "plain_step",
    "rigid_kernel",
]

# ------------------------------------------------------- coefficient layout
COEFFICIENTS: list[tuple[str, str]] = []
"""The coefficient vector's layout: ``(name, meaning with unit)`` per entry, in order.

Filled by the ``C_* = _coef(...)`` rows below (the one table); :func:`pack`
builds a vector from values given by these names."""


def _coef(name: str, meaning: str) -> int:
    """Append a row to :data:`COEFFICIENTS`; returns its index (a ``C_*`` constant)."""
    COEFFICIENTS.append((name, meaning))
    return len(COEFFICIENTS) - 1


C_DT = _coef("dt", "controller cycle, s")
C_KV = _coef("kv", "position gain, 1/s")
C_KP = _coef("kp", "speed gain, Nm·s/rad")
C_KP_TI = _coef("kp_ti", "speed gain over integral time Kp/Ti, Nm/rad")
C_TLIM = _coef("tlim", "torque limit, Nm")
C_A_LAG = _coef("a_lag", "torque lag step 1 - exp(-dt/τ), 1")
C_B_LAG = _coef("b_lag", "mean of exp(-t/τ) over a cycle, τ·(1 - exp(-dt/τ))/dt")
C_JD = _coef("jd", "motor + gear inertia, kg·m²")
C_ETA = _coef("eta", "gear efficiency η, 1")
C_INV_ETA = _coef("inv_eta", "1/η, 1")
C_BMA = _coef("bma", "loss constant, Nm")
C_BMB = _coef("bmb", "loss viscous, Nm·s/rad")
C_BMC = _coef("bmc", "loss quadratic, Nm·s²/rad²")
C_MASS = _coef("mass", "moving mass m_b + m_t + m_p, kg")
C_CARRIED = _coef("carried", "carried mass m_t + m_p, kg")
C_MU_G_COS = _coef("mu_g_cos", "μ·g·cosβ: kinetic rail friction force per kg of moving mass, N/kg")
C_STATIC = _coef("static", "static/kinetic friction ratio in effect (1 without stick-slip), 1")
C_G_SIN = _coef("g_sin", "g·sinβ, N/kg")
C_KRV = _coef("krv", "belt speed per motor speed r/i, m/rad")
C_PITCH_R = _coef("pitch_r", "sprocket pitch radius R, m")
C_RATIO = _coef("ratio", "gear ratio i, 1")
C_TEETH = _coef("teeth", "sprocket teeth z (0 unknown)")
C_POLYGON = _coef("polygon", "1.0: polygon effect on, 0.0 off")
C_LOOP = _coef("loop", "loop length, m")
C_STIFF = _coef("stiff", "belt stiffness, N/m")
C_DAMP = _coef("damp", "belt damping, N·s/m")
C_OBS_POS = _coef("obs_pos", "obstruction start, m")
C_OBS_WIDTH = _coef("obs_width", "obstruction width, m")
C_OBS_FORCE = _coef("obs_force", "obstruction force, N")
C_IMP_PERIOD = _coef("imp_period", "impulse period, rad")
C_IMP_WIDTH = _coef("imp_width", "impulse width, rad")
C_IMP_AMP = _coef("imp_amp", "impulse amplitude, Nm")
C_STEP_K = _coef("step_k", "cycle of the payload step (-1: none), cycles")
C_STEP_KG = _coef("step_kg", "payload step, kg")
C_THETA0 = _coef("theta0", "initial motor angle, rad")
C_X0 = _coef("x0", "initial belt position, m")
C_NSUB = _coef("nsub", "elastic sub-steps per cycle (1 when rigid)")
C_NRIP = _coef("nrip", "number of ripple orders")
C_TAU = _coef("tau", "torque time constant, s")
C_M_RED0 = _coef("m_red0", "plain model: reflected mass m·(r/i)² before the payload step, kg·m²")
C_FC0 = _coef("fc0", "plain model: kinetic friction torque at the motor, Nm")
C_FG0 = _coef("fg0", "plain model: incline torque at the motor, Nm")
C_HJM0 = _coef("hjm0", "dt/(J_d + M/η), s/(kg·m²)")
C_HJG0 = _coef("hjg0", "dt/(J_d + M·η), s/(kg·m²)")
C_BRKP0 = _coef("brkp0", "breakaway level forward, Nm")
C_BRKN0 = _coef("brkn0", "breakaway level backward, Nm")
C_M_RED1 = _coef("m_red1", "m_red0 after the payload step, kg·m²")
C_FC1 = _coef("fc1", "fc0 after the payload step, Nm")
C_FG1 = _coef("fg1", "fg0 after the payload step, Nm")
C_HJM1 = _coef("hjm1", "hjm0 after the payload step, s/(kg·m²)")
C_HJG1 = _coef("hjg1", "hjg0 after the payload step, s/(kg·m²)")
C_BRKP1 = _coef("brkp1", "brkp0 after the payload step, Nm")
C_BRKN1 = _coef("brkn1", "brkn0 after the payload step, Nm")
C_STEP_SCALE = _coef("step_scale", "speed factor at the payload step (momentum kept)")
N_COEF = len(COEFFICIENTS)
_COEF_NAMES = tuple(name for name, _ in COEFFICIENTS)


_get_coefficients = operator.itemgetter(*_COEF_NAMES)


def pack(values: Mapping[str, float]) -> FloatArray:
    """The coefficient vector from one value per :data:`COEFFICIENTS` name.

    Raises
    ------
    ModelError
        When a name is missing or not in the layout (a programming error).
    """
    try:
        row = _get_coefficients(values)
    except KeyError:
        row = ()
    if len(values) != N_COEF or len(row) != N_COEF:
        missing = sorted(set(_COEF_NAMES) - values.keys())
        unknown = sorted(values.keys() - set(_COEF_NAMES))
        raise ModelError(f"coefficients: missing {missing}, unknown {unknown}")
    return np.fromiter(row, np.float64, N_COEF)


# ----------------------------------------------------------- output layout
O_TORQUE_SP = 0
O_TORQUE = 1
O_SPEED = 2
O_POSITION = 3
O_BELT_SPEED = 4
O_BELT_POSITION = 5
O_FORCE = 6
O_LOAD = 7
O_LOSS = 8
N_OUT = 9

# fastmath without nnan/ninf: NaN/inf checks must keep working
_FASTMATH = {"nsz", "contract"}
# the plain rigid model (and the pieces it shares) runs without contraction:
# LLVM fuses a multiply into an add only where the product has no other use,
# which depends on which outputs a kernel keeps, so results could differ in
# the last bit. Fused multiply-adds are written out (:func:`fma`) instead.
_EXACT = {"nsz"}
_HUGE = 1e300
_STOP_RAD_S = 1e-6  # motor speeds decaying below this snap to standstill, rad/s
_STOP_M_S = 1e-8  # same for the belt mass of the elastic model, m/s


# ------------------------------------------------------------------ pieces
@intrinsic
def _fma(typingctx: Any, a: Any, b: Any, c: Any) -> Any:
    del typingctx
    if not all(isinstance(t, types.Float) for t in (a, b, c)):
        return None
    f8 = types.float64

    def codegen(context: Any, builder: Any, signature: Any, args: Any) -> Any:
        values = [
            context.cast(builder, v, t, f8) for v, t in zip(args, signature.args, strict=True)
        ]
        dbl = llvm_ir.DoubleType()
        fnty = llvm_ir.FunctionType(dbl, [dbl, dbl, dbl])
        return builder.call(builder.module.declare_intrinsic("llvm.fma", [dbl], fnty), values)

    return f8(a, b, c), codegen


fma = cast(Callable[[float, float, float], float], _fma)
"""``fma(a, b, c)``: ``a·b + c`` rounded once (``llvm.fma``; one
instruction, vectorises). Only inside compiled functions."""


@njit(inline="always", fastmath=_FASTMATH, error_model="numpy", cache=True)
def mass_terms(
    mass: float, carried: float, mu_g_cos: float, static: float, g_sin: float, k: float
) -> tuple[float, float, float, float]:
    """Belt terms at the motor for a ratio ``k = ρ/i`` (ideal gear).

    Returns ``(M, f_c, f_s, f_g)``: reflected mass ``m·k²`` (kg·m²), kinetic
    and static friction torque magnitudes ``μ g cosβ m k`` (Nm) and the
    incline torque ``g sinβ m_c k`` (Nm, signed).
    """
    fc = mu_g_cos * mass * k
    return mass * k * k, fc, fc * static, g_sin * carried * k


@njit(inline="always", fastmath=_FASTMATH, error_model="numpy", cache=True)
def step_gains(
    dt: float, jd: float, m_red: float, eta: float, inv_eta: float
) -> tuple[float, float]:
    """``dt/J`` while motoring (``J = J_d + M/η``) and generating (``J_d + M·η``)."""
    return dt / (jd + m_red * inv_eta), dt / (jd + m_red * eta)


@njit(inline="always", fastmath=_FASTMATH, error_model="numpy", cache=True)
def breakaway_levels(
    fs: float, fg: float, bma: float, eta: float, inv_eta: float
) -> tuple[float, float]:
    """Drive torques that start a stuck belt forward (above) or backward (below), Nm.

    Static friction ``fs`` plus BmA against the motion, the incline term
    ``fg`` with it; the gear efficiency is that of the power flow the motion
    would have (motoring ``1/η``, generating ``η``).
    """
    q_pos = fg + fs
    q_neg = fg - fs
    return (
        bma + q_pos * (inv_eta if q_pos > 0.0 else eta),
        q_neg * (inv_eta if q_neg < 0.0 else eta) - bma,
    )


def belt_terms(
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
) -> tuple[float, float, float, float, float, float, float]:
    """Belt terms of :func:`plain_kernel`, layout ``M_RED0 … BRKN0``, in Python.

    Runs the Python source of :func:`mass_terms`, :func:`step_gains` and
    :func:`breakaway_levels` (the same equations the other kernels compile)
    on Python floats, once per simulation: IEEE operations without fused
    multiply-adds. Returns ``(M, f_c, f_g, dt/J_mot, dt/J_gen, brk+, brk-)``
    in kg·m², Nm, Nm, s/(kg·m²), s/(kg·m²), Nm, Nm.
    """
    m_red, fc, fs, fg = mass_terms.py_func(mass, carried, mu_g_cos, static, g_sin, k)
    hjm, hjg = step_gains.py_func(dt, jd, m_red, eta, inv_eta)
    brk_pos, brk_neg = breakaway_levels.py_func(fs, fg, bma, eta, inv_eta)
    return m_red, fc, fg, hjm, hjg, brk_pos, brk_neg


@njit(inline="always", fastmath=_EXACT, error_model="numpy", cache=True)
def controller(
    w_sp: float,
    p_sp: float,
    theta: float,
    omega: float,
    integ: float,
    kv: float,
    kp: float,
    kp_ti: float,
    dt: float,
    tlim: float,
) -> tuple[float, float]:
    """Position P + speed PI with clamping anti-windup; returns ``(u, integral)``.

    ``u = Kp·e + (Kp/Ti)·∫e dt`` with the speed error
    ``e = ω_sp + Kv·(θ_sp − θ) − ω``. The integral (rad) stops integrating
    while the output is clamped and the error would push it further into
    the limit.
    """
    e = fma(kv, p_sp - theta, w_sp) - omega
    kp_e = kp * e
    trial = fma(e, dt, integ)
    u = fma(kp_ti, trial, kp_e)
    # pushed further into the limit: u > tlim with e > 0 or u < -tlim with
    # e < 0, i.e. sign(e)·u > tlim (with e = ±0 either choice gives the same)
    freeze = math.copysign(1.0, e) * u > tlim
    new = integ if freeze else trial
    # u of the frozen integral computed beside the trial one (same bits as
    # recomputing from ``new``, shorter dependency chain)
    u = fma(kp_ti, integ, kp_e) if freeze else u
    u = tlim if u > tlim else (-tlim if u < -tlim else u)
    return u, new


@njit(inline="always", fastmath=_EXACT, error_model="numpy", cache=True)
def settle(new: float, old: float, direction: float, eps: float) -> float:
    """Coulomb friction stop: a speed never crosses zero within a step.

    A speed that would cross zero, or that does not grow while inside the
    band ``|v| < eps``, becomes exactly 0 (stuck); ``direction`` 0 (stuck and
    not breaking away) gives 0. The threshold depends only on the old
    speed, which keeps the comparison off the step's dependency chain.
    """
    mag = abs(old)
    thr = (mag if mag < eps else eps) if direction != 0.0 else np.inf
    keep = (new > thr) if direction >= 0.0 else (new < -thr)
    return new if keep else 0.0


@njit(inline="always", fastmath=_EXACT, error_model="numpy", cache=True)
def rigid_core(
    t_drive: float,
    omega: float,
    m_red: float,
    fc: float,
    fg: float,
    cen: float,
    brk_pos: float,
    brk_neg: float,
    jd: float,
    eta: float,
    inv_eta: float,
    bma: float,
    bmb: float,
    bmc: float,
    hjm: float,
    hjg: float,
) -> tuple[float, float, float, bool]:
    """One rigid-plant step; returns ``(ω_new, direction, f, motoring)``.

    ``t_drive`` is the mean motor torque minus disturbance torques, ``f_*``
    the belt terms at the motor (ideal gear), ``cen`` the polygon term
    ``m·k·(dk/dθ)·ω²``, ``brk_*`` from :func:`breakaway_levels`,
    ``hjm``/``hjg`` from :func:`step_gains`. Both power-flow cases are
    computed side by side and the choice made last, which keeps the
    dependency chain through ω short.
    """
    # direction of motion; from standstill the breakaway decides (static
    # friction, efficiency of the would-be flow)
    d = 1.0 if t_drive > brk_pos else (-1.0 if t_drive < brk_neg else 0.0)
    se = 1.0 if omega > 0.0 else (-1.0 if omega < 0.0 else d)
    # net torque A = a0 - wc with the speed-dependent losses wc kept apart
    # (arranged so that the dependency chain through ω stays short)
    a0 = fma(-bma, se, t_drive)
    f = fma(fc, se, fg) + cen
    wc = omega * fma(bmc, abs(omega), bmb)
    # motoring iff Q·ω > 0 with Q ∝ f·J_d + M·A (see the module notes)
    nn = fma(-m_red, wc, fma(m_red, a0, f * jd))
    # both cases in parallel, the choice last
    w_mot = fma(-hjm, wc, fma(fma(-f, inv_eta, a0), hjm, omega))
    w_gen = fma(-hjg, wc, fma(fma(-f, eta, a0), hjg, omega))
    mot = (nn >= 0.0) if se > 0.0 else (nn <= 0.0)
    w = w_mot if mot else w_gen
    w = settle(w, omega, se, _STOP_RAD_S)
    return w, se, f, mot


@njit(inline="always", fastmath=_FASTMATH, error_model="numpy", cache=True)
def polygon(
    psi: float, pitch_r: float, pitch_ang: float, chord: float, half_sin: float
) -> tuple[float, float, float]:
    """Polygonal sprocket turned by ψ: ``(X(ψ), cos φ, sin φ)``.

    ``φ = ψ − n·p − p/2`` with ``n = ⌊ψ/p⌋``, p = 2π/z, sweeps [−p/2, p/2)
    per tooth; the effective radius is R·cos φ and the chain travel
    ``X(ψ) = n·chord + R·(sin φ + sin(p/2))`` is continuous with slope R·cos φ.
    """
    n = np.floor(psi / pitch_ang)
    phi = psi - n * pitch_ang - 0.5 * pitch_ang
    sin_phi = math.sin(phi)
    return n * chord + pitch_r * (sin_phi + half_sin), math.cos(phi), sin_phi


@njit(fastmath=_FASTMATH, error_model="numpy", cache=True)
def _impulse_cum(x: float, period: float, width: float) -> float:
    n = np.floor(x / period)
    r = x - n * period
    return n * width + (r if r < width else width)


@njit(fastmath=_FASTMATH, error_model="numpy", cache=True)
def disturbance(
    theta: float,
    dtheta: float,
    s: float,
    n_rip: int,
    orders: FloatArray,
    amps: FloatArray,
    imp_period: float,
    imp_width: float,
    imp_amp: float,
) -> float:
    """Mean disturbance torque over the angle swept in a step, Nm.

    Ripple ``Σ a·sin(o·θ)`` averaged over [θ, θ+Δθ] (exact for constant
    speed); tooth-damage impulses resist motion (``sign(ω)·amp``) over the
    fraction of the step spent inside an impulse window.
    """
    total = 0.0
    mid = theta + 0.5 * dtheta
    for r in range(n_rip):
        o = orders[r]
        hx = 0.5 * o * dtheta
        sinc = 1.0 if abs(hx) < 1e-8 else math.sin(hx) / hx
        total += amps[r] * math.sin(o * mid) * sinc
    if imp_amp != 0.0 and s != 0.0:
        lo = theta if dtheta >= 0.0 else theta + dtheta
        span = abs(dtheta)
        if span > 1e-12 * imp_period:
            frac = (
                _impulse_cum(lo + span, imp_period, imp_width)
                - _impulse_cum(lo, imp_period, imp_width)
            ) / span
        else:
            r0 = lo - np.floor(lo / imp_period) * imp_period
            frac = 1.0 if r0 < imp_width else 0.0
        total += imp_amp * s * frac
    return total


@njit(inline="always", fastmath=_FASTMATH, error_model="numpy", cache=True)
def in_bump(x: float, start: float, width: float, loop: float) -> bool:
    """Whether belt position x (modulo the loop) lies in [start, start + width)."""
    r = x - start
    r = r - np.floor(r / loop) * loop
    return r < width


@njit(fastmath=_FASTMATH, error_model="numpy", cache=True)
def _fail(out: FloatArray, k: int) -> None:
    for q in range(out.shape[0]):
        for j in range(k, out.shape[1]):
            out[q, j] = np.nan


# ------------------------------------------------------------ rigid kernel
@njit(fastmath=_FASTMATH, error_model="numpy", cache=True, nogil=True)
def rigid_kernel(
    coef: FloatArray,
    orders: FloatArray,
    amps: FloatArray,
    w_sp: FloatArray,
    p_sp: FloatArray,
    out: FloatArray,
) -> tuple[int, int, int]:
    """Simulate the rigid model; fills ``out`` (N_OUT, n).

    Returns ``(status, failed_cycle, saturated_cycles)``: status 0 ok,
    1 non-finite state (then the rest of ``out`` is NaN).
    """
    n = w_sp.size
    dt = coef[C_DT]
    kv = coef[C_KV]
    kp = coef[C_KP]
    kp_ti = coef[C_KP_TI]
    tlim = coef[C_TLIM]
    a_lag = coef[C_A_LAG]
    b_lag = coef[C_B_LAG]
    jd = coef[C_JD]
    eta = coef[C_ETA]
    inv_eta = coef[C_INV_ETA]
    bma = coef[C_BMA]
    bmb = coef[C_BMB]
    bmc = coef[C_BMC]
    mass = coef[C_MASS]
    carried = coef[C_CARRIED]
    mu_g_cos = coef[C_MU_G_COS]
    static = coef[C_STATIC]
    g_sin = coef[C_G_SIN]
    krv = coef[C_KRV]
    inv_krv = 1.0 / krv
    inv_dt = 1.0 / dt
    pitch_r = coef[C_PITCH_R]
    ratio = coef[C_RATIO]
    has_polygon = coef[C_POLYGON] != 0.0
    loop = coef[C_LOOP]
    obs_pos = coef[C_OBS_POS]
    obs_w = coef[C_OBS_WIDTH]
    obs_f = coef[C_OBS_FORCE]
    has_obs = obs_w > 0.0 and obs_f > 0.0
    imp_period = coef[C_IMP_PERIOD]
    imp_width = coef[C_IMP_WIDTH]
    imp_amp = coef[C_IMP_AMP]
    n_rip = int(coef[C_NRIP])
    has_dist = n_rip > 0 or imp_amp != 0.0
    k_step = int(coef[C_STEP_K])
    step_kg = coef[C_STEP_KG]
    theta0 = coef[C_THETA0]
    x0 = coef[C_X0]

    pitch_ang = 2.0 * math.pi / coef[C_TEETH] if has_polygon else 1.0
    half_sin = math.sin(0.5 * pitch_ang)
    chord = 2.0 * pitch_r * half_sin
    travel0, cos_phi, sin_phi = polygon(theta0 / ratio, pitch_r, pitch_ang, chord, half_sin)

    m_red, fc, fs, fg = mass_terms(mass, carried, mu_g_cos, static, g_sin, krv)
    hjm, hjg = step_gains(dt, jd, m_red, eta, inv_eta)

    theta = theta0
    omega = 0.0
    torque = 0.0
    u_prev = 0.0
    integ = 0.0
    x = x0
    n_sat = 0
    for k in range(n):
        if k == k_step:
            # tray placed on the moving belt: momentum of the moving parts kept
            kk = pitch_r * cos_phi / ratio if has_polygon else krv
            j_old = jd + mass * kk * kk
            mass += step_kg
            carried += step_kg
            m_red, fc, fs, fg = mass_terms(mass, carried, mu_g_cos, static, g_sin, krv)
            hjm, hjg = step_gains(dt, jd, m_red, eta, inv_eta)
            omega = omega * (j_old / (jd + mass * kk * kk))
        u, integ = controller(w_sp[k], p_sp[k], theta, omega, integ, kv, kp, kp_ti, dt, tlim)
        if u >= tlim or u <= -tlim:
            n_sat += 1
        t_avg = u_prev + (torque - u_prev) * b_lag
        t_next = torque + a_lag * (u_prev - torque)

        if has_polygon:
            kk = pitch_r * cos_phi / ratio  # ρ/i
            dkk = -pitch_r * sin_phi / (ratio * ratio)  # d(ρ/i)/dθ
            mk, fck, fsk, fgk = mass_terms(mass, carried, mu_g_cos, static, g_sin, kk)
            cen = mass * kk * dkk * omega * omega
            hjm_k, hjg_k = step_gains(dt, jd, mk, eta, inv_eta)
        else:
            kk = krv
            mk = m_red
            fck = fc
            fsk = fs
            fgk = fg
            cen = 0.0
            hjm_k = hjm
            hjg_k = hjg
        if has_obs and in_bump(x, obs_pos, obs_w, loop):
            fck += obs_f * kk
            fsk += obs_f * kk
        brk_pos, brk_neg = breakaway_levels(fsk, fgk, bma, eta, inv_eta)
        t_dist = 0.0
        if has_dist:
            s0 = 1.0 if omega > 0.0 else (-1.0 if omega < 0.0 else 0.0)
            t_dist = disturbance(
                theta, dt * omega, s0, n_rip, orders, amps, imp_period, imp_width, imp_amp
            )
        t_drive = t_avg - t_dist
        w, se, f, mot = rigid_core(
            t_drive,
            omega,
            mk,
            fck,
            fgk,
            cen,
            brk_pos,
            brk_neg,
            jd,
            eta,
            inv_eta,
            bma,
            bmb,
            bmc,
            hjm_k,
            hjg_k,
        )
        moving = se != 0.0
        q = f + mk * ((w - omega) * inv_dt) if moving else t_drive
        out[O_TORQUE_SP, k] = u
        out[O_TORQUE, k] = torque
        out[O_SPEED, k] = omega
        out[O_POSITION, k] = theta
        out[O_BELT_SPEED, k] = kk * omega
        out[O_BELT_POSITION, k] = x
        out[O_FORCE, k] = q * (inv_krv if not has_polygon else 1.0 / kk)
        out[O_LOAD, k] = (f * (inv_eta if mot else eta) + t_dist) if moving else t_avg
        out[O_LOSS, k] = bma * se + omega * (bmb + bmc * abs(omega))

        theta = theta + 0.5 * dt * (omega + w)
        omega = w
        torque = t_next
        u_prev = u
        if has_polygon:
            travel, cos_phi, sin_phi = polygon(theta / ratio, pitch_r, pitch_ang, chord, half_sin)
            x = x0 + (travel - travel0)
        else:
            x = x0 + krv * (theta - theta0)
        if not (abs(omega) < _HUGE and abs(theta) < _HUGE and abs(torque) < _HUGE):
            _fail(out, k + 1)
            return 1, k + 1, n_sat
    return 0, -1, n_sat


@njit(inline="always", fastmath=_EXACT, error_model="numpy", cache=True)
def plain_step(
    ws: float,
    ps: float,
    theta: float,
    omega: float,
    torque: float,
    u_prev: float,
    integ: float,
    kv: float,
    kp: float,
    kp_ti: float,
    dt: float,
    tlim: float,
    a_lag: float,
    b_lag: float,
    jd: float,
    eta: float,
    inv_eta: float,
    bma: float,
    bmb: float,
    bmc: float,
    m_red: float,
    fc: float,
    fg: float,
    brk_pos: float,
    brk_neg: float,
    hjm: float,
    hjg: float,
) -> tuple[float, float, bool, float, float, float, float, float, bool]:
    """One controller cycle of the plain rigid model (no realism, no fault).

    Returns ``(u, integral, saturated, t_avg, t_next, ω_new, direction, f,
    motoring)``.
    """
    u, integ = controller(ws, ps, theta, omega, integ, kv, kp, kp_ti, dt, tlim)
    sat = abs(u) >= tlim
    t_avg = fma(torque - u_prev, b_lag, u_prev)
    t_next = fma(-a_lag, torque - u_prev, torque)
    w, se, f, mot = rigid_core(
        t_avg,
        omega,
        m_red,
        fc,
        fg,
        0.0,
        brk_pos,
        brk_neg,
        jd,
        eta,
        inv_eta,
        bma,
        bmb,
        bmc,
        hjm,
        hjg,
    )
    return u, integ, sat, t_avg, t_next, w, se, f, mot


@njit(inline="always", fastmath=_EXACT, error_model="numpy", cache=True)
def plain_extra(
    t_avg: float,
    omega: float,
    w: float,
    se: float,
    f: float,
    mot: bool,
    m_red: float,
    inv_dt: float,
    inv_krv: float,
    eta: float,
    inv_eta: float,
    bma: float,
    bmb: float,
    bmc: float,
) -> tuple[float, float, float]:
    """Sprocket force (N), load and loss torque (Nm) of a plain rigid step."""
    moving = se != 0.0
    q = fma(m_red, (w - omega) * inv_dt, f) if moving else t_avg
    load = (f * (inv_eta if mot else eta)) if moving else t_avg
    loss = fma(bma, se, omega * fma(bmc, abs(omega), bmb))
    return q * inv_krv, load, loss


@njit(fastmath=_EXACT, error_model="numpy", cache=True, nogil=True)
def plain_kernel(
    coef: FloatArray,
    w_sp: FloatArray,
    p_sp: FloatArray,
    out: FloatArray,
) -> tuple[int, int, int]:
    """Rigid model without faults (the identification model), lean and fast.

    One :func:`plain_step` per cycle; the model of :func:`rigid_kernel` with every
    feature off, with the belt terms taken from the coefficients
    (``C_M_RED0`` …). Returns as :func:`rigid_kernel`.
    """
    n = w_sp.size
    dt = coef[C_DT]
    kv = coef[C_KV]
    kp = coef[C_KP]
    kp_ti = coef[C_KP_TI]
    tlim = coef[C_TLIM]
    a_lag = coef[C_A_LAG]
    b_lag = coef[C_B_LAG]
    jd = coef[C_JD]
    eta = coef[C_ETA]
    inv_eta = coef[C_INV_ETA]
    bma = coef[C_BMA]
    bmb = coef[C_BMB]
    bmc = coef[C_BMC]
    krv = coef[C_KRV]
    inv_krv = 1.0 / krv
    inv_dt = 1.0 / dt
    half_dt = 0.5 * dt
    k_step = int(coef[C_STEP_K])
    theta0 = coef[C_THETA0]
    x0 = coef[C_X0]
    m_red = coef[C_M_RED0]
    fc = coef[C_FC0]
    fg = coef[C_FG0]
    hjm = coef[C_HJM0]
    hjg = coef[C_HJG0]
    brk_pos = coef[C_BRKP0]
    brk_neg = coef[C_BRKN0]
    theta = theta0
    omega = 0.0
    torque = 0.0
    u_prev = 0.0
    integ = 0.0
    n_sat = 0
    o_usp = out[O_TORQUE_SP]
    o_tq = out[O_TORQUE]
    o_w = out[O_SPEED]
    o_th = out[O_POSITION]
    o_v = out[O_BELT_SPEED]
    o_x = out[O_BELT_POSITION]
    o_f = out[O_FORCE]
    o_load = out[O_LOAD]
    o_loss = out[O_LOSS]
    for k in range(n):
        if k == k_step:
            # tray placed on the moving belt: momentum of the moving parts kept
            m_red = coef[C_M_RED1]
            fc = coef[C_FC1]
            fg = coef[C_FG1]
            hjm = coef[C_HJM1]
            hjg = coef[C_HJG1]
            brk_pos = coef[C_BRKP1]
            brk_neg = coef[C_BRKN1]
            omega = omega * coef[C_STEP_SCALE]
        u, integ, sat, t_avg, t_next, w, se, f, mot = plain_step(
            w_sp[k],
            p_sp[k],
            theta,
            omega,
            torque,
            u_prev,
            integ,
            kv,
            kp,
            kp_ti,
            dt,
            tlim,
            a_lag,
            b_lag,
            jd,
            eta,
            inv_eta,
            bma,
            bmb,
            bmc,
            m_red,
            fc,
            fg,
            brk_pos,
            brk_neg,
            hjm,
            hjg,
        )
        n_sat += 1 if sat else 0
        force, load, loss = plain_extra(
            t_avg, omega, w, se, f, mot, m_red, inv_dt, inv_krv, eta, inv_eta, bma, bmb, bmc
        )
        o_usp[k] = u
        o_tq[k] = torque
        o_w[k] = omega
        o_th[k] = theta
        o_v[k] = krv * omega
        o_x[k] = fma(krv, theta - theta0, x0)
        o_f[k] = force
        o_load[k] = load
        o_loss[k] = loss
        theta = fma(half_dt, omega + w, theta)
        omega = w
        torque = t_next
        u_prev = u
    # the torque limit bounds this model; a non-finite state (extreme
    # parameters) persists in the angle and the torque, so check once
    if not (abs(theta) < _HUGE and abs(torque) < _HUGE):
        for k in range(n):
            if not (abs(o_th[k]) < _HUGE and abs(o_tq[k]) < _HUGE):
                _fail(out, k)
                return 1, k, n_sat
        return 1, n, n_sat
    return 0, -1, n_sat


# ---------------------------------------------------------- elastic kernel
@njit(fastmath=_FASTMATH, error_model="numpy", cache=True, nogil=True)
def elastic_kernel(
    coef: FloatArray,
    orders: FloatArray,
    amps: FloatArray,
    w_sp: FloatArray,
    p_sp: FloatArray,
    out: FloatArray,
) -> tuple[int, int, int]:
    """Simulate the two-mass (elastic belt) model; fills ``out`` (N_OUT, n).

    Drive side (J_d, angle θ) and belt mass m₂ (position x) joined by a
    spring k and damper c between the sprocket rim motion ``U(θ)`` (r·θ/i,
    or the polygonal travel) and x. ``n_sub`` semi-implicit Euler sub-steps
    per cycle; the lagged motor torque is averaged exactly over each
    sub-step. Returns as :func:`rigid_kernel`.
    """
    n = w_sp.size
    dt = coef[C_DT]
    kv = coef[C_KV]
    kp = coef[C_KP]
    kp_ti = coef[C_KP_TI]
    tlim = coef[C_TLIM]
    a_lag = coef[C_A_LAG]
    jd = coef[C_JD]
    inv_jd = 1.0 / jd
    eta = coef[C_ETA]
    inv_eta = coef[C_INV_ETA]
    bma = coef[C_BMA]
    bmb = coef[C_BMB]
    bmc = coef[C_BMC]
    mass = coef[C_MASS]
    carried = coef[C_CARRIED]
    mu_g_cos = coef[C_MU_G_COS]
    static = coef[C_STATIC]
    g_sin = coef[C_G_SIN]
    krv = coef[C_KRV]
    pitch_r = coef[C_PITCH_R]
    ratio = coef[C_RATIO]
    has_polygon = coef[C_POLYGON] != 0.0
    loop = coef[C_LOOP]
    stiff = coef[C_STIFF]
    damp = coef[C_DAMP]
    obs_pos = coef[C_OBS_POS]
    obs_w = coef[C_OBS_WIDTH]
    obs_f = coef[C_OBS_FORCE]
    has_obs = obs_w > 0.0 and obs_f > 0.0
    imp_period = coef[C_IMP_PERIOD]
    imp_width = coef[C_IMP_WIDTH]
    imp_amp = coef[C_IMP_AMP]
    n_rip = int(coef[C_NRIP])
    has_dist = n_rip > 0 or imp_amp != 0.0
    k_step = int(coef[C_STEP_K])
    step_kg = coef[C_STEP_KG]
    theta0 = coef[C_THETA0]
    x0 = coef[C_X0]
    n_sub = int(coef[C_NSUB])
    tau = coef[C_TAU]
    h = dt / n_sub

    # mean of exp(-t/τ) over each sub-step, relative to the cycle start
    weights = np.zeros(n_sub)
    if tau > 0.0:
        for j in range(n_sub):
            weights[j] = tau / h * (math.exp(-j * h / tau) - math.exp(-(j + 1) * h / tau))
    decay = 1.0 - a_lag

    pitch_ang = 2.0 * math.pi / coef[C_TEETH] if has_polygon else 1.0
    half_sin = math.sin(0.5 * pitch_ang)
    chord = 2.0 * pitch_r * half_sin
    u_rim0 = (
        polygon(theta0 / ratio, pitch_r, pitch_ang, chord, half_sin)[0]
        if has_polygon
        else krv * theta0
    )

    fc2 = mu_g_cos * mass
    fs2 = fc2 * static
    fg2 = g_sin * carried
    inv_m2 = 1.0 / mass

    theta = theta0
    omega = 0.0
    x = x0
    xd = 0.0
    torque = 0.0
    u_prev = 0.0
    integ = 0.0
    n_sat = 0
    for k in range(n):
        if k == k_step:
            old = mass
            mass += step_kg
            carried += step_kg
            fc2 = mu_g_cos * mass
            fs2 = fc2 * static
            fg2 = g_sin * carried
            inv_m2 = 1.0 / mass
            xd = xd * (old / mass)
        u, integ = controller(w_sp[k], p_sp[k], theta, omega, integ, kv, kp, kp_ti, dt, tlim)
        if u >= tlim or u <= -tlim:
            n_sat += 1
        out[O_TORQUE_SP, k] = u
        out[O_TORQUE, k] = torque
        out[O_SPEED, k] = omega
        out[O_POSITION, k] = theta
        out[O_BELT_SPEED, k] = xd
        out[O_BELT_POSITION, k] = x
        v_in = u_prev
        acc_force = 0.0
        acc_load = 0.0
        acc_loss = 0.0
        for j in range(n_sub):
            t_avg = v_in + (torque - v_in) * weights[j]
            if has_polygon:
                u_rim, cos_phi, _ = polygon(theta / ratio, pitch_r, pitch_ang, chord, half_sin)
                kk = pitch_r * cos_phi / ratio
            else:
                kk = krv
                u_rim = krv * theta
            stretch = (u_rim - u_rim0) - (x - x0)
            f_spring = stiff * stretch + damp * (kk * omega - xd)
            # gear output load: motoring while F·ω >= 0 (1/η), else generating (η)
            t_gear = f_spring * kk * (inv_eta if f_spring * omega >= 0.0 else eta)
            t_dist = 0.0
            if has_dist:
                s0 = 1.0 if omega > 0.0 else (-1.0 if omega < 0.0 else 0.0)
                t_dist = disturbance(
                    theta, h * omega, s0, n_rip, orders, amps, imp_period, imp_width, imp_amp
                )
            # drive side, Coulomb part BmA with stop-at-zero
            net = t_avg - t_dist - t_gear
            s = 1.0 if omega > 0.0 else (-1.0 if omega < 0.0 else 0.0)
            d = 1.0 if net > bma else (-1.0 if net < -bma else 0.0)
            se = s if s != 0.0 else d
            loss = bma * se + omega * (bmb + bmc * abs(omega))
            w = omega + h * (net - loss) * inv_jd
            w = settle(w, omega, se, _STOP_RAD_S)
            # belt side: friction (static until breakaway), incline, obstruction
            fck = fc2
            fsk = fs2
            if has_obs and in_bump(x, obs_pos, obs_w, loop):
                fck += obs_f
                fsk += obs_f
            net_b = f_spring - fg2
            sb = 1.0 if xd > 0.0 else (-1.0 if xd < 0.0 else 0.0)
            db = 1.0 if net_b > fsk else (-1.0 if net_b < -fsk else 0.0)
            seb = sb if sb != 0.0 else db
            v = xd + h * (net_b - fck * seb) * inv_m2
            v = settle(v, xd, seb, _STOP_M_S)
            acc_force += f_spring
            acc_load += t_gear + t_dist
            acc_loss += loss
            omega = w
            theta += h * w
            xd = v
            x += h * v
        out[O_FORCE, k] = acc_force / n_sub
        out[O_LOAD, k] = acc_load / n_sub
        out[O_LOSS, k] = acc_loss / n_sub
        torque = v_in + (torque - v_in) * decay
        u_prev = u
        if not (abs(omega) < _HUGE and abs(theta) < _HUGE and abs(x) < _HUGE):
            _fail(out, k + 1)
            return 1, k + 1, n_sat
    return 0, -1, n_sat
