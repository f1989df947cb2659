"""Closed-form conveyor physics on the motor shaft (docs/design.md, section 2).

Everything is SI: kg, m, s, rad, N, Nm. Symbols: gear ratio i, efficiency η,
sprocket pitch radius R with z teeth and chordal mean radius
r = R·sin(π/z)/(π/z), belt mass m_b, tray m_t, payload m_p, incline β.

Efficiency and the direction of power flow
------------------------------------------
The gear unit loses a fraction of the power that passes through it, in
whichever direction it flows:

* **motoring** (power flows motor → belt, ``(F + m·a)·v > 0``): the motor
  supplies ``(F + m·a)·r/(i·η)``; belt inertia enters as ``m·r²/(i²·η)``;
* **generating** (the belt drives the motor: a hard stop, downhill):
  the motor sees ``(F + m·a)·r·η/i`` and ``m·r²·η/i²``.

:func:`gear_factor` returns the factor (``1/η`` or ``η``) for a case.
"""

from __future__ import annotations

import math
from typing import overload

import numpy as np

from chaintwin._types import FloatArray
from chaintwin.units import G

__all__ = [
    "G",
    "belt_force_n",
    "chordal_radius_m",
    "gear_factor",
    "load_torque_nm",
    "loss_torque_nm",
    "motoring",
    "payload_sensitivity_nm_kg",
    "polygon_radius_m",
    "reflected_inertia_kgm2",
    "steady_torque_nm",
    "two_mass_frequency_hz",
]


def chordal_radius_m(pitch_radius_m: float, teeth: int | None) -> float:
    """Chordal mean radius ``r = R·sin(π/z)/(π/z)``, m.

    A chain on a z-tooth sprocket advances r per sprocket radian on average.

    Parameters
    ----------
    pitch_radius_m : float
        Pitch radius R, m.
    teeth : int or None
        Tooth count z; None or 0 when unknown (then r = R).

    Returns
    -------
    float
        r, m.
    """
    if not teeth:
        return pitch_radius_m
    x = math.pi / teeth
    return pitch_radius_m * math.sin(x) / x


def polygon_radius_m(pitch_radius_m: float, teeth: int, sprocket_angle_rad: float) -> float:
    """Instantaneous effective radius ``R·cos φ`` of a polygonal sprocket, m.

    ``φ = (ψ mod 2π/z) − π/z`` with ψ the sprocket angle, so φ sweeps
    [−π/z, π/z) once per tooth; its mean over a tooth is the chordal radius.

    Parameters
    ----------
    pitch_radius_m : float
        Pitch radius R, m.
    teeth : int
        Tooth count z (≥ 3).
    sprocket_angle_rad : float
        Sprocket angle ψ, rad.

    Returns
    -------
    float
        Effective radius, m.
    """
    pitch = 2.0 * math.pi / teeth
    phi = math.fmod(sprocket_angle_rad, pitch)
    if phi < 0.0:
        phi += pitch
    return pitch_radius_m * math.cos(phi - 0.5 * pitch)


def belt_force_n(
    *,
    mu: float,
    moving_mass_kg: float,
    carried_mass_kg: float,
    incline_rad: float = 0.0,
    direction: float = 1.0,
) -> float:
    """Belt resistance at the sprocket, N.

    ``F = μ·g·cosβ·(m_b + m_t + m_p)·sign(v) + g·sinβ·(m_t + m_p)``: both
    strands slide on rails; only the carried mass climbs (the belt's own
    weight cancels between the strands).

    Parameters
    ----------
    mu : float
        Kinetic friction coefficient μ.
    moving_mass_kg : float
        Belt + tray + payload, kg.
    carried_mass_kg : float
        Tray + payload, kg.
    incline_rad : float
        Incline β, rad (positive: conveying uphill).
    direction : float
        sign(v): +1 forward, -1 backward, 0 at standstill (then only the
        incline term remains).

    Returns
    -------
    float
        F, N (positive resists forward motion).
    """
    sign = float(np.sign(direction))
    return (
        mu * G * math.cos(incline_rad) * moving_mass_kg * sign
        + G * math.sin(incline_rad) * carried_mass_kg
    )


