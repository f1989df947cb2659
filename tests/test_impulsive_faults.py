"""A worn sprocket, payload events and the causes of impulsive features."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from chaintwin import examples
from chaintwin.calibrating.procedure import calibrate
from chaintwin.diagnose.causes import (
    NOTE_CAUSES,
    impact_context,
    one_per_revolution,
    resolve_causes,
)
from chaintwin.diagnose.features import recording_features
from chaintwin.errors import ModelError
from chaintwin.identify.calibration import Calibration
from chaintwin.read.profile import ConveyorProfile, load_profile
from chaintwin.simulate.faults import (
    PAYLOAD_EVENT_CHANCE,
    SPROCKET_IMPACT,
    Fault,
    parse_faults,
)
from chaintwin.simulate.virtual import faulty_plant, run_virtual
from chaintwin.validate import inspect_recording


@pytest.fixture(scope="module")
def calibrated(reference_profile: ConveyorProfile) -> Calibration:
    runs = [(0.0, 1400.0), (0.0, 700.0), (0.0, 420.0), (20.0, 1400.0)]
    recs = [
        run_virtual(
            reference_profile, payload_kg=load, seed=100 + k, calibration=True, speed_rpm=rpm
        ).recording
        for k, (load, rpm) in enumerate(runs)
    ]
    return calibrate(recs, reference_profile)


@pytest.fixture(scope="module")
def reference_profile() -> ConveyorProfile:  # module scope, for the calibration
    return load_profile(Path(examples.__file__).parent / "profiles" / "white-belt-01.yaml")


def test_a_worn_sprocket_knocks_once_per_tooth_engagement(
    reference_profile: ConveyorProfile,
) -> None:
    plant = faulty_plant(reference_profile, payload_kg=10.0, faults=[Fault("sprocket", 0.5)])
    # by hand: the motor turns ratio/z revolutions per tooth pass
    assert plant.impulse_period_rad == pytest.approx(2 * np.pi * plant.ratio / plant.teeth)
    tn = reference_profile.motor.nominal_torque_nm
    assert plant.impulse_amplitude_nm == pytest.approx(0.5 * SPROCKET_IMPACT * tn)
    # no friction or radius change: that is elongation
    healthy = faulty_plant(reference_profile, payload_kg=10.0)
    assert plant.mu == healthy.mu and plant.pitch_radius_m == healthy.pitch_radius_m


def test_faults_that_share_a_plant_mechanism_are_refused_together() -> None:
    with pytest.raises(ModelError, match="gear_tooth and sprocket"):
        parse_faults(["gear_tooth:0.5", "sprocket:0.5"])
    with pytest.raises(ModelError, match="rail_obstacle and payload_event"):
        parse_faults(["rail_obstacle:1", "payload_event:1"])
    assert len(parse_faults(["sprocket:1", "payload_event:1"])) == 2


def test_payload_events_come_in_some_recordings_only(reference_profile: ConveyorProfile) -> None:
    n = 60
    events = [
        run_virtual(
            reference_profile, payload_kg=10.0, faults=[Fault("payload_event", 1.0)], seed=s
        ).truth["payload_event_s"]
        for s in range(n)
    ]
    drawn = [e for e in events if e is not None]
    # binomial(60, 0.15): 9 expected, 2-18 covers 99.9 %
    assert 2 <= len(drawn) <= 18, PAYLOAD_EVENT_CHANCE
    for start, duration in drawn:
        assert 0.0 < duration <= 1.0 and start > 0.0
    # the same seed without the fault draws nothing and simulates as before
    plain = run_virtual(reference_profile, payload_kg=10.0, seed=0)
    assert plain.truth["payload_event_s"] is None


def test_sprocket_comb_rises_with_a_worn_sprocket_not_with_an_elongated_chain(
    reference_profile: ConveyorProfile, calibrated: Calibration
) -> None:
    def comb(faults: list[Fault]) -> float:
        values = []
        for seed in range(3):
            run = run_virtual(reference_profile, payload_kg=20.0, faults=faults, seed=seed)
            feats = recording_features(
                inspect_recording(run.recording, reference_profile), calibrated
            )
            values.append(feats.values["sprocket_comb"])
        return float(np.median(values))

    healthy = comb([])
    assert comb([Fault("sprocket", 1.0)]) > 3.0 * healthy
    assert comb([Fault("elongation", 1.0)]) < 1.5 * healthy


def test_impulsive_features_take_their_cause_from_what_else_rose_and_the_impacts() -> None:
    # a specific cause alarmed at the same recording explains them
    assert resolve_causes(["residual_kurtosis", "sprocket_comb"])["residual_kurtosis"] == (
        "sprocket"
    )
    assert resolve_causes(["tooth_pass", "sprocket_comb"])["tooth_pass"] == "sprocket"
    assert resolve_causes(["tooth_pass"])["tooth_pass"] == "elongation"
    # else the recording's own impacts say
    obstacle = {"impact_isolated": 1.0, "impact_hits_per_rev": 0.9, "impact_pooled_hits": 3.0}
    assert impact_context(obstacle, []) == "obstruction"
    # the rate is pooled: a recording between two hits still names the obstacle
    pooled = {"impact_hits_per_rev": 0.9, "impact_pooled_hits": 3.0}
    assert impact_context(pooled, []) == "obstruction"
    # by hand (Poisson): 2 knocks over 4.55 revolutions, P(N <= 2) = 0.17: consistent;
    # 3 over 30 revolutions, P(N <= 3) = 3e-10: knocks, but not one per revolution
    assert one_per_revolution(2.0, 2.0 / 4.55)
    assert not one_per_revolution(3.0, 0.1)
    assert not one_per_revolution(12.0, 12.0 / 4.0)  # P(N >= 12 | 4) = 0.0009: too many
    assert not one_per_revolution(0.0, 0.0)
    few = {"impact_isolated": 1.0, "impact_hits_per_rev": 0.1, "impact_pooled_hits": 3.0}
    assert impact_context(few, []) == "payload_event"
    assert impact_context({"impact_drags": 1.0}, []) == "payload_event"
    assert impact_context({}, ["sprocket_comb"]) == "sprocket"
    assert impact_context({}, ["comb_rotor"]) == "gear"
    assert impact_context({}, []) == "impulsive"
    context = impact_context({}, [])
    resolved = resolve_causes(["crest_factor", "impact_count"], context)
    # impulsive with nothing standing out names no cause; impacts with no wear
    # pattern are events of operation: both are notes, never alarms
    assert resolved == {"crest_factor": "impulsive", "impact_count": "payload_event"}
    assert {"impulsive", "payload_event"} <= NOTE_CAUSES


@pytest.mark.parametrize(
    ("name", "sample_time_s", "scopes"),
    [("white-belt-01", 0.006, 24), ("short-fast-03", 0.001, 80)],
)
def test_a_rail_obstacle_is_hit_about_once_per_belt_revolution(
    name: str, sample_time_s: float, scopes: int
) -> None:
    """Pooled over scopes at random belt positions, about four belt revolutions of
    travel searched (a 1 ms scope searches half a second)."""
    profile = load_profile(Path(examples.__file__).parent / "profiles" / f"{name}.yaml")
    runs = [(0.0, 1400.0), (0.0, 700.0), (0.0, 420.0), (20.0, 1400.0)]
    cal = calibrate(
        [
            run_virtual(
                profile,
                payload_kg=load,
                sample_time_s=sample_time_s,
                seed=100 + k,
                calibration=True,
                speed_rpm=rpm,
            ).recording
            for k, (load, rpm) in enumerate(runs)
        ],
        profile,
    )

    def per_revolution(faults: list[Fault]) -> float:
        knocks = travel = 0.0
        for seed in range(scopes):
            run = run_virtual(
                profile, payload_kg=20.0, sample_time_s=sample_time_s, faults=faults, seed=seed
            )
            v = recording_features(inspect_recording(run.recording, profile), cal).values
            knocks += v["impact_isolated"]
            travel += v["belt_travel_m"]
        return knocks / travel * profile.loop_length_m

    assert per_revolution([]) == 0.0
    assert 0.5 <= per_revolution([Fault("rail_obstacle", 1.0)]) <= 1.5


def test_an_unexplained_peak_on_the_output_shafts_comb_reads_as_the_gear() -> None:
    """Orders seen on a drawn conveyor with a damaged output-stage tooth (i = 16.144)."""
    from chaintwin.diagnose.causes import shaft_harmonic

    out = 1.0 / 16.144114705460915
    tol = 1.5 * (1.0 / 24.576) / (1400.0 / 60.0)  # a 12 ms scope's bin at 1400 rpm, in orders
    for order in (0.1256, 0.1849, 0.3104, 0.3732, 0.4953):  # k = 2, 3, 5, 6, 8
        assert shaft_harmonic(order, out, tol), order
    assert not shaft_harmonic(3.57, out, tol)  # a bearing's outer-race order: k = 58
    assert not shaft_harmonic(0.5 * (0.1849 + 0.2477), out, tol)  # between two harmonics
    assert not shaft_harmonic(0.1849, 0.0, tol)
