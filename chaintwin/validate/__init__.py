"""Stage 2, validate: movement phases and the warnings a usable recording carries."""

from chaintwin.validate.checks import Inspection, inspect_recording, load_recording, tray_mass_kg
from chaintwin.validate.phases import Phase, segment, segment_speed

__all__ = [
    "Inspection",
    "Phase",
    "inspect_recording",
    "load_recording",
    "segment",
    "segment_speed",
    "tray_mass_kg",
]
