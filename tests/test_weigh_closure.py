"""Known-answer test: a calibration that cannot read back its own recordings says so.

A 21.7 m belt recorded by a 1 ms scope (2048 samples: 2 s, a 0.26 s ramp and
under a second at speed), calibrated from empty runs at three speeds in both
directions and an 11.4 kg reference load (half its largest payload). The
rigid model does not hold over these recordings: the calibration's rail
friction comes out far too high against a negative constant loss, and the
friction signature reads every recording, its own included, about 30 kg
light while stating ±5 kg. The calibration weighs its own recordings,
warns ``calibration_misreads_own`` and carries the misread into μ's
uncertainty, so that every weight with it stays within its uncertainty.
"""

from __future__ import annotations

from typing import Any

import pytest

from chaintwin.calibrating.procedure import calibrate
from chaintwin.identify.calibration import Calibration
from chaintwin.read.profile import ConveyorProfile, parse_profile
from chaintwin.read.recording import Recording
from chaintwin.simulate.virtual import default_setpoints, run_virtual
from chaintwin.validate.checks import inspect_recording
from chaintwin.weigh.weigh import weigh

SAMPLE_TIME_S = 0.001
SEED = 20268126
REFERENCE_KG = 11.4


def _profile() -> ConveyorProfile:
    doc: dict[str, Any] = {
        "id": "long-belt-1ms",
        "belt": {"length_m": 21.742, "mass_per_m_kg": 5.4325, "incline_deg": -1.555},
        "sprocket": {"pitch_diameter_m": 0.18552, "teeth": 8},
        "gear": {"ratio": 23.791, "efficiency": 0.91076, "inertia_kgm2": 0.00025341},
        "motor": {
            "inertia_kgm2": 0.0050682,
            "nominal_torque_nm": 5.3386,
            "nominal_speed_rpm": 1400.0,
        },
        "controller": {"speed_gain_nm_s_rad": 0.74925, "torque_limit_nm": 16.016},
        "tray_mass_kg": 6.9831,
        "model": {
            "friction": 0.19772,
            "static_friction_ratio": 1.1485,
            "loss_constant_nm": 0.0002349,
            "loss_viscous_nm_s_rad": 0.0044844,
            "loss_quadratic_nm_s2_rad2": 4.2709e-06,
            "belt_stiffness_n_m": 197770.0,
            "back_efficiency": 0.8691,
            "stribeck_speed_m_s": 0.016313,
            "unlisted_inertia_kgm2": 0.00044998,
        },
    }
    return parse_profile(doc, "long belt, 1 ms scope")


def _run(
    prof: ConveyorProfile,
    payload: float,
    seed: int,
    *,
    direction: int = 1,
    share: float = 1.0,
    calibration: bool = False,
) -> Recording:
    """One 2048-sample recording: a 0.256 s ramp, 0.936 s at speed, a 0.256 s ramp."""
    sp = default_setpoints(
        prof,
        duration_s=2048 * SAMPLE_TIME_S,
        speed_rpm=share * 1400.0,
        ramp_s=0.256,
        hold_s=0.936,
        direction=direction,
    )
    return run_virtual(
        prof,
        payload_kg=payload,
        sample_time_s=SAMPLE_TIME_S,
        seed=seed,
        setpoints=sp,
        calibration=calibration,
    ).recording


@pytest.fixture(scope="module")
def long_belt() -> tuple[ConveyorProfile, Calibration]:
    prof = _profile()
    empty = [
        _run(prof, 0.0, SEED + 10 + 2 * k + (s < 0), direction=s, share=share, calibration=True)
        for k, share in enumerate((0.3, 0.6, 1.0))
        for s in (1, -1)
    ]
    ref = _run(prof, REFERENCE_KG, SEED + 20, calibration=True)
    return prof, calibrate([*empty, ref], prof)


def test_a_calibration_that_misreads_its_own_recordings_warns(
    long_belt: tuple[ConveyorProfile, Calibration],
) -> None:
    _prof, cal = long_belt
    notes = [w.message for w in cal.warnings if w.code == "calibration_misreads_own"]
    assert len(notes) == 1, [w.code for w in cal.warnings]
    assert "added to mu's uncertainty" in notes[0]


def test_its_weights_stay_within_their_uncertainty(
    long_belt: tuple[ConveyorProfile, Calibration],
) -> None:
    """Four payloads over the conveyor's range: each weight within 3u, or none."""
    prof, cal = long_belt
    for j, payload in enumerate((2.0, 8.0, 14.0, 20.0)):
        res = weigh(inspect_recording(_run(prof, payload, SEED + 100 + j), prof), cal)
        if res.payload_kg is None:
            assert res.unweighable is not None
            continue
        assert res.uncertainty_kg is not None
        assert abs(res.payload_kg - payload) <= 3.0 * res.uncertainty_kg, (
            payload,
            res.payload_kg,
            res.uncertainty_kg,
        )
