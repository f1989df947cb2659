"""Many recording files at once: which conveyor each belongs to, and their order.

Monitoring and ingest take a conveyor's recordings in recorded order; both
first read each file's metadata and content hash (one read per file) and
group the files by conveyor (:func:`group_by_conveyor`), then order each
group (:func:`order_recordings`).
"""

from __future__ import annotations

import hashlib
from collections.abc import Collection, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime

from chaintwin.errors import ChaintwinError, RecordingError
from chaintwin.read.formats import parse_file_metadata, read_bytes

__all__ = ["RecordingFile", "group_by_conveyor", "order_recordings"]


@dataclass(frozen=True, slots=True)
class RecordingFile:
    """A recording file as a batch sees it before reading it whole."""

    path: str
    sha256: str
    recorded_at: datetime | None


def group_by_conveyor(
    files: Sequence[str], conveyors: Collection[str]
) -> tuple[dict[str, list[RecordingFile]], list[tuple[str, str]]]:
    """Group files by their ``conveyor`` metadata, in the order given.

    Parameters
    ----------
    files : sequence of str
        Recording files.
    conveyors : collection of str
        The conveyor ids with a profile; with exactly one, a file without
        ``conveyor`` metadata is taken to be of that conveyor.

    Returns
    -------
    (dict, list)
        Files by conveyor id, and the refused files as ``(file, error)``.
    """
    single = next(iter(conveyors)) if len(conveyors) == 1 else None
    groups: dict[str, list[RecordingFile]] = {}
    refused: list[tuple[str, str]] = []
    for f in files:
        try:
            raw = read_bytes(f)
            meta = parse_file_metadata(raw, f)
            conveyor = meta.conveyor or single
            if conveyor is None:
                raise RecordingError(
                    f, "has no 'conveyor' in its metadata; add '# conveyor: <profile id>'"
                )
            if conveyor not in conveyors:
                raise RecordingError(
                    f,
                    f"is a recording of conveyor '{conveyor}', for which no profile was given "
                    f"(profiles: {', '.join(sorted(conveyors))})",
                )
        except ChaintwinError as exc:
            refused.append((f, str(exc)))
            continue
        sha = hashlib.sha256(raw).hexdigest()
        groups.setdefault(conveyor, []).append(RecordingFile(f, sha, meta.recorded_at))
    return groups, refused


def order_recordings(
    items: Sequence[tuple[str, datetime | None]],
) -> tuple[list[str], set[str]]:
    """Recorded order: by ``recorded_at``; one without it stays after its predecessor in file order.

    Times are compared in UTC, whatever offset each file gives.

    Returns
    -------
    (list of str, set of str)
        The files in processing order, and those without ``recorded_at``.
    """
    keyed: list[tuple[str, int, str]] = []
    last = ""
    missing: set[str] = set()
    for k, (f, when) in enumerate(items):
        if when is None:
            missing.add(f)
        else:
            last = when.astimezone(UTC).isoformat()
        keyed.append((last, k, f))
    keyed.sort()
    return [f for _t, _k, f in keyed], missing
