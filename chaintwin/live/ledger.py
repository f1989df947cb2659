"""What the live service keeps in the store: refused files, its sources, leases.

Leases let several ``serve`` processes (on several hosts, one PostgreSQL
store) share the sources: a process follows a source only while it holds
the source's lease, renews it every third of its length, and a holder that
dies stops renewing, so its lease expires and another process takes the
source over. The store's unique content hashes are the second guard: a
recording stored twice is refused by the database.
"""

from __future__ import annotations

import time
from collections.abc import Collection
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

from sqlalchemy import delete, select, update
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from chaintwin.store.schema import LeaseRow, LiveSourceRow, RecordingRow, RefusedFileRow
from chaintwin.store.store import Store
from chaintwin.store.supersede import STANDING, stored_partials

__all__ = [
    "Refusal",
    "SourceRecord",
    "acquire_lease",
    "forget_refusal",
    "is_refused",
    "known_paths",
    "record_refusal",
    "refusals",
    "release_lease",
    "source_records",
    "update_source",
]


def _now() -> str:
    return datetime.now(UTC).isoformat()


# ------------------------------------------------------------------ refusals
def is_refused(store: Store, sha256: str) -> bool:
    """Whether a content was refused already (it is not read again)."""
    with Session(store.engine) as s:
        return (
            s.scalars(select(RefusedFileRow.id).where(RefusedFileRow.sha256 == sha256)).first()
            is not None
        )


def record_refusal(
    store: Store,
    sha256: str,
    path: str,
    source: str,
    reason: str,
    *,
    cause: str = "recording",
    conveyor: str | None = None,
) -> None:
    """Keep a refusal (a second one of the same content, by another process, is dropped).

    ``cause`` is ``profile`` when the file's conveyor had no profile, or the
    store monitors it with another (it is read again once a profile is
    added or changed), else ``recording``; ``conveyor`` is the conveyor the
    file names, when known.
    """
    try:
        with Session(store.engine) as s, s.begin():
            s.add(
                RefusedFileRow(
                    sha256=sha256,
                    path=path,
                    source=source,
                    reason=reason,
                    refused_at=_now(),
                    cause=cause,
                    conveyor=conveyor,
                )
            )
    except IntegrityError:
        pass  # refused already, by this content


def known_paths(store: Store, paths: Collection[str], chunk: int = 500) -> set[str]:
    """Which of these files the store has stored or refused, by path (as given).

    A watched folder remembers the files it handed over for a while only
    (:data:`~.watch.MAX_REMEMBERED`); its rescans ask the store about the
    others, instead of reading and hashing every old file again. A file
    stored only as a partial recording (``incomplete_cycle``, not yet
    superseded) is not known: its rest may still come, and is then read.
    """
    out: set[str] = set()
    todo = list(paths)
    with Session(store.engine) as s:
        for k in range(0, len(todo), chunk):
            part = todo[k : k + chunk]
            found = set(
                s.scalars(select(RecordingRow.file).where(RecordingRow.file.in_(part), STANDING))
            )
            partial = {f for f, _at in stored_partials(s, None, found)}
            out.update(found - partial)
            out.update(s.scalars(select(RefusedFileRow.path).where(RefusedFileRow.path.in_(part))))
    return out


@dataclass(frozen=True, slots=True)
class Refusal:
    """A refused file as the store keeps it."""

    sha256: str
    path: str
    source: str
    reason: str
    refused_at: str
    cause: str
    conveyor: str | None

    def to_dict(self) -> dict[str, Any]:
        """``chaintwin refused list --json``'s object."""
        return {
            "path": self.path,
            "source": self.source,
            "conveyor": self.conveyor,
            "cause": self.cause,
            "reason": self.reason,
            "refused_at": self.refused_at,
            "sha256": self.sha256,
        }


def refusals(
    store: Store, *, cause: str | None = None, conveyors: Collection[str] | None = None
) -> list[Refusal]:
    """The refused files, oldest first.

    Parameters
    ----------
    store : Store
        The results store.
    cause : str, optional
        Only those of this cause (``profile``, ``recording``).
    conveyors : collection of str, optional
        Only those of these conveyors, and those whose conveyor is not known.
    """
    q = select(RefusedFileRow).order_by(RefusedFileRow.refused_at, RefusedFileRow.id)
    if cause is not None:
        q = q.where(RefusedFileRow.cause == cause)
    if conveyors is not None:
        q = q.where(
            RefusedFileRow.conveyor.in_(list(conveyors)) | RefusedFileRow.conveyor.is_(None)
        )
    with Session(store.engine) as s:
        return [
            Refusal(r.sha256, r.path, r.source, r.reason, r.refused_at, r.cause, r.conveyor)
            for r in s.scalars(q)
        ]


