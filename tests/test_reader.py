"""Known-answer tests of the recording reader: every unit, both dialects, metadata."""

from __future__ import annotations

import math
from datetime import UTC, datetime, timedelta, timezone

import numpy as np
import pytest
from conftest import make_text, to_semicolon

from chaintwin import parse_recording, read_recording
from chaintwin.read.columns import ColumnMap
from chaintwin.read.profile import ConveyorProfile

N = 40


def grid(header: str, rows: list[str], meta: str = "") -> str:
    return meta + header + "\n" + "\n".join(rows) + "\n"


def const_rows(values: str, n: int = N, dt_ms: float = 6.0, time_in_ms: bool = False) -> list[str]:
    """n rows: a time column then the given fixed values."""
    out = []
    for k in range(n):
        t = k * dt_ms if time_in_ms else k * dt_ms / 1000.0
        out.append(f"{t:.3f},{values}")
    return out


@pytest.mark.parametrize(
    ("unit", "value", "expected"),
    [
        ("rad/s", "10.5", 10.5),
        ("rpm", "1415", 1415 * 2 * math.pi / 60),
        ("1/min", "60", 2 * math.pi),
    ],
)
def test_speed_units(unit: str, value: str, expected: float) -> None:
    text = grid(f"time [s],speed [{unit}],torque [Nm]", const_rows(f"{value},1.0"))
    rec = parse_recording(text, "r.csv")
    np.testing.assert_allclose(rec.speed, expected, rtol=1e-15)
    assert rec.units["speed"] == unit
    assert rec.si_units()["speed"] == "rad/s"


@pytest.mark.parametrize(
    ("unit", "value", "meta", "expected"),
    [
        ("rad", "3.5", "", 3.5),
        ("rev", "2.25", "", 2.25 * 2 * math.pi),
        ("inc", "6144", "# increments_per_rev: 4096\n", 1.5 * 2 * math.pi),
    ],
)
def test_position_units(unit: str, value: str, meta: str, expected: float) -> None:
    text = grid(
        f"time [s],speed [rpm],position [{unit}],torque [Nm]",
        const_rows(f"0,{value},1.0"),
        meta,
    )
    rec = parse_recording(text, "r.csv")
    assert rec.position is not None
    np.testing.assert_allclose(rec.position, expected, rtol=1e-15)


@pytest.mark.parametrize(
    ("unit", "value", "meta", "expected"),
    [
        ("Nm", "1.25", "", 1.25),
        ("%", "40", "# nominal_torque_nm: 2.5\n", 1.0),
    ],
)
def test_torque_units(unit: str, value: str, meta: str, expected: float) -> None:
    text = grid(
        f"time [s],speed [rpm],torque_setpoint [{unit}],torque [{unit}]",
        const_rows(f"0,{value},{value}"),
        meta,
    )
    rec = parse_recording(text, "r.csv")
    np.testing.assert_allclose(rec.torque, expected, rtol=1e-15)
    assert rec.torque_setpoint is not None
    np.testing.assert_allclose(rec.torque_setpoint, expected, rtol=1e-15)


def test_time_in_ms() -> None:
    text = grid("time [ms],speed [rpm],torque [Nm]", const_rows("0,0", time_in_ms=True))
    rec = parse_recording(text, "r.csv")
    np.testing.assert_allclose(rec.time, np.arange(N) * 0.006, rtol=1e-12)
    assert rec.sample_time_s == pytest.approx(0.006)


def test_percent_torque_from_profile_and_metadata_wins(reference_profile: ConveyorProfile) -> None:
    body = const_rows("0,40")
    no_meta = grid("time [s],speed [rpm],torque [%]", body)
    rec = parse_recording(no_meta, "r.csv", profile=reference_profile)  # nominal 2.5 Nm
    np.testing.assert_allclose(rec.torque, 1.0)
    with_meta = grid("time [s],speed [rpm],torque [%]", body, "# nominal_torque_nm: 5.0\n")
    rec = parse_recording(with_meta, "r.csv", profile=reference_profile)
    np.testing.assert_allclose(rec.torque, 2.0)


def test_digital_inputs_and_extra_channels_kept() -> None:
    text = grid(
        "time [s],speed [rpm],torque [Nm],digital_inputs [-],motor_temp [degC],dc_link [V]",
        [f"{k * 0.006:.3f},0,0,{k % 4},{40 + k * 0.1:.1f},565" for k in range(N)],
    )
    rec = parse_recording(text, "r.csv")
    assert rec.digital_inputs is not None
    assert rec.digital_inputs.dtype == np.int64
    np.testing.assert_array_equal(rec.digital_inputs, np.arange(N) % 4)
    assert rec.extra_channels == ("motor_temp", "dc_link")
    assert rec.units["motor_temp"] == "degC"
    np.testing.assert_allclose(rec.channels["motor_temp"], 40 + np.arange(N) * 0.1, rtol=1e-12)
    assert rec.si_units()["dc_link"] == "V"


def test_column_order_is_free() -> None:
    a = grid(
        "time [s],speed [rpm],torque [Nm]", [f"{k * 0.006:.3f},{k},{k / 10}" for k in range(N)]
    )
    b = grid(
        "torque [Nm],time [s],speed [rpm]", [f"{k / 10},{k * 0.006:.3f},{k}" for k in range(N)]
    )
    ra, rb = parse_recording(a, "a"), parse_recording(b, "b")
    for name in ("time", "speed", "torque"):
        np.testing.assert_array_equal(ra.channels[name], rb.channels[name])


