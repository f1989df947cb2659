"""Stage 3, identify: conveyor and drive parameters from recordings.

Estimators follow the scikit-learn contract (settings in ``__init__``,
``fit`` returns ``self``, fitted values end in ``_``). Identification never
reads a profile's ``model:`` section. Calibrating a conveyor (the fit checked
by weighing its recordings) is :mod:`chaintwin.calibrating`.
"""

import typing as _typing

from chaintwin._lazy import lazy_getattr

if _typing.TYPE_CHECKING:
    from chaintwin.identify.calibration import (
        Calibration,
        identification_profile,
        load_calibration,
        sensitivity_nm_per_kg,
    )
    from chaintwin.identify.output_error import OutputErrorFit
    from chaintwin.identify.regression import RigidModelRegression
    from chaintwin.identify.rls import RecursiveLeastSquares
    from chaintwin.identify.signatures import SignatureFit, fit_signatures
    from chaintwin.identify.torque_lag import (
        MAX_DELAY_CYCLES,
        TorqueLagEstimator,
        TorqueLagResult,
        identify_torque_lag,
        lag_gain,
        simulate_torque_lag,
    )

_LAZY: dict[str, str] = {
    "Calibration": "chaintwin.identify.calibration",
    "MAX_DELAY_CYCLES": "chaintwin.identify.torque_lag",
    "OutputErrorFit": "chaintwin.identify.output_error",
    "RecursiveLeastSquares": "chaintwin.identify.rls",
    "RigidModelRegression": "chaintwin.identify.regression",
    "SignatureFit": "chaintwin.identify.signatures",
    "TorqueLagEstimator": "chaintwin.identify.torque_lag",
    "TorqueLagResult": "chaintwin.identify.torque_lag",
    "fit_signatures": "chaintwin.identify.signatures",
    "identification_profile": "chaintwin.identify.calibration",
    "identify_torque_lag": "chaintwin.identify.torque_lag",
    "lag_gain": "chaintwin.identify.torque_lag",
    "load_calibration": "chaintwin.identify.calibration",
    "sensitivity_nm_per_kg": "chaintwin.identify.calibration",
    "simulate_torque_lag": "chaintwin.identify.torque_lag",
}
"""Module of each public name (imported on first use, PEP 562)."""

__all__ = [
    "MAX_DELAY_CYCLES",
    "Calibration",
    "OutputErrorFit",
    "RecursiveLeastSquares",
    "RigidModelRegression",
    "SignatureFit",
    "TorqueLagEstimator",
    "TorqueLagResult",
    "fit_signatures",
    "identification_profile",
    "identify_torque_lag",
    "lag_gain",
    "load_calibration",
    "sensitivity_nm_per_kg",
    "simulate_torque_lag",
]


__getattr__ = lazy_getattr(__name__, _LAZY)
