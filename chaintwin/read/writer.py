"""Write recordings in the data-contract format.

The writer is the reader's inverse: metadata lines, a ``name [unit]`` header
and the samples converted from SI to the chosen units, in either dialect.
Reading what it wrote gives the same values to the printed precision, and
writing that again gives the same text.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from datetime import UTC
from pathlib import Path

import numpy as np

from chaintwin.errors import RecordingError
from chaintwin.read.files import write_atomic
from chaintwin.read.recording import Metadata, Recording
from chaintwin.units import CANONICAL_CHANNELS, UnitContext, from_si_factor

__all__ = ["DEFAULT_DECIMALS", "format_recording", "write_recording"]

#: The minus sign of a cell that prints a zero ('-0', '-0.000'), not of '-0.001'.
_NEGATIVE_ZERO = re.compile(r"(?m)(?:^|(?<=,))-(?=0(?:\.0*)?(?:,|$))")

#: Decimals printed per unit, chosen so that scope resolution is kept.
DEFAULT_DECIMALS: Mapping[str, int] = {
    "s": 6,
    "ms": 3,
    "rad/s": 5,
    "rpm": 3,
    "1/min": 3,
    "rad": 6,
    "rev": 7,
    "inc": 0,
    "Nm": 5,
    "%": 3,
    "-": 0,
}


def _metadata_lines(meta: Metadata) -> list[str]:
    lines: list[str] = []
    if meta.conveyor is not None:
        lines.append(f"# conveyor: {meta.conveyor}")
    if meta.recorded_at is not None:
        stamp = meta.recorded_at.astimezone(UTC).isoformat().replace("+00:00", "Z")
        lines.append(f"# recorded_at: {stamp}")
    for key in (
        "sample_time_s",
        "nominal_torque_nm",
        "increments_per_rev",
        "payload_kg",
        "tray_kg",
    ):
        value = getattr(meta, key)
        if value is not None:
            lines.append(f"# {key}: {value:.12g}")
    lines.extend(f"# {k}: {v}" for k, v in meta.extra.items())
    return lines


def format_recording(
    recording: Recording,
    *,
    units: Mapping[str, str] | None = None,
    dialect: str = ",",
    decimals: Mapping[str, int] | None = None,
) -> str:
    """Return the text of a recording in the data-contract format.

    Parameters
    ----------
    recording : Recording
        The recording (SI inside).
    units : Mapping[str, str], optional
        Channel → unit to write; default: the units it was read with.
    dialect : {",", ";"}
        ``","`` with ``.`` decimals or ``";"`` with ``,`` decimals.
    decimals : Mapping[str, int], optional
        Channel → decimals printed; default by unit (:data:`DEFAULT_DECIMALS`),
        9 significant digits for extra channels.

    Raises
    ------
    RecordingError
        When a unit is not accepted or needs a number the metadata lacks.
    """
    if dialect not in (",", ";"):
        raise ValueError(f"dialect must be ',' or ';', not {dialect!r}")
    meta = recording.metadata
    context = UnitContext(
        increments_per_rev=meta.increments_per_rev, nominal_torque_nm=meta.nominal_torque_nm
    )
    chosen = dict(recording.units)
    if units:
        chosen.update(units)
    names = list(recording.channels)
    header: list[str] = []
    columns: list[np.ndarray] = []
    fmts: list[str] = []
    for name in names:
        unit = chosen[name]
        values = recording.channels[name]
        if name in CANONICAL_CHANNELS:
            try:
                factor = from_si_factor(name, unit, context)
            except KeyError:
                raise RecordingError(
                    recording.source, f"cannot write {name} in unknown unit '{unit}'"
                ) from None
            except ValueError as exc:
                raise RecordingError(
                    recording.source,
                    f"cannot write {name} in '{unit}': metadata {exc} is not set",
                ) from None
            values = values * factor
            places = (decimals or {}).get(name, DEFAULT_DECIMALS[unit])
            fmts.append(f"%.{places}f")
        else:
            places = (decimals or {}).get(name, -1)
            fmts.append(f"%.{places}f" if places >= 0 else "%.9g")
        header.append(f"{name} [{unit}]")
        columns.append(_no_negative_zero(np.asarray(values, dtype=np.float64), fmts[-1]))
    table = np.column_stack(columns)
    # as numpy's savetxt prints it (one %-format a row), on Python floats: twice as fast
    row = ",".join(fmts)
    body = "".join([row % tuple(values) + "\n" for values in table.tolist()])
    if dialect == ";":
        body = body.replace(",", ";").replace(".", ",")
    lines = _metadata_lines(meta)
    lines.append(dialect.join(header))
    return "\n".join(lines) + "\n" + body


def _no_negative_zero(values: np.ndarray, fmt: str) -> np.ndarray:
    """The values with those that would print as a negative zero ('-0', '-0.000') made
    +0.0: the same samples, printed '0.000' (what :func:`_fix_negative_zero` does to
    the text, without scanning it)."""
    values = values + 0.0  # -0.0 + 0.0 is +0.0
    if fmt.endswith("f"):  # '%.3f': small negatives may round to '-0.000'
        places = int(fmt[2:-1])
        small = np.flatnonzero((values < 0.0) & (values > -(10.0**-places)))
        if small.size:
            zero = fmt % 0.0
            for k in small.tolist():
                if fmt % -values[k] == zero:
                    values[k] = 0.0
    return values


def _fix_negative_zero(body: str) -> str:
    """Print '-0.000' as '0.000': the same sample, and a stable round trip."""
    if "-0" not in body:
        return body
    return _NEGATIVE_ZERO.sub("", body)


def write_recording(
    recording: Recording,
    path: str | Path,
    *,
    units: Mapping[str, str] | None = None,
    dialect: str = ",",
    decimals: Mapping[str, int] | None = None,
) -> Path:
    """Write a recording file; see :func:`format_recording` for the options.

    The file is written to a temporary name and renamed, so a reader never
    sees half a file.

    Returns
    -------
    Path
        The path written.
    """
    text = format_recording(recording, units=units, dialect=dialect, decimals=decimals)
    return write_atomic(path, text, what="recording", error=lambda t, m: RecordingError(t, m))
