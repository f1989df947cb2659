"""Retention: drop the samples of old recordings, keep their results (``--keep-samples-days``).

A recording's samples are most of the store (about 60-130 kB a recording
compressed, against 2-3 kB for its result and metadata). Past the retention
time the samples are emptied; the recording's row (content hash, metadata,
warnings) and its result stay, so trends, alarms and exports are whole.
What needs the samples (re-weighing, the recording plot of the dashboard)
says that they were dropped. Recordings that still wait for a learned
calibration (no result yet) keep theirs.
"""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

from sqlalchemy import select, update
from sqlalchemy.orm import Session

from chaintwin.store.schema import RecordingRow, ResultRow
from chaintwin.store.store import Store

__all__ = ["DROPPED", "drop_samples"]

DROPPED = b""
"""The samples column of a recording whose samples were dropped."""


def drop_samples(store: Store, days: float, *, batch: int = 500) -> int:
    """Empty the samples of recordings recorded more than ``days`` ago; how many.

    Recordings without a recorded time are judged by their result's write
    time. Runs in batches (short transactions next to the ingest).
    """
    cutoff = (datetime.now(UTC) - timedelta(days=days)).isoformat()
    total = 0
    while True:
        with Session(store.engine) as s, s.begin():
            ids = list(
                s.scalars(
                    select(RecordingRow.id)
                    .join(ResultRow, ResultRow.recording_id == RecordingRow.id)
                    .where(
                        RecordingRow.samples != DROPPED,
                        (RecordingRow.recorded_at < cutoff)
                        | (RecordingRow.recorded_at.is_(None) & (ResultRow.stored_at < cutoff)),
                    )
                    .limit(batch)
                )
            )
            if ids:
                s.execute(
                    update(RecordingRow).where(RecordingRow.id.in_(ids)).values(samples=DROPPED)
                )
        total += len(ids)
        if len(ids) < batch:
            return total
