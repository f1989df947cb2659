"""The results store: one interface over SQLite (embedded) and PostgreSQL (shared).

``Store(url)`` opens (and creates) a store from a SQLAlchemy URL:
``sqlite:///plant.db`` (a file in the working folder, the default
``sqlite:///chaintwin.db``) or ``postgresql://user:pass@host/db`` (psycopg 3).
The URL may come from the environment variable ``CHAINTWIN_DB`` so that
credentials stay off the command line (:func:`store_url`).

Writes are atomic per recording: :meth:`Store.commit_recording` stores the
recording (with its samples), its result and the conveyor's health model in
one transaction. A recording already stored (same content SHA-256) is not
stored again. Two ingests may run at once: the health model carries a
version, and a writer whose model was advanced by the other in the meantime
gets :class:`StateConflict` and goes again from the newer model.
"""

from __future__ import annotations

import io
import json
import os
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

import numpy as np
from sqlalchemy import create_engine, event, select, update
from sqlalchemy.engine import Engine
from sqlalchemy.exc import IntegrityError, OperationalError, SQLAlchemyError
from sqlalchemy.orm import Session

from chaintwin.diagnose.monitor import ConveyorMonitor, MonitorSettings, RecordingResult
from chaintwin.diagnose.state import json_ready
from chaintwin.errors import StoreError
from chaintwin.identify.calibration import Calibration
from chaintwin.read.profile import ConveyorProfile
from chaintwin.read.recording import Recording

from .schema import (
    SCHEMA_VERSION,
    AlarmRow,
    Base,
    CalibrationRow,
    ConveyorRow,
    EventRow,
    MonitorStateRow,
    RecordingRow,
    ResultRow,
    SchemaRow,
)

__all__ = [
    "DEFAULT_URL",
    "HISTORY_IN_STATE",
    "Finished",
    "StateConflict",
    "Store",
    "load_samples",
    "pack_samples",
    "recording_meta",
    "store_url",
]

DEFAULT_URL = "sqlite:///chaintwin.db"
"""The embedded default: a SQLite file in the working folder."""

HISTORY_IN_STATE = 300
"""Recent results kept inside a stored health model (for trend forecasts); all
results are in the ``results`` table."""


@dataclass(frozen=True, slots=True)
class Finished:
    """A recording that monitoring has taken, ready to be stored."""

    recording: Recording
    sha256: str
    result: RecordingResult
    samples: bytes | None = None
    """The compressed channels (:func:`pack_samples`), when packed already (in a worker)."""


class StateConflict(Exception):
    """Another writer advanced a conveyor's health model first (not a user error)."""


def store_url(given: str | None) -> str:
    """The store URL: as given, else ``CHAINTWIN_DB``, else :data:`DEFAULT_URL`."""
    return given or os.environ.get("CHAINTWIN_DB") or DEFAULT_URL


def _now() -> str:
    return datetime.now(UTC).isoformat()


def _safe_url(url: str) -> str:
    """The URL without its password, for messages."""
    head, sep, tail = url.partition("@")
    if not sep or "://" not in head:
        return url
    scheme, _, cred = head.partition("://")
    user = cred.split(":", 1)[0]
    return f"{scheme}://{user}:***@{tail}"


def pack_samples(recording: Recording) -> bytes:
    """The channels (SI) of a recording, compressed (``numpy.savez_compressed``)."""
    buf = io.BytesIO()
    arrays: dict[str, Any] = {k: np.asarray(v) for k, v in recording.channels.items()}
    np.savez_compressed(buf, **arrays)
    return buf.getvalue()


def load_samples(blob: bytes) -> dict[str, np.ndarray]:
    """The channels (SI) of a stored recording."""
    with np.load(io.BytesIO(blob)) as data:
        return {k: data[k] for k in data.files}


