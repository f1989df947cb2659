"""The writer produces the contract format; round trips are lossless to the printed precision."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import make_text, to_semicolon

from chaintwin import format_recording, parse_recording, read_recording, write_recording
from chaintwin.read.writer import DEFAULT_DECIMALS, _fix_negative_zero


@pytest.mark.parametrize("dialect", [",", ";"])
def test_round_trip_text_is_stable(dialect: str) -> None:
    rec = parse_recording(make_text(), "a.csv")
    first = format_recording(rec, dialect=dialect)
    again = parse_recording(first, "b.csv")
    assert format_recording(again, dialect=dialect) == first
    assert again.metadata == rec.metadata
    assert again.units == rec.units


def test_values_survive_to_printed_precision() -> None:
    rec = parse_recording(make_text(), "a.csv")
    back = parse_recording(format_recording(rec), "b.csv")
    for name, values in rec.channels.items():
        np.testing.assert_allclose(back.channels[name], values, rtol=1e-12, atol=1e-12)


def test_original_text_reproduced_in_its_units() -> None:
    """The bundled test text uses rpm, inc and %: the writer prints the same numbers."""
    text = make_text()
    rec = parse_recording(text, "a.csv")
    out = format_recording(
        rec,
        decimals={"time": 3, "speed_setpoint": 1, "speed": 1, "torque_setpoint": 2, "torque": 2},
    )
    # data lines identical, but for "-0.00" that the writer prints as "0.00"
    assert out.split("\n")[6:] == _fix_negative_zero(text).split("\n")[6:]


def test_unit_change_and_semicolon_dialect() -> None:
    rec = parse_recording(make_text(), "a.csv")
    text = format_recording(
        rec, units={"speed": "rad/s", "torque": "Nm", "position": "rev", "time": "ms"}, dialect=";"
    )
    header = next(line for line in text.split("\n") if line.startswith("time"))
    assert header.split(";")[0] == "time [ms]"
    assert "speed [rad/s]" in header
    back = parse_recording(text, "b.csv")
    np.testing.assert_allclose(back.speed, rec.speed, atol=0.5 * 10 ** -DEFAULT_DECIMALS["rad/s"])
    np.testing.assert_allclose(back.torque, rec.torque, atol=0.5 * 10 ** -DEFAULT_DECIMALS["Nm"])
    assert back.position is not None and rec.position is not None
    np.testing.assert_allclose(back.position, rec.position, atol=2 * np.pi * 0.5e-7)
    # the ';' text is the ',' text with the marks swapped
    comma = format_recording(
        rec, units={"speed": "rad/s", "torque": "Nm", "position": "rev", "time": "ms"}
    )
    assert to_semicolon(comma) == text


def test_write_file_is_atomic_and_readable(tmp_path) -> None:  # type: ignore[no-untyped-def]
    rec = parse_recording(make_text(), "a.csv")
    path = write_recording(rec, tmp_path / "out.csv")
    assert not (tmp_path / "out.csv.tmp").exists()
    np.testing.assert_allclose(read_recording(path).torque, rec.torque, atol=1e-12)


def test_negative_zero_is_printed_unsigned() -> None:
    rec = parse_recording(make_text(direction=-1), "a.csv")
    text = format_recording(rec)
    for line in text.split("\n")[6:]:
        for cell in line.split(","):
            assert not (cell.startswith("-") and float(cell) == 0.0), line


def _savetxt_body(table: np.ndarray, fmts: list[str]) -> str:
    """The body as the writer printed it before: numpy's savetxt, then '-0.0' as '0.0' cell
    by cell."""
    import io

    buf = io.StringIO()
    np.savetxt(buf, table, fmt=fmts, delimiter=",")
    lines = []
    for line in buf.getvalue().split("\n"):
        cells = line.split(",")
        cells = [c[1:] if c.startswith("-0") and float(c) == 0.0 else c for c in cells]
        lines.append(",".join(cells))
    return "\n".join(lines)


@pytest.mark.parametrize("units", [None, {"speed": "rad/s", "torque": "Nm", "time": "ms"}])
def test_body_is_printed_as_savetxt_prints_it_with_negative_zeros_dropped(
    units: dict[str, str] | None,
) -> None:
    from chaintwin.units import UnitContext, from_si_factor

    rec = parse_recording(make_text(), "a.csv")
    rng = np.random.default_rng(5)
    n = rec.time.shape[0]
    channels = dict(rec.channels)
    # zeros of both signs, values that print as -0.000 and as -0.001, large ones
    mixed = rng.choice([0.0, -0.0, -1e-9, -4e-4, -6e-4, 1e-9, -0.5, 12345.678901, -98765.4321], n)
    channels["speed"] = mixed
    channels["torque"] = -np.abs(mixed)
    rec = rec.__class__(
        source=rec.source, channels=channels, units=rec.units, headers=rec.headers,
        metadata=rec.metadata,
    )  # fmt: skip
    text = format_recording(rec, units=units)
    chosen = {**rec.units, **(units or {})}
    meta = rec.metadata
    ctx = UnitContext(
        increments_per_rev=meta.increments_per_rev, nominal_torque_nm=meta.nominal_torque_nm
    )
    table = np.column_stack(
        [rec.channels[k] * from_si_factor(k, chosen[k], ctx) for k in rec.channels]
    )
    fmts = [f"%.{DEFAULT_DECIMALS[chosen[k]]}f" for k in rec.channels]
    header_at = text.index("\ntime [") + 1
    body = text[text.index("\n", header_at) + 1 :]
    assert body == _savetxt_body(table, fmts)
    # the case arose: numpy printed negative zeros, and negative numbers that stay
    import io
    import re

    raw = io.StringIO()
    np.savetxt(raw, table, fmt=fmts, delimiter=",")
    negative_zero = re.compile(r"(?m)(^|,)-0(\.0+)?(,|$)")
    assert negative_zero.search(raw.getvalue()) and not negative_zero.search(body)
    assert re.search(r"(?m)(^|,)-0\.0*[1-9]", body)
