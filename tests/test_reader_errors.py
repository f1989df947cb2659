"""Every contract violation is refused with the file, the place and what to do."""

from __future__ import annotations

import pytest
from conftest import make_text

from chaintwin import RecordingError, parse_recording, read_recording
from chaintwin.cli.common import error_message

N = 40
OK_HEAD = "time [s],speed [rpm],torque [Nm]"


def rows(n: int = N) -> list[str]:
    return [f"{k * 0.006:.3f},{k}.0,0.5" for k in range(n)]


def text_of(header: str, body: list[str], meta: str = "") -> str:
    return meta + header + "\n" + "\n".join(body) + "\n"


def refuse(text: str | bytes, source: str = "bad.csv") -> RecordingError:
    with pytest.raises(RecordingError) as info:
        parse_recording(text, source)
    err = info.value
    msg = str(err)
    assert msg.startswith(source), msg
    assert "\n" not in msg, msg
    return err


def test_missing_required_column() -> None:
    err = refuse(text_of("time [s],speed [rpm]", [f"{k * 0.006:.3f},1" for k in range(N)]))
    assert "missing required column 'torque'" in str(err)
    assert err.line == 1
    assert err.field == "column_map"
    assert "--columns" in error_message(err)  # the command line names its option


def test_unknown_unit_names_column() -> None:
    err = refuse(text_of("time [s],speed [rps],torque [Nm]", rows()))
    assert err.column == "speed [rps]"
    assert "unknown unit 'rps'" in str(err)
    assert "rad/s, rpm, 1/min" in str(err)


def test_header_without_unit() -> None:
    err = refuse(text_of("time [s],speed,torque [Nm]", rows()))
    assert "column 2" in str(err)
    assert "'speed'" in str(err)
    assert err.line == 1


def test_duplicate_column() -> None:
    err = refuse(
        text_of(
            "time [s],speed [rpm],speed [rad/s],torque [Nm]",
            [f"{k * 0.006:.3f},1,1,1" for k in range(N)],
        )
    )
    assert "appears twice" in str(err)


def test_non_monotonic_time_names_line() -> None:
    body = rows()
    body[20] = "0.110,20.0,0.5"  # 0.110 < 0.114 before it
    err = refuse(text_of(OK_HEAD, body, "# conveyor: c\n"))
    assert err.line == 3 + 20  # metadata line, header, then row 0 on line 3
    assert err.column == "time [s]"
    assert "does not increase" in str(err)


def test_repeated_time_is_refused() -> None:
    body = rows()
    body[5] = body[4]
    err = refuse(text_of(OK_HEAD, body))
    assert err.line == 1 + 5 + 1


def test_nan_names_line_and_column() -> None:
    body = rows()
    body[7] = "0.042,nan,0.5"
    err = refuse(text_of(OK_HEAD, body))
    assert err.line == 9
    assert err.column == "speed [rpm]"
    assert "finite number" in str(err)


def test_empty_field_is_not_a_number() -> None:
    body = rows()
    body[3] = "0.018,,0.5"
    err = refuse(text_of(OK_HEAD, body))
    assert err.line == 5
    assert err.column == "speed [rpm]"
    assert "not a number" in str(err)


def test_text_value_names_line_and_column() -> None:
    body = rows()
    body[30] = "0.180,fast,0.5"
    err = refuse(text_of(OK_HEAD, body))
    assert (err.line, err.column) == (32, "speed [rpm]")
    assert "'fast'" in str(err)


def test_wrong_field_count() -> None:
    body = rows()
    body[12] = "0.072,12.0"
    err = refuse(text_of(OK_HEAD, body))
    assert err.line == 14
    assert "has 2 fields, the header has 3" in str(err)


def test_too_few_samples() -> None:
    err = refuse(text_of(OK_HEAD, rows(31)))
    assert "holds 31 samples; at least 32" in str(err)


def test_percent_without_nominal_torque() -> None:
    err = refuse(text_of("time [s],speed [rpm],torque [%]", rows()))
    assert err.column == "torque [%]"
    assert "nominal_torque_nm" in str(err)
    assert "add '# nominal_torque_nm" in str(err)


def test_inc_without_increments_per_rev() -> None:
    err = refuse(
        text_of(
            "time [s],speed [rpm],position [inc],torque [Nm]",
            [f"{k * 0.006:.3f},1,{k},1" for k in range(N)],
        )
    )
    assert err.column == "position [inc]"
    assert "increments_per_rev" in str(err)


@pytest.mark.parametrize(
    ("line", "expect"),
    [
        ("# sample_time_s: 0,006", "use '.' as decimal mark"),
        ("# payload_kg: heavy", "not a number"),
        ("# nominal_torque_nm: -2.5", "positive number"),
        ("# recorded_at: yesterday", "ISO 8601"),
        ("# recorded_at: 2026-13-01T00:00:00Z", "ISO 8601"),
    ],
)
def test_bad_metadata_names_line(line: str, expect: str) -> None:
    err = refuse(text_of(OK_HEAD, rows(), "# conveyor: c1\n" + line + "\n"))
    assert expect in str(err)
    assert err.line == 2


