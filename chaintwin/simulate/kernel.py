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
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
from numba import njit, prange

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "LANES",
    "N_COEF",
    "N_MAIN",
    "N_OUT",
    "batch_general_kernel",
    "batch_plain_kernel",
    "elastic_kernel",
    "plain_kernel",
    "rigid_kernel",
]

# ------------------------------------------------------- coefficient layout
C_DT = 0  # controller cycle, s
C_KV = 1  # position gain, 1/s
C_KP = 2  # speed gain, Nm·s/rad
C_KP_TI = 3  # Kp/Ti, Nm/rad
C_TLIM = 4  # torque limit, Nm
C_A_LAG = 5  # 1 - exp(-dt/τ)
C_B_LAG = 6  # mean of exp(-t/τ) over a cycle, τ·(1 - exp(-dt/τ))/dt
C_JD = 7  # motor + gear inertia, kg·m²
C_ETA = 8  # gear efficiency
C_INV_ETA = 9  # 1/η
C_BMA = 10  # loss constant, Nm
C_BMB = 11  # loss viscous, Nm·s/rad
C_BMC = 12  # loss quadratic, Nm·s²/rad²
C_MASS = 13  # moving mass m_b + m_t + m_p, kg
C_CARRIED = 14  # carried mass m_t + m_p, kg
C_MU_G_COS = 15  # μ·g·cosβ, N/kg
C_STATIC = 16  # static/kinetic friction ratio in effect (1 without stick-slip)
C_G_SIN = 17  # g·sinβ, N/kg
C_KRV = 18  # r/i, m/rad
C_PITCH_R = 19  # R, m
C_RATIO = 20  # i
C_TEETH = 21  # z (0 unknown)
C_POLYGON = 22  # 1.0: polygon effect on
C_LOOP = 23  # loop length, m
C_STIFF = 24  # belt stiffness, N/m
C_DAMP = 25  # belt damping, N·s/m
C_OBS_POS = 26  # obstruction start, m
C_OBS_WIDTH = 27  # obstruction width, m
C_OBS_FORCE = 28  # obstruction force, N
C_IMP_PERIOD = 29  # impulse period, rad
C_IMP_WIDTH = 30  # impulse width, rad
C_IMP_AMP = 31  # impulse amplitude, Nm
C_STEP_K = 32  # cycle of the payload step (-1: none)
C_STEP_KG = 33  # payload step, kg
C_THETA0 = 34  # initial motor angle, rad
C_X0 = 35  # initial belt position, m
C_NSUB = 36  # elastic sub-steps per cycle
C_NRIP = 37  # number of ripple orders
C_TAU = 38  # torque time constant, s
N_COEF = 39

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
N_MAIN = 5  # rows 0..4 are what a batch always keeps

# fastmath without nnan/ninf: NaN/inf checks must keep working
_FASTMATH = {"nsz", "contract"}
_HUGE = 1e300
_STOP_RAD_S = 1e-6  # motor speeds decaying below this snap to standstill, rad/s
_STOP_M_S = 1e-8  # same for the belt mass of the elastic model, m/s


# ------------------------------------------------------------------ pieces
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


@njit(inline="always", fastmath=_FASTMATH, error_model="numpy", cache=True)
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
    e = w_sp + kv * (p_sp - theta) - omega
    kp_e = kp * e
    trial = integ + e * dt
    u = kp_e + kp_ti * trial
    freeze = ((u > tlim) & (e > 0.0)) | ((u < -tlim) & (e < 0.0))
    new = integ if freeze else trial
    u = kp_e + kp_ti * new
    u = tlim if u > tlim else (-tlim if u < -tlim else u)
    return u, new


@njit(inline="always", fastmath=_FASTMATH, error_model="numpy", cache=True)
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


