"""Helpers shared by the command modules: file lists, profiles, output."""

from __future__ import annotations

import json
import sys
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from chaintwin.errors import RecordingError
from chaintwin.read.columns import ColumnMap, load_column_map
from chaintwin.read.profile import ConveyorProfile, load_profile

__all__ = ["expand_recordings", "load_options", "print_json"]


def expand_recordings(paths: Iterable[Path]) -> list[str]:
    """Expand folders into their ``*.csv`` files (sorted); keep files as given.

    Raises
    ------
    RecordingError
        When a folder holds no ``*.csv`` file.
    """
    out: list[str] = []
    for p in paths:
        if p.is_dir():
            found = sorted(str(f) for f in p.rglob("*.csv"))
            if not found:
                raise RecordingError(str(p), "folder holds no *.csv recording")
            out.extend(found)
        else:
            out.append(str(p))
    return out


def load_options(
    profile: Path | None, columns: Path | None
) -> tuple[ConveyorProfile | None, ColumnMap | None]:
    """Load the optional ``--profile`` and ``--columns`` files."""
    prof = load_profile(profile) if profile is not None else None
    cmap = load_column_map(columns) if columns is not None else None
    return prof, cmap


def print_json(data: Any) -> None:
    """Print JSON to standard output (NaN/inf become null)."""
    sys.stdout.write(json.dumps(_finite(data), indent=2, ensure_ascii=False) + "\n")


def _finite(obj: Any) -> Any:
    if isinstance(obj, float):
        return obj if obj == obj and obj not in (float("inf"), float("-inf")) else None
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_finite(v) for v in obj]
    return obj
