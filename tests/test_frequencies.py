"""Characteristic frequency/order table: hand calculation, folding, aliasing."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from chaintwin.errors import ModelError
from chaintwin.model.frequencies import (
    CharacteristicLine,
    characteristic_lines,
    characteristic_orders,
    characteristic_table,
    fold_frequency,
)
from chaintwin.read.profile import ConveyorProfile, load_profile, parse_profile

PROFILES = Path(__file__).resolve().parents[1] / "chaintwin" / "examples" / "profiles"


@pytest.fixture(scope="module")
def white_belt() -> ConveyorProfile:
    return load_profile(PROFILES / "white-belt-01.yaml")


def _hand_white_belt_1415() -> dict[str, float]:
    """White-belt-01 at 1415 rpm, from the profile's numbers written out by hand."""
    rotor = 1415 / 60  # 23.583 Hz
    # gear stages [[12, 43], [23, 75], [23, 61]], motor side first
    stage2_shaft = rotor * 12 / 43
    stage3_shaft = stage2_shaft * 23 / 75
    output = stage3_shaft * 23 / 61
    ratio = (43 / 12) * (75 / 23) * (61 / 23)  # 30.990, nameplate 30.99
    assert ratio == pytest.approx(30.99, rel=1e-5)
    # sprocket: 10 teeth, pitch diameter 0.121 m -> chordal mean radius
    r = 0.121 / 2 * math.sin(math.pi / 10) / (math.pi / 10)  # 0.059510 m
    loop = 2 * 4.3 + math.pi * 0.121  # 8.9801 m
    belt_speed = 2 * math.pi * rotor * r / ratio  # 0.28455 m/s
    # belt 4.1 kg/m, tray 10 kg, k = model.belt_stiffness_n_m = 1e6 N/m
    k = 1.0e6
    strand = 4.1 * 4.3 + 10.0  # carrying strand + tray, 27.63 kg
    m1 = (0.0022 + 0.00012) * ratio**2 / r**2  # drive side at the belt, 629 kg
    m2 = 4.1 * loop + 10.0  # belt + tray, 46.82 kg
    return {
        "rotor": rotor,
        "stage1_mesh": 12 * rotor,
        "stage2_shaft": stage2_shaft,
        "stage2_mesh": 23 * stage2_shaft,
        "stage3_shaft": stage3_shaft,
        "stage3_mesh": 23 * stage3_shaft,
        "output_shaft": output,
        "sprocket_tooth_pass": 10 * output,
        "belt_revolution": belt_speed / loop,
        "belt_mode_1": 0.5 * math.sqrt(k / strand),
        "belt_mode_2": 1.0 * math.sqrt(k / strand),
        "belt_mode_3": 1.5 * math.sqrt(k / strand),
        "two_mass_mode": math.sqrt(k * (1 / m1 + 1 / m2)) / (2 * math.pi),
    }


# name: (frequency Hz, apparent at 6 ms, apparent at 12 ms), rounded by hand
WHITE_BELT_1415 = {
    "rotor": (23.583, 23.583, 23.583),
    "stage1_mesh": (283.000, 50.333, 33.000),
    "stage2_shaft": (6.581, 6.581, 6.581),
    "stage2_mesh": (151.372, 15.295, 15.295),
    "stage3_shaft": (2.018, 2.018, 2.018),
    "stage3_mesh": (46.421, 46.421, 36.913),
    "output_shaft": (0.761, 0.761, 0.761),
    "sprocket_tooth_pass": (7.610, 7.610, 7.610),
    "belt_revolution": (0.0317, 0.0317, 0.0317),
    "belt_mode_1": (95.122, 71.545, 11.788),
    "belt_mode_2": (190.243, 23.577, 23.577),
    "belt_mode_3": (285.365, 47.968, 35.365),
    "two_mass_mode": (24.110, 24.110, 24.110),
}


def test_white_belt_lines_match_hand_calculation(white_belt: ConveyorProfile) -> None:
    lines = characteristic_lines(white_belt, 1415.0)
    hand = _hand_white_belt_1415()
    assert [line.name for line in lines] == list(hand)
    for line in lines:
        assert line.frequency_hz == pytest.approx(hand[line.name], rel=1e-12), line.name
        assert line.frequency_hz == pytest.approx(WHITE_BELT_1415[line.name][0], abs=1e-3)


