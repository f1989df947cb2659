"""The data contract's recording format, CSV: the first registered format.

Drive recordings ("scopes") read exactly as the data contract writes them
(:mod:`chaintwin.read.formats` dispatches a file to its format; this module
is one, with ``NAME``, ``PATTERNS``, :func:`recognises`,
:func:`parse_recording` and :func:`parse_metadata`).

The format (docs/data-contract.md, section 1)::

    # conveyor: white-belt-01
    # sample_time_s: 0.006
    time [s],speed_setpoint [rpm],speed [rpm],...,torque [%],digital_inputs [-]
    0.000,0.0,0.3,...

* optional leading ``# key: value`` metadata lines (numbers with ``.``);
* one header row of ``name [unit]`` cells (or headers a column map knows);
* ``,`` separated fields with ``.`` decimals, or ``;`` separated with ``,``
  decimals, detected from the header row.

Reading is on the hot path of every fleet run. The numeric body is parsed in
one compiled pass (:mod:`chaintwin.read.fastparse`) that also checks every
row's field count; only when that fast path fails does a line-by-line parser
run, which handles the unusual (blank lines, long mantissas) or names the bad
line.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from datetime import UTC, datetime
from typing import TYPE_CHECKING

import numpy as np

from chaintwin._types import FloatArray
from chaintwin.errors import RecordingError
from chaintwin.read.columns import ColumnMap
from chaintwin.read.fastparse import parse_grid
from chaintwin.read.recording import Metadata, Recording
from chaintwin.units import (
    CANONICAL_CHANNELS,
    REQUIRED_CHANNELS,
    RPM_TO_RAD_S,
    UnitContext,
    to_si_factor,
)

if TYPE_CHECKING:
    from chaintwin.read.profile import ConveyorProfile

__all__ = [
    "MAX_COLUMNS",
    "MAX_VALUES",
    "MIN_SAMPLES",
    "NAME",
    "PATTERNS",
    "parse_metadata",
    "parse_recording",
    "recognises",
    "recording_from_samples",
]

NAME = "csv"
"""The format's name (:mod:`chaintwin.read.formats`)."""

PATTERNS: tuple[str, ...] = ("*.csv",)
"""File patterns of the format's files."""

MIN_SAMPLES = 32
"""Fewest samples a recording may hold."""

MAX_VALUES = 8_000_000
"""Most values (sample lines × columns) a recording may hold: 64 MB as numbers, a
thousand times a scope's 2048 samples × 8 channels; more is refused before parsing."""

MAX_COLUMNS = 256
"""Most header columns a recording may have (a drive's scope has a few dozen); more is
refused before the header is looked at cell by cell."""

SAMPLE_TIME_RANGE_S = (1e-4, 0.1)
"""Sample times a drive scope can have, s (0.1 to 100 ms); others are refused."""

YEAR_RANGE = (1970, 2200)
"""Years a recording may be dated in; others are refused."""

MAX_TORQUE_NOMINALS = 10.0
"""|torque| above this many nominal torques is no drive's recording: refused."""

MAX_SPEED_NOMINALS = 3.0
"""|speed| above this many nominal speeds is no drive's recording: refused."""

_HEADER_RE = re.compile(r"^\s*(?P<name>[^\[\]]*?)\s*\[(?P<unit>[^\[\]]*)\]\s*$")
_NUMBER_KEYS = ("sample_time_s", "nominal_torque_nm", "increments_per_rev", "payload_kg", "tray_kg")


def recognises(name: str, head: bytes) -> bool:
    """Every file: the data contract's text is what a file no other format
    recognises is read as (its refusal names what is wrong with it)."""
    return True


def parse_metadata(raw: bytes, source: str) -> Metadata:
    """The ``# key: value`` metadata of a recording's bytes
    (:func:`~chaintwin.read.formats.read_metadata`)."""
    items, _lineno, _header, _body = _split_head(source, _decode(raw))
    return _parse_metadata(source, items)


