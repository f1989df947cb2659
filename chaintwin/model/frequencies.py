"""Characteristic frequencies and orders of a conveyor, and where a scope sees them.

A table of the lines a spectrum of the motor torque (or speed) may hold,
computed from the profile alone (docs/design.md, section 3, "Spectra"):

==========================  ===========  =========================================
name                        kind         order (per motor revolution)
==========================  ===========  =========================================
``rotor``                   shaft        1 (also stage 1's input shaft)
``stage<s>_mesh``           mesh         pinion teeth × order of stage s's input
``stage<s>_shaft``          shaft        order of stage s's input shaft, s ≥ 2
``output_shaft``            shaft        1/i
``sprocket_tooth_pass``     tooth_pass   z/i
``belt_revolution``         belt         (2π·r/i)/(2L + π·d)
``belt_mode_<n>``           structural   None: does not scale with speed
``two_mass_mode``           structural   None
``lateral_mode_<n>``        structural   None
==========================  ===========  =========================================

Kinematics
----------
* The gear stages' tooth counts (``gear.stages``, motor side first, each
  ``(pinion, gear)``) give every shaft's and mesh's order exactly. When they
  are given, the kinematic ratio i is their product ``Π(gear/pinion)``: the
  teeth are exact integers while ``gear.ratio`` is a rounded nameplate value
  (the profile accepts up to 2 % between them). Without stages, i is
  ``gear.ratio`` and only the output shaft is listed.
* The belt moves on average by the chordal mean radius r = R·sin(π/z)/(π/z)
  per sprocket radian (R when z is unknown), so the belt speed is
  v = ω·r/i and one belt revolution takes ``loop_length / v``.

Natural frequencies (structural lines)
--------------------------------------
Both use the belt stiffness k (N/m) of
:meth:`~chaintwin.read.profile.ConveyorProfile.belt_stiffness_n_m`:
``model.belt_stiffness_n_m`` when given, else E·A/L with L the conveying
length. This table may read the profile's ``model:`` section for that, unlike
identification: it only places bands, it fits nothing.

* ``belt_mode_<n>``: longitudinal modes of the carrying strand as a uniform
  bar of length L, held at both sprockets, with axial stiffness E·A = k·L and
  the strand's mass ``m_c = q·L + m_t + m_p`` (the tray and the payload
  smeared along the strand). The wave speed is c = √(E·A/(m_c/L)), so
  ``f_n = n·c/(2L) = (n/2)·√(k/m_c)``. A point load lowers the modes
  differently from a smeared one: take these as the places of bands, a few
  percent to some ten percent off, not as exact lines.
* ``two_mass_mode``: the elastic two-mass model of docs/design.md, section 2,
  ``f = √(k·(1/m₁ + 1/m₂))/(2π)`` with the drive side seen as a mass at the
  belt, ``m₁ = (J_motor + J_gear)·i²/r²``, and the belt side
  ``m₂ = m_b + m_t + m_p``.

Lines that cannot be computed are left out: the stage lines when
``gear.stages`` is not given, the tooth-pass line when ``sprocket.teeth`` is
not given, and the structural lines when the belt stiffness is unknown (no
``model.belt_stiffness_n_m`` and no ``youngs_modulus_pa`` with
``cross_section_m2``).

* ``lateral_mode_<n>``: transverse (string) modes of a free strand of length
  L (``belt.length_m``) under the static pretension T (``belt.tension_n``)
  with the belt's mass per metre m' (``belt.mass_per_m_kg``; the free strand
  carries no trays or payload): ``f_n = n/(2L)·√(T/m')``. They need the
  tension: without ``belt.tension_n`` they are left out and
  :func:`lateral_modes_note` says so.

Aliasing
--------
Drive scopes sample without an anti-alias filter, so a line at f appears at
``fold_frequency(f, Ts)``: f folded about the Nyquist frequency fs/2
(fs = 1/Ts) repeatedly into [0, fs/2].
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
import numpy.typing as npt

from chaintwin.errors import EstimationError, ModelError
from chaintwin.read.profile import ConveyorProfile

__all__ = [
    "SHAFT_HARMONICS",
    "CharacteristicLine",
    "LineKind",
    "apparent_order",
    "apparent_orders",
    "characteristic_lines",
    "characteristic_orders",
    "characteristic_table",
    "fold_frequencies",
    "fold_frequency",
    "known_line_orders",
    "lateral_mode_hz",
    "lateral_modes_note",
    "line_orders",
    "shaft_orders",
]

SHAFT_HARMONICS = 8
"""Harmonics of a shaft order a spectrum is looked at for (the ``comb_`` features)."""

LineKind = Literal["shaft", "mesh", "tooth_pass", "belt", "structural"]

_RPM_TO_HZ = 1.0 / 60.0


def _check_sample_time(sample_time_s: float) -> float:
    ts = float(sample_time_s)
    if not math.isfinite(ts) or ts <= 0.0:
        raise ModelError(
            f"sample time {sample_time_s!r} s is not a positive number; give the scope's "
            "sample time in seconds (e.g. 0.006)"
        )
    return ts


def fold_frequency(f_hz: float, sample_time_s: float) -> float:
    """Where a line shows up when sampled every ``sample_time_s`` without anti-alias filter.

    The frequency is folded about the Nyquist frequency ``fs/2`` (``fs = 1/Ts``)
    as often as needed to land in ``[0, fs/2]``: ``|f|`` modulo fs, mirrored
    about fs/2 when above it. A frequency at or below the Nyquist frequency is
    returned unchanged.

    Parameters
    ----------
    f_hz : float
        The line's true frequency, Hz (the sign is ignored).
    sample_time_s : float
        The scope's sample time Ts, s.

    Returns
    -------
    float
        The apparent frequency, Hz, in ``[0, 0.5/Ts]``.

    Raises
    ------
    ModelError
        When the frequency is not finite or the sample time is not positive.

    Examples
    --------
    >>> round(fold_frequency(100.0, 0.006), 3)
    66.667
    >>> round(fold_frequency(100.0, 0.012), 3)
    16.667
    """
    ts = _check_sample_time(sample_time_s)
    f = abs(float(f_hz))
    if not math.isfinite(f):
        raise ModelError(f"frequency {f_hz!r} Hz is not finite; cannot fold it")
    return float(fold_frequencies(f, ts))


def fold_frequencies(f_hz: npt.ArrayLike, sample_time_s: float) -> npt.NDArray[np.float64]:
    """:func:`fold_frequency` of many frequencies at once (the same arithmetic).

    Parameters
    ----------
    f_hz : array_like
        True frequencies, Hz (the sign is ignored).
    sample_time_s : float
        The scope's sample time Ts, s.

    Returns
    -------
    ndarray
        The apparent frequencies, Hz, each in ``[0, 0.5/Ts]``.

    Raises
    ------
    ModelError
        When a frequency is not finite or the sample time is not positive.
    """
    ts = _check_sample_time(sample_time_s)
    f = np.abs(np.asarray(f_hz, dtype=np.float64))
    if not np.isfinite(f).all():
        raise ModelError("a frequency is not finite; cannot fold it")
    # in cycles per sample, so that the result is exactly within [0, 0.5]/Ts
    cycles = np.fmod(f * ts, 1.0)
    folded = np.where(cycles > 0.5, 1.0 - cycles, cycles) / ts
    return np.where(f <= 0.5 / ts, f, folded)


@dataclass(frozen=True, slots=True)
class CharacteristicLine:
    """One characteristic line of a conveyor at a given motor speed.

    Parameters
    ----------
    name : str
        ``rotor``, ``stage<s>_mesh``, ``stage<s>_shaft``, ``output_shaft``,
        ``sprocket_tooth_pass``, ``belt_revolution``, ``belt_mode_<n>`` or
        ``two_mass_mode``.
    kind : {"shaft", "mesh", "tooth_pass", "belt", "structural"}
        What produces the line.
    order : float or None
        Line frequency per motor revolution (dimensionless); None for the
        structural modes, which do not scale with speed.
    frequency_hz : float
        The line's frequency at the given motor speed, Hz.
    """

    name: str
    kind: LineKind
    order: float | None
    frequency_hz: float

    def apparent_hz(self, sample_time_s: float) -> float:
        """Where the line appears in a scope sampled every ``sample_time_s``, Hz.

        See :func:`fold_frequency`: no anti-alias filter, folded into ``[0, fs/2]``.
        """
        return fold_frequency(self.frequency_hz, sample_time_s)

    def aliased(self, sample_time_s: float) -> bool:
        """True when the line lies above the Nyquist frequency ``0.5/sample_time_s``."""
        return self.frequency_hz > 0.5 / _check_sample_time(sample_time_s)


def _kinematic_ratio(profile: ConveyorProfile) -> float:
    """Motor over output-shaft speed: the tooth-count product when stages are given."""
    return profile.kinematic_ratio


def characteristic_orders(profile: ConveyorProfile) -> dict[str, float]:
    """Orders of the speed-locked lines, per motor revolution.

    For order analysis (torque resampled to equal steps of motor angle): the
    rotor, each gear stage's mesh and shaft, the output shaft, the sprocket
    tooth pass and the belt revolution, in that order (see the module
    docstring for the formulas and which lines are left out).

    Parameters
    ----------
    profile : ConveyorProfile
        The conveyor.

    Returns
    -------
    dict of str to float
        Line name to order (dimensionless: events per motor revolution).
    """
    orders: dict[str, float] = {"rotor": 1.0}
    stages = profile.gear.stages
    if stages:
        shaft = 1.0
        for s, (pinion, gear) in enumerate(stages, start=1):
            if s > 1:
                orders[f"stage{s}_shaft"] = shaft
            orders[f"stage{s}_mesh"] = pinion * shaft
            shaft *= pinion / gear
    ratio = _kinematic_ratio(profile)
    out = 1.0 / ratio
    orders["output_shaft"] = out
    if profile.sprocket.teeth is not None:
        orders["sprocket_tooth_pass"] = profile.sprocket.teeth * out
    orders["belt_revolution"] = (
        out * 2.0 * math.pi * profile.chordal_radius_m / (profile.loop_length_m)
    )
    return orders


_KINDS: dict[str, LineKind] = {
    "rotor": "shaft",
    "output_shaft": "shaft",
    "sprocket_tooth_pass": "tooth_pass",
    "belt_revolution": "belt",
}


def _kind_of(name: str) -> LineKind:
    if name in _KINDS:
        return _KINDS[name]
    return "mesh" if name.endswith("_mesh") else "shaft"


def lateral_mode_hz(profile: ConveyorProfile, n: int = 1) -> float | None:
    """The n-th transverse (string) mode of a free strand, Hz; None without a tension.

    ``f_n = n/(2L)·√(T/m')`` with L = ``belt.length_m`` (m), T =
    ``belt.tension_n`` (N) and m' = ``belt.mass_per_m_kg`` (kg/m).

    Raises
    ------
    ModelError
        When ``n`` is not a whole number ≥ 1.
    """
    if n < 1:
        raise ModelError(f"lateral mode number n={n} must be ≥ 1")
    tension = profile.belt.tension_n
    if tension is None:
        return None
    return n / (2.0 * profile.belt.length_m) * math.sqrt(tension / profile.belt.mass_per_m_kg)


def lateral_modes_note(profile: ConveyorProfile) -> str | None:
    """Why the lateral modes are left out (no ``belt.tension_n``), or None when listed."""
    if profile.belt.tension_n is not None:
        return None
    return (
        f"profile '{profile.id}': no belt.tension_n, so the lateral (string) modes of the "
        "free strands are left out; give the static pretension in N to list them"
    )


def characteristic_lines(
    profile: ConveyorProfile,
    motor_speed_rpm: float,
    *,
    payload_kg: float = 0.0,
    belt_modes: int = 3,
) -> list[CharacteristicLine]:
    """Characteristic lines of a conveyor at a motor speed.

    Speed-locked lines first (motor to belt, as :func:`characteristic_orders`),
    then the structural modes; see the module docstring for every formula and
    for which lines are left out when the profile lacks the data.

    Parameters
    ----------
    profile : ConveyorProfile
        The conveyor.
    motor_speed_rpm : float
        Motor speed, rpm (the sign is ignored).
    payload_kg : float
        Payload on the belt, kg; moves the structural modes only.
    belt_modes : int
        How many longitudinal belt modes, and lateral modes when
        ``belt.tension_n`` is given, to list (0 for none).

    Returns
    -------
    list of CharacteristicLine

    Raises
    ------
    ModelError
        When the speed is not finite, or the payload or ``belt_modes`` is negative.
    """
    speed = float(motor_speed_rpm)
    if not math.isfinite(speed):
        raise ModelError(f"motor speed {motor_speed_rpm!r} rpm is not finite; give a speed")
    if not math.isfinite(payload_kg) or payload_kg < 0.0:
        raise ModelError(f"payload {payload_kg!r} kg must be a finite number ≥ 0")
    if belt_modes < 0:
        raise ModelError(f"belt_modes={belt_modes} must be ≥ 0")
    rotor_hz = abs(speed) * _RPM_TO_HZ

    lines = [
        CharacteristicLine(name, _kind_of(name), order, order * rotor_hz)
        for name, order in characteristic_orders(profile).items()
    ]
    for n in range(1, belt_modes + 1):
        f_lateral = lateral_mode_hz(profile, n)
        if f_lateral is not None:
            lines.append(CharacteristicLine(f"lateral_mode_{n}", "structural", None, f_lateral))

    k = profile.belt_stiffness_n_m()
    if k is None:
        return lines
    strand_mass = (
        profile.belt.mass_per_m_kg * profile.belt.length_m + profile.tray_mass_kg + payload_kg
    )
    for n in range(1, belt_modes + 1):
        lines.append(
            CharacteristicLine(
                f"belt_mode_{n}", "structural", None, 0.5 * n * math.sqrt(k / strand_mass)
            )
        )
    ratio = _kinematic_ratio(profile)
    r = profile.chordal_radius_m
    drive_mass = (profile.motor.inertia_kgm2 + profile.gear.inertia_kgm2) * ratio**2 / r**2
    belt_side_mass = profile.moving_mass_kg(payload_kg)
    two_mass_hz = math.sqrt(k * (1.0 / drive_mass + 1.0 / belt_side_mass)) / (2.0 * math.pi)
    lines.append(CharacteristicLine("two_mass_mode", "structural", None, two_mass_hz))
    return lines


def characteristic_table(
    profile: ConveyorProfile,
    motor_speed_rpm: float,
    sample_time_s: float,
    *,
    payload_kg: float = 0.0,
    belt_modes: int = 3,
) -> list[dict[str, object]]:
    """The characteristic lines as JSON-ready rows, with where a scope shows them.

    Parameters
    ----------
    profile : ConveyorProfile
        The conveyor.
    motor_speed_rpm : float
        Motor speed, rpm.
    sample_time_s : float
        The scope's sample time, s (no anti-alias filter assumed).
    payload_kg : float
        Payload on the belt, kg.
    belt_modes : int
        How many longitudinal belt modes to list.

    Returns
    -------
    list of dict
        One row per line with ``name``, ``kind``, ``order`` (None for
        structural modes), ``frequency_hz``, ``apparent_hz`` and ``aliased``
        (True when the line lies above the Nyquist frequency).
    """
    ts = _check_sample_time(sample_time_s)
    return [
        {
            "name": line.name,
            "kind": line.kind,
            "order": line.order,
            "frequency_hz": line.frequency_hz,
            "apparent_hz": line.apparent_hz(ts),
            "aliased": line.aliased(ts),
        }
        for line in characteristic_lines(
            profile, motor_speed_rpm, payload_kg=payload_kg, belt_modes=belt_modes
        )
    ]


# ------------------------------------------------------------------ where lines appear
def apparent_order(order: float, speed_rpm: float, sample_time_s: float) -> float:
    """Where a line at ``order`` appears in a scope's spectrum, as an order.

    ``fold_frequency(order·f_rot, Ts) / f_rot`` with ``f_rot = |speed_rpm|/60``:
    a line above the Nyquist frequency ``0.5/Ts`` folds back (drive scopes
    have no anti-alias filter). Multiplied by ``f_rot`` it is the apparent
    frequency, Hz.

    Parameters
    ----------
    order : float
        The line's true order, cycles per motor revolution.
    speed_rpm : float
        Motor speed, rpm (the sign is ignored).
    sample_time_s : float
        The scope's sample time Ts, s.

    Returns
    -------
    float
        The apparent order, in ``[0, 30/(|speed_rpm|·Ts)]``.

    Raises
    ------
    EstimationError
        When the speed is zero or not finite.
    ModelError
        When the sample time is not positive or the order not finite.

    Examples
    --------
    A bearing line at order 3.57 and 1415 rpm is at 84.19 Hz, above the
    83.33 Hz Nyquist frequency of a 6 ms scope; it appears at 82.47 Hz:

    >>> round(apparent_order(3.57, 1415.0, 0.006), 4)
    3.4971
    """
    rot_hz = _rotation_hz(speed_rpm)
    return fold_frequency(order * rot_hz, sample_time_s) / rot_hz


def _rotation_hz(speed_rpm: float) -> float:
    """Motor revolutions per second, Hz, of a speed in rpm (the sign ignored).

    Raises
    ------
    EstimationError
        When the speed is zero or not finite.
    """
    rot_hz = abs(float(speed_rpm)) / 60.0
    if not math.isfinite(rot_hz) or rot_hz == 0.0:
        raise EstimationError(f"motor speed {speed_rpm!r} rpm: no apparent order without rotation")
    return rot_hz


def apparent_orders(
    orders: npt.ArrayLike, speed_rpm: float, sample_time_s: float
) -> npt.NDArray[np.float64]:
    """:func:`apparent_order` of many orders at once, with the same arithmetic.

    Parameters
    ----------
    orders : array_like
        True orders, cycles per motor revolution.
    speed_rpm : float
        Motor speed, rpm (the sign is ignored).
    sample_time_s : float
        The scope's sample time Ts, s.

    Returns
    -------
    ndarray
        The apparent orders, equal to ``apparent_order`` of each.

    Raises
    ------
    EstimationError
        When the speed is zero or not finite.
    ModelError
        When the sample time is not positive or an order not finite.
    """
    rot_hz = _rotation_hz(speed_rpm)
    return fold_frequencies(np.asarray(orders, dtype=np.float64) * rot_hz, sample_time_s) / rot_hz


def line_orders(profile: ConveyorProfile) -> dict[str, float]:
    """The speed-locked lines looked at, by name: orders per motor revolution.

    :func:`~chaintwin.model.frequencies.characteristic_orders` plus the 2nd
    and 3rd harmonics of the sprocket tooth pass (the polygon effect is not
    sinusoidal) as ``sprocket_tooth_pass_h2`` and ``sprocket_tooth_pass_h3``.

    Parameters
    ----------
    profile : ConveyorProfile
        The conveyor.

    Returns
    -------
    dict of str to float
        Line name to order.
    """
    orders = characteristic_orders(profile)
    tooth_pass = orders.get("sprocket_tooth_pass")
    if tooth_pass is not None:
        orders["sprocket_tooth_pass_h2"] = 2.0 * tooth_pass
        orders["sprocket_tooth_pass_h3"] = 3.0 * tooth_pass
    return orders


def shaft_orders(profile: ConveyorProfile) -> dict[str, float]:
    """The rotor's and each gear stage's shaft order, by name (cycles per motor revolution)."""
    return {
        name: order
        for name, order in characteristic_orders(profile).items()
        if name == "rotor" or (name.startswith("stage") and name.endswith("_shaft"))
    }


def known_line_orders(profile: ConveyorProfile) -> list[float]:
    """Orders of every characteristic line and its harmonics a spectrum may hold.

    Shaft orders with :data:`SHAFT_HARMONICS` harmonics, meshes and the
    tooth pass with three; the output shaft and the belt revolution are too
    low to matter at a scope's resolution.
    """
    out: list[float] = []
    for name, order in characteristic_orders(profile).items():
        if name in ("output_shaft", "belt_revolution"):
            continue
        harmonics = SHAFT_HARMONICS if name == "rotor" or name.endswith("_shaft") else 3
        out += [h * order for h in range(1, harmonics + 1)]
    return out