@njit(inline="always", fastmath=_FASTMATH, error_model="numpy", cache=True)
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
    ``hjm``/``hjg`` from :func:`step_gains`.
    """
    s = 1.0 if omega > 0.0 else (-1.0 if omega < 0.0 else 0.0)
    # breakaway from standstill: static friction, efficiency of the would-be flow
    d = 1.0 if t_drive > brk_pos else (-1.0 if t_drive < brk_neg else 0.0)
    se = s if s != 0.0 else d
    # net torque A = a0 - wc with the speed-dependent losses wc kept apart
    # (arranged so that the dependency chain through ω stays short)
    a0 = t_drive - bma * se
    f = fc * se + fg + cen
    wc = omega * (bmb + bmc * abs(omega))
    w_mot = (omega + (a0 - f * inv_eta) * hjm) - hjm * wc
    w_gen = (omega + (a0 - f * eta) * hjg) - hjg * wc
    # motoring iff Q·ω > 0 with Q ∝ f·J_d + M·A (see the module notes)
    nn = (f * jd + m_red * a0) - m_red * wc
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


@njit(fastmath=_FASTMATH, error_model="numpy", cache=True, nogil=True)
def plain_kernel(
    coef: FloatArray,
    w_sp: FloatArray,
    p_sp: FloatArray,
    out: FloatArray,
) -> tuple[int, int, int]:
    """Rigid model without faults (the identification model), lean and fast.

    Same arithmetic as :func:`batch_plain_kernel` per member and as
    :func:`rigid_kernel` with every feature off. Returns as
    :func:`rigid_kernel`.
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
    krv = coef[C_KRV]
    inv_krv = 1.0 / krv
    inv_dt = 1.0 / dt
    k_step = int(coef[C_STEP_K])
    theta0 = coef[C_THETA0]
    x0 = coef[C_X0]
    m_red, fc, fs, fg = mass_terms(
        mass, coef[C_CARRIED], coef[C_MU_G_COS], coef[C_STATIC], coef[C_G_SIN], krv
    )
    hjm, hjg = step_gains(dt, jd, m_red, eta, inv_eta)
    brk_pos, brk_neg = breakaway_levels(fs, fg, bma, eta, inv_eta)
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
            step_kg = coef[C_STEP_KG]
            new_mass = mass + step_kg
            j_old = jd + mass * krv * krv
            m_red, fc, fs, fg = mass_terms(
                new_mass,
                coef[C_CARRIED] + step_kg,
                coef[C_MU_G_COS],
                coef[C_STATIC],
                coef[C_G_SIN],
                krv,
            )
            hjm, hjg = step_gains(dt, jd, m_red, eta, inv_eta)
            brk_pos, brk_neg = breakaway_levels(fs, fg, bma, eta, inv_eta)
            omega = omega * (j_old / (jd + new_mass * krv * krv))
        u, integ = controller(w_sp[k], p_sp[k], theta, omega, integ, kv, kp, kp_ti, dt, tlim)
        n_sat += 1 if (u >= tlim) | (u <= -tlim) else 0
        t_avg = u_prev + (torque - u_prev) * b_lag
        t_next = torque + a_lag * (u_prev - torque)
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
        moving = se != 0.0
        q = f + m_red * ((w - omega) * inv_dt) if moving else t_avg
        o_usp[k] = u
        o_tq[k] = torque
        o_w[k] = omega
        o_th[k] = theta
        o_v[k] = krv * omega
        o_x[k] = x0 + krv * (theta - theta0)
        o_f[k] = q * inv_krv
        o_load[k] = (f * (inv_eta if mot else eta) + 0.0) if moving else t_avg
        o_loss[k] = bma * se + omega * (bmb + bmc * abs(omega))
        theta = theta + 0.5 * dt * (omega + w)
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


# ----------------------------------------------------------- batch kernels
LANES = 64
"""Row length of a batch chunk's work buffer (a compile-time constant, so
that the vectoriser sees fixed distances between the buffer's rows)."""

# work-buffer rows: parameters, state, outputs
_B_KV, _B_KP, _B_KP_TI, _B_TLIM, _B_A_LAG, _B_B_LAG, _B_JD, _B_ETA, _B_INV_ETA = range(9)
_B_BMA, _B_BMB, _B_BMC, _B_M, _B_FC, _B_BRKP, _B_BRKN, _B_FG, _B_KRV, _B_HJM = range(9, 19)
_B_HJG, _B_THETA0, _B_X0, _B_INV_KRV, _B_TH, _B_OM, _B_TQ, _B_UP, _B_IN, _B_SAT = range(19, 29)
_B_OUT = 29
_B_ROWS = _B_OUT + N_OUT