def _decode(raw: bytes) -> str:
    if raw.startswith(b"\xef\xbb\xbf"):
        raw = raw[3:]
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError:
        # Inverter tools on Windows export in cp1252; latin-1 never fails.
        try:
            return raw.decode("cp1252")
        except UnicodeDecodeError:
            return raw.decode("latin-1")


def _parse_metadata(source: str, items: list[tuple[int, str, str]]) -> Metadata:
    values: dict[str, object] = {}
    extra: dict[str, str] = {}
    for lineno, key, value in items:
        if key in extra:
            extra[key] = value  # unknown keys are kept, not rejected: the last one wins
            continue
        if key in values:
            raise RecordingError(
                source, f"metadata key '{key}' is given twice; keep one", line=lineno
            )
        if key in _NUMBER_KEYS:
            try:
                number = float(value)
            except ValueError:
                hint = " (use '.' as decimal mark)" if "," in value else ""
                raise RecordingError(
                    source, f"metadata '{key}' is '{value}', not a number{hint}", line=lineno
                ) from None
            if (
                not np.isfinite(number)
                or number < 0
                or (number == 0 and key not in ("payload_kg", "tray_kg"))
            ):
                raise RecordingError(
                    source,
                    f"metadata '{key}' is {value}; it must be a positive number",
                    line=lineno,
                )
            low, high = SAMPLE_TIME_RANGE_S
            if key == "sample_time_s" and not low <= number <= high:
                raise RecordingError(
                    source,
                    f"metadata 'sample_time_s' is {value} s; a drive scope samples every "
                    f"{low * 1e3:g} to {high * 1e3:g} ms (is the unit s?)",
                    line=lineno,
                )
            values[key] = number
        elif key == "recorded_at":
            try:
                stamp = datetime.fromisoformat(value)
            except ValueError:
                raise RecordingError(
                    source,
                    f"metadata 'recorded_at' is '{value}', not an ISO 8601 time "
                    "(e.g. 2026-11-21T10:15:00Z)",
                    line=lineno,
                ) from None
            if not YEAR_RANGE[0] <= stamp.year <= YEAR_RANGE[1]:
                raise RecordingError(
                    source,
                    f"metadata 'recorded_at' is '{value}'; a recording is dated between "
                    f"{YEAR_RANGE[0]} and {YEAR_RANGE[1]} (check the drive's clock)",
                    line=lineno,
                )
            values[key] = stamp if stamp.tzinfo else stamp.replace(tzinfo=UTC)
        elif key == "conveyor":
            if not value:
                raise RecordingError(source, "metadata 'conveyor' is empty", line=lineno)
            values[key] = value
        else:
            extra[key] = value
    return Metadata(extra=extra, **values)  # type: ignore[arg-type]


def _split_head(source: str, text: str) -> tuple[list[tuple[int, str, str]], int, str, str]:
    """Return (metadata items, header line number, header line, body text)."""
    items, lineno, header, pos = _head(source, text)
    return items, lineno, header, text[pos:]


def _head(source: str, text: str) -> tuple[list[tuple[int, str, str]], int, str, int]:
    """Return (metadata items, header line number, header line, where the body starts)."""
    items: list[tuple[int, str, str]] = []
    pos = 0
    lineno = 0
    n = len(text)
    while pos < n:
        end = text.find("\n", pos)
        if end < 0:
            end = n
        line = text[pos:end]
        lineno += 1
        pos = end + 1
        stripped = line.strip()
        if not stripped:
            continue
        if stripped.startswith("#"):
            body = stripped[1:].strip()
            key, sep, value = body.partition(":")
            if sep and key.strip() and " " not in key.strip():
                items.append((lineno, key.strip(), value.strip()))
            continue  # other comment lines are allowed and ignored
        return items, lineno, line, min(pos, n)
    raise RecordingError(
        source,
        "holds no header row; a recording needs a row like 'time [s],speed [rpm],torque [Nm]'",
    )


