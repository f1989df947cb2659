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

Note: the published values for this kind of conveyor (about 0.01-0.02) are
not consistent with μ ≈ 0.23 in the same source; this implementation follows
the physics.
"""

from __future__ import annotations

import numpy as np

from chaintwin.model.physics import gear_factor
from chaintwin.model.rigid import RigidParameters, gear_input_torque_nm
from chaintwin.read.profile import ConveyorProfile
from chaintwin.read.recording import Recording
from chaintwin.units import G

__all__ = ["MIN_PAYLOAD_KG", "sprocket_work_and_distance", "transport_loss_factor"]

MIN_PAYLOAD_KG = 1.0
"""Below this payload the transport loss factor is undefined, kg."""


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
    speed = np.abs(w) * profile.chordal_radius_m / profile.kinematic_ratio
    distance = float(np.sum(0.5 * (speed[1:] + speed[:-1]) * h))
    return work, distance


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
