"""Known-answer test: a calibration its own file could not hold is refused.

A conveyor whose drive dwarfs its belt (ratio 90, a 71 mm sprocket, 12 ms
scope), calibrated from three empty runs at one speed: the runs cannot
separate the rail friction from the losses, and the fit puts μ at about
-2.5. ``load_calibration`` refuses such a file; ``calibrate`` refuses to
make it, rather than hand weighing a calibration that weighs wrong numbers.
"""

from __future__ import annotations

from typing import Any

import pytest

from chaintwin.calibrating.procedure import calibrate
from chaintwin.errors import CalibrationError
from chaintwin.read.profile import ConveyorProfile, parse_profile
from chaintwin.simulate.virtual import default_setpoints, run_virtual

SAMPLE_TIME_S = 0.012
SEED = 20271126


def _profile() -> ConveyorProfile:
    doc: dict[str, Any] = {
        "id": "heavy-drive-12ms",
        "belt": {"length_m": 10.194, "mass_per_m_kg": 7.5631, "incline_deg": -6.1638},
        "sprocket": {"pitch_diameter_m": 0.070843, "teeth": 8},
        "gear": {"ratio": 90.298, "efficiency": 0.95726, "inertia_kgm2": 2.4915e-05},
        "motor": {
            "inertia_kgm2": 0.0004983,
            "nominal_torque_nm": 0.6481,
            "nominal_speed_rpm": 1400.0,
        },
        "controller": {"speed_gain_nm_s_rad": 0.04497, "torque_limit_nm": 1.9443},
        "tray_mass_kg": 12.979,
        "model": {
            "friction": 0.33835,
            "static_friction_ratio": 1.3792,
            "loss_constant_nm": 2.8516e-05,
            "loss_viscous_nm_s_rad": 0.0005444,
            "loss_quadratic_nm_s2_rad2": 5.1848e-07,
            "belt_stiffness_n_m": 421820.0,
            "back_efficiency": 0.752,
            "stribeck_speed_m_s": 0.019059,
            "unlisted_inertia_kgm2": 9.3815e-05,
        },
    }
    return parse_profile(doc, "heavy drive, 12 ms scope")


def test_an_impossible_calibration_is_refused_with_what_to_record() -> None:
    prof = _profile()
    window = 2048 * SAMPLE_TIME_S
    runs = [
        run_virtual(
            prof,
            payload_kg=0.0,
            sample_time_s=SAMPLE_TIME_S,
            seed=SEED + k,
            setpoints=default_setpoints(
                prof, duration_s=window, ramp_s=0.5, hold_s=window - 1.6, direction=-1
            ),
            calibration=True,
        ).recording
        for k in range(3)
    ]
    with pytest.raises(CalibrationError, match=r"friction coefficient mu is -.*reference load"):
        calibrate(runs, prof)
