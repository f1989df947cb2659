"""The rigid model of the conveyor, evaluated on a recording: written once, used everywhere.

The motor shaft sees (docs/design.md, section 2)::

    T_m = J_d·α + g_f·(F + M·a) + T_loss(ω)

    F      = μ·g·cosβ·M·sign(ω) + g·sinβ·(m_t + m_p)      belt resistance, N
    T_loss = BmA·sign(ω) + BmB·ω + BmC·ω·|ω|                gear and motor losses, Nm
    a      = α·r/i                                          belt acceleration, m/s²
    g_f    = r/(i·η) motoring, r·η/i when the belt drives the motor, m

with M = m_b + m_t + m_p the moving mass, r the sprocket's chordal mean
radius, i the gear ratio and η the gear efficiency. Identification
(:mod:`chaintwin.model.windows`, :mod:`chaintwin.identify`), weighing and the
transport loss factor (:mod:`chaintwin.weigh`), the condition features and
residuals (:mod:`chaintwin.diagnose`) and the report all evaluate it through
this module, so each rule below exists once:

* **Acceleration** α: :func:`acceleration`, the Savitzky-Golay derivative of
  the measured speed over about 25 ms (:data:`DERIVATIVE_WINDOW_S`, at least
  5 samples).
* **Power flow**: :func:`motoring_mask`. Motoring (power motor → belt) where
  the torque that reaches the gear input, ``Q = T_m − J_d·α − T_loss``
  (:func:`gear_input_torque_nm`), moves with the motor: ``Q·ω ≥ 0``. The
  motor torque alone would not do: in a deceleration it is negative (the
  drive brakes its own rotor) while the gear still pushes the belt against
  its friction. The simulator decides the same case from its state, ``(F +
  M·a)·v ≥ 0`` (:func:`chaintwin.physics.motoring`): the two agree
  whenever the model holds, one needs the measured torque and the other the
  true force.
* **Standstill**: where ``|ω|`` is below 2 % of the recording's peak
  (:data:`STANDSTILL_SHARE`) the Coulomb terms (friction and BmA) are zero in
  :func:`model_torque`: at standstill Coulomb friction holds whatever the
  motor applies, and the sign of a speed that is only noise would put ± the
  full friction torque there.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from chaintwin._types import FloatArray
from chaintwin.errors import EstimationError
from chaintwin.physics import (
    belt_force_n,
    gear_factor,
    loss_torque_nm,
    reflected_inertia_kgm2,
)
from chaintwin.read.profile import ConveyorProfile
from chaintwin.read.recording import Recording
from chaintwin.units import G
from chaintwin.validate.filters import savgol

__all__ = [
    "DERIVATIVE_WINDOW_S",
    "PARAMETER_NAMES",
    "STANDSTILL_SHARE",
    "RigidParameters",
    "acceleration",
    "drive_inertia_at",
    "gear_input_torque_nm",
    "incline_terms",
    "model_torque",
    "motoring_mask",
]

PARAMETER_NAMES = ("J_d", "mu", "BmA", "BmB", "BmC")
"""The rigid model's parameters, in this order: drive inertia J_d (kg·m²),
friction coefficient μ (-), losses BmA (Nm), BmB (Nm·s/rad), BmC (Nm·s²/rad²)."""

DERIVATIVE_WINDOW_S = 0.025
"""Savitzky-Golay window for the acceleration, s (at least 5 samples, odd)."""

STANDSTILL_SHARE = 0.02
"""Below this share of the peak |ω| the Coulomb terms of :func:`model_torque` are zero."""


@dataclass(frozen=True, slots=True)
class RigidParameters:
    """Rigid-model parameters with their covariance.

    Parameters
    ----------
    values : FloatArray
        In the order of :data:`PARAMETER_NAMES`.
    covariance : FloatArray
        5 × 5 covariance (zero rows/columns for fixed parameters).
    fixed : tuple of str
        Parameters that were not fitted but set to a prior value.
    """

    values: FloatArray
    covariance: FloatArray
    fixed: tuple[str, ...] = ()

    def __getitem__(self, name: str) -> float:
        return float(self.values[PARAMETER_NAMES.index(name)])

    def stderr(self, name: str) -> float:
        """Standard error of a parameter (0 for a fixed one)."""
        k = PARAMETER_NAMES.index(name)
        return float(np.sqrt(max(self.covariance[k, k], 0.0)))

    def as_dict(self) -> dict[str, float]:
        """Name → value."""
        return {n: float(v) for n, v in zip(PARAMETER_NAMES, self.values, strict=True)}

    @property
    def losses(self) -> tuple[float, float, float]:
        """(BmA, BmB, BmC): Nm, Nm·s/rad, Nm·s²/rad²."""
        return self["BmA"], self["BmB"], self["BmC"]


Parameters = Mapping[str, float] | RigidParameters
"""Anything that maps the names of :data:`PARAMETER_NAMES` to values."""


def _parameter(parameters: Parameters, name: str) -> float:
    try:
        return float(parameters[name])
    except (KeyError, ValueError) as exc:
        raise EstimationError(
            f"the rigid model needs the parameters {', '.join(PARAMETER_NAMES)}; "
            f"'{name}' is missing"
        ) from exc


def incline_terms(profile: ConveyorProfile) -> tuple[float, float]:
    """Return (g·cosβ, g·sinβ) for the profile's incline β, m/s²."""
    beta = math.radians(profile.belt.incline_deg)
    return G * math.cos(beta), G * math.sin(beta)