def test_duplicate_metadata_key() -> None:
    err = refuse(text_of(OK_HEAD, rows(), "# payload_kg: 1\n# payload_kg: 2\n"))
    assert err.line == 2
    assert "given twice" in str(err)


def test_empty_and_header_only_files() -> None:
    assert "no header row" in str(refuse(""))
    assert "no header row" in str(refuse("# conveyor: x\n\n"))
    assert "holds 0 samples" in str(refuse(OK_HEAD + "\n"))


def test_binary_file() -> None:
    assert "binary" in str(refuse(b"\x00\x01\x02PK\x03\x04"))


def test_out_of_range_value_after_conversion() -> None:
    # 1e308 revolutions is a finite number; in radians it is not
    body = [f"{k * 0.006:.3f},0,1e308,0.5" for k in range(N)]
    err = refuse(text_of("time [s],speed [rpm],position [rev],torque [Nm]", body))
    assert err.column == "position [rev]"
    assert "too large" in str(err)


def test_missing_file_and_folder(tmp_path) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(RecordingError, match="cannot be read"):
        read_recording(tmp_path / "nope.csv")
    with pytest.raises(RecordingError, match="is a folder"):
        read_recording(tmp_path)


def test_error_in_semicolon_dialect_names_line() -> None:
    text = make_text().replace(",", ";")
    lines = text.split("\n")
    lines[20] = lines[20].split(";")[0] + ";x" * 7
    err = refuse("\n".join(lines))
    assert err.line == 21


def test_cli_names_the_option_where_the_library_names_the_field() -> None:
    from chaintwin.errors import ModelError

    assert error_message(ModelError("days 0: must be at least 1", field="days")) == (
        "--days 0: must be at least 1"
    )
    # only the field as a whole word, only its first mention
    err = ModelError("per_day 0 (days 3, per_day below 1)", field="per_day")
    assert error_message(err) == "--per-day 0 (days 3, per_day below 1)"
    # no field, or a field no option sets: the library's words stand
    assert error_message(ModelError("days 0")) == "days 0"
    assert error_message(ModelError("speed_rpm 0", field="speed_rpm")) == "speed_rpm 0"


def test_values_no_drive_records_are_refused_at_their_line_and_column() -> None:
    from conftest import REFERENCE_PROFILE

    from chaintwin.read.profile import load_profile

    profile = load_profile(REFERENCE_PROFILE)  # nominal 1415 rpm, 2.5 Nm
    body = rows()
    # torque 30 Nm: over ten times the 2.5 Nm nominal torque (from the metadata)
    bad = [*body[:7], "0.042,7.0,30.0", *body[8:]]
    err = refuse(text_of(OK_HEAD, bad, "# nominal_torque_nm: 2.5\n"))
    assert (err.line, err.column) == (10, "torque [Nm]")
    assert "more than 10 times the nominal torque" in str(err)
    # the same sample without a nominal torque anywhere: nothing to compare with
    assert parse_recording(text_of(OK_HEAD, bad), "x.csv").samples == N
    # a percent torque of 1e300 %: refused (too large to convert, or implausible)
    huge = [*body[:3], "0.018,3.0,1e300", *body[4:]]
    err = refuse(text_of("time [s],speed [rpm],torque [%]", huge, "# nominal_torque_nm: 2.5\n"))
    assert (err.line, err.column) == (6, "torque [%]")
    # speed 5000 rpm: over three times the profile's 1415 rpm
    fast = [*body[:10], "0.060,5000.0,0.5", *body[11:]]
    with pytest.raises(RecordingError) as info:
        parse_recording(text_of(OK_HEAD, fast), "bad.csv", profile=profile)
    assert (info.value.line, info.value.column) == (12, "speed [rpm]")
    assert "3 times the nominal speed" in str(info.value)


def test_sample_times_and_dates_out_of_range_are_refused() -> None:
    # 6 µs apart: the time column was exported in ms, read as s
    micro = [f"{k * 0.000006:.6f},{k}.0,0.5" for k in range(N)]
    err = refuse(text_of(OK_HEAD, micro))
    assert err.column == "time [s]"
    assert "0.1 to 100 ms" in str(err)
    err = refuse(text_of(OK_HEAD, rows(), "# sample_time_s: 6\n"))
    assert err.line == 1
    assert "sample_time_s" in str(err)
    for stamp in ("0001-01-01T00:30:00+01:00", "1969-12-31T23:59:59Z", "2201-01-01T00:00:00Z"):
        err = refuse(text_of(OK_HEAD, rows(), f"# recorded_at: {stamp}\n"))
        assert err.line == 1
        assert "between 1970 and 2200" in str(err), stamp