def test_white_belt_kinds_and_orders(white_belt: ConveyorProfile) -> None:
    lines = {line.name: line for line in characteristic_lines(white_belt, 1415.0)}
    assert lines["rotor"].order == 1.0
    assert lines["stage1_mesh"].order == 12.0
    assert lines["stage2_mesh"].order == pytest.approx(12 / 43 * 23)
    assert lines["stage3_mesh"].order == pytest.approx(12 / 43 * 23 / 75 * 23)
    assert lines["output_shaft"].order == pytest.approx(1 / 30.99, rel=1e-5)
    assert lines["sprocket_tooth_pass"].order == pytest.approx(10 / 30.99, rel=1e-5)
    kinds = {name: line.kind for name, line in lines.items()}
    assert kinds["stage1_mesh"] == kinds["stage2_mesh"] == kinds["stage3_mesh"] == "mesh"
    assert kinds["rotor"] == kinds["stage2_shaft"] == kinds["output_shaft"] == "shaft"
    assert kinds["sprocket_tooth_pass"] == "tooth_pass"
    assert kinds["belt_revolution"] == "belt"
    for name in ("belt_mode_1", "belt_mode_2", "belt_mode_3", "two_mass_mode"):
        assert kinds[name] == "structural"
        assert lines[name].order is None
    for line in lines.values():
        if line.order is not None:
            assert line.frequency_hz == pytest.approx(line.order * 1415 / 60, rel=1e-12)


@pytest.mark.parametrize(("sample_time_s", "column"), [(0.006, 1), (0.012, 2)])
def test_white_belt_apparent_frequencies(
    white_belt: ConveyorProfile, sample_time_s: float, column: int
) -> None:
    rows = characteristic_table(white_belt, 1415.0, sample_time_s)
    nyquist = 0.5 / sample_time_s
    for row in rows:
        name = str(row["name"])
        assert row["apparent_hz"] == pytest.approx(WHITE_BELT_1415[name][column], abs=1e-3)
        assert row["aliased"] is (WHITE_BELT_1415[name][0] > nyquist)
    assert set(rows[0]) == {"name", "kind", "order", "frequency_hz", "apparent_hz", "aliased"}


def test_table_rows_are_json_ready(white_belt: ConveyorProfile) -> None:
    import json

    rows = characteristic_table(white_belt, 1415.0, 0.006)
    back = json.loads(json.dumps(rows))
    assert back == rows


def test_characteristic_orders(white_belt: ConveyorProfile) -> None:
    orders = characteristic_orders(white_belt)
    lines = characteristic_lines(white_belt, 900.0)
    assert orders == {line.name: line.order for line in lines if line.order is not None}
    assert orders["belt_revolution"] == pytest.approx(
        2 * math.pi * 0.0595097 / 30.99 / 8.980133, rel=1e-5
    )


@pytest.mark.parametrize(
    ("f_hz", "sample_time_s", "expected"),
    [
        (100.0, 0.006, 66.6667),  # Nyquist 83.33 Hz
        (100.0, 0.012, 16.6667),  # Nyquist 41.67 Hz, folded twice
        (283.0, 0.006, 50.3333),  # stage 1 mesh at 1415 rpm
        (283.0, 0.012, 33.0),
        (50.0, 0.006, 50.0),  # below Nyquist: unchanged
        (1000.0 / 6 / 2, 0.006, 83.3333),  # exactly Nyquist
        (1000.0 / 6, 0.006, 0.0),  # exactly fs
        (2 * 1000.0 / 6 + 5.0, 0.006, 5.0),
        (-100.0, 0.006, 66.6667),  # sign ignored
        (0.0, 0.001, 0.0),
    ],
)
def test_fold_known_answers(f_hz: float, sample_time_s: float, expected: float) -> None:
    assert fold_frequency(f_hz, sample_time_s) == pytest.approx(expected, abs=1e-4)


@given(
    f_hz=st.floats(min_value=0.0, max_value=1.0e5, allow_nan=False),
    sample_time_s=st.floats(min_value=1.0e-5, max_value=1.0),
)
@settings(deadline=None)  # a pause of the loaded CI machine is no failure of the property
def test_fold_stays_in_band(f_hz: float, sample_time_s: float) -> None:
    apparent = fold_frequency(f_hz, sample_time_s)
    nyquist = 0.5 / sample_time_s
    assert 0.0 <= apparent <= nyquist
    if f_hz <= nyquist:
        assert apparent == f_hz
    line = CharacteristicLine("x", "shaft", 1.0, f_hz)
    assert line.apparent_hz(sample_time_s) == apparent
    assert line.aliased(sample_time_s) is (f_hz > nyquist)


@pytest.mark.parametrize("sample_time_s", [0.001, 0.006, 0.012])
def test_sampled_sine_peaks_at_apparent_frequency(
    white_belt: ConveyorProfile, sample_time_s: float
) -> None:
    n = 2**16
    t = np.arange(n) * sample_time_s
    window = np.hanning(n)
    freqs = np.fft.rfftfreq(n, sample_time_s)
    bin_hz = freqs[1]
    for line in characteristic_lines(white_belt, 1415.0):
        # a phase offset keeps a line that folds onto 0 or fs/2 from sampling to zeros
        x = np.sin(2 * np.pi * line.frequency_hz * t + 0.4)
        peak = freqs[int(np.argmax(np.abs(np.fft.rfft(x * window))))]
        assert abs(peak - line.apparent_hz(sample_time_s)) <= 1.0 * bin_hz, line.name


