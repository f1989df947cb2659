"""Both transport loss factors (sprocket work, motor-shaft work) against hand calculations."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import REFERENCE_PROFILE

from chaintwin.model.rigid import PARAMETER_NAMES, RigidParameters
from chaintwin.read.profile import load_profile
from chaintwin.simulate import Realism, run_virtual
from chaintwin.units import G
from chaintwin.weigh.tlf import (
    PUBLISHED_TLF,
    PUBLISHED_TLF_NOTE,
    TLF_DEFINITIONS,
    motor_shaft_transport_loss_factor,
    motor_shaft_work,
    transport_loss_factor,
)

PROFILE = load_profile(REFERENCE_PROFILE)
MODEL = PROFILE.model
assert MODEL is not None
PAYLOAD_KG = 60.0


def _truth() -> RigidParameters:
    assert MODEL is not None
    values = {
        "J_d": PROFILE.motor.inertia_kgm2 + PROFILE.gear.inertia_kgm2,
        "mu": MODEL.friction,
        "BmA": MODEL.loss_constant_nm,
        "BmB": MODEL.loss_viscous_nm_s_rad,
        "BmC": MODEL.loss_quadratic_nm_s2_rad2,
    }
    n = len(PARAMETER_NAMES)
    return RigidParameters(np.array([values[k] for k in PARAMETER_NAMES]), np.zeros((n, n)))


def test_both_definitions_on_the_rigid_conveyor() -> None:
    run = run_virtual(PROFILE, payload_kg=PAYLOAD_KG, realism=Realism.off(), seed=3)
    rec = run.recording
    sprocket = transport_loss_factor(rec, PROFILE, _truth(), PAYLOAD_KG)
    shaft = motor_shaft_transport_loss_factor(rec, PROFILE, PAYLOAD_KG)
    assert sprocket is not None and shaft is not None
    # flat, nearly constant speed: f_T = mu (m_b + m_t + m_p) / m_p at the sprocket
    hand = MODEL.friction * PROFILE.moving_mass_kg(PAYLOAD_KG) / PAYLOAD_KG
    assert sprocket == pytest.approx(hand, rel=0.02)
    # at the motor shaft the gear passes eta of the power on and the gear losses add:
    # W_shaft = W_sprocket / eta + ∫T_loss·ω dt (the inertia's work nets out over the move)
    w = rec.speed
    loss = MODEL.loss_constant_nm + MODEL.loss_viscous_nm_s_rad * np.abs(w)
    loss = loss + MODEL.loss_quadratic_nm_s2_rad2 * w * w
    p = loss * np.abs(w)
    loss_work = float(np.sum(0.5 * (p[1:] + p[:-1]) * np.diff(rec.time)))
    speed = np.abs(w) * PROFILE.chordal_radius_m / PROFILE.kinematic_ratio
    travel = float(np.sum(0.5 * (speed[1:] + speed[:-1]) * np.diff(rec.time)))
    expected = sprocket / PROFILE.gear.efficiency + loss_work / (PAYLOAD_KG * G * travel)
    assert shaft == pytest.approx(expected, rel=0.01)
    assert shaft > sprocket
    assert motor_shaft_work(rec) == pytest.approx(shaft * PAYLOAD_KG * G * travel)
    # under 1 kg neither is defined
    assert motor_shaft_transport_loss_factor(rec, PROFILE, 0.5) is None


def test_the_published_value_is_labelled_not_compared() -> None:
    low, high = PUBLISHED_TLF
    # the physics' floor (flat, steady): mu, whatever the load, far above the published range
    assert MODEL.friction > 10 * high
    assert "not comparable" in PUBLISHED_TLF_NOTE
    assert set(TLF_DEFINITIONS) == {"tlf", "tlf_motor_shaft"}
    assert low < high