def motoring(
    force_n: float, moving_mass_kg: float, belt_accel_m_s2: float, belt_speed_m_s: float
) -> bool:
    """Whether power flows from the motor to the belt, ``(F + m·a)·v > 0``.

    Parameters
    ----------
    force_n : float
        Belt resistance F, N.
    moving_mass_kg : float
        m = m_b + m_t + m_p, kg.
    belt_accel_m_s2 : float
        Belt acceleration a, m/s².
    belt_speed_m_s : float
        Belt speed v, m/s.

    Returns
    -------
    bool
        True when motoring; at ``v = 0`` True (no power flows; the motoring
        factor is the conservative one for breakaway).
    """
    power = (force_n + moving_mass_kg * belt_accel_m_s2) * belt_speed_m_s
    return bool(power >= 0.0)


def gear_factor(efficiency: float, *, motoring: bool = True) -> float:
    """Efficiency factor on belt-side torque and inertia at the motor.

    Parameters
    ----------
    efficiency : float
        Gear efficiency η in (0, 1].
    motoring : bool
        True when power flows motor → belt (``1/η``), False when the belt
        drives the motor (``η``).

    Returns
    -------
    float
        ``1/η`` or ``η``.
    """
    return 1.0 / efficiency if motoring else efficiency


def load_torque_nm(
    force_n: float, radius_m: float, ratio: float, efficiency: float, *, motoring: bool = True
) -> float:
    """A belt-side force referred to the motor, ``F·r/(i·η)`` (or ``·η``), Nm.

    Parameters
    ----------
    force_n : float
        Force at the sprocket, N.
    radius_m : float
        Sprocket radius (chordal mean r), m.
    ratio : float
        Gear ratio i.
    efficiency : float
        Gear efficiency η.
    motoring : bool
        Power flow case (see the module notes).

    Returns
    -------
    float
        Torque at the motor, Nm.
    """
    return force_n * radius_m / ratio * gear_factor(efficiency, motoring=motoring)


@overload
def loss_torque_nm(
    speed_rad_s: float, constant_nm: float, viscous_nm_s_rad: float, quadratic_nm_s2_rad2: float
) -> float: ...
@overload
def loss_torque_nm(
    speed_rad_s: FloatArray,
    constant_nm: float,
    viscous_nm_s_rad: float,
    quadratic_nm_s2_rad2: float,
) -> FloatArray: ...
def loss_torque_nm(
    speed_rad_s: float | FloatArray,
    constant_nm: float,
    viscous_nm_s_rad: float,
    quadratic_nm_s2_rad2: float,
) -> float | FloatArray:
    """Gear unit and motor losses ``BmA·sign(ω) + BmB·ω + BmC·ω·|ω|``, Nm.

    Parameters
    ----------
    speed_rad_s : float or ndarray of float
        Motor speed ω, rad/s.
    constant_nm : float
        BmA, Nm.
    viscous_nm_s_rad : float
        BmB, Nm/(rad/s).
    quadratic_nm_s2_rad2 : float
        BmC, Nm/(rad/s)².

    Returns
    -------
    float or ndarray of float
        Loss torque, Nm, same shape as ``speed_rad_s``.
    """
    w = np.asarray(speed_rad_s, dtype=np.float64)
    loss = constant_nm * np.sign(w) + viscous_nm_s_rad * w + quadratic_nm_s2_rad2 * w * np.abs(w)
    if loss.ndim == 0:
        return float(loss)
    return loss


def reflected_inertia_kgm2(
    *,
    motor_inertia_kgm2: float,
    gear_inertia_kgm2: float,
    moving_mass_kg: float,
    radius_m: float,
    ratio: float,
    efficiency: float,
    motoring: bool = True,
) -> float:
    """Inertia at the motor shaft, kg·m².

    ``J = J_motor + J_gear + m·r²/(i²·η)`` while motoring; ``·η`` instead of
    ``/η`` when the belt drives the motor.

    Parameters
    ----------
    motor_inertia_kgm2, gear_inertia_kgm2 : float
        Rotor and gear unit inertia (at the motor shaft), kg·m².
    moving_mass_kg : float
        Belt + tray + payload, kg.
    radius_m : float
        Chordal mean radius r, m.
    ratio : float
        Gear ratio i.
    efficiency : float
        Gear efficiency η.
    motoring : bool
        Power flow case.

    Returns
    -------
    float
        J, kg·m².
    """
    k = radius_m / ratio
    return (
        motor_inertia_kgm2
        + gear_inertia_kgm2
        + moving_mass_kg * k * k * gear_factor(efficiency, motoring=motoring)
    )


