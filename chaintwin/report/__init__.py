"""Reports: self-contained HTML pages per conveyor and for the fleet, from the results store."""

from .html import CONVEYOR_SECTIONS, FLEET_SECTIONS, conveyor_page, fleet_page, write_page

__all__ = ["CONVEYOR_SECTIONS", "FLEET_SECTIONS", "conveyor_page", "fleet_page", "write_page"]
