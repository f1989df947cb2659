"""The transport loss factor: a conveyor's performance index.

Definition (docs/design.md, section 3)::

    f_T = W / (m_p · g · s)

* ``W``: the net mechanical work delivered at the sprocket to the belt over
  the recording, ``∫F_sprocket·v dt``; the gear unit's and the motor's
  losses are excluded. From the drive's data: the torque that reaches the
  gear input, ``Q = T_m − J_d·α − T_loss(ω)`` (motor torque less the drive's
  own inertia and the identified losses), passes the gear with efficiency η
  in the direction the power flows, so the sprocket delivers ``η·Q·ω`` while
  motoring and ``Q·ω/η`` while the belt drives the motor.
* ``m_p``: the payload (estimated by weighing, or known), kg;
  ``g = 9.81 m/s²``.
* ``s``: the distance the belt moved, ``∫|ω|·r/i dt`` with r the chordal mean
  radius, m.

Dimensionless. It is undefined (None) for a payload under 1 kg: dividing by
a near-zero payload measures nothing. Hand case: flat conveyor at constant
speed, ``W = μ·g·(m_b + m_t + m_p)·s``, so ``f_T = μ·(m_b + m_t + m_p)/m_p``.

Two definitions
---------------
:func:`transport_loss_factor` is the sprocket-work definition above (the
gear's and motor's losses left out: what the belt itself costs).
:func:`motor_shaft_transport_loss_factor` takes ``W`` as the work at the
motor shaft, ``∫T_m·ω dt`` (motor torque times motor speed), as the published
definition reads: the gear losses and the drive's own inertia are then in it
(the inertia's share returns while braking, so over a whole move it nets
out). Both are labelled wherever they are shown.

The published benchmark (:data:`PUBLISHED_TLF`, about 0.01-0.02 for this kind
of conveyor) is not comparable with either: flat and at constant speed both
are at least μ ≈ 0.23 of the same source whatever the load
(:data:`PUBLISHED_TLF_NOTE`); the code follows the physics and shows the
published range beside its numbers for reference only.
"""

from __future__ import annotations

import numpy as np

from chaintwin.model.rigid import RigidParameters, gear_input_torque_nm
from chaintwin.physics import gear_factor
from chaintwin.read.profile import ConveyorProfile
from chaintwin.read.recording import Recording
from chaintwin.units import G

__all__ = [
    "MIN_PAYLOAD_KG",
    "PUBLISHED_TLF",
    "PUBLISHED_TLF_NOTE",
    "TLF_DEFINITIONS",
    "belt_travel_m",
    "motor_shaft_transport_loss_factor",
    "motor_shaft_work",
    "sprocket_work_and_distance",
    "transport_loss_factor",
]

MIN_PAYLOAD_KG = 1.0
"""Below this payload the transport loss factor is undefined, kg."""

PUBLISHED_TLF: tuple[float, float] = (0.01, 0.02)
"""The published transport loss factors for this kind of conveyor (low, high), -."""

PUBLISHED_TLF_NOTE = (
    "not comparable: flat and at constant speed both definitions are at least the rail "
    "friction coefficient (mu = 0.23 in the same source) whatever the load, so the published "
    "0.01-0.02 must rest on a normalisation the source does not give"
)
"""Why :data:`PUBLISHED_TLF` is shown beside the computed factors, not compared with them."""

TLF_DEFINITIONS: dict[str, str] = {
    "tlf": "sprocket work: net work at the sprocket over payload weight times belt travel",
    "tlf_motor_shaft": "motor-shaft work: motor torque times speed over payload weight times "
    "belt travel (the published definition; gear losses included)",
}
"""The label of each transport loss factor, by its JSON name."""


def sprocket_work_and_distance(
    recording: Recording, profile: ConveyorProfile, params: RigidParameters
) -> tuple[float, float]:
    """Net work at the sprocket (J) and belt travel (m) over a recording.

    Parameters
    ----------
    recording : Recording
        Speed and actual torque.
    profile : ConveyorProfile
        r, i, η.
    params : RigidParameters
        Identified J_d and losses.
    """
    t = recording.time
    w = recording.speed
    q = gear_input_torque_nm(recording, drive_inertia_kgm2=params["J_d"], losses=params.losses)
    p_in = q * w
    eta = profile.gear.efficiency
    # the gear passes η of the power on while motoring, 1/η of it when the belt drives
    p_out = p_in / np.where(
        p_in >= 0.0, gear_factor(eta, motoring=True), gear_factor(eta, motoring=False)
    )
    h = np.diff(t)
    work = float(np.sum(0.5 * (p_out[1:] + p_out[:-1]) * h))
    return work, belt_travel_m(recording, profile)


def belt_travel_m(recording: Recording, profile: ConveyorProfile) -> float:
    """Belt travel ``∫|ω|·r/i dt`` over the recording, m."""
    speed = np.abs(recording.speed) * profile.chordal_radius_m / profile.kinematic_ratio
    return float(np.sum(0.5 * (speed[1:] + speed[:-1]) * np.diff(recording.time)))


def motor_shaft_work(recording: Recording) -> float:
    """Work at the motor shaft ``∫T_m·ω dt`` over a recording, J (trapezoid rule)."""
    p = recording.torque * recording.speed
    return float(np.sum(0.5 * (p[1:] + p[:-1]) * np.diff(recording.time)))


def motor_shaft_transport_loss_factor(
    recording: Recording, profile: ConveyorProfile, payload_kg: float | None
) -> float | None:
    """Transport loss factor from the motor-shaft work, ``∫T_m·ω dt/(m_p·g·s)``, or None.

    The published definition as it reads (see the module notes); None under
    :data:`MIN_PAYLOAD_KG` or without belt travel.

    Parameters
    ----------
    recording : Recording
        Speed (rad/s) and actual torque (Nm).
    profile : ConveyorProfile
        r and i, for the belt travel.
    payload_kg : float or None
        Payload, kg.
    """
    if payload_kg is None or payload_kg < MIN_PAYLOAD_KG:
        return None
    distance = belt_travel_m(recording, profile)
    if distance <= 0.0:
        return None
    return motor_shaft_work(recording) / (payload_kg * G * distance)


def transport_loss_factor(
    recording: Recording,
    profile: ConveyorProfile,
    params: RigidParameters,
    payload_kg: float | None,
) -> float | None:
    """Transport loss factor f_T = W/(m_p·g·s), or None (payload under 1 kg, no travel).

    Parameters
    ----------
    recording : Recording
        The recording.
    profile : ConveyorProfile
        r, i, η.
    params : RigidParameters
        Identified J_d and losses.
    payload_kg : float or None
        Payload, kg.
    """
    if payload_kg is None or payload_kg < MIN_PAYLOAD_KG:
        return None
    work, distance = sprocket_work_and_distance(recording, profile, params)
    if distance <= 0.0:
        return None
    return work / (payload_kg * G * distance)
