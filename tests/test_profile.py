"""Conveyor profiles: validation with field paths, defaults, derived quantities."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
from conftest import EXAMPLES, REFERENCE_PROFILE

from chaintwin import ProfileError, load_profile, load_profiles
from chaintwin.read.files import yaml_load
from chaintwin.read.profile import ConveyorProfile, parse_profile

I_TEETH = (43 / 12) * (75 / 23) * (61 / 23)
"""The reference gear's ratio from its teeth (nameplate 30.99): what kinematics use."""


def reference_dict() -> dict:  # type: ignore[type-arg]
    return yaml_load(REFERENCE_PROFILE.read_text())  # YAML 1.2 numbers, as load_profile


def test_examples_load_and_have_three_conveyors() -> None:
    profiles = load_profiles(EXAMPLES / "profiles")
    assert set(profiles) == {"white-belt-01", "incline-line-02", "short-fast-03"}


def test_reference_derived_quantities_by_hand(reference_profile: ConveyorProfile) -> None:
    p = reference_profile
    R = 0.121 / 2
    r = R * math.sin(math.pi / 10) / (math.pi / 10)
    assert p.pitch_radius_m == pytest.approx(0.0605)
    assert p.chordal_radius_m == pytest.approx(r, rel=1e-12)
    assert p.chordal_radius_m / p.pitch_radius_m == pytest.approx(0.98363, abs=1e-5)  # 1.6 % less
    m_b = 4.1 * (2 * 4.3 + math.pi * 0.121)
    assert p.belt_mass_kg == pytest.approx(m_b, rel=1e-12)
    assert p.belt_mass_kg == pytest.approx(36.8185, abs=1e-3)
    assert p.belt_speed_per_motor_speed == pytest.approx(r / I_TEETH)
    j = 0.0022 + 0.00012 + (m_b + 10 + 40) * r**2 / (I_TEETH**2 * 0.93)
    assert p.reflected_inertia_kgm2(40) == pytest.approx(j, rel=1e-12)
    jg = 0.0022 + 0.00012 + (m_b + 10 + 40) * r**2 / I_TEETH**2 * 0.93
    assert p.reflected_inertia_kgm2(40, motoring=False) == pytest.approx(jg, rel=1e-12)
    assert p.torque_limit_nm == 7.5
    assert p.belt_stiffness_n_m() == 1.0e6


def test_defaults_are_documented_values() -> None:
    d = reference_dict()
    for key in ("model", "controller", "tray_mass_kg"):
        d.pop(key)
    d["gear"] = {"ratio": 30.99}
    d["motor"] = {"inertia_kgm2": 0.0022, "nominal_torque_nm": 2.5}
    d["sprocket"] = {"pitch_diameter_m": 0.121}
    p = parse_profile(d)
    assert p.gear.efficiency == 0.95
    assert p.gear.inertia_kgm2 == 0.0
    assert p.tray_mass_kg == 0.0
    assert p.controller.cycle_s == 0.001
    assert p.torque_limit_nm == pytest.approx(7.5)  # 3 × nominal
    assert p.chordal_radius_m == p.pitch_radius_m  # teeth unknown
    assert p.model is None
    assert p.belt.incline_deg == 0.0


@pytest.mark.parametrize(
    ("section", "field"),
    [
        ("belt", "length_m"),
        ("belt", "mass_per_m_kg"),
        ("sprocket", "pitch_diameter_m"),
        ("gear", "ratio"),
        ("motor", "inertia_kgm2"),
    ],
)
def test_missing_required_field_names_path(section: str, field: str) -> None:
    d = reference_dict()
    del d[section][field]
    with pytest.raises(ProfileError) as info:
        parse_profile(d, "white.yaml")
    msg = str(info.value)
    assert msg.startswith("white.yaml: ")
    assert f"field '{section}.{field}'" in msg
    assert "add it" in msg


