"""A partial recording replaced by its complete version.

A file picked up while its writer paused can be stored with the
``incomplete_cycle`` warning. When its complete version arrives (same
conveyor, file name and recorded time, other content) it is stored as any
recording, and the partial one is marked: its ``superseded_by`` holds the id
of the recording that replaced it. Nothing is deleted (results stay
append-only); queries, exports, trends and the dashboard leave superseded
recordings out (:data:`STANDING`).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

from sqlalchemy import ColumnElement, select, update
from sqlalchemy.orm import Session

from chaintwin.read.recording import Recording

from .schema import RecordingRow, ResultRow

__all__ = [
    "PARTIAL",
    "STANDING",
    "STANDING_RESULT",
    "complete",
    "mark_superseded",
    "stored_partials",
]

PARTIAL = "incomplete_cycle"
"""The warning of a recording that does not hold a whole movement."""

STANDING: ColumnElement[bool] = RecordingRow.superseded_by.is_(None)
"""The condition on ``recordings`` of those not replaced by a complete version."""

STANDING_RESULT: ColumnElement[bool] = ResultRow.recording_id.not_in(
    select(RecordingRow.id).where(RecordingRow.superseded_by.is_not(None))
)
"""The condition on ``results`` of those whose recording was not superseded (a seek
on the index of ``superseded_by``, which holds next to nothing)."""

Key = tuple[str, str]
"""(file name as stored, recorded time in UTC ISO 8601)."""


def complete(recording: Recording) -> bool:
    """Whether a recording can replace a stored partial one (it holds a whole movement)."""
    return not recording.has_warning(PARTIAL)


def stored_partials(s: Session, conveyor: str | None, files: Iterable[str]) -> dict[Key, list[str]]:
    """The conveyor's stored partial recordings not yet superseded, of these file names.

    Parameters
    ----------
    s : Session
        An open session.
    conveyor : str or None
        The conveyor id (None: any conveyor).
    files : iterable of str
        File names as stored (an index seek each, in chunks of 500).

    Returns
    -------
    dict
        Content SHA-256 of the stored partial recordings, by (file, recorded
        time); recordings without a recorded time are left out (nothing can
        match their time).
    """
    wanted = sorted(set(files))
    out: dict[Key, list[str]] = {}
    for k in range(0, len(wanted), 500):
        q = select(
            RecordingRow.sha256, RecordingRow.file, RecordingRow.recorded_at, RecordingRow.warnings
        ).where(
            RecordingRow.file.in_(wanted[k : k + 500]),
            RecordingRow.recorded_at.is_not(None),
            STANDING,
        )
        if conveyor is not None:
            q = q.where(RecordingRow.conveyor_id == conveyor)
        for sha, file, at, warnings in s.execute(q):
            if any(isinstance(w, dict) and w.get("code") == PARTIAL for w in warnings or []):
                out.setdefault((str(file), str(at)), []).append(str(sha))
    return out


def mark_superseded(
    s: Session, conveyor: str, new: Sequence[tuple[Key, str, int]]
) -> dict[str, int]:
    """Mark the stored partial recordings that these new complete ones replace.

    Parameters
    ----------
    s : Session
        The session of the transaction that stores the new recordings.
    conveyor : str
        The conveyor id.
    new : sequence of ((str, str), str, int)
        Each new complete recording's key (file, recorded time), content
        SHA-256 and id.

    Returns
    -------
    dict
        The id of the replacing recording, by the superseded one's SHA-256.
    """
    by_key = {key: (sha, rid) for key, sha, rid in new}
    marked: dict[str, int] = {}
    for key, shas in stored_partials(s, conveyor, (f for f, _ in by_key)).items():
        if key not in by_key:
            continue
        sha, rid = by_key[key]
        for old in shas:
            if old != sha:
                marked[old] = rid
    for old, rid in marked.items():
        s.execute(update(RecordingRow).where(RecordingRow.sha256 == old).values(superseded_by=rid))
    return marked
