"""The two-mass (elastic belt) kernel."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from numba import njit

from chaintwin._types import FloatArray
from chaintwin.simulate._kernel.layout import (
    C_A_LAG,
    C_BMA,
    C_BMB,
    C_BMC,
    C_CARRIED,
    C_DAMP,
    C_DT,
    C_ETA,
    C_G_SIN,
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
    C_MASS,
    C_MU_G_COS,
    C_NRIP,
    C_NSUB,
    C_OBS_FORCE,
    C_OBS_POS,
    C_OBS_WIDTH,
    C_PITCH_R,
    C_POLYGON,
    C_RATIO,
    C_STATIC,
    C_STEP_K,
    C_STEP_KG,
    C_STIFF,
    C_STRIBECK_V,
    C_TAU,
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
    FASTMATH,
    HUGE,
    STOP_M_S,
    STOP_RAD_S,
    controller,
    disturbance,
    fail,
    in_bump,
    polygon,
    settle,
    stribeck,
)

keep_cache_fresh(__file__, *(str(Path(__file__).with_name(f)) for f in ("layout.py", "pieces.py")))


# ---------------------------------------------------------- elastic kernel
@njit(fastmath=FASTMATH, error_model="numpy", cache=True, nogil=True)
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
    vs = coef[C_STRIBECK_V]
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
            w = settle(w, omega, se, STOP_RAD_S)
            # belt side: friction (static until breakaway, then the Stribeck
            # curve), incline, obstruction
            fck = stribeck(fc2, fs2, xd, vs)
            fsk = fs2
            if has_obs and in_bump(x, obs_pos, obs_w, loop):
                fck += obs_f
                fsk += obs_f
            net_b = f_spring - fg2
            sb = 1.0 if xd > 0.0 else (-1.0 if xd < 0.0 else 0.0)
            db = 1.0 if net_b > fsk else (-1.0 if net_b < -fsk else 0.0)
            seb = sb if sb != 0.0 else db
            v = xd + h * (net_b - fck * seb) * inv_m2
            v = settle(v, xd, seb, STOP_M_S)
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
        if not (abs(omega) < HUGE and abs(theta) < HUGE and abs(x) < HUGE):
            fail(out, k + 1)
            return 1, k + 1, n_sat
    return 0, -1, n_sat