def drive_inertia_at(profile: ConveyorProfile, drive_inertia_kgm2: float, mass_kg: float) -> float:
    """Inertia at the motor shaft while motoring, ``J_d + m·r²/(i²·η)``, kg·m².

    :func:`~chaintwin.physics.reflected_inertia_kgm2` with an identified
    drive inertia J_d (motor and gear together) in place of the profile's.

    Parameters
    ----------
    profile : ConveyorProfile
        r, i, η.
    drive_inertia_kgm2 : float
        J_d, kg·m².
    mass_kg : float
        Moving mass m (belt + tray + payload), kg.
    """
    return reflected_inertia_kgm2(
        motor_inertia_kgm2=drive_inertia_kgm2,
        gear_inertia_kgm2=0.0,
        moving_mass_kg=mass_kg,
        radius_m=profile.chordal_radius_m,
        ratio=profile.kinematic_ratio,
        efficiency=profile.gear.efficiency,
    )


def acceleration(recording: Recording) -> FloatArray:
    """Motor acceleration α, rad/s²: Savitzky-Golay derivative of the measured speed.

    Window about :data:`DERIVATIVE_WINDOW_S` (25 ms), at least 5 samples, odd,
    at most the recording's length; polynomial order 2; the end samples get
    the derivative of the fit to the first and last window. A time-based
    window keeps the smoothing the same at every sample time (5 samples at
    6 and 12 ms, 25 at 1 ms).

    Raises
    ------
    EstimationError
        With fewer than 3 samples.
    """
    cached: FloatArray | None = recording.memo.get("acceleration")
    if cached is not None:
        return cached
    n = recording.samples
    if n < 3:
        raise EstimationError(
            f"{recording.source}: {n} samples; at least 3 are needed to differentiate the speed"
        )
    dt = recording.sample_time_s
    win = max(5, round(DERIVATIVE_WINDOW_S / dt))
    win += 1 - win % 2  # odd
    win = min(win, n if n % 2 else n - 1)
    out: FloatArray = savgol(recording.speed, win, 2, deriv=1, delta=dt)
    # computed once per recording (the power-flow mask, both model torques and
    # the TLF ask for it); read-only, as every caller shares it
    out.setflags(write=False)
    recording.memo["acceleration"] = out
    return out


def gear_input_torque_nm(
    recording: Recording,
    *,
    drive_inertia_kgm2: float,
    losses: tuple[float, float, float] = (0.0, 0.0, 0.0),
    alpha: FloatArray | None = None,
    torque_channel: str = "torque",
) -> FloatArray:
    """Torque that reaches the gear input, ``Q = T_m − J_d·α − T_loss(ω)``, Nm.

    Parameters
    ----------
    recording : Recording
        Measured speed (rad/s) and torque (Nm).
    drive_inertia_kgm2 : float
        Motor + gear inertia J_d, kg·m².
    losses : (float, float, float)
        BmA (Nm), BmB (Nm·s/rad), BmC (Nm·s²/rad²).
    alpha : FloatArray, optional
        Acceleration, rad/s²; default :func:`acceleration`.
    torque_channel : str
        Torque channel used (``torque`` or ``torque_setpoint``).
    """
    w = recording.speed
    a = acceleration(recording) if alpha is None else alpha
    out: FloatArray = (
        recording.channels[torque_channel] - drive_inertia_kgm2 * a - loss_torque_nm(w, *losses)
    )
    return out


