"""The fault table: one entry per simulated fault, read by the simulator, the
causes, the command line and the evaluations."""

from __future__ import annotations

import sys
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from conftest import REFERENCE_PROFILE

from chaintwin.cli.app import main
from chaintwin.diagnose.causes import CAUSE_PRIORITY, NOTE_CAUSES, explaining_causes, resolve_causes
from chaintwin.diagnose.features import FEATURES, IMPULSIVE, is_tracked
from chaintwin.errors import ModelError
from chaintwin.read.formats import read_recording
from chaintwin.read.profile import ConveyorProfile
from chaintwin.simulate.faults import (
    Fault,
    FaultType,
    PlantEdit,
    exclusive_groups,
    expected_causes,
    fault_names,
    fault_type,
    fault_types,
    parse_fault,
    parse_faults,
    register_fault,
    unregister_fault,
)
from chaintwin.simulate.virtual import faulty_plant, run_virtual

SCRIPTS = Path(__file__).resolve().parent.parent / "scripts"


def _wax(edit: PlantEdit, s: float) -> None:
    """A toy fault: the rail friction grows as the built-in ``friction`` makes it."""
    edit.mu *= 1.0 + s


@pytest.fixture
def toy_faults() -> Iterator[None]:
    """Two toy faults: one that diagnoses as friction, one with a cause of its own."""
    register_fault(FaultType("rail_wax", _wax, "friction", moves=("friction",), end_severity=0.4))
    register_fault(
        FaultType(
            "toy_jam",
            _wax,
            "jam",
            moves=("residual_std", IMPULSIVE),
            mechanism="resisting place on the belt",
        )
    )
    try:
        yield
    finally:
        unregister_fault("rail_wax")
        unregister_fault("toy_jam")


def test_every_cause_of_the_table_is_one_the_diagnosis_knows() -> None:
    for t in fault_types():
        assert t.cause is None or t.cause in CAUSE_PRIORITY or t.cause in NOTE_CAUSES, t.name
        for key in t.moves:
            assert key in ("comb", "mode", IMPULSIVE) or is_tracked(key), (t.name, key)


def test_two_faults_map_to_one_cause() -> None:
    assert fault_type("rail_obstacle").cause == fault_type("obstruction").cause == "obstruction"
    assert expected_causes()["gear_tooth"] == "gear"
    assert "payload_event" not in expected_causes()  # an event: reported, never alarmed
    assert "payload_step" not in expected_causes()


def test_the_table_reproduces_the_hand_written_explanations() -> None:
    # the map the causes held before the table: each feature to the specific
    # causes that explain its rise, in the order they win
    by_hand = {
        "friction": ("obstruction", "sprocket", "elongation"),
        "residual_std": ("obstruction", "sprocket", "gear", "elongation"),
        "unexplained_peak": ("obstruction", "sprocket", "gear"),
        "comb": ("obstruction", "sprocket"),
        "tooth_pass": ("sprocket",),
        "mode": ("obstruction", "sprocket", "gear", "elongation", "bearing"),
        IMPULSIVE: ("obstruction", "sprocket", "gear"),
    }
    for key in {*FEATURES, *by_hand}:
        assert explaining_causes(key) == by_hand.get(key, ()), key


def test_exclusive_groups_come_from_the_mechanisms() -> None:
    assert exclusive_groups() == (
        ("gear_tooth", "sprocket"),
        ("obstruction", "rail_obstacle", "payload_event"),
    )
    with pytest.raises(ModelError, match="gear_tooth and sprocket cannot be simulated together"):
        parse_faults(["gear_tooth:0.5", "sprocket:0.5"])


def test_a_name_is_registered_once() -> None:
    with pytest.raises(ModelError, match="'friction' is registered already"):
        register_fault(FaultType("friction", _wax, "friction"))
    with pytest.raises(ModelError, match="unknown fault 'rail_wax'; use one of friction"):
        Fault("rail_wax", 0.1)


@pytest.mark.usefixtures("toy_faults")
def test_a_registered_toy_fault_is_simulated(reference_profile: ConveyorProfile) -> None:
    assert fault_names()[-2:] == ("rail_wax", "toy_jam")
    assert parse_fault("rail_wax:0.3") == Fault("rail_wax", 0.3)
    healthy = faulty_plant(reference_profile, payload_kg=5.0)
    waxed = faulty_plant(reference_profile, payload_kg=5.0, faults=[Fault("rail_wax", 0.3)])
    assert waxed.mu == pytest.approx(1.3 * healthy.mu, rel=1e-12)
    # the toy applies what the built-in friction applies: the same recording, bit for bit
    toy = run_virtual(reference_profile, payload_kg=5.0, faults=[Fault("rail_wax", 0.3)], seed=4)
    builtin = run_virtual(
        reference_profile, payload_kg=5.0, faults=[Fault("friction", 0.3)], seed=4
    )
    assert toy.truth["faults"] == {"rail_wax": 0.3}
    for name, values in builtin.recording.channels.items():
        assert np.array_equal(toy.recording.channels[name], values), name
    # its mechanism is the obstruction's: refused together
    with pytest.raises(ModelError, match="obstruction and toy_jam cannot"):
        parse_faults(["toy_jam:0.1", "obstruction:0.1"])


@pytest.mark.usefixtures("toy_faults")
def test_a_registered_toy_fault_through_the_command_line(tmp_path: Path) -> None:
    out = tmp_path / "waxed.csv"
    args = ["simulate", "--profile", str(REFERENCE_PROFILE), "--out", str(out), "--seed", "3"]
    assert main([*args, "--payload", "8", "--fault", "rail_wax:0.5", "--json"]) == 0
    healthy = tmp_path / "healthy.csv"
    healthy_args = ["simulate", "--profile", str(REFERENCE_PROFILE), "--out", str(healthy)]
    assert main([*healthy_args, "--seed", "3"]) == 0
    waxed = read_recording(out)
    assert waxed.channels["torque"].size > 100
    # the waxed rail takes more torque at constant speed than the healthy one
    assert float(np.mean(np.abs(waxed.channels["torque"]))) > float(
        np.mean(np.abs(read_recording(healthy).channels["torque"]))
    )


@pytest.mark.usefixtures("toy_faults")
def test_a_registered_toy_fault_names_its_cause() -> None:
    # a cause of its own explains the features its fault moves, after the built-in ones
    assert explaining_causes("residual_std") == (
        "obstruction",
        "sprocket",
        "gear",
        "elongation",
        "jam",
    )
    assert resolve_causes(["residual_std"], open_causes={"jam"}) == {"residual_std": "jam"}
    assert resolve_causes(["residual_std", "crest_factor"], context="jam") == {
        "residual_std": "jam",
        "crest_factor": "jam",
    }
    # the evaluations expect what the table says
    sys.path.insert(0, str(SCRIPTS))
    try:
        import evaluate_monitor
        import fidelity_monitoring
    finally:
        sys.path.remove(str(SCRIPTS))
    assert evaluate_monitor.EXPECTED["gear_tooth"] == "gear"
    assert fidelity_monitoring.END_SEVERITY["rail_obstacle"] == 1.0
    assert expected_causes()["rail_wax"] == "friction"
    assert expected_causes()["toy_jam"] == "jam"


def test_the_adding_a_fault_page_runs_as_written() -> None:
    import doctest

    from conftest import EXAMPLES

    page = Path(__file__).resolve().parents[1] / "docs" / "adding-a-fault.md"
    try:
        result = doctest.testfile(str(page), module_relative=False, globs={"examples": EXAMPLES})
    finally:
        unregister_fault("sticky_rail")
    assert result.attempted >= 8
    assert result.failed == 0