class Store:
    """A results store.

    Parameters
    ----------
    url : str
        SQLAlchemy URL (``sqlite:///file.db``, ``postgresql://...``).

    Raises
    ------
    StoreError
        When it cannot be opened, or was written by a newer chaintwin.
    """

    def __init__(self, url: str) -> None:
        self.url = url
        if url.startswith("postgresql://"):
            url = "postgresql+psycopg://" + url[len("postgresql://") :]
        try:
            self.engine: Engine = create_engine(url, future=True, pool_pre_ping=True)
        except (SQLAlchemyError, ImportError, ValueError) as exc:
            raise StoreError(
                f"--db {_safe_url(self.url)}: not a usable database URL ({exc}); use "
                "sqlite:///file.db or postgresql://user:password@host/database"
            ) from None
        if self.engine.dialect.name == "sqlite":
            event.listen(self.engine, "connect", _sqlite_pragmas)
        try:
            Base.metadata.create_all(self.engine)
            with Session(self.engine) as s, s.begin():
                row = s.get(SchemaRow, 1)
                if row is None:
                    s.add(SchemaRow(id=1, version=SCHEMA_VERSION))
                elif row.version > SCHEMA_VERSION:
                    raise StoreError(
                        f"--db {_safe_url(self.url)}: the store has schema version "
                        f"{row.version}, written by a newer chaintwin (this one knows "
                        f"{SCHEMA_VERSION}); upgrade chaintwin"
                    )
        except OperationalError as exc:
            raise StoreError(
                f"--db {_safe_url(self.url)}: cannot open the store ({exc.orig}); check the "
                "path or server"
            ) from None

    def close(self) -> None:
        """Release the connections."""
        self.engine.dispose()

    # ------------------------------------------------------------ conveyors
    def put_profile(self, profile: ConveyorProfile) -> None:
        """Add a conveyor, or update its profile."""
        with Session(self.engine) as s, s.begin():
            row = s.get(ConveyorRow, profile.id)
            content = profile.model_dump(mode="json")
            if row is None:
                s.add(
                    ConveyorRow(
                        id=profile.id, profile=content, profile_sha256=profile.content_hash()
                    )
                )
            else:
                row.profile = content
                row.profile_sha256 = profile.content_hash()

    def put_calibration(self, calibration: Calibration) -> None:
        """Keep a calibration; the newest of a conveyor is the one used."""
        self.put_profile(calibration.profile)
        with Session(self.engine) as s, s.begin():
            s.add(
                CalibrationRow(
                    conveyor_id=calibration.profile.id,
                    created_at=_now(),
                    content=json.loads(json.dumps(calibration.to_dict())),
                )
            )

    def calibration(self, conveyor: str) -> Calibration | None:
        """The newest calibration of a conveyor, if any."""
        with Session(self.engine) as s:
            row = s.scalars(
                select(CalibrationRow)
                .where(CalibrationRow.conveyor_id == conveyor)
                .order_by(CalibrationRow.id.desc())
                .limit(1)
            ).first()
            return None if row is None else Calibration.from_dict(row.content, "store")

    # ------------------------------------------------------------ recordings
    def known(self, hashes: Iterable[str]) -> set[str]:
        """Which of these content hashes are stored already."""
        wanted = list(hashes)
        out: set[str] = set()
        with Session(self.engine) as s:
            for k in range(0, len(wanted), 500):
                chunk = wanted[k : k + 500]
                out.update(
                    s.scalars(select(RecordingRow.sha256).where(RecordingRow.sha256.in_(chunk)))
                )
        return out

    def monitor(
        self, profile: ConveyorProfile, settings: MonitorSettings
    ) -> tuple[ConveyorMonitor | None, int]:
        """A conveyor's stored health model and its version (None, 0 when new)."""
        with Session(self.engine) as s:
            row = s.get(MonitorStateRow, profile.id)
            if row is None:
                return None, 0
            mon = ConveyorMonitor.from_state(row.state, profile, source=_safe_url(self.url))
            mon.settings = settings
            return mon, row.version

    def commit_recording(
        self,
        recording: Recording,
        sha256: str,
        result: RecordingResult,
        monitor: ConveyorMonitor,
        version: int,
    ) -> int:
        """Store one recording, its result and the health model (see :meth:`commit_recordings`)."""
        return self.commit_recordings([Finished(recording, sha256, result)], monitor, version)

    def commit_recordings(
        self, items: Sequence[Finished], monitor: ConveyorMonitor, version: int
    ) -> int:
        """Store recordings, their results and the health model, in one transaction.

        The group is stored whole or not at all, and the health model stored
        with it is the one that produced the results: a kill between two
        groups loses nothing, a kill inside one leaves none of it.

        Parameters
        ----------
        items : sequence of Finished
            Recordings of ``monitor``'s conveyor with their results, in the
            order monitoring took them.
        monitor : ConveyorMonitor
            The health model after the last of them.
        version : int
            The model's version when it was read from the store (0: new).

        Returns
        -------
        int
            The health model's new version.

        Raises
        ------
        StateConflict
            When another writer advanced the model since ``version`` or stored
            one of the recordings meanwhile (nothing was stored; go again from
            the newer model).
        """
        conveyor = monitor.profile.id
        state = monitor.to_state()
        state["history"] = state["history"][-HISTORY_IN_STATE:]
        state = json_ready(state)
        now = _now()
        try:
            with Session(self.engine) as s, s.begin():
                if version == 0:
                    s.add(
                        MonitorStateRow(
                            conveyor_id=conveyor, state=state, updated_at=now, version=1
                        )
                    )
                    s.flush()
                else:
                    done = s.execute(
                        update(MonitorStateRow)
                        .where(
                            MonitorStateRow.conveyor_id == conveyor,
                            MonitorStateRow.version == version,
                        )
                        .values(state=state, updated_at=now, version=version + 1)
                    )
                    if done.rowcount != 1:  # type: ignore[attr-defined]
                        raise StateConflict(conveyor)
                recs = [
                    RecordingRow(
                        sha256=item.sha256,
                        conveyor_id=conveyor,
                        file=item.result.file,
                        recorded_at=item.result.recorded_at,
                        meta=recording_meta(item.recording),
                        warnings=[w.to_dict() for w in item.recording.warnings],
                        samples=item.samples or pack_samples(item.recording),
                    )
                    for item in items
                ]
                s.add_all(recs)
                s.flush()
                s.add_all(
                    ResultRow(
                        recording_id=rec.id,
                        conveyor_id=conveyor,
                        recorded_at=item.result.recorded_at,
                        status=item.result.status,
                        alarm=item.result.alarm,
                        payload_kg=item.result.payload_kg,
                        tlf=item.result.tlf,
                        content=json_ready(item.result.to_dict()),
                    )
                    for rec, item in zip(recs, items, strict=True)
                )
                self._put_alarms_events(s, monitor)
        except IntegrityError:
            # one of the recordings was stored by another writer in the meantime
            raise StateConflict(conveyor) from None
        return 1 if version == 0 else version + 1

    @staticmethod
    def _put_alarms_events(s: Session, monitor: ConveyorMonitor) -> None:
        """Bring the alarm and event rows of a conveyor up to its health model."""
        conveyor = monitor.profile.id
        rows = {
            r.id: r for r in s.scalars(select(AlarmRow).where(AlarmRow.conveyor_id == conveyor))
        }
        for alarm in monitor.alarms:
            values = {
                "conveyor_id": conveyor,
                "feature": alarm["feature"],
                "cause": alarm["cause"],
                "status": alarm["status"],
                "since": alarm.get("since"),
                "content": json_ready(alarm),
            }
            row = rows.get(alarm["id"])
            if row is None:
                s.add(AlarmRow(id=alarm["id"], **values))
            elif row.content != values["content"] or row.status != values["status"]:
                for k, v in values.items():
                    setattr(row, k, v)
        known = set(s.scalars(select(EventRow.id).where(EventRow.conveyor_id == conveyor)))
        for ev in monitor.events:
            if ev["id"] not in known:
                s.add(
                    EventRow(
                        id=ev["id"],
                        conveyor_id=conveyor,
                        kind=ev["kind"],
                        at=ev["at"],
                        content=json_ready(ev),
                    )
                )

    # ------------------------------------------------------------ reading
    def results(self, conveyor: str | None = None) -> list[dict[str, Any]]:
        """Stored results (``monitor --json`` objects), in recorded order."""
        with Session(self.engine) as s:
            q = select(ResultRow).order_by(ResultRow.recorded_at, ResultRow.id)
            if conveyor is not None:
                q = q.where(ResultRow.conveyor_id == conveyor)
            return [dict(r.content) for r in s.scalars(q)]

    def conveyors(self) -> list[str]:
        """Ids of the stored conveyors."""
        with Session(self.engine) as s:
            return list(s.scalars(select(ConveyorRow.id).order_by(ConveyorRow.id)))

    def counts(self) -> dict[str, int]:
        """Rows per table (recordings, results, alarms, calibrations)."""
        from sqlalchemy import func

        with Session(self.engine) as s:
            return {
                "recordings": s.scalar(select(func.count()).select_from(RecordingRow)) or 0,
                "results": s.scalar(select(func.count()).select_from(ResultRow)) or 0,
                "alarms": s.scalar(select(func.count()).select_from(AlarmRow)) or 0,
                "calibrations": s.scalar(select(func.count()).select_from(CalibrationRow)) or 0,
            }


def recording_meta(recording: Recording) -> dict[str, Any]:
    """A recording's metadata and channel units, JSON-ready, as stored."""
    m = recording.metadata
    out: dict[str, Any] = {
        k: getattr(m, k)
        for k in ("conveyor", "sample_time_s", "payload_kg", "tray_kg")
        if getattr(m, k, None) is not None
    }
    if m.recorded_at is not None:
        out["recorded_at"] = m.recorded_at.isoformat()
    out["extra"] = dict(m.extra)
    out["units"] = dict(recording.si_units())
    return json_ready(out)  # type: ignore[no-any-return]


def _sqlite_pragmas(dbapi_connection: Any, _record: Any) -> None:
    """WAL journal (readers do not block the writer) and a wait for the lock."""
    cur = dbapi_connection.cursor()
    cur.execute("PRAGMA journal_mode=WAL")
    cur.execute("PRAGMA busy_timeout=30000")
    cur.execute("PRAGMA foreign_keys=ON")
    cur.close()