def test_both_dialects_give_identical_recordings() -> None:
    text = make_text()
    comma = parse_recording(text, "c.csv")
    semi = parse_recording(to_semicolon(text), "s.csv")
    assert list(comma.channels) == list(semi.channels)
    for name in comma.channels:
        np.testing.assert_array_equal(comma.channels[name], semi.channels[name])
    assert comma.metadata == semi.metadata


def test_semicolon_known_values() -> None:
    text = grid(
        "time [s];speed [rpm];torque [Nm]",
        [f"{k * 0.006:.3f};-12,5;0,75".replace(".", ",") for k in range(N)],
    )
    rec = parse_recording(text, "r.csv")
    np.testing.assert_allclose(rec.speed, -12.5 * 2 * math.pi / 60)
    np.testing.assert_allclose(rec.torque, 0.75)
    np.testing.assert_allclose(rec.time[1], 0.006)


def test_metadata_typed_and_unknown_keys_kept() -> None:
    meta = (
        "# conveyor: white-belt-01\n"
        "# recorded_at: 2026-11-21T10:15:00Z\n"
        "# sample_time_s: 0.006\n"
        "# payload_kg: 20\n"
        "# tray_kg: 9.5\n"
        "# operator: J. Doe\n"
        "# a free comment line without a key\n"
    )
    rec = parse_recording(grid("time [s],speed [rpm],torque [Nm]", const_rows("0,0"), meta), "r")
    m = rec.metadata
    assert m.conveyor == "white-belt-01"
    assert m.recorded_at == datetime(2026, 11, 21, 10, 15, tzinfo=UTC)
    assert m.sample_time_s == 0.006
    assert m.payload_kg == 20.0
    assert m.tray_kg == 9.5
    assert m.extra == {"operator": "J. Doe"}


def test_recorded_at_offset_and_naive_is_utc() -> None:
    def stamp(value: str) -> datetime | None:
        text = grid(
            "time [s],speed [rpm],torque [Nm]", const_rows("0,0"), f"# recorded_at: {value}\n"
        )
        return parse_recording(text, "r").metadata.recorded_at

    assert stamp("2026-11-21T11:15:00+01:00") == datetime(
        2026, 11, 21, 11, 15, tzinfo=timezone(timedelta(hours=1))
    )
    naive = stamp("2026-11-21T10:15:00")
    assert naive is not None
    assert naive.tzinfo == UTC


def test_crlf_bom_and_cp1252(write) -> None:  # type: ignore[no-untyped-def]
    text = make_text()
    ref = parse_recording(text, "x")
    crlf = ("\ufeff" + text.replace("\n", "\r\n")).encode("utf-8")
    rec = read_recording(write(crlf))
    np.testing.assert_array_equal(rec.torque, ref.torque)
    latin = text.replace(
        "# conveyor: white-belt-01", "# conveyor: white-belt-01\n# Ort: Fördertechnik Süd"
    )
    rec = read_recording(write(latin.encode("cp1252"), "cp.csv"))
    assert rec.metadata.extra["Ort"] == "Fördertechnik Süd"


def test_blank_lines_between_rows_are_tolerated() -> None:
    rows = const_rows("0,0")
    rows.insert(10, "")
    rec = parse_recording(grid("time [s],speed [rpm],torque [Nm]", rows) + "\n\n", "r")
    assert rec.samples == N


def test_column_map_reads_vendor_export() -> None:
    cmap = ColumnMap.model_validate(
        {
            "columns": {
                "Zeit [ms]": {"name": "time", "unit": "ms"},
                "Actual speed [1/min]": {"name": "speed", "unit": "rpm"},
                "n_set": {"name": "speed_setpoint", "unit": "rpm"},
                "Istwert Moment": {"name": "torque", "unit": "%"},
            }
        }
    )
    text = grid(
        "Zeit [ms];n_set;Actual speed [1/min];Istwert Moment;Temperatur [°C]",
        [f"{k * 6};100,0;99,5;40,0;35,5" for k in range(N)],
        "# nominal_torque_nm: 2.5\n",
    )
    rec = parse_recording(text, "vendor.csv", column_map=cmap)
    np.testing.assert_allclose(rec.speed, 99.5 * 2 * math.pi / 60)
    np.testing.assert_allclose(rec.torque, 1.0)
    assert rec.speed_setpoint is not None
    np.testing.assert_allclose(rec.time[-1], (N - 1) * 0.006)
    assert rec.headers["speed"] == "Actual speed [1/min]"
    assert rec.units["Temperatur"] == "°C"


def test_long_recordings_are_read() -> None:
    text = make_text(n=5000, dt=0.002)
    assert parse_recording(text, "long").samples == 5000


def test_slow_path_values_equal_fast_path() -> None:
    text = make_text()
    fast = parse_recording(text, "f")
    # a blank line forces the line-by-line parser
    slow_text = text.replace("\n0.012,", "\n\n0.012,", 1)
    slow = parse_recording(slow_text, "s")
    for name in fast.channels:
        np.testing.assert_array_equal(fast.channels[name], slow.channels[name])


def test_zero_tray_and_repeated_unknown_keys_are_kept() -> None:
    meta = "# tray_kg: 0\n# note: first\n# note: second\n"
    rec = parse_recording(grid("time [s],speed [rpm],torque [Nm]", const_rows("0,0"), meta), "r")
    assert rec.metadata.tray_kg == 0.0
    assert rec.metadata.extra == {"note": "second"}
