"""Reports: self-contained HTML pages per conveyor and for the fleet, from the results store."""

import typing as _typing

from chaintwin._lazy import lazy_getattr

if _typing.TYPE_CHECKING:
    from chaintwin.report.html import (
        CONVEYOR_SECTIONS,
        FLEET_SECTIONS,
        conveyor_page,
        fleet_page,
        write_page,
    )

_LAZY: dict[str, str] = {
    "CONVEYOR_SECTIONS": "chaintwin.report.html",
    "FLEET_SECTIONS": "chaintwin.report.html",
    "conveyor_page": "chaintwin.report.html",
    "fleet_page": "chaintwin.report.html",
    "write_page": "chaintwin.report.html",
}
"""Module of each public name (imported on first use, PEP 562)."""

__all__ = ["CONVEYOR_SECTIONS", "FLEET_SECTIONS", "conveyor_page", "fleet_page", "write_page"]


__getattr__ = lazy_getattr(__name__, _LAZY)