@njit(parallel=True, fastmath=_FASTMATH, error_model="numpy", cache=True)
def batch_plain_kernel(
    coefs: FloatArray,
    w_sp: FloatArray,
    p_sp: FloatArray,
    chunk: int,
    out: FloatArray,
    saturated: FloatArray,
) -> None:
    """Rigid model without faults for many members at once.

    ``coefs`` (B, N_COEF); ``out`` (Q, n, B) with Q = N_MAIN or N_OUT rows
    (the first Q output rows are kept). Members are processed in chunks of
    ``chunk`` ≤ LANES lanes (one chunk per task, across threads); the inner
    loop runs over the lanes of a chunk (vectorised) and does exactly the
    arithmetic of :func:`rigid_kernel`.
    """
    n_members = coefs.shape[0]
    n = w_sp.size
    n_q = out.shape[0]
    dt = coefs[0, C_DT]
    inv_dt = 1.0 / dt
    n_chunks = (n_members + chunk - 1) // chunk
    flat = out.reshape(-1)
    for c in prange(n_chunks):
        c0 = c * chunk
        m = min(chunk, n_members - c0)
        width = (m + 7) // 8 * 8  # padded lanes copy member c0
        buf = np.zeros(_B_ROWS * LANES)
        step_k = np.full(LANES, -1)
        any_step = False
        for j in range(width):
            b = c0 + j if j < m else c0
            cf = coefs[b]
            buf[_B_KV * LANES + j] = cf[C_KV]
            buf[_B_KP * LANES + j] = cf[C_KP]
            buf[_B_KP_TI * LANES + j] = cf[C_KP_TI]
            buf[_B_TLIM * LANES + j] = cf[C_TLIM]
            buf[_B_A_LAG * LANES + j] = cf[C_A_LAG]
            buf[_B_B_LAG * LANES + j] = cf[C_B_LAG]
            buf[_B_JD * LANES + j] = cf[C_JD]
            buf[_B_ETA * LANES + j] = cf[C_ETA]
            buf[_B_INV_ETA * LANES + j] = cf[C_INV_ETA]
            buf[_B_BMA * LANES + j] = cf[C_BMA]
            buf[_B_BMB * LANES + j] = cf[C_BMB]
            buf[_B_BMC * LANES + j] = cf[C_BMC]
            m_red, fc, fs, fg = mass_terms(
                cf[C_MASS], cf[C_CARRIED], cf[C_MU_G_COS], cf[C_STATIC], cf[C_G_SIN], cf[C_KRV]
            )
            hjm, hjg = step_gains(dt, cf[C_JD], m_red, cf[C_ETA], cf[C_INV_ETA])
            buf[_B_M * LANES + j] = m_red
            buf[_B_FC * LANES + j] = fc
            brk_pos, brk_neg = breakaway_levels(fs, fg, cf[C_BMA], cf[C_ETA], cf[C_INV_ETA])
            buf[_B_BRKP * LANES + j] = brk_pos
            buf[_B_BRKN * LANES + j] = brk_neg
            buf[_B_FG * LANES + j] = fg
            buf[_B_KRV * LANES + j] = cf[C_KRV]
            buf[_B_HJM * LANES + j] = hjm
            buf[_B_HJG * LANES + j] = hjg
            buf[_B_THETA0 * LANES + j] = cf[C_THETA0]
            buf[_B_X0 * LANES + j] = cf[C_X0]
            buf[_B_INV_KRV * LANES + j] = 1.0 / cf[C_KRV]
            buf[_B_TH * LANES + j] = cf[C_THETA0]
            if j < m and cf[C_STEP_K] >= 0.0:
                step_k[j] = int(cf[C_STEP_K])
                any_step = True
        for k in range(n):
            if any_step:
                for j in range(m):
                    if step_k[j] == k:
                        cf = coefs[c0 + j]
                        kk = cf[C_KRV]
                        jd = cf[C_JD]
                        mass = cf[C_MASS] + cf[C_STEP_KG]
                        j_old = jd + cf[C_MASS] * kk * kk
                        m_red, fc, fs, fg = mass_terms(
                            mass,
                            cf[C_CARRIED] + cf[C_STEP_KG],
                            cf[C_MU_G_COS],
                            cf[C_STATIC],
                            cf[C_G_SIN],
                            kk,
                        )
                        hjm, hjg = step_gains(dt, jd, m_red, cf[C_ETA], cf[C_INV_ETA])
                        buf[_B_M * LANES + j] = m_red
                        buf[_B_FC * LANES + j] = fc
                        brk_pos, brk_neg = breakaway_levels(
                            fs, fg, cf[C_BMA], cf[C_ETA], cf[C_INV_ETA]
                        )
                        buf[_B_BRKP * LANES + j] = brk_pos
                        buf[_B_BRKN * LANES + j] = brk_neg
                        buf[_B_FG * LANES + j] = fg
                        buf[_B_HJM * LANES + j] = hjm
                        buf[_B_HJG * LANES + j] = hjg
                        om = buf[_B_OM * LANES + j]
                        buf[_B_OM * LANES + j] = om * (j_old / (jd + mass * kk * kk))
            ws = w_sp[k]
            ps = p_sp[k]
            for j in range(width):
                kv = buf[_B_KV * LANES + j]
                kp = buf[_B_KP * LANES + j]
                kp_ti = buf[_B_KP_TI * LANES + j]
                tlim = buf[_B_TLIM * LANES + j]
                a_lag = buf[_B_A_LAG * LANES + j]
                b_lag = buf[_B_B_LAG * LANES + j]
                jd = buf[_B_JD * LANES + j]
                eta = buf[_B_ETA * LANES + j]
                inv_eta = buf[_B_INV_ETA * LANES + j]
                bma = buf[_B_BMA * LANES + j]
                bmb = buf[_B_BMB * LANES + j]
                bmc = buf[_B_BMC * LANES + j]
                m_red = buf[_B_M * LANES + j]
                fc = buf[_B_FC * LANES + j]
                brk_pos = buf[_B_BRKP * LANES + j]
                brk_neg = buf[_B_BRKN * LANES + j]
                fg = buf[_B_FG * LANES + j]
                krv = buf[_B_KRV * LANES + j]
                hjm = buf[_B_HJM * LANES + j]
                hjg = buf[_B_HJG * LANES + j]
                theta = buf[_B_TH * LANES + j]
                omega = buf[_B_OM * LANES + j]
                torque = buf[_B_TQ * LANES + j]
                u_prev = buf[_B_UP * LANES + j]
                integ = buf[_B_IN * LANES + j]
                u, integ = controller(ws, ps, theta, omega, integ, kv, kp, kp_ti, dt, tlim)
                sat = (u >= tlim) | (u <= -tlim)
                t_avg = u_prev + (torque - u_prev) * b_lag
                t_next = torque + a_lag * (u_prev - torque)
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
                moving = se != 0.0
                q = f + m_red * ((w - omega) * inv_dt) if moving else t_avg
                buf[(_B_OUT + O_TORQUE_SP) * LANES + j] = u
                buf[(_B_OUT + O_TORQUE) * LANES + j] = torque
                buf[(_B_OUT + O_SPEED) * LANES + j] = omega
                buf[(_B_OUT + O_POSITION) * LANES + j] = theta
                buf[(_B_OUT + O_BELT_SPEED) * LANES + j] = krv * omega
                buf[(_B_OUT + O_BELT_POSITION) * LANES + j] = buf[_B_X0 * LANES + j] + krv * (
                    theta - buf[_B_THETA0 * LANES + j]
                )
                buf[(_B_OUT + O_FORCE) * LANES + j] = q * buf[_B_INV_KRV * LANES + j]
                buf[(_B_OUT + O_LOAD) * LANES + j] = (
                    (f * (inv_eta if mot else eta) + 0.0) if moving else t_avg
                )
                buf[(_B_OUT + O_LOSS) * LANES + j] = bma * se + omega * (bmb + bmc * abs(omega))
                buf[_B_TH * LANES + j] = theta + 0.5 * dt * (omega + w)
                buf[_B_OM * LANES + j] = w
                buf[_B_TQ * LANES + j] = t_next
                buf[_B_UP * LANES + j] = u
                buf[_B_IN * LANES + j] = integ
                buf[_B_SAT * LANES + j] += 1.0 if sat else 0.0
            for r in range(n_q):
                # unsigned indices: no negative-index wraparound in the copy
                dst = np.uint64((r * n + k) * n_members + c0)
                src = np.uint64((_B_OUT + r) * LANES)
                for j in range(m):
                    uj = np.uint64(j)
                    flat[dst + uj] = buf[src + uj]
        for j in range(m):
            saturated[c0 + j] = buf[_B_SAT * LANES + j]


@njit(parallel=True, fastmath=_FASTMATH, error_model="numpy", cache=True)
def batch_general_kernel(
    coefs: FloatArray,
    orders: FloatArray,
    amps: FloatArray,
    elastic: npt.NDArray[np.bool_],
    w_sp: FloatArray,
    p_sp: FloatArray,
    out: FloatArray,
    status: npt.NDArray[np.int64],
) -> None:
    """Members with realism or faults, one per task: ``out`` (B, N_OUT, n).

    Runs :func:`rigid_kernel` or :func:`elastic_kernel` per member;
    ``status`` (B, 3) receives their return values.
    """
    for b in prange(coefs.shape[0]):
        if elastic[b]:
            res = elastic_kernel(coefs[b], orders[b], amps[b], w_sp, p_sp, out[b])
        else:
            res = rigid_kernel(coefs[b], orders[b], amps[b], w_sp, p_sp, out[b])
        status[b, 0] = res[0]
        status[b, 1] = res[1]
        status[b, 2] = res[2]
