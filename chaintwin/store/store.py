"""The results store: one interface over SQLite (embedded) and PostgreSQL (shared).

``Store(url)`` opens (and creates) a store from a SQLAlchemy URL:
``sqlite:///plant.db`` (a file in the working folder, the default
``sqlite:///chaintwin.db``) or ``postgresql://user:pass@host/db`` (psycopg 3).
The URL may come from the environment variable ``CHAINTWIN_DB`` so that
credentials stay off the command line (:func:`store_url`).

Writes are atomic per recording: :meth:`Store.commit_recordings` stores a
group of recordings (with their samples), their results and the conveyor's
health model in one transaction. A recording already stored (same content SHA-256) is not
stored again. Two ingests may run at once: the health model carries a
version, and a writer whose model was advanced by the other in the meantime
gets :class:`StateConflict` and goes again from the newer model.
"""

from __future__ import annotations

import contextlib
import itertools
import json
import os
from collections.abc import Callable, Iterable, Iterator, Sequence
from contextvars import ContextVar
from datetime import UTC, datetime
from typing import Any, Self, TypeVar

from sqlalchemy import insert, select, update
from sqlalchemy.engine import Engine
from sqlalchemy.exc import DatabaseError, IntegrityError, OperationalError
from sqlalchemy.orm import Session

from chaintwin.diagnose.monitor import ConveyorMonitor
from chaintwin.diagnose.monitor_state import MonitorState
from chaintwin.diagnose.records import Alarm, Event, MonitorSettings
from chaintwin.diagnose.state import json_ready
from chaintwin.errors import StoreError
from chaintwin.identify.calibration import Calibration
from chaintwin.read.profile import ConveyorProfile
from chaintwin.read.recording import Recording

from . import migrate
from .engine import (
    _first_line,
    engine_for,
    hide_password,
    safe_url,
    sqlite_path,
    writable_place,
)
from .recognise import recognise
from .rows import Finished, Waiting, put_alarms_events
from .samples import pack_samples, recording_meta, stored_recording
from .schema import (
    AlarmAliasRow,
    AlarmRow,
    CalibrationRow,
    ConveyorRow,
    EventRow,
    MonitorStateRow,
    RecordingRow,
    ResultRow,
)
from .supersede import STANDING, complete, mark_superseded, stored_partials

__all__ = [
    "HISTORY_IN_STATE",
    "Finished",
    "StateConflict",
    "Store",
    "Waiting",
]

_STORES_OPENED = itertools.count()
"""Numbers each :class:`Store` made in the process (:attr:`Store.cache_key`)."""

HISTORY_IN_STATE = 300
"""Recent results kept inside a stored health model (for trend forecasts); all
results are in the ``results`` table."""


T = TypeVar("T")

_STORED = "store:"
"""Path prefix by which the health model finds a waiting recording kept in the store."""


_READING: ContextVar[tuple[Store, Session] | None] = ContextVar("chaintwin_reading", default=None)
"""The read session :meth:`Store.session` holds in this thread or task, with its store."""


def _iso_time(recording: Recording) -> str | None:
    """``recorded_at`` in UTC, as monitoring writes it."""
    at = recording.metadata.recorded_at
    return None if at is None else at.astimezone(UTC).isoformat()


def _why(exc: DatabaseError, url: str) -> str:
    """The database's reason, on one line (psycopg's run over several), the URL's password
    hidden (a driver names the host it could not reach, where a password's tail may be)."""
    return hide_password(_first_line(exc.orig or exc), url)


class StateConflict(Exception):
    """Another writer advanced a conveyor's health model first (not a user error)."""


def _now() -> str:
    return datetime.now(UTC).isoformat()


