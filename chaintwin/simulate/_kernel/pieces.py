"""Compiled pieces the simulator kernels share.

Controller, rigid step, Coulomb friction stop, polygonal sprocket and
disturbance torques.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, cast

import numpy as np
from llvmlite import ir as llvm_ir  # type: ignore[import-untyped]
from numba import njit, types
from numba.extending import intrinsic

from chaintwin._types import FloatArray

# fastmath without nnan/ninf: NaN/inf checks must keep working
FASTMATH = {"nsz", "contract"}
# the plain rigid model (and the pieces it shares) runs without contraction:
# LLVM fuses a multiply into an add only where the product has no other use,
# which depends on which outputs a kernel keeps, so results could differ in
# the last bit. Fused multiply-adds are written out (:func:`fma`) instead.
EXACT = {"nsz"}
HUGE = 1e300
STOP_RAD_S = 1e-6  # motor speeds decaying below this snap to standstill, rad/s
STOP_M_S = 1e-8  # same for the belt mass of the elastic model, m/s


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


@njit(inline="always", fastmath=FASTMATH, error_model="numpy", cache=True)
def stribeck(fc: float, fs: float, v: float, vs: float) -> float:
    """Sliding friction at belt speed ``v``: from ``fs`` at rest down to ``fc``.

    ``fc + (fs − fc)·exp(−(v/vs)²)`` (the Stribeck curve without its viscous
    part, which the gear losses hold); ``vs`` the Stribeck speed, m/s
    (0: Coulomb friction ``fc``). Any unit of force or torque.
    """
    if vs <= 0.0:
        return fc
    r = v / vs
    return fc + (fs - fc) * math.exp(-r * r)


@njit(inline="always", fastmath=FASTMATH, error_model="numpy", cache=True)
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


@njit(inline="always", fastmath=FASTMATH, error_model="numpy", cache=True)
def step_gains(
    dt: float, jd: float, m_red: float, eta: float, inv_eta: float
) -> tuple[float, float]:
    """``dt/J`` while motoring (``J = J_d + M/η``) and generating (``J_d + M·η``)."""
    return dt / (jd + m_red * inv_eta), dt / (jd + m_red * eta)


@njit(inline="always", fastmath=FASTMATH, error_model="numpy", cache=True)
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


@njit(inline="always", fastmath=EXACT, error_model="numpy", cache=True)
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


@njit(inline="always", fastmath=EXACT, error_model="numpy", cache=True)
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


@njit(inline="always", fastmath=EXACT, error_model="numpy", cache=True)
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
    w = settle(w, omega, se, STOP_RAD_S)
    return w, se, f, mot


@njit(inline="always", fastmath=FASTMATH, error_model="numpy", cache=True)
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


@njit(fastmath=FASTMATH, error_model="numpy", cache=True)
def _impulse_cum(x: float, period: float, width: float) -> float:
    n = np.floor(x / period)
    r = x - n * period
    return n * width + (r if r < width else width)


@njit(fastmath=FASTMATH, error_model="numpy", cache=True)
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


@njit(inline="always", fastmath=FASTMATH, error_model="numpy", cache=True)
def in_bump(x: float, start: float, width: float, loop: float) -> bool:
    """Whether belt position x (modulo the loop) lies in [start, start + width)."""
    r = x - start
    r = r - np.floor(r / loop) * loop
    return r < width


@njit(fastmath=FASTMATH, error_model="numpy", cache=True)
def fail(out: FloatArray, k: int) -> None:
    """Fill ``out`` with NaN from cycle ``k`` on (a diverged simulation)."""
    for q in range(out.shape[0]):
        for j in range(k, out.shape[1]):
            out[q, j] = np.nan