def _parse_header(
    source: str, header: str, sep: str, lineno: int, column_map: ColumnMap | None
) -> tuple[list[str], list[str], list[str]]:
    ncols = header.count(sep) + 1
    if ncols > MAX_COLUMNS:
        raise RecordingError(
            source,
            f"header row has {ncols} columns, more than the {MAX_COLUMNS} a recording may have; "
            "is this a drive recording?",
            line=lineno,
        )
    cells = [c.strip().strip('"').strip() for c in header.split(sep)]
    names: list[str] = []
    units: list[str] = []
    seen: set[str] = set()
    for idx, cell in enumerate(cells, start=1):
        target = column_map.lookup(cell) if column_map is not None else None
        if target is not None:
            name, unit = target.name, target.unit
        else:
            match = _HEADER_RE.match(cell)
            if match is None or not match["name"]:
                raise RecordingError(
                    source,
                    f"header of column {idx} is '{cell}', not 'name [unit]'; "
                    "rename it or map it with a column map (column_map)",
                    line=lineno,
                    field="column_map",
                )
            name, unit = match["name"], match["unit"].strip()
            spec = CANONICAL_CHANNELS.get(name)
            if spec is not None and unit not in spec.units:
                raise RecordingError(
                    source,
                    f"unknown unit '{unit}' for {name}; use one of {', '.join(spec.units)}",
                    line=lineno,
                    column=cell,
                )
        if name in seen:
            raise RecordingError(
                source,
                f"channel '{name}' appears twice in the header; keep one column per channel",
                line=lineno,
                column=cell,
            )
        seen.add(name)
        names.append(name)
        units.append(unit)
    missing = [r for r in REQUIRED_CHANNELS if r not in seen]
    if missing:
        found = ", ".join(cells)
        raise RecordingError(
            source,
            f"missing required column '{missing[0]}' (header has: {found}); "
            "add it, or map the exported header to it with a column map (column_map)",
            line=lineno,
            field="column_map",
        )
    return cells, names, units


def _fast_body(buf: bytes, start: int, stop: int, sep: str, ncols: int) -> FloatArray | None:
    """Parse the numeric body ``buf[start:stop]`` in one compiled pass, in place.

    None when anything is unusual. Every value takes at least two characters
    (a digit and a separator or line end): a body too short for ``lines ×
    columns`` values (blank lines) is left to the line-by-line parser
    without allocating its grid. The grid is in column order, so each
    channel is a contiguous column of it (no copy).
    """
    nrows = buf.count(b"\n", start, stop) + 1
    if 2 * nrows * ncols - 1 > stop - start:
        return None
    view = memoryview(buf)[start:stop]
    return parse_grid(view, sep, "." if sep == "," else ",", nrows, ncols)


def _rstrip_end(text: str, start: int) -> int:
    """Where ``text[start:]`` ends once trailing whitespace is stripped (no copy of it)."""
    end = len(text)
    while end > start:
        low = max(start, end - 4096)
        chunk = text[low:end]
        if not chunk.isspace():
            return low + len(chunk.rstrip())
        end = low
    return end


def _lstrip_newlines(text: str, start: int, stop: int) -> int:
    """Where ``text[start:stop]`` starts once leading line ends are stripped (no copy)."""
    while start < stop:
        chunk = text[start : min(stop, start + 4096)]
        kept = len(chunk.lstrip("\n"))
        start += len(chunk) - kept
        if kept:
            break
    return start