def steady_torque_nm(
    *,
    speed_rad_s: float,
    mu: float,
    moving_mass_kg: float,
    carried_mass_kg: float,
    incline_rad: float,
    radius_m: float,
    ratio: float,
    efficiency: float,
    loss_constant_nm: float,
    loss_viscous_nm_s_rad: float,
    loss_quadratic_nm_s2_rad2: float,
) -> float:
    """Motor torque at constant speed (rigid model), Nm.

    ``T = F·r/(i·η) + BmA·sign(ω) + BmB·ω + BmC·ω·|ω|`` while motoring
    (``F·v > 0``); ``F·r·η/i`` when the belt drives the motor (steep
    downhill). At constant speed ``a = 0`` so only F decides the case.

    Parameters
    ----------
    speed_rad_s : float
        Motor speed ω, rad/s (non-zero).
    mu : float
        Friction coefficient μ.
    moving_mass_kg, carried_mass_kg : float
        Belt + tray + payload and tray + payload, kg.
    incline_rad : float
        β, rad.
    radius_m : float
        Chordal mean radius r, m.
    ratio, efficiency : float
        i and η.
    loss_constant_nm, loss_viscous_nm_s_rad, loss_quadratic_nm_s2_rad2 : float
        BmA, BmB, BmC.

    Returns
    -------
    float
        Motor torque, Nm.
    """
    force = belt_force_n(
        mu=mu,
        moving_mass_kg=moving_mass_kg,
        carried_mass_kg=carried_mass_kg,
        incline_rad=incline_rad,
        direction=speed_rad_s,
    )
    is_motoring = force * speed_rad_s >= 0.0
    return load_torque_nm(
        force, radius_m, ratio, efficiency, motoring=is_motoring
    ) + loss_torque_nm(
        speed_rad_s, loss_constant_nm, loss_viscous_nm_s_rad, loss_quadratic_nm_s2_rad2
    )


def payload_sensitivity_nm_kg(
    *, mu: float, incline_rad: float, radius_m: float, ratio: float, efficiency: float
) -> float:
    """Steady torque per kg of payload while motoring, ``g·(μ·cosβ + sinβ)·r/(i·η)``, Nm/kg.

    Parameters
    ----------
    mu : float
        Friction coefficient μ.
    incline_rad : float
        β, rad.
    radius_m : float
        Chordal mean radius r, m.
    ratio, efficiency : float
        i and η.

    Returns
    -------
    float
        Nm per kg.
    """
    return (
        G * (mu * math.cos(incline_rad) + math.sin(incline_rad)) * radius_m / (ratio * efficiency)
    )


def two_mass_frequency_hz(
    *,
    drive_inertia_kgm2: float,
    ratio: float,
    radius_m: float,
    belt_mass_kg: float,
    stiffness_n_m: float,
) -> float:
    """Belt mode of the two-mass model, ``f = √(k·(1/m₁ + 1/m₂))/(2π)``, Hz.

    ``m₁ = J_drive·i²/r²`` is the drive side seen as a mass at the belt and
    ``m₂`` the belt-side mass. ``√(k/m₂)/(2π)`` would hold only with the
    drive side locked.

    Parameters
    ----------
    drive_inertia_kgm2 : float
        J_motor + J_gear, kg·m².
    ratio : float
        Gear ratio i.
    radius_m : float
        Chordal mean radius r, m.
    belt_mass_kg : float
        m₂ = belt + tray + payload, kg.
    stiffness_n_m : float
        Belt stiffness k, N/m.

    Returns
    -------
    float
        f, Hz.
    """
    m1 = drive_inertia_kgm2 * (ratio / radius_m) ** 2
    return math.sqrt(stiffness_n_m * (1.0 / m1 + 1.0 / belt_mass_kg)) / (2.0 * math.pi)
