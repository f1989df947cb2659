"""The kernels' coefficient and output layouts, and their numba cache freshness.

Plain Python (nothing compiled here): the kernels freeze these constants when
numba compiles them.
"""

from __future__ import annotations

import operator
import os
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from chaintwin._types import FloatArray
from chaintwin.errors import ModelError

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
C_STRIBECK_V = _coef(
    "stribeck_v", "Stribeck speed: the friction falls from static to kinetic over it, m/s (0: none)"
)
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


def keep_cache_fresh(module_file: str, *dependencies: str) -> None:
    """Make numba's on-disk cache of a kernel module see changes in its dependencies.

    numba stamps a cached function with the modification time and size of
    its own file only, while a kernel compiles in the shared pieces and the
    layout constants of other files. Giving the kernel's file a modification
    time newer than any dependency's (as ``make`` would) invalidates its
    cache entries after a dependency changed. Call it before the module's
    first ``@njit(cache=True)``; on a read-only installation it does nothing
    (installed files do not change).

    Parameters
    ----------
    module_file : str
        The kernel module's ``__file__``.
    *dependencies : str
        Files whose code or constants the module's kernels compile in.
    """
    here = Path(module_file)
    try:
        newest = max(Path(dep).stat().st_mtime_ns for dep in dependencies)
        if here.stat().st_mtime_ns <= newest:
            os.utime(here, ns=(newest + 1, newest + 1))
    except OSError:
        pass
