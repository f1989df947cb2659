"""Stage 1, read: drive recordings, column maps and conveyor profiles."""

import typing as _typing

from chaintwin._lazy import lazy_getattr

if _typing.TYPE_CHECKING:
    from chaintwin.read.columns import ColumnMap, ColumnTarget, load_column_map
    from chaintwin.read.formats import read_recording
    from chaintwin.read.profile import ConveyorProfile, load_profile, load_profiles, parse_profile
    from chaintwin.read.reader import MIN_SAMPLES, parse_recording
    from chaintwin.read.recording import WARNING_CODES, Metadata, Recording, RecordingWarning
    from chaintwin.read.writer import format_recording, write_recording

_LAZY: dict[str, str] = {
    "ColumnMap": "chaintwin.read.columns",
    "ColumnTarget": "chaintwin.read.columns",
    "ConveyorProfile": "chaintwin.read.profile",
    "MIN_SAMPLES": "chaintwin.read.reader",
    "Metadata": "chaintwin.read.recording",
    "Recording": "chaintwin.read.recording",
    "RecordingWarning": "chaintwin.read.recording",
    "WARNING_CODES": "chaintwin.read.recording",
    "format_recording": "chaintwin.read.writer",
    "load_column_map": "chaintwin.read.columns",
    "load_profile": "chaintwin.read.profile",
    "load_profiles": "chaintwin.read.profile",
    "parse_profile": "chaintwin.read.profile",
    "parse_recording": "chaintwin.read.reader",
    "read_recording": "chaintwin.read.formats",
    "write_recording": "chaintwin.read.writer",
}
"""Module of each public name (imported on first use, PEP 562)."""

__all__ = [
    "MIN_SAMPLES",
    "WARNING_CODES",
    "ColumnMap",
    "ColumnTarget",
    "ConveyorProfile",
    "Metadata",
    "Recording",
    "RecordingWarning",
    "format_recording",
    "load_column_map",
    "load_profile",
    "load_profiles",
    "parse_profile",
    "parse_recording",
    "read_recording",
    "write_recording",
]


__getattr__ = lazy_getattr(__name__, _LAZY)