def _slow_body(
    source: str, body: str, sep: str, cells: list[str], first_line: int
) -> tuple[FloatArray, list[int]]:
    """Parse line by line; raise naming the first bad line and column.

    The lines are taken one at a time (no list of them all) into a table
    that doubles as rows come, up to the most rows the body can hold (each
    takes at least two characters a column), so memory follows the values,
    not the line count.
    """
    ncols = len(cells)
    most = min(body.count("\n") + 1, len(body) // (2 * ncols) + 1)
    table = np.empty((min(most, 1024), ncols), dtype=np.float64)
    nrows = 0
    linenos: list[int] = []
    pos = 0
    n = len(body)
    offset = -1
    while pos <= n:
        end = body.find("\n", pos)
        if end < 0:
            end = n
        line = body[pos:end]
        pos = end + 1
        offset += 1
        lineno = first_line + offset
        if not line.strip():
            continue
        fields = line.split(sep)
        if len(fields) != ncols:
            raise RecordingError(
                source,
                f"has {len(fields)} fields, the header has {ncols}; "
                f"every row needs one value per column (separator '{sep}')",
                line=lineno,
            )
        row: list[float] = []
        for cell, value in zip(cells, fields, strict=True):
            text = value.strip()
            if sep == ";":
                text = text.replace(",", ".")
            try:
                if not text or "_" in text:
                    raise ValueError(text)
                row.append(float(text))
            except ValueError:
                raise RecordingError(
                    source,
                    f"value '{value.strip()}' is not a number; "
                    f"write numbers with '{'.' if sep == ',' else ','}' as decimal mark",
                    line=lineno,
                    column=cell,
                ) from None
        if nrows == table.shape[0]:
            grown = np.empty((min(most, 2 * nrows), ncols), dtype=np.float64)
            grown[:nrows] = table
            table = grown
        table[nrows] = row
        nrows += 1
        linenos.append(lineno)
    return np.asfortranarray(table[:nrows]), linenos


def parse_recording(
    data: bytes | str,
    source: str = "<text>",
    *,
    profile: ConveyorProfile | None = None,
    column_map: ColumnMap | None = None,
) -> Recording:
    """Parse the text of one recording; see :func:`~chaintwin.read.formats.read_recording`.

    Parameters
    ----------
    data : bytes or str
        The file's content.
    source : str
        Name used in messages and kept as ``Recording.source``.
    profile, column_map
        As for :func:`~chaintwin.read.formats.read_recording`.
    """
    # ASCII bytes are their own text: the body is parsed from them where they are
    raw = data if isinstance(data, bytes) and data.isascii() and b"\r" not in data else None
    text = _decode(data) if isinstance(data, bytes) else data
    if "\r" in text:
        text = text.replace("\r\n", "\n").replace("\r", "\n")
    if "\x00" in text:
        raise RecordingError(source, "is a binary file, not a text recording")
    items, header_line, header, start = _head(source, text)
    metadata = _parse_metadata(source, items)

    sep = ";" if ";" in header else ","
    cells, names, units = _parse_header(source, header, sep, header_line, column_map)
    ncols = len(cells)

    stop = _rstrip_end(text, start)
    # leading blank lines between header and data shift the line numbers
    body_at = _lstrip_newlines(text, start, stop)
    first_line = header_line + 1 + text.count("\n", start, body_at)
    if raw is not None:
        buf = raw
        del text  # memory holds the file's bytes once, and the samples
    else:
        buf = text[body_at:stop].encode("utf-8")
        body_at, stop = 0, len(buf)
    lines = buf.count(b"\n", body_at, stop) + 1 if stop > body_at else 0
    if lines * ncols > MAX_VALUES:
        raise RecordingError(
            source,
            f"holds {lines} lines of {ncols} columns, more than the {MAX_VALUES} values a "
            "recording may hold; cut it into shorter recordings",
            line=first_line,
        )
    table = _fast_body(buf, body_at, stop, sep, ncols) if stop > body_at else None
    if table is not None:
        linenos: list[int] | None = None
    else:
        body = str(memoryview(buf)[body_at:stop], "utf-8")
        del buf
        table, linenos = _slow_body(source, body, sep, cells, first_line)

    return _recording(source, metadata, cells, names, units, table, first_line, linenos, profile)


def recording_from_samples(
    head: str,
    table: FloatArray,
    source: str = "<samples>",
    *,
    profile: ConveyorProfile | None = None,
) -> Recording:
    """A recording from the text of its head and its samples as numbers.

    What :func:`parse_recording` makes of ``head`` followed by ``table``
    printed exactly (``%.17g``), without printing and parsing the numbers:
    the same metadata, header and unit checks, the same refusals (with the
    line numbers the rows would have in that text), the same values. A
    drive's scope read over OPC UA comes this way
    (:func:`chaintwin.live.opcua.recording_from_scope`).

    Parameters
    ----------
    head : str
        The ``# key: value`` metadata lines and the header row, ``,``
        separated (``time [s],speed [rpm],...``).
    table : ndarray
        The samples, one row per sample and one column per header cell.
    source : str
        Name used in messages and kept as ``Recording.source``.
    profile : ConveyorProfile, optional
        As for :func:`~chaintwin.read.formats.read_recording`.

    Raises
    ------
    RecordingError
        As :func:`parse_recording` would for the same text.
    """
    if "\r" in head:
        head = head.replace("\r\n", "\n").replace("\r", "\n")
    if "\x00" in head:
        raise RecordingError(source, "is a binary file, not a text recording")
    items, header_line, header, rest = _split_head(source, head)
    if rest.strip():
        raise RecordingError(source, "the head holds more than metadata and one header row")
    metadata = _parse_metadata(source, items)
    sep = ";" if ";" in header else ","
    cells, names, units = _parse_header(source, header, sep, header_line, None)
    # a copy of its own, in column order: the caller's samples are never changed
    table = np.array(table, dtype=np.float64, order="F")
    if table.ndim != 2 or table.shape[1] != len(cells):
        raise RecordingError(
            source,
            f"has {table.shape[-1] if table.ndim else 0} columns of samples, the header has "
            f"{len(cells)}; every row needs one value per column (separator '{sep}')",
            line=header_line + 1,
        )
    return _recording(source, metadata, cells, names, units, table, header_line + 1, None, profile)


def _recording(
    source: str,
    metadata: Metadata,
    cells: list[str],
    names: list[str],
    units: list[str],
    table: FloatArray,
    first_line: int,
    linenos: list[int] | None,
    profile: ConveyorProfile | None,
) -> Recording:
    """The checks and unit conversions of a parsed recording's samples (one code path
    for files and for samples read otherwise, :func:`recording_from_samples`)."""

    def line_of(row: int) -> int:
        return linenos[row] if linenos is not None else first_line + row

    nrows = table.shape[0]
    if nrows < MIN_SAMPLES:
        raise RecordingError(
            source,
            f"holds {nrows} samples; at least {MIN_SAMPLES} are needed (record a longer scope)",
        )
    # column by column (a column's flags at a time, not the table's); the first bad
    # value in row order, as a reader going down the file meets it
    first: tuple[int, int] | None = None
    for j in range(table.shape[1]):
        finite = np.isfinite(table[:, j])
        if not finite.all():
            bad = (int(np.flatnonzero(~finite)[0]), j)
            first = bad if first is None else min(first, bad)
    if first is not None:
        row, col = first
        raise RecordingError(
            source,
            f"value is {float(table[row, col])!r}; every sample must be a finite number "
            "(re-export the scope or cut the recording before it)",
            line=line_of(int(row)),
            column=cells[int(col)],
        )

    time_col = names.index("time")
    times = table[:, time_col]
    falls = times[1:] <= times[:-1]  # finite values: the step is not positive
    if falls.any():
        row = int(np.flatnonzero(falls)[0]) + 1
        raise RecordingError(
            source,
            f"time {table[row, time_col]:g} does not increase after {table[row - 1, time_col]:g}; "
            "time must rise strictly from row to row",
            line=line_of(row),
            column=cells[time_col],
        )

    nominal = metadata.nominal_torque_nm
    if nominal is None and profile is not None:
        nominal = profile.nominal_torque_nm
    context = UnitContext(increments_per_rev=metadata.increments_per_rev, nominal_torque_nm=nominal)

    channels: dict[str, FloatArray] = {}
    unit_of: dict[str, str] = {}
    header_of: dict[str, str] = {}
    for j, (cell, name, unit) in enumerate(zip(cells, names, units, strict=True)):
        column = np.ascontiguousarray(table[:, j])
        if name in CANONICAL_CHANNELS:
            try:
                factor = to_si_factor(name, unit, context)
            except ValueError as exc:
                missing = str(exc)
                where = (
                    "add '# nominal_torque_nm: <Nm>' to the metadata or give a profile "
                    "with motor.nominal_torque_nm"
                    if missing == "nominal_torque_nm"
                    else "add '# increments_per_rev: <count>' to the metadata"
                )
                raise RecordingError(
                    source,
                    f"unit '{unit}' needs {missing}, which is not known; {where}",
                    column=cell,
                ) from None
            if factor != 1.0:
                # rounding is monotonic: no product overflows unless the largest does
                largest = max(float(column.max()), -float(column.min()))
                if not math.isfinite(largest * abs(factor)):
                    with np.errstate(over="ignore"):
                        converted = column * factor
                    row = int(np.flatnonzero(~np.isfinite(converted))[0])
                    raise RecordingError(
                        source,
                        f"value {table[row, j]:g} {unit} is too large to convert to SI; "
                        "correct the value or its unit",
                        line=line_of(row),
                        column=cell,
                    )
                column *= factor  # in the table's own column: no second copy
        channels[name] = column
        unit_of[name] = unit
        header_of[name] = cell
    _check_plausible(source, channels, header_of, line_of, nominal, profile)
    return Recording(
        source=source, channels=channels, units=unit_of, headers=header_of, metadata=metadata
    )


def _check_plausible(
    source: str,
    channels: dict[str, FloatArray],
    header_of: dict[str, str],
    line_of: Callable[[int], int],
    nominal_torque_nm: float | None,
    profile: ConveyorProfile | None,
) -> None:
    """Refuse values no drive records: sample time, torque and speed far out of range.

    Suspect but possible values are left to validation's warnings; these are
    the impossible ones (a unit or export error), named by line and column.
    """
    time = channels["time"]
    dt = float(time[-1] - time[0]) / (time.shape[0] - 1)  # time rises strictly: the mean step
    low, high = SAMPLE_TIME_RANGE_S
    if not low <= dt <= high:
        raise RecordingError(
            source,
            f"samples are {dt * 1e3:g} ms apart; a drive scope samples every "
            f"{low * 1e3:g} to {high * 1e3:g} ms (is the time column in s?)",
            line=line_of(1),
            column=header_of["time"],
        )
    nominal_speed = (
        profile.motor.nominal_speed_rpm * RPM_TO_RAD_S
        if profile is not None and profile.motor.nominal_speed_rpm is not None
        else None
    )
    limits = (
        ("torque", nominal_torque_nm, MAX_TORQUE_NOMINALS, "nominal torque"),
        ("torque_setpoint", nominal_torque_nm, MAX_TORQUE_NOMINALS, "nominal torque"),
        ("speed", nominal_speed, MAX_SPEED_NOMINALS, "nominal speed"),
        ("speed_setpoint", nominal_speed, MAX_SPEED_NOMINALS, "nominal speed"),
    )
    for name, nominal, times, what in limits:
        values = channels.get(name)
        if values is None or nominal is None:
            continue
        limit = times * nominal
        if float(values.max()) > limit or float(values.min()) < -limit:  # the common case: no
            row = int(np.flatnonzero(np.abs(values) > limit)[0])
            raise RecordingError(
                source,
                f"{name} {values[row]:.6g} (SI) is more than {times:g} times the {what} "
                f"({nominal:.6g}); no drive records that: check the value and the unit",
                line=line_of(row),
                column=header_of[name],
            )
