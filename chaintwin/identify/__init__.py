"""Stage 3, identify: conveyor and drive parameters from recordings.

Estimators follow the scikit-learn contract (settings in ``__init__``,
``fit`` returns ``self``, fitted values end in ``_``). Identification never
reads a profile's ``model:`` section.
"""

from chaintwin.identify.calibrating import calibrate
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

__all__ = [
    "MAX_DELAY_CYCLES",
    "Calibration",
    "OutputErrorFit",
    "RecursiveLeastSquares",
    "RigidModelRegression",
    "SignatureFit",
    "TorqueLagEstimator",
    "TorqueLagResult",
    "calibrate",
    "fit_signatures",
    "identification_profile",
    "identify_torque_lag",
    "lag_gain",
    "load_calibration",
    "sensitivity_nm_per_kg",
    "simulate_torque_lag",
]