def motoring_mask(
    recording: Recording,
    *,
    drive_inertia_kgm2: float,
    losses: tuple[float, float, float] = (0.0, 0.0, 0.0),
    alpha: FloatArray | None = None,
    torque_channel: str = "torque",
) -> np.ndarray:
    """True where power flows motor → belt: ``Q·ω ≥ 0`` (see the module notes).

    Parameters are those of :func:`gear_input_torque_nm`.
    """
    q = gear_input_torque_nm(
        recording,
        drive_inertia_kgm2=drive_inertia_kgm2,
        losses=losses,
        alpha=alpha,
        torque_channel=torque_channel,
    )
    mask: np.ndarray = q * recording.speed >= 0.0
    return mask


def model_torque(
    recording: Recording,
    profile: ConveyorProfile,
    parameters: Parameters,
    payload_kg: float,
    *,
    tray_kg: float | None = None,
    motoring: np.ndarray | None = None,
    alpha: FloatArray | None = None,
) -> FloatArray:
    """Motor torque of the rigid model per sample, Nm (the equation of the module notes).

    Parameters
    ----------
    recording : Recording
        Measured speed (rad/s, motor side) and, for the default power-flow
        mask, torque (Nm).
    profile : ConveyorProfile
        Sprocket, gear (i, η), belt mass and incline; its ``model:`` section
        is not read.
    parameters : Mapping[str, float] or RigidParameters
        ``J_d``, ``mu``, ``BmA``, ``BmB``, ``BmC`` (:data:`PARAMETER_NAMES`),
        e.g. a :class:`~chaintwin.identify.calibration.Calibration`'s
        ``parameters``.
    payload_kg : float
        Payload on the belt, kg.
    tray_kg : float, optional
        Tray mass, kg; default the recording's ``metadata.tray_kg``, else the
        profile's ``tray_mass_kg``.
    motoring : np.ndarray of bool, optional
        Power-flow direction per sample (True: motor → belt); default
        :func:`motoring_mask` with the given J_d and losses.
    alpha : FloatArray, optional
        The recording's acceleration, rad/s², when the caller has it already;
        default :func:`acceleration`.

    Returns
    -------
    FloatArray
        Model motor torque, Nm, one value per sample.

    Raises
    ------
    EstimationError
        When a parameter is missing, the mask has the wrong length or the
        recording has fewer than 3 samples.
    """
    mu = _parameter(parameters, "mu")
    losses = (
        _parameter(parameters, "BmA"),
        _parameter(parameters, "BmB"),
        _parameter(parameters, "BmC"),
    )
    j_d = _parameter(parameters, "J_d")
    if tray_kg is None:
        tray_kg = recording.metadata.tray_kg
    if tray_kg is None:
        tray_kg = profile.tray_mass_kg

    w = recording.speed
    if alpha is None:
        alpha = acceleration(recording)
    if motoring is None:
        motoring = motoring_mask(recording, drive_inertia_kgm2=j_d, losses=losses, alpha=alpha)
    motoring = np.asarray(motoring, dtype=bool)
    if motoring.shape != w.shape:
        raise EstimationError(
            f"{recording.source}: motoring mask has shape {motoring.shape}, the recording {w.shape}"
        )

    r = profile.chordal_radius_m
    i = profile.kinematic_ratio
    eta = profile.gear.efficiency
    carried = tray_kg + payload_kg
    moving_mass = profile.belt_mass_kg + carried
    peak = float(np.max(np.abs(w))) if w.size else 0.0
    still = np.abs(w) < STANDSTILL_SHARE * peak
    direction = np.where(still, 0.0, np.sign(w))

    # F is linear in sign(v): split into its incline part (direction 0) and
    # its friction part per unit of direction
    def force(d: float) -> float:
        return belt_force_n(
            mu=mu,
            moving_mass_kg=moving_mass,
            carried_mass_kg=carried,
            incline_rad=profile.incline_rad,
            direction=d,
        )

    f_incline = force(0.0)
    f_friction = force(1.0) - f_incline
    belt_force = f_friction * direction + f_incline
    g_f = (r / i) * np.where(
        motoring, gear_factor(eta, motoring=True), gear_factor(eta, motoring=False)
    )
    belt_accel = alpha * (r / i)
    loss = loss_torque_nm(w, 0.0, losses[1], losses[2]) + losses[0] * direction
    out: FloatArray = j_d * alpha + g_f * (belt_force + moving_mass * belt_accel) + loss
    return out
