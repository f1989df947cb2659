"""Closed-form conveyor physics and the characteristic frequency/order table."""

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

__all__ = [
    "CharacteristicLine",
    "G",
    "belt_force_n",
    "characteristic_lines",
    "characteristic_orders",
    "characteristic_table",
    "chordal_radius_m",
    "fold_frequency",
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
