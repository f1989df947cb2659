"""Stage 2, validate: movement phases and the warnings a usable recording carries."""

import typing as _typing

from chaintwin._lazy import lazy_getattr

if _typing.TYPE_CHECKING:
    from chaintwin.validate.checks import (
        Inspection,
        inspect_recording,
        load_recording,
        tray_mass_kg,
    )
    from chaintwin.validate.phases import Phase, segment, segment_speed

_LAZY: dict[str, str] = {
    "Inspection": "chaintwin.validate.checks",
    "Phase": "chaintwin.validate.phases",
    "inspect_recording": "chaintwin.validate.checks",
    "load_recording": "chaintwin.validate.checks",
    "segment": "chaintwin.validate.phases",
    "segment_speed": "chaintwin.validate.phases",
    "tray_mass_kg": "chaintwin.validate.checks",
}
"""Module of each public name (imported on first use, PEP 562)."""

__all__ = [
    "Inspection",
    "Phase",
    "inspect_recording",
    "load_recording",
    "segment",
    "segment_speed",
    "tray_mass_kg",
]


__getattr__ = lazy_getattr(__name__, _LAZY)