class Store:
    """A results store.

    The database is recognised through a read-only connection before it is
    opened for writing (:func:`~.recognise.recognise`: SQLite's header and
    ``PRAGMA quick_check`` up to :data:`~.engine.QUICK_CHECK_MAX_MB`, the
    tables and schema revision always): a damaged file or another program's
    database is refused, changed in nothing (not even switched to WAL).

    Parameters
    ----------
    url : str
        SQLAlchemy URL (``sqlite:///file.db``, ``postgresql://...``).
    create : bool
        Create a SQLite store that does not exist yet (False for commands
        that only read or change what is stored: a mistyped path is then an
        error, not a new empty store).
    read_only : bool
        Open it for reading only (commands that only read: ``export``,
        ``report``): the database cannot be changed through this object.
    pool_size : int, optional
        Connections kept open; SQLAlchemy's default 5. ``serve`` keeps more on
        PostgreSQL: its requests come in bursts.
    max_overflow : int, optional
        Connections opened beyond ``pool_size`` for a while (each closed when
        given back); default as many as ``pool_size``.
    sqlite_cache_kib : int, optional
        Each SQLite connection's page cache at most, KiB (SQLite's default
        2 000); ``serve`` keeps it small, its memory bounded.

    Raises
    ------
    StoreError
        When it cannot be opened, is not a chaintwin store, or its schema is
        not this chaintwin's (older: ``chaintwin db upgrade``; newer).
    """

    def __init__(
        self,
        url: str,
        *,
        create: bool = True,
        read_only: bool = False,
        pool_size: int | None = None,
        max_overflow: int | None = None,
        sqlite_cache_kib: int | None = None,
    ) -> None:
        self.url = url
        # what the process's caches of this store's reads are keyed by: its URL and this
        # object (a file recreated at the same path, or two in-memory databases, are
        # other stores)
        self.cache_key: tuple[str, int] = (url, next(_STORES_OPENED))
        path = sqlite_path(url)
        if (not create or read_only) and path is not None and not os.path.exists(path):
            raise StoreError(
                f"url {safe_url(url)}: there is no store there; give the store's URL (or set "
                "CHAINTWIN_DB), or ingest recordings into it first",
                field="url",
            )
        where = safe_url(self.url)
        revision = migrate.require_head(recognise(url, where), where)  # nothing written yet
        if revision is None and read_only:
            raise StoreError(
                f"url {where}: the database holds no chaintwin store; ingest recordings into "
                "it first",
                field="url",
            )
        if (
            not read_only
            and path is not None
            and os.path.exists(path)
            and not (
                writable_place(path) and writable_place(os.path.dirname(os.path.abspath(path)))
            )
        ):
            raise StoreError(
                f"url {where}: the store cannot be written there (a read-only file, folder or "
                "file system); `export` and `report` read it as it is; copy it to a writable "
                "place to change it",
                field="url",
            )
        self.engine: Engine = engine_for(
            url,
            read_only=read_only,
            pool_size=pool_size,
            max_overflow=max_overflow,
            sqlite_cache_kib=sqlite_cache_kib,
        )
        try:
            if revision is None:
                migrate.upgrade(self.engine, where)  # a new store
        except OperationalError as exc:
            self.engine.dispose()
            raise StoreError(
                f"url {where}: cannot open the store ({_why(exc, self.url)}); "
                "check the path or server",
                field="url",
            ) from None
        except DatabaseError as exc:
            self.engine.dispose()
            raise StoreError(
                f"url {where}: the file is not a usable SQLite database ({_why(exc, self.url)}); "
                "restore the store from a backup",
                field="url",
            ) from None
        except BaseException:
            self.engine.dispose()  # refused: no connection left open
            raise

    def close(self) -> None:
        """Release the connections."""
        self.engine.dispose()

    def __enter__(self) -> Self:
        """The store itself: ``with Store(url) as store:`` closes it however the block ends."""
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @contextlib.contextmanager
    def session(self) -> Iterator[Session]:
        """One database session for every read of this store inside the block.

        ``with store.session():`` around the reads of one request (a
        conveyor's page: its profile, results, health model, forecasts,
        alarms, events, verdict) makes them share one session, i.e. one
        connection taken from the pool once, rather than a session and a
        checkout per read (on PostgreSQL a round trip each to begin and end
        its transaction). The reads of this store (its methods, and the
        queries of :mod:`~chaintwin.store.queries`, :mod:`~chaintwin.store.derived`
        and :mod:`~chaintwin.store.verdicts`) use the session held by the
        current thread or task; a nested block shares the outer one. Writes
        keep their own session and transaction. A session belongs to one
        thread: hold it in synchronous code only, never across an ``await``.

        Yields
        ------
        Session
            The session (read with it; do not commit through it).
        """
        held = _READING.get()
        if held is not None and held[0] is self:
            yield held[1]
            return
        with Session(self.engine) as s:
            token = _READING.set((self, s))
            try:
                yield s
            finally:
                _READING.reset(token)

    @contextlib.contextmanager
    def reading(self, what: str) -> Iterator[Session]:
        """:meth:`session` for a read of ``what`` ("the trends of 'belt-01'"), a failing
        database told as :class:`~chaintwin.errors.StoreError` naming it.

        Raises
        ------
        StoreError
            When the database fails.
        """
        try:
            with self.session() as s:
                yield s
        except OperationalError as exc:
            raise StoreError(f"{safe_url(self.url)}: cannot read {what} ({exc.orig})") from None

    # ------------------------------------------------------------ conveyors
    def put_profile(self, profile: ConveyorProfile) -> None:
        """Add a conveyor, or update its profile.

        Raises
        ------
        StoreError
            When the conveyor is monitored with another version of its
            profile (its health model would no longer fit it); nothing is
            changed then.
        """
        with Session(self.engine) as s, s.begin():
            state = s.get(MonitorStateRow, profile.id)
            if state is not None and state.state.get("profile_sha256") != profile.content_hash():
                raise StoreError(
                    f"{safe_url(self.url)}: conveyor '{profile.id}' is monitored with another "
                    "version of its profile; give the profile it was monitored with (the "
                    "store's copy: `chaintwin export`), or keep the changed conveyor in a new "
                    "store"
                )
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
        with self.session() as s:
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
        with self.session() as s:
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
        with self.session() as s:
            row = s.get(MonitorStateRow, profile.id)
            if row is None:
                return None, 0
            state, version = dict(row.state), row.version
        # recordings waiting for a learned calibration are kept in the store
        # (without a result): the health model reads them back from there
        state["pending"] = [
            dict(p) | {"path": _STORED + str(p["sha256"])} for p in state.get("pending", [])
        ]
        mon = ConveyorMonitor.from_state(
            state, profile, loader=self._stored, source=safe_url(self.url)
        )
        mon.settings = settings
        return mon, version

    def partials(self, conveyor: str, recordings: Iterable[Recording]) -> set[str]:
        """Content SHA-256 of the stored partial recordings these complete ones replace.

        A stored recording with the ``incomplete_cycle`` warning, not yet
        superseded, of the same conveyor, file name and recorded time as one
        of ``recordings`` that holds a whole movement
        (:mod:`~.supersede`). They are marked when the new ones are stored
        (:meth:`commit_recordings`).
        """
        keys = [
            (rec.source, at)
            for rec in recordings
            if (at := _iso_time(rec)) is not None and complete(rec)
        ]
        if not keys:
            return set()
        with self.session() as s:
            found = stored_partials(s, conveyor, (f for f, _ in keys))
        return {sha for key in keys for sha in found.get(key, [])}

    def partial_files(self, conveyor: str, files: Iterable[str]) -> set[str]:
        """Which of these file names a stored partial recording of the conveyor has.

        One query per 500 names: an ingest asks this once per conveyor, and
        :meth:`partials` (a query per recording) only for the names found.
        """
        with self.session() as s:
            return {f for f, _at in stored_partials(s, conveyor, files)}

    def _stored(self, path: str) -> Recording:
        """A stored recording by its ``store:<sha256>`` path (the health model's loader)."""
        sha = path.removeprefix(_STORED)
        with self.session() as s:
            row = s.scalars(select(RecordingRow).where(RecordingRow.sha256 == sha)).first()
            if row is None:
                raise StoreError(f"{safe_url(self.url)}: no stored recording {sha[:12]}")
            return stored_recording(row.file, row.meta, row.warnings, row.samples)

    def commit_recordings(
        self,
        items: Sequence[Finished],
        monitor: ConveyorMonitor,
        version: int,
        waiting: Sequence[Waiting] = (),
    ) -> int:
        """Store recordings, their results and the health model, in one transaction.

        The group is stored whole or not at all, and the health model stored
        with it is the one that produced the results: a kill between two
        groups loses nothing, a kill inside one leaves none of it.

        Parameters
        ----------
        items : sequence of Finished
            Recordings of ``monitor``'s conveyor with their results, in the
            order monitoring took them; those stored earlier while they waited
            (``stored``) get their result only.
        monitor : ConveyorMonitor
            The health model after the last of them.
        version : int
            The model's version when it was read from the store (0: new).
        waiting : sequence of Waiting
            Recordings the health model holds back until it has learned a
            calibration: kept without a result, so that a later ingest finds
            them in the store.

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
        StoreError
            When the database stays locked or fails.
        """
        conveyor = monitor.profile.id
        state = monitor.to_state().to_dict()
        state["history"] = state["history"][-HISTORY_IN_STATE:]
        waiting_sha = {w.sha256 for w in waiting}
        state["pending"] = [
            p | {"path": _STORED + str(p["sha256"])}
            if p["sha256"] in waiting_sha or str(p["path"]).startswith(_STORED)
            else p
            for p in state["pending"]
        ]
        # no json_ready copy: the column's serializer writes non-finite floats as
        # null itself (_to_json), and the health model is the largest value stored
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
                earlier = [item.sha256 for item in items if item.stored]
                ids: dict[str, int] = {}
                if earlier:
                    q = select(RecordingRow.sha256, RecordingRow.id).where(
                        RecordingRow.sha256.in_(earlier)
                    )
                    ids = {str(sha): int(rid) for sha, rid in s.execute(q)}
                if len(ids) != len(earlier):
                    raise StateConflict(conveyor)  # a waiting recording is gone: start over
                new: list[Finished | Waiting] = [item for item in items if not item.stored]
                new += waiting
                # bulk inserts (one executemany each) instead of the unit of work;
                # the new ids are read back by content hash (unique), which needs
                # no RETURNING (SQLite before 3.35 has none)
                if new:
                    s.execute(
                        insert(RecordingRow),
                        [
                            {
                                "sha256": item.sha256,
                                "conveyor_id": conveyor,
                                "file": item.recording.source,
                                "recorded_at": _iso_time(item.recording),
                                "meta": recording_meta(item.recording),
                                "warnings": [w.to_dict() for w in item.recording.warnings],
                                "samples": item.samples or pack_samples(item.recording),
                            }
                            for item in new
                        ],
                    )
                    q = select(RecordingRow.sha256, RecordingRow.id).where(
                        RecordingRow.sha256.in_([item.sha256 for item in new])
                    )
                    ids.update({str(sha): int(rid) for sha, rid in s.execute(q)})
                    keyed = [
                        ((item.recording.source, at), item.sha256, ids[item.sha256])
                        for item in new
                        if (at := _iso_time(item.recording)) is not None
                        and complete(item.recording)
                    ]
                    if keyed:
                        mark_superseded(s, conveyor, keyed)
                if items:
                    stored_at = _now()
                    s.execute(
                        insert(ResultRow),
                        [
                            {
                                "recording_id": ids[item.sha256],
                                "conveyor_id": conveyor,
                                "recorded_at": item.result.recorded_at,
                                "status": item.result.status,
                                "alarm": item.result.alarm,
                                "payload_kg": item.result.payload_kg,
                                "tlf": item.result.tlf,
                                "content": item.result.to_dict(),  # null for NaN: _to_json
                                "stored_at": stored_at,
                            }
                            for item in items
                        ],
                    )
                put_alarms_events(s, conveyor, monitor.alarms, monitor.events, monitor.to_state)
        except IntegrityError:
            # one of the recordings was stored by another writer in the meantime
            raise StateConflict(conveyor) from None
        except OperationalError as exc:
            raise StoreError(
                f"{safe_url(self.url)}: cannot write to the store ({_why(exc, self.url)}); "
                "nothing of this group was stored, run the command again"
            ) from None
        return 1 if version == 0 else version + 1

    # ------------------------------------------------------------ reading
    def results(
        self, conveyor: str | None = None, *, with_ids: bool = False
    ) -> list[dict[str, Any]]:
        """Stored results (``monitor --json`` objects), per conveyor in the order monitored.

        That is recorded order (ingest sorts by ``recorded_at``; a recording
        without one follows its predecessor in the batch), the same on every
        database. ``with_ids`` adds ``recording_id`` (the recording's content
        SHA-256, the key the store and the web API know it by) and
        ``stored_at``. A partial recording superseded by its complete
        version is left out (:mod:`~.supersede`).
        """
        with self.session() as s:
            q = (
                select(ResultRow, RecordingRow.sha256)
                .join(RecordingRow, RecordingRow.id == ResultRow.recording_id)
                .where(STANDING)
                .order_by(ResultRow.conveyor_id, ResultRow.id)
            )
            if conveyor is not None:
                q = q.where(ResultRow.conveyor_id == conveyor)
            if not with_ids:
                return [dict(r.content) for r, _sha in s.execute(q)]
            return [
                dict(r.content) | {"recording_id": sha, "stored_at": r.stored_at}
                for r, sha in s.execute(q)
            ]

    def profile(self, conveyor: str) -> ConveyorProfile | None:
        """A stored conveyor's profile, if the conveyor is stored."""
        from chaintwin.read.profile import parse_profile

        with self.session() as s:
            row = s.get(ConveyorRow, conveyor)
            if row is None:
                return None
            return parse_profile(row.profile, f"{safe_url(self.url)} conveyor {conveyor}")

    def state(self, conveyor: str) -> MonitorState | None:
        """A conveyor's stored health model (None when it has none).

        Raises
        ------
        StoreError
            When the stored model is damaged.
        """
        with self.session() as s:
            row = s.get(MonitorStateRow, conveyor)
            if row is None:
                return None
            data = dict(row.state)
        return MonitorState.from_dict(data, source=f"{safe_url(self.url)} conveyor {conveyor}")

    def alarms(self, conveyor: str | None = None) -> list[Alarm]:
        """Stored alarms (as the health model keeps them), oldest first.

        Raises
        ------
        StoreError
            When a stored alarm is damaged.
        """
        with self.session() as s:
            q = select(AlarmRow).order_by(AlarmRow.since, AlarmRow.id)
            if conveyor is not None:
                q = q.where(AlarmRow.conveyor_id == conveyor)
            return [
                self._record(Alarm.from_dict, dict(r.content) | {"conveyor": r.conveyor_id}, r.id)
                for r in s.scalars(q)
            ]

    def events(self, conveyor: str | None = None) -> list[Event]:
        """Stored maintenance events, oldest first.

        Raises
        ------
        StoreError
            When a stored event is damaged.
        """
        with self.session() as s:
            q = select(EventRow).order_by(EventRow.at, EventRow.id)
            if conveyor is not None:
                q = q.where(EventRow.conveyor_id == conveyor)
            return [self._record(Event.from_dict, dict(r.content), r.id) for r in s.scalars(q)]

    def _record(self, parse: Callable[[dict[str, Any]], T], content: dict[str, Any], key: str) -> T:
        """A stored alarm or event as its record; StoreError naming it when damaged."""
        try:
            return parse(content)
        except (KeyError, TypeError, ValueError) as exc:
            raise StoreError(
                f"{safe_url(self.url)}: stored record '{key}' is damaged ({exc!r}); "
                "run `chaintwin db upgrade` or restore the store from a backup"
            ) from None

    def recording_index(self, conveyor: str) -> list[tuple[int, str, str | None]]:
        """``(id, file, recorded_at)`` of a conveyor's monitored recordings, in the order monitored.

        Recordings refused by monitoring or still waiting for a learned
        calibration are left out, and those whose samples retention dropped, and
        partial ones superseded by their complete version.
        """
        with self.session() as s:
            q = (
                select(RecordingRow.id, RecordingRow.file, RecordingRow.recorded_at)
                .join(ResultRow, ResultRow.recording_id == RecordingRow.id)
                .where(
                    RecordingRow.conveyor_id == conveyor,
                    ResultRow.status != "refused",
                    RecordingRow.samples != b"",
                    STANDING,
                )
                .order_by(ResultRow.id)
            )
            return [(int(i), str(f), t) for i, f, t in s.execute(q)]

    def recording(self, recording_id: int) -> Recording:
        """A stored recording, rebuilt from its samples (SI) and metadata.

        Raises
        ------
        StoreError
            When there is no such recording.
        """
        with self.session() as s:
            row = s.get(RecordingRow, recording_id)
            if row is None:
                raise StoreError(f"{safe_url(self.url)}: no recording with id {recording_id}")
            return stored_recording(row.file, row.meta, row.warnings, row.samples)

    def edit_state(self, conveyor: str, edit: Callable[[dict[str, Any]], T]) -> T:
        """Change a conveyor's stored health model (maintenance, acknowledgement), atomically.

        Parameters
        ----------
        conveyor : str
            Conveyor id.
        edit : callable
            Called with ``{"conveyors": {conveyor: state}}`` (the layout of a
            state file, so that :func:`~chaintwin.diagnose.state.add_maintenance`
            and :func:`~chaintwin.diagnose.state.acknowledge_alarm` apply); it
            changes the state in place and returns what the caller wants back.

        Raises
        ------
        StoreError
            When the store has no health model of the conveyor, or from ``edit``.
        """
        for _attempt in range(20):
            try:
                return self._edit_once(conveyor, edit)
            except StateConflict:
                continue  # an ingest advanced the model meanwhile: edit the newer one
            except OperationalError as exc:
                raise StoreError(
                    f"{safe_url(self.url)}: cannot write to the store ({_why(exc, self.url)}); "
                    "nothing was changed, run the command again"
                ) from None
        raise StoreError(f"the health model of '{conveyor}' kept changing; try again")

    def _edit_once(self, conveyor: str, edit: Callable[[dict[str, Any]], T]) -> T:
        with Session(self.engine) as s, s.begin():
            row = s.get(MonitorStateRow, conveyor)
            if row is None:
                raise StoreError(
                    f"{safe_url(self.url)}: no health model of conveyor '{conveyor}' "
                    f"(stored: {', '.join(self._monitored(s)) or 'none'}); ingest its "
                    "recordings first"
                )
            state = json.loads(json.dumps(row.state))  # a copy to change
            out = edit({"conveyors": {conveyor: state}})
            done = s.execute(
                update(MonitorStateRow)
                .where(
                    MonitorStateRow.conveyor_id == conveyor,
                    MonitorStateRow.version == row.version,
                )
                .values(state=json_ready(state), updated_at=_now(), version=row.version + 1)
            )
            if done.rowcount != 1:  # type: ignore[attr-defined]
                raise StateConflict(conveyor)  # rolls the transaction back
            typed = MonitorState.from_dict(
                state, source=f"{safe_url(self.url)} conveyor {conveyor}"
            )
            put_alarms_events(s, conveyor, typed.alarms, typed.events, lambda: typed)
            return out

    def alarm_conveyor(self, alarm_id: str) -> str:
        """The conveyor an alarm belongs to.

        Raises
        ------
        StoreError
            When the store has no alarm with that id.
        """
        with self.session() as s:
            row = s.get(AlarmRow, alarm_id)
            alias = None if row is not None else s.get(AlarmAliasRow, alarm_id)
            if alias is not None:  # an alarm grouped into another: the other's conveyor
                row = s.get(AlarmRow, alias.alarm_id)
            if row is None:
                raise StoreError(
                    f"{safe_url(self.url)}: no alarm '{alarm_id}'; the ids are in "
                    "`chaintwin export --format json` and in the reports"
                )
            return row.conveyor_id

    @staticmethod
    def _monitored(s: Session) -> list[str]:
        return list(s.scalars(select(MonitorStateRow.conveyor_id)))

    def conveyors(self) -> list[str]:
        """Ids of the stored conveyors."""
        with self.session() as s:
            return list(s.scalars(select(ConveyorRow.id).order_by(ConveyorRow.id)))

    def counts(self) -> dict[str, int]:
        """Rows per table (recordings, results, alarms, calibrations)."""
        from sqlalchemy import func

        with self.session() as s:
            return {
                "recordings": s.scalar(select(func.count()).select_from(RecordingRow)) or 0,
                "results": s.scalar(select(func.count()).select_from(ResultRow)) or 0,
                "alarms": s.scalar(select(func.count()).select_from(AlarmRow)) or 0,
                "calibrations": s.scalar(select(func.count()).select_from(CalibrationRow)) or 0,
            }