def test_unknown_field_is_refused_with_path() -> None:
    d = reference_dict()
    d["belt"]["lenght_m"] = 4.3
    with pytest.raises(
        ProfileError,
        match=r"field 'belt\.lenght_m': unknown field; remove it or correct its spelling",
    ):
        parse_profile(d, "p.yaml")
    d = reference_dict()
    d["colour"] = "white"
    with pytest.raises(ProfileError, match="field 'colour'"):
        parse_profile(d, "p.yaml")


def test_bad_values_name_path() -> None:
    d = reference_dict()
    d["gear"]["efficiency"] = 1.3
    with pytest.raises(ProfileError, match=r"field 'gear\.efficiency'"):
        parse_profile(d, "p.yaml")
    d = reference_dict()
    d["belt"]["length_m"] = -1
    with pytest.raises(ProfileError, match=r"field 'belt\.length_m'"):
        parse_profile(d, "p.yaml")


def test_stages_must_match_ratio() -> None:
    d = reference_dict()
    d["gear"]["stages"] = [[12, 43], [23, 75]]
    with pytest.raises(ProfileError, match="multiply to"):
        parse_profile(d, "p.yaml")


def test_yaml_errors_and_duplicate_ids(tmp_path: Path) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text("id: x\nbelt: [unclosed\n")
    with pytest.raises(ProfileError, match=r"bad\.yaml, line \d+: not valid YAML"):
        load_profile(bad)
    (tmp_path / "bad.yaml").unlink()
    (tmp_path / "a.yaml").write_text(REFERENCE_PROFILE.read_text())
    (tmp_path / "b.yaml").write_text(REFERENCE_PROFILE.read_text())
    with pytest.raises(ProfileError, match="also the id of"):
        load_profiles(tmp_path)
    with pytest.raises(ProfileError, match="cannot be read"):
        load_profile(tmp_path / "missing.yaml")
    with pytest.raises(ProfileError, match="must be a YAML mapping"):
        parse_profile([1, 2], "list.yaml")


def test_content_hash_changes_with_content(reference_profile: ConveyorProfile) -> None:
    d = reference_dict()
    assert parse_profile(d).content_hash() == reference_profile.content_hash()
    d["tray_mass_kg"] = 11.0
    assert parse_profile(d).content_hash() != reference_profile.content_hash()


def test_numbers_must_be_numbers(tmp_path: Path) -> None:
    text = REFERENCE_PROFILE.read_text()
    for value in ("true", '"30.99"'):  # a boolean, a quoted number
        bad = tmp_path / "bad.yaml"
        bad.write_text(text.replace("ratio: 30.99", f"ratio: {value}"))
        with pytest.raises(ProfileError, match=r"field 'gear\.ratio': Input should be a valid"):
            load_profile(bad)
    # YAML 1.2 numbers: an exponent without a sign is a number, not a string
    ok = tmp_path / "ok.yaml"
    ok.write_text(text.replace("ratio: 30.99", "ratio: 3.099e1"))
    assert load_profile(ok).gear.ratio == pytest.approx(30.99)


def test_a_conveyor_id_is_at_most_100_characters_and_names_a_page_of_any_length() -> None:
    from chaintwin.read.profile import MAX_ID_LENGTH
    from chaintwin.report.html import report_file_name

    d = reference_dict()
    d["id"] = "x" * (MAX_ID_LENGTH + 200)
    with pytest.raises(ProfileError, match=r"field 'id': String should have at most 100"):
        parse_profile(d, "p.yaml")
    d["id"] = "é" * MAX_ID_LENGTH  # 200 bytes in UTF-8
    assert parse_profile(d, "p.yaml").id == d["id"]
    for conveyor in ("é" * MAX_ID_LENGTH, "ü" * 300, "a/b" * 100):
        name = report_file_name(conveyor)
        assert len(name.encode()) <= 255 and name.endswith(".html")
    assert report_file_name("ü" * 300) != report_file_name("ü" * 299)  # cut names stay apart
