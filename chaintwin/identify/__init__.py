"""Identification: conveyor and drive parameters from recordings.

Identification never reads a profile's ``model:`` section.
"""

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
    "TorqueLagEstimator",
    "TorqueLagResult",
    "identify_torque_lag",
    "lag_gain",
    "simulate_torque_lag",
]
