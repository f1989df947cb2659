"""The rigid-model kernels.

With every realism effect and fault (:func:`rigid_kernel`), and the plain
identification model (:func:`plain_kernel`).
"""

from __future__ import annotations

import math
from pathlib import Path

from numba import njit

from chaintwin._types import FloatArray
from chaintwin.simulate._kernel.layout import (
    C_A_LAG,
    C_B_LAG,
    C_BMA,
    C_BMB,
    C_BMC,
    C_BRKN0,
    C_BRKN1,
    C_BRKP0,
    C_BRKP1,
    C_CARRIED,
    C_DT,
    C_ETA,
    C_FC0,
    C_FC1,
    C_FG0,
    C_FG1,
    C_G_SIN,
    C_HJG0,
    C_HJG1,
    C_HJM0,
    C_HJM1,
    C_IMP_AMP,
    C_IMP_PERIOD,
    C_IMP_WIDTH,
    C_INV_ETA,
    C_JD,
    C_KP,
    C_KP_TI,
    C_KRV,
    C_KV,
    C_LOOP,
    C_M_RED0,
    C_M_RED1,
    C_MASS,
    C_MU_G_COS,
    C_NRIP,
    C_OBS_FORCE,
    C_OBS_POS,
    C_OBS_WIDTH,
    C_PITCH_R,
    C_POLYGON,
    C_RATIO,
    C_STATIC,
    C_STEP_K,
    C_STEP_KG,
    C_STEP_SCALE,
    C_STRIBECK_V,
    C_TEETH,
    C_THETA0,
    C_TLIM,
    C_X0,
    O_BELT_POSITION,
    O_BELT_SPEED,
    O_FORCE,
    O_LOAD,
    O_LOSS,
    O_POSITION,
    O_SPEED,
    O_TORQUE,
    O_TORQUE_SP,
    keep_cache_fresh,
)
from chaintwin.simulate._kernel.pieces import (
    EXACT,
    FASTMATH,
    HUGE,
    breakaway_levels,
    controller,
    disturbance,
    fail,
    fma,
    in_bump,
    mass_terms,
    polygon,
    rigid_core,
    step_gains,
    stribeck,
)

keep_cache_fresh(__file__, *(str(Path(__file__).with_name(f)) for f in ("layout.py", "pieces.py")))


# ------------------------------------------------------------ rigid kernel
@njit(fastmath=FASTMATH, error_model="numpy", cache=True, nogil=True)
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
    vs = coef[C_STRIBECK_V]
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
        # Stribeck: sliding friction falls from static to kinetic with belt speed
        fck = stribeck(fck, fsk, kk * omega, vs)
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
        if not (abs(omega) < HUGE and abs(theta) < HUGE and abs(torque) < HUGE):
            fail(out, k + 1)
            return 1, k + 1, n_sat
    return 0, -1, n_sat


@njit(inline="always", fastmath=EXACT, error_model="numpy", cache=True)
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


@njit(inline="always", fastmath=EXACT, error_model="numpy", cache=True)
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


@njit(fastmath=EXACT, error_model="numpy", cache=True, nogil=True)
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
    if not (abs(theta) < HUGE and abs(torque) < HUGE):
        for k in range(n):
            if not (abs(o_th[k]) < HUGE and abs(o_tq[k]) < HUGE):
                fail(out, k)
                return 1, k, n_sat
        return 1, n, n_sat
    return 0, -1, n_sat
