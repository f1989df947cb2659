"""Recording formats: how each drive maker's scope export is recognised and read.

A format is a module (or any object) with

* ``NAME``: a short name (``csv``);
* ``PATTERNS``: the file name patterns its files have (``("*.csv",)``); the
  command line's folders and the live service's watched folders take every
  registered format's patterns;
* ``recognises(name, head)``: whether a file of this name (no folder) whose
  first :data:`HEAD_BYTES` bytes are ``head`` is one of its files;
* ``parse_recording(data, source, *, profile=None, column_map=None)``: the
  recording in SI, built through
  :func:`~chaintwin.read.reader.recording_from_samples` (or, for the data
  contract's text, :func:`~chaintwin.read.reader.parse_recording`), so that
  every format meets the same checks and refusals;
* ``parse_metadata(data, source)``: its metadata alone (the conveyor, the
  time), for ordering files before reading them whole.

The data contract's CSV (:mod:`chaintwin.read.reader`, with its column maps)
is the first format, and the one a file no other format recognises is read
as: it names what is wrong with a file that is not a recording. A format
registered later (:func:`register_format`) is asked first. Bytes come in one
way only, :func:`~chaintwin.read.files.read_limited` (:func:`read_bytes`):
a format parses bytes and never opens a file itself.
"""

from __future__ import annotations

import fnmatch
import os
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

from chaintwin.errors import RecordingError
from chaintwin.read import reader as csv_format
from chaintwin.read.files import read_limited

if TYPE_CHECKING:
    from chaintwin.read.columns import ColumnMap
    from chaintwin.read.profile import ConveyorProfile
    from chaintwin.read.recording import Metadata, Recording

__all__ = [
    "CSV",
    "HEAD_BYTES",
    "RecordingFormat",
    "format_of",
    "is_recording_name",
    "parse_file",
    "parse_file_metadata",
    "read_bytes",
    "read_metadata",
    "read_recording",
    "recording_formats",
    "recording_patterns",
    "register_format",
    "unregister_format",
]

HEAD_BYTES = 4096
"""How much of a file's start a format's ``recognises`` is shown, bytes."""


class RecordingFormat(Protocol):
    """What a recording format module provides (see the module's docstring)."""

    NAME: str
    PATTERNS: tuple[str, ...]

    def recognises(self, name: str, head: bytes) -> bool: ...

    def parse_recording(
        self,
        data: bytes,
        source: str,
        *,
        profile: ConveyorProfile | None = None,
        column_map: ColumnMap | None = None,
    ) -> Recording: ...

    def parse_metadata(self, data: bytes, source: str) -> Metadata: ...


CSV: RecordingFormat = csv_format
"""The data contract's CSV (:mod:`chaintwin.read.reader`), the first format."""

_FORMATS: list[RecordingFormat] = [CSV]


def register_format(fmt: RecordingFormat) -> RecordingFormat:
    """Add a recording format (``docs/adding-a-reader.md``); it is asked before the others.

    Raises
    ------
    RecordingError
        When a format of that name is registered already, or it has no pattern.
    """
    if any(f.NAME == fmt.NAME for f in _FORMATS):
        raise RecordingError(f"format '{fmt.NAME}'", "is registered already; give it another NAME")
    if not fmt.PATTERNS:
        raise RecordingError(f"format '{fmt.NAME}'", "has no PATTERNS; give its file patterns")
    _FORMATS.append(fmt)
    return fmt


def unregister_format(name: str) -> None:
    """Remove a registered format by name (the CSV stays)."""
    _FORMATS[:] = [f for f in _FORMATS if name != f.NAME or f is CSV]


def recording_formats() -> tuple[RecordingFormat, ...]:
    """Every registered format, the CSV first."""
    return tuple(_FORMATS)


def recording_patterns() -> tuple[str, ...]:
    """Every registered format's file patterns, each once, the CSV's first."""
    return tuple(dict.fromkeys(p for f in _FORMATS for p in f.PATTERNS))


def is_recording_name(path: str) -> bool:
    """Whether a file's name matches a registered format's pattern (case ignored)."""
    name = os.path.basename(path).lower()
    return any(fnmatch.fnmatchcase(name, p.lower()) for p in recording_patterns())


def format_of(source: str, raw: bytes) -> RecordingFormat:
    """The format that reads a file: the latest registered that recognises it, else the CSV.

    Parameters
    ----------
    source : str
        The file's path or name.
    raw : bytes
        Its content (the first :data:`HEAD_BYTES` are shown to the formats).
    """
    name = os.path.basename(source)
    head = raw[:HEAD_BYTES]
    for fmt in reversed(_FORMATS[1:]):
        if fmt.recognises(name, head):
            return fmt
    return CSV


def read_bytes(path: str | Path) -> bytes:
    """A recording file's bytes (:func:`~chaintwin.read.files.read_limited`).

    Raises
    ------
    RecordingError
        When it cannot be read, is a folder or not a regular file, or is
        larger than the input file limit.
    """
    return read_limited(path, what="recording", error=RecordingError)


def parse_file(
    raw: bytes,
    source: str,
    *,
    profile: ConveyorProfile | None = None,
    column_map: ColumnMap | None = None,
) -> Recording:
    """A recording file's bytes read by its format (:func:`format_of`)."""
    fmt = format_of(source, raw)
    return fmt.parse_recording(raw, source, profile=profile, column_map=column_map)


def parse_file_metadata(raw: bytes, source: str) -> Metadata:
    """A recording file's metadata read by its format (:func:`format_of`)."""
    return format_of(source, raw).parse_metadata(raw, source)


def read_recording(
    path: str | Path,
    *,
    profile: ConveyorProfile | None = None,
    column_map: ColumnMap | None = None,
) -> Recording:
    """Read one recording file into SI channels, in whichever registered format it is.

    Parameters
    ----------
    path : str or Path
        The recording file. Its name as given is kept as ``source``.
    profile : ConveyorProfile, optional
        Supplies what the file lacks (``nominal_torque_nm`` for ``%``).
        Metadata wins where both give a value.
    column_map : ColumnMap, optional
        Maps exported headers named otherwise to canonical names and units.

    Returns
    -------
    Recording
        Without warnings; :func:`chaintwin.validate.load_recording` adds them.

    Raises
    ------
    RecordingError
        Naming the file, the line or column, and what to do.
    """
    source = str(path)
    return parse_file(read_bytes(path), source, profile=profile, column_map=column_map)


def read_metadata(path: str | Path) -> Metadata:
    """Read only the metadata of a recording file.

    For matching recordings to conveyors (``conveyor``) and ordering them
    (``recorded_at``) before reading them whole.

    Raises
    ------
    RecordingError
        When the file cannot be read, has no header row or bad metadata.
    """
    return parse_file_metadata(read_bytes(path), str(path))
