"""Benchmark of the closed-loop simulator (a script, not a test).

Run: ``.venv/bin/python benchmarks/bench_simulate.py``

Scenario: reference conveyor white-belt-01 with 40 kg payload, a trapezoid to
the nominal 1415 rpm with 0.5 s ramps, held 10.5 s (12 s in all, 12 001
controller cycles at 1 ms). Prints one table:

* time per simulated cycle, rigid model and elastic + polygon + stick-slip;
* the same rigid model in continuous time through scipy's ``solve_ivp``
  (LSODA and RK45, rtol 1e-6) and the speed-up against both.

Times are the best of several repetitions after a warm-up (numba compiled).
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # no BLAS threads competing with numba's

import math  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import numba  # noqa: E402
import numpy as np  # noqa: E402
from scipy.integrate import solve_ivp  # noqa: E402

import chaintwin.examples  # noqa: E402
from chaintwin.physics import G  # noqa: E402
from chaintwin.read.profile import load_profile  # noqa: E402
from chaintwin.simulate import (  # noqa: E402
    PlantParameters,
    Setpoints,
    _kernel,
    simulate,
    trapezoid,
)
from chaintwin.simulate.engine import _coefficients  # noqa: E402

NOMINAL = 1415.0 * 2.0 * math.pi / 60.0
RIGID_TARGET_MS = 0.3


def best_of(fn: Callable[[], Any], repeat: int, number: int = 1) -> tuple[float, float]:
    """Best and median time of one call, s."""
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        for _ in range(number):
            fn()
        times.append((time.perf_counter() - t0) / number)
    return min(times), statistics.median(times)


def continuous_rhs(p: PlantParameters, sp: Setpoints) -> Callable[[float, Any], Any]:
    """The rigid model in continuous time: states θ, ω, T (lag), ∫e (PI integral).

    Same controller (position P, speed PI with clamping anti-windup) and
    plant (power-flow dependent efficiency), continuous instead of discrete:
    no controller sampling, no one-cycle delay. The Coulomb terms are
    regularised, sign(ω) → tanh(ω/0.01 rad/s), or the solvers stall at
    standstill.
    """
    t_knots = sp.time
    w_knots = np.asarray(sp.speed)
    p_knots = np.asarray(sp.position)
    jd = p.drive_inertia_kgm2
    k = p.belt_speed_per_motor_speed
    m = p.moving_mass_kg
    m_red = m * k * k
    fc = p.mu * G * math.cos(p.incline_rad) * m * k
    fg = G * math.sin(p.incline_rad) * p.carried_mass_kg * k
    eta = p.efficiency
    kp, ti, kv, lim = (
        p.speed_gain_nm_s_rad,
        p.speed_integral_time_s,
        p.position_gain_1_s,
        p.torque_limit_nm,
    )
    tau = p.torque_time_constant_s
    bma, bmb, bmc = p.loss_constant_nm, p.loss_viscous_nm_s_rad, p.loss_quadratic_nm_s2_rad2

    def rhs(t: float, y: Any) -> Any:
        theta, w, torque, integ = y
        w_sp = np.interp(t, t_knots, w_knots)
        p_sp = np.interp(t, t_knots, p_knots)
        e = w_sp + kv * (p_sp - theta) - w
        u = kp * (e + integ / ti)
        d_integ = 0.0 if (u > lim and e > 0.0) or (u < -lim and e < 0.0) else e
        u = min(max(u, -lim), lim)
        s = math.tanh(w / 0.01)
        a_net = torque - bma * s - bmb * w - bmc * w * abs(w)
        f = fc * s + fg
        ke = 1.0 / eta if (f * jd + m_red * a_net) * s >= 0.0 else eta
        alpha = (a_net - f * ke) / (jd + m_red * ke)
        return [w, alpha, (u - torque) / tau, d_integ]

    return rhs


def main() -> int:
    profile = load_profile(Path(chaintwin.examples.__file__).parent / "profiles/white-belt-01.yaml")
    plant = PlantParameters.from_profile(profile, payload_kg=40.0)
    realism = plant.replace(elastic=True, polygon=True, stick_slip=True)
    sp = trapezoid(speed_rad_s=NOMINAL, accel_rad_s2=NOMINAL / 0.5, hold_s=10.5)
    n = len(sp)
    threads = numba.get_num_threads()
    print(
        f"chaintwin simulator benchmark: white-belt-01, 40 kg, trapezoid to {NOMINAL:.2f} rad/s "
        f"(1415 rpm), 0.5 s ramps, {sp.duration_s:.1f} s = {n} cycles at "
        f"{sp.cycle_s * 1e3:g} ms; numba {numba.__version__}, {threads} threads, "
        f"{os.cpu_count()} CPUs"
    )

    # warm-up: compile (or load the on-disk cache)
    t0 = time.perf_counter()
    simulate(plant, sp)
    simulate(realism, sp)
    print(f"warm-up (compile or load cache): {time.perf_counter() - t0:.1f} s")

    rows: list[tuple[str, str, str]] = []

    # ------------------------------------------------------------- single
    numba.set_num_threads(1)
    rigid_best, rigid_med = best_of(lambda: simulate(plant, sp), repeat=300)
    coef = _coefficients(plant, n)
    out = np.empty((_kernel.N_OUT, n))
    kern_best, _ = best_of(
        lambda: _kernel.plain_kernel(coef, sp.speed, sp.position, out), repeat=300
    )
    real_best, real_med = best_of(lambda: simulate(realism, sp), repeat=50)
    ok = "meets" if rigid_best * 1e3 <= RIGID_TARGET_MS else "MISSES"
    rows += [
        (
            "rigid, simulate() per 12 s cycle (1 core)",
            f"{rigid_best * 1e3:.3f} ms (median {rigid_med * 1e3:.3f})",
            f"{ok} ≤ {RIGID_TARGET_MS} ms",
        ),
        (
            "rigid, kernel alone per 12 s cycle",
            f"{kern_best * 1e3:.3f} ms = {kern_best / n * 1e9:.1f} ns/step",
            "",
        ),
        (
            "elastic+polygon+stick-slip per cycle",
            f"{real_best * 1e3:.3f} ms (median {real_med * 1e3:.3f})",
            f"{_sub(realism)} sub-steps/cycle; info",
        ),
    ]

    # ------------------------------------------------------------- solve_ivp
    rhs = continuous_rhs(plant, sp)
    y0 = [0.0, 0.0, 0.0, 0.0]
    horizon = sp.duration_s
    for method in ("LSODA", "RK45"):
        t0 = time.perf_counter()
        sol = solve_ivp(rhs, (0.0, horizon), y0, method=method, rtol=1e-6, atol=1e-8)
        first = time.perf_counter() - t0
        repeats = 3 if first < 5.0 else 1
        best = first
        if repeats > 1:

            def again(m: str = method) -> None:
                solve_ivp(rhs, (0.0, horizon), y0, method=m, rtol=1e-6, atol=1e-8)

            best = min(first, best_of(again, repeat=repeats - 1)[0])
        hold = (sol.t > 2.0) & (sol.t < 10.0)
        torque_check = float(np.mean(sol.y[2][hold])) if np.any(hold) else float("nan")
        rows.append(
            (
                f"solve_ivp {method} rtol 1e-6, full {horizon:.0f} s",
                f"{best * 1e3:.0f} ms ({sol.nfev} RHS calls)",
                f"×{best / rigid_best:,.0f} slower (target ≥ "
                f"{50 if method == 'LSODA' else 500}×); steady T {torque_check:.4f} Nm",
            )
        )

    width = max(len(r[0]) for r in rows)
    width2 = max(len(r[1]) for r in rows)
    print()
    print(f"{'measure':<{width}}  {'result':<{width2}}  note")
    print("-" * (width + width2 + 40))
    for name, value, note in rows:
        print(f"{name:<{width}}  {value:<{width2}}  {note}")
    print()
    print(
        "solve_ivp runs the continuous-time rigid model (Coulomb terms regularised with "
        "tanh(ω/0.01)); its ratio is against simulate() of the rigid model."
    )
    return 0


def _sub(p: PlantParameters) -> int:
    from chaintwin.simulate import elastic_substeps

    return elastic_substeps(p)


if __name__ == "__main__":
    sys.exit(main())
