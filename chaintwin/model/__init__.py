"""Conveyor physics: closed-form relations, the rigid model on recordings, its window
integrals, and the characteristic frequency/order table."""

from chaintwin.model.frequencies import (
    CharacteristicLine,
    characteristic_lines,
    characteristic_orders,
    characteristic_table,
    fold_frequency,
)
from chaintwin.model.physics import (
    G,
    belt_force_n,
    chordal_radius_m,
    gear_factor,
    load_torque_nm,
    loss_torque_nm,
    motoring,
    payload_sensitivity_nm_kg,
    polygon_radius_m,
    reflected_inertia_kgm2,
    steady_torque_nm,
    two_mass_frequency_hz,
)
from chaintwin.model.rigid import (
    PARAMETER_NAMES,
    RigidParameters,
    acceleration,
    gear_input_torque_nm,
    incline_terms,
    model_torque,
    motoring_mask,
)
from chaintwin.model.windows import WindowIntegrals, window_integrals

__all__ = [
    "PARAMETER_NAMES",
    "CharacteristicLine",
    "G",
    "RigidParameters",
    "WindowIntegrals",
    "acceleration",
    "belt_force_n",
    "characteristic_lines",
    "characteristic_orders",
    "characteristic_table",
    "chordal_radius_m",
    "fold_frequency",
    "gear_factor",
    "gear_input_torque_nm",
    "incline_terms",
    "load_torque_nm",
    "loss_torque_nm",
    "model_torque",
    "motoring",
    "motoring_mask",
    "payload_sensitivity_nm_kg",
    "polygon_radius_m",
    "reflected_inertia_kgm2",
    "steady_torque_nm",
    "two_mass_frequency_hz",
    "window_integrals",
]