def forget_refusal(store: Store, sha256: str) -> bool:
    """Drop a refusal so that its file is read again; whether this call dropped it.

    Of several processes retrying the same refusal at once, one drops it
    (and reads the file again); the others get False.
    """
    with Session(store.engine) as s, s.begin():
        done = s.execute(delete(RefusedFileRow).where(RefusedFileRow.sha256 == sha256))
        return bool(done.rowcount == 1)  # type: ignore[attr-defined]


# ------------------------------------------------------------------ sources
@dataclass(frozen=True, slots=True)
class SourceRecord:
    """A source's row: who follows it, its state and counts."""

    key: str
    kind: str
    holder: str | None
    state: str
    ingested: int
    refused: int
    missed: int
    last_error: str | None
    updated_at: str

    def to_dict(self) -> dict[str, Any]:
        """The health endpoint's object."""
        return {
            "key": self.key,
            "kind": self.kind,
            "holder": self.holder,
            "state": self.state,
            "ingested": self.ingested,
            "refused": self.refused,
            "missed": self.missed,
            "last_error": self.last_error,
            "updated_at": self.updated_at,
        }


def update_source(
    store: Store,
    key: str,
    kind: str,
    *,
    holder: str | None,
    state: str,
    ingested: int = 0,
    refused: int = 0,
    missed: int | None = None,
    last_error: str | None = None,
) -> None:
    """Write a source's state; ``ingested`` and ``refused`` are added to its counts.

    ``missed`` (a drive's scopes missed, counted by its follower) replaces
    the stored count when given; ``last_error`` replaces the last one (None:
    the source works again).
    """
    for _attempt in range(3):
        try:
            with Session(store.engine) as s, s.begin():
                row = s.get(LiveSourceRow, key)
                if row is None:
                    s.add(
                        LiveSourceRow(
                            key=key,
                            kind=kind,
                            holder=holder,
                            state=state,
                            ingested=ingested,
                            refused=refused,
                            missed=missed or 0,
                            last_error=last_error,
                            updated_at=_now(),
                        )
                    )
                else:
                    row.holder = holder
                    row.state = state
                    row.ingested += ingested
                    row.refused += refused
                    if missed is not None:
                        row.missed = missed
                    row.last_error = last_error
                    row.updated_at = _now()
            return
        except IntegrityError:
            continue  # another process created the row at the same moment: update it


def source_records(store: Store) -> list[SourceRecord]:
    """Every source's row, by key."""
    with Session(store.engine) as s:
        return [
            SourceRecord(
                r.key,
                r.kind,
                r.holder,
                r.state,
                r.ingested,
                r.refused,
                r.missed,
                r.last_error,
                r.updated_at,
            )
            for r in s.scalars(select(LiveSourceRow).order_by(LiveSourceRow.key))
        ]


# ------------------------------------------------------------------ leases
def acquire_lease(store: Store, source: str, holder: str, seconds: float) -> bool:
    """Take or renew the lease of ``source`` for ``seconds``; whether ``holder`` has it.

    A lease held by another process is taken only once expired. Atomic on
    both databases: one conditional UPDATE, or an INSERT that the primary
    key lets only one process make.
    """
    now = time.time()
    with Session(store.engine) as s, s.begin():
        done = s.execute(
            update(LeaseRow)
            .where(
                LeaseRow.source == source,
                (LeaseRow.holder == holder) | (LeaseRow.expires_at < now),
            )
            .values(holder=holder, expires_at=now + seconds)
        )
        if done.rowcount == 1:  # type: ignore[attr-defined]
            return True
    try:
        with Session(store.engine) as s, s.begin():
            if s.get(LeaseRow, source) is not None:
                return False  # held by another, not expired
            s.add(
                LeaseRow(source=source, holder=holder, expires_at=now + seconds, acquired_at=_now())
            )
        return True
    except IntegrityError:
        return False  # another process took it at the same moment


def release_lease(store: Store, source: str, holder: str) -> None:
    """Give a lease back (a clean stop: another process may take the source at once)."""
    with Session(store.engine) as s, s.begin():
        s.execute(delete(LeaseRow).where(LeaseRow.source == source, LeaseRow.holder == holder))