def test_profile_without_stages_teeth_or_stiffness(white_belt: ConveyorProfile) -> None:
    data: dict[str, Any] = white_belt.model_dump()
    data["gear"]["stages"] = None
    data["sprocket"]["teeth"] = None
    data["model"] = None
    for key in ("youngs_modulus_pa", "density_kg_m3", "cross_section_m2"):
        data["belt"][key] = None
    bare = parse_profile(data)
    lines = characteristic_lines(bare, 1415.0)
    assert [line.name for line in lines] == ["rotor", "output_shaft", "belt_revolution"]
    out = 1415 / 60 / 30.99
    assert lines[1].frequency_hz == pytest.approx(out, rel=1e-12)
    # no teeth: the belt moves by the pitch radius R per sprocket radian
    assert lines[2].frequency_hz == pytest.approx(
        2 * math.pi * out * 0.0605 / (2 * 4.3 + math.pi * 0.121), rel=1e-12
    )


def test_stiffness_from_material_data() -> None:
    incline = load_profile(PROFILES / "incline-line-02.yaml")
    lines = {line.name: line for line in characteristic_lines(incline, 1430.0)}
    k = 2.7e9 * 0.0046 / 12.0  # E·A/L: no model.belt_stiffness_n_m in this profile
    assert lines["belt_mode_1"].frequency_hz == pytest.approx(
        0.5 * math.sqrt(k / (7.5 * 12.0)), rel=1e-12
    )


def test_payload_moves_only_structural_lines(white_belt: ConveyorProfile) -> None:
    empty = characteristic_lines(white_belt, 1415.0)
    loaded = characteristic_lines(white_belt, 1415.0, payload_kg=100.0)
    for a, b in zip(empty, loaded, strict=True):
        if a.order is None:
            assert b.frequency_hz < a.frequency_hz
        else:
            assert b.frequency_hz == a.frequency_hz


def test_speed_sign_zero_and_modes(white_belt: ConveyorProfile) -> None:
    forward = characteristic_lines(white_belt, 1415.0)
    backward = characteristic_lines(white_belt, -1415.0)
    assert forward == backward
    still = characteristic_lines(white_belt, 0.0, belt_modes=0)
    assert all(line.frequency_hz == 0.0 for line in still if line.order is not None)
    assert [line.name for line in still if line.order is None] == ["two_mass_mode"]


@pytest.mark.parametrize(
    "call",
    [
        lambda p: characteristic_lines(p, float("nan")),
        lambda p: characteristic_lines(p, 1415.0, payload_kg=-1.0),
        lambda p: characteristic_lines(p, 1415.0, belt_modes=-1),
        lambda p: characteristic_table(p, 1415.0, 0.0),
        lambda p: fold_frequency(float("inf"), 0.006),
        lambda p: fold_frequency(10.0, -0.006),
    ],
)
def test_bad_inputs_raise_model_error(white_belt: ConveyorProfile, call: Any) -> None:
    with pytest.raises(ModelError):
        call(white_belt)


def test_the_line_catalogue_is_the_one_source_of_the_features_lines() -> None:
    """Features, monitor and report read their lines from model.frequencies alone."""
    from conftest import EXAMPLES

    from chaintwin.calibrating.procedure import calibrate
    from chaintwin.diagnose.features import recording_features
    from chaintwin.model.frequencies import (
        SHAFT_HARMONICS,
        known_line_orders,
        line_orders,
        shaft_orders,
    )
    from chaintwin.read.profile import load_profile
    from chaintwin.validate.checks import load_recording

    profile = load_profile(EXAMPLES / "profiles" / "white-belt-01.yaml")
    cal_files = sorted((EXAMPLES / "recordings").glob("white-belt-01-cal-*.csv"))
    cal = calibrate([load_recording(f, profile=profile).recording for f in cal_files], profile)
    ins = load_recording(EXAMPLES / "recordings" / "white-belt-01-40kg.csv", profile=profile)
    combs = {k for k in recording_features(ins, cal).values if k.startswith("comb_")}
    assert combs == {f"comb_{name}" for name in shaft_orders(profile)}
    catalogue = line_orders(profile)
    orders = known_line_orders(profile)
    for name, order in shaft_orders(profile).items():
        assert catalogue[name] == order
        assert SHAFT_HARMONICS * order in orders
    assert catalogue["sprocket_tooth_pass_h3"] == 3 * catalogue["sprocket_tooth_pass"]
    assert 3 * catalogue["sprocket_tooth_pass"] in orders
