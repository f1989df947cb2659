"""Conveyor physics: closed-form relations, the rigid model on recordings, its window
integrals, and the characteristic frequency/order table."""

import typing as _typing

from chaintwin._lazy import lazy_getattr

if _typing.TYPE_CHECKING:
    from chaintwin.model.frequencies import (
        CharacteristicLine,
        characteristic_lines,
        characteristic_orders,
        characteristic_table,
        fold_frequency,
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
    from chaintwin.physics import (
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

_LAZY: dict[str, str] = {
    "CharacteristicLine": "chaintwin.model.frequencies",
    "G": "chaintwin.physics",
    "PARAMETER_NAMES": "chaintwin.model.rigid",
    "RigidParameters": "chaintwin.model.rigid",
    "WindowIntegrals": "chaintwin.model.windows",
    "acceleration": "chaintwin.model.rigid",
    "belt_force_n": "chaintwin.physics",
    "characteristic_lines": "chaintwin.model.frequencies",
    "characteristic_orders": "chaintwin.model.frequencies",
    "characteristic_table": "chaintwin.model.frequencies",
    "chordal_radius_m": "chaintwin.physics",
    "fold_frequency": "chaintwin.model.frequencies",
    "gear_factor": "chaintwin.physics",
    "gear_input_torque_nm": "chaintwin.model.rigid",
    "incline_terms": "chaintwin.model.rigid",
    "load_torque_nm": "chaintwin.physics",
    "loss_torque_nm": "chaintwin.physics",
    "model_torque": "chaintwin.model.rigid",
    "motoring": "chaintwin.physics",
    "motoring_mask": "chaintwin.model.rigid",
    "payload_sensitivity_nm_kg": "chaintwin.physics",
    "polygon_radius_m": "chaintwin.physics",
    "reflected_inertia_kgm2": "chaintwin.physics",
    "steady_torque_nm": "chaintwin.physics",
    "two_mass_frequency_hz": "chaintwin.physics",
    "window_integrals": "chaintwin.model.windows",
}
"""Module of each public name (imported on first use, PEP 562)."""

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


__getattr__ = lazy_getattr(__name__, _LAZY)
