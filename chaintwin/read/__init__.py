"""Stage 1, read: drive recordings, column maps and conveyor profiles."""

from chaintwin.read.columns import ColumnMap, ColumnTarget, load_column_map
from chaintwin.read.profile import ConveyorProfile, load_profile, load_profiles, parse_profile
from chaintwin.read.reader import MIN_SAMPLES, parse_recording, read_recording
from chaintwin.read.recording import WARNING_CODES, Metadata, Recording, RecordingWarning
from chaintwin.read.writer import format_recording, write_recording

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
