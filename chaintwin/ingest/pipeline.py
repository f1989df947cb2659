"""Ingest: read, validate, weigh and monitor many recordings into the store.

The expensive part of a recording (reading, validation, weighing, features)
does not depend on the other recordings once the conveyor is calibrated, so
it runs in parallel: on a local process pool by default, on a Dask cluster
when given its scheduler address. Both are used through the same
``concurrent.futures`` interface (:class:`~.executors.ClusterExecutor` wraps
``distributed.Client.get_executor()``), so the code path is the same; what
the tasks share (profile, calibration) goes to a cluster's workers once
(:func:`~.executors.shared`). The health model of a conveyor then takes the
recordings one by one in recorded order, in this process. Recordings are
stored in groups (up to :data:`COMMIT_GROUP`, or what :data:`COMMIT_EVERY_S`
gathered), each group in one transaction with the health model that produced
its results (:meth:`Store.commit_recordings`): writing the health model once
per group instead of once per recording is what lets the store keep up with
the workers.

A conveyor without a calibration in the store (``calibrate --db``) learns one
from its first recordings; until then its recordings are read in parallel but
weighed here, one by one.

Refused files never stop the batch; a file already stored (same content) is
counted as a duplicate and skipped; running ingest again after a crash or a
kill finishes the job. The complete version of a stored partial file (same
conveyor, name and recorded time; the stored one has ``incomplete_cycle``)
is stored and the partial one marked superseded (:mod:`~.supersede`); the
health model takes the partial one back before judging it
(:meth:`~chaintwin.diagnose.monitor.ConveyorMonitor.forget`).
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import FIRST_COMPLETED, Executor, Future, ProcessPoolExecutor, wait
from dataclasses import dataclass, field, replace
from datetime import UTC, datetime
from typing import Any

from chaintwin.diagnose.records import MonitorSettings
from chaintwin.diagnose.session import resume, undated
from chaintwin.errors import StoreError
from chaintwin.identify.calibration import Calibration
from chaintwin.read.batch import RecordingFile, group_by_conveyor, order_recordings
from chaintwin.read.columns import ColumnMap
from chaintwin.read.profile import ConveyorProfile
from chaintwin.read.recording import Recording, RecordingWarning
from chaintwin.store.engine import safe_url
from chaintwin.store.store import HISTORY_IN_STATE, Finished, StateConflict, Store, Waiting

from .executors import InlineExecutor, executor, lanes, shared, signals_deferred
from .worker import Prepared, prepare, prepare_many

__all__ = [
    "COMMIT_GROUP",
    "IngestSummary",
    "InlineExecutor",
    "Prepared",
    "executor",
    "ingest",
    "prepare",
    "prepare_many",
]


@dataclass
class IngestSummary:
    """What an ingest did (``ingest --json``)."""

    processed: int = 0
    duplicates: int = 0
    refused: int = 0
    warnings: int = 0
    new_alarms: int = 0
    waiting: int = 0
    """Stored without a result: held back until the conveyor's calibration is learned."""
    refusals: list[dict[str, str]] = field(default_factory=list)
    seconds: float = 0.0
    profile_refused: set[str] = field(default_factory=set)
    """Files (as named in ``refusals``) refused because the store monitors their
    conveyor with another profile: a matter of the profile, not of the file."""
    stored_for: set[str] = field(default_factory=set)
    """Conveyors whose health model this ingest changed (their forecasts to refit)."""

    def to_dict(self) -> dict[str, Any]:
        """The ``ingest --json`` object."""
        return {
            "processed": self.processed,
            "duplicates": self.duplicates,
            "refused": self.refused,
            "warnings": self.warnings,
            "new_alarms": self.new_alarms,
            "refusals": self.refusals,
            "waiting": self.waiting,
            "seconds": self.seconds,
        }


CHUNK = 16
"""Recordings per task sent to a worker (fewer, larger messages between processes)."""

IN_FLIGHT_PER_WORKER = 3
"""Tasks submitted ahead per local worker process."""

DASK_IN_FLIGHT = 64
"""Tasks submitted ahead to a Dask cluster that has no worker yet when the ingest starts."""

COMMIT_GROUP = 64
"""Most recordings stored in one transaction."""

COMMIT_EVERY_S = 2.0
"""A group is stored at the latest this long after its first recording, s."""


_PARTLY = RecordingWarning(
    "supersedes_partial",
    "replaces a partial recording of the same file and time stored earlier; recordings "
    "monitored after that one were judged with it, and their results stay as they were",
).to_dict()
"""The warning of a complete recording whose partial version was not the latest monitored."""


def _same(a: Calibration | None, b: Calibration | None) -> bool:
    """Whether two calibrations are the same (the same object, or equal content)."""
    if a is b:
        return True
    return a is not None and b is not None and a.to_dict() == b.to_dict()


class _Conveyor:
    """One conveyor's part of an ingest: its health model and what is not yet stored."""

    def __init__(
        self,
        store: Store,
        profile: ConveyorProfile,
        settings: MonitorSettings,
        summary: IngestSummary,
        group: int,
        refit: bool = True,
    ) -> None:
        self.store = store
        self.refit = refit
        self.profile = profile
        self.settings = settings
        self.summary = summary
        self.group = group
        store.put_profile(profile)  # refused when the stored health model has another profile
        saved, self.version = store.monitor(profile, settings)
        waited = {r.source: (r, str(h)) for r, h in (saved.waiting() if saved else [])}
        # the store's calibration made anew (calibrate --db) replaces the model's
        cal, where = store.calibration(profile.id), safe_url(store.url)
        self.monitor, flushed = resume(
            saved, profile, settings, cal, other_calibration="replace", source=where
        )
        self.opened = {a.id for a in self.monitor.alarms}
        # this run's recordings taken by monitoring but not yet stored (file -> input)
        self.inputs: dict[str, Prepared] = {}
        self.digests: dict[str, str] = {}
        # file names of this run with a stored partial recording (Store.partial_files)
        self.suspects: set[str] = set()
        # the calibration each recording's features were computed with
        self.weighed_with: dict[str, Calibration | None] = {}
        # recordings stored while they wait for a learned calibration (file -> recording, sha)
        self.carried: dict[str, tuple[Recording, str]] = {}
        self._carry()
        # recordings that waited in the store, weighed now with the new calibration
        self.finished: list[Finished] = [
            Finished(*waited[res.file], res, stored=True) for res in flushed
        ]
        self.group_started = 0.0

    def _carry(self) -> None:
        """The waiting recordings the health model read back from the store."""
        self.carried = {
            rec.source: (rec, str(sha))
            for rec, sha in self.monitor.waiting()
            if rec.source not in self.inputs
        }

    def take(self, item: Prepared, digest: str, calibration: Calibration | None) -> None:
        """Monitor one recording; store the group when it is full or old."""
        rec = item.recording
        assert rec is not None
        if not self.inputs:
            self.group_started = time.monotonic()
        self.inputs[rec.source] = item
        self.weighed_with[rec.source] = calibration
        self.digests[rec.source] = digest
        self._process(item)
        if len(self.finished) >= self.group or self.stale():
            self.flush()

    def stale(self) -> bool:
        """Whether the group not yet stored began more than :data:`COMMIT_EVERY_S` ago."""
        return bool(self.inputs) and time.monotonic() - self.group_started > COMMIT_EVERY_S

    def _process(self, item: Prepared) -> None:
        rec = item.recording
        assert rec is not None
        replaced = (
            self.store.partials(self.profile.id, [rec]) if rec.source in self.suspects else set()
        )
        # the complete version of a stored partial file: judged in its place
        partly = bool(replaced) and not self.monitor.forget(replaced)
        features = item.features
        if features is not None and not _same(
            self.weighed_with.get(rec.source), self.monitor.calibration
        ):
            features = None  # computed with another calibration: the monitor computes them
        for res in self.monitor.process(rec, self.digests[rec.source], features=features):
            if partly and res.file == rec.source:
                res.warnings.append(_PARTLY)
            if res.file in self.inputs:
                done = self.inputs[res.file]
                assert done.recording is not None
                fin = Finished(done.recording, self.digests[res.file], res, done.samples)
            else:  # waited in the store for the learned calibration
                old, sha = self.carried[res.file]
                fin = Finished(old, sha, res, stored=True)
            self.finished.append(fin)

    def flush(self) -> None:
        """Store the finished recordings and those waiting for a learned calibration.

        After a lost race with another ingest, the recordings go again on the
        newer health model.
        """
        with signals_deferred():  # a stop lands after the bookkeeping, never between
            self._flush()

    def _flush(self) -> None:
        while True:
            done = {fin.result.file for fin in self.finished}
            waiting = [
                Waiting(item.recording, self.digests[f], item.samples)
                for f, item in self.inputs.items()
                if f not in done and item.recording is not None
            ]
            if not self.finished and not waiting:
                return
            try:
                self.version = self.store.commit_recordings(
                    self.finished, self.monitor, self.version, waiting
                )
            except StateConflict:
                self._again()
                continue
            break
        self.summary.stored_for.add(self.profile.id)
        for fin in self.finished:
            res = fin.result
            if res.error is not None:
                self.summary.refused += 1
                self.summary.refusals.append({"file": res.file, "error": res.error})
            else:
                self.summary.processed += 1
                self.summary.warnings += len(res.warnings)
            self.carried.pop(res.file, None)
        for w in waiting:
            self.carried[w.recording.source] = (w.recording, w.sha256)
        self.summary.waiting += len(waiting)
        self._trim_history()
        self.inputs = {}
        self.weighed_with = {}
        self.finished = []

    def _trim_history(self) -> None:
        """Keep the stored share of the model's result history in memory, no more.

        The store keeps a conveyor's latest :data:`~.store.HISTORY_IN_STATE`
        results inside its health model (all of them in its results table),
        and that is what the next ingest reads back. The model in memory
        would otherwise keep every result of the batch (a few kB each: about
        80 MB over 20,000 recordings, measured); once a group is
        stored it keeps what a new ingest would read back. Monitoring a
        recording reads only the latest results, and this batch's duplicates
        are found before monitoring (content hashes), so results are the same.
        """
        mon = self.monitor
        if len(mon.history) <= HISTORY_IN_STATE:
            return
        del mon.history[:-HISTORY_IN_STATE]
        mon.processed = {h["sha256"]: k for k, h in enumerate(mon.history) if h.get("sha256")}

    def _again(self) -> None:
        """Another ingest advanced this conveyor: take this run's recordings on its model."""
        mon, self.version = self.store.monitor(self.profile, self.settings)
        if mon is None:  # pragma: no cover - a row never disappears
            raise StoreError(f"the health model of '{self.profile.id}' vanished") from None
        self.monitor = mon
        self.opened |= {a.id for a in mon.alarms}  # not this run's news
        self.finished = []
        stored = self.store.known(self.digests[f] for f in self.inputs)
        again = list(self.inputs.items())
        self.inputs = {}
        self._carry()
        for f, item in again:
            if self.digests[f] in stored:
                self.summary.duplicates += 1
                continue
            self.inputs[f] = item
            self._process(item)

    def close(self) -> None:
        """Store what is left; count the alarms this ingest opened; refit the forecasts."""
        self.flush()
        self.summary.new_alarms += len({a.id for a in self.monitor.alarms} - self.opened)
        if self.refit:
            from chaintwin.report.trend_series import refit_with_trends

            refit_with_trends(self.store, self.profile.id)


SCAN_CHUNK = 128
"""Most files per task of the first pass (conveyor, recorded time, content hash).

Such a task takes about 0.1 ms per file: small tasks would spend as long
being handed to a worker as being done."""


@dataclass
class _Window:
    """How many recordings go to the workers, and in which pieces."""

    tasks: int
    """Most tasks in flight."""
    biggest: int
    """Most recordings in a task."""
    lanes: int
    """Workers that take tasks at once."""
    left: int
    """Recordings not yet submitted."""

    def size(self) -> int:
        """Recordings in the next task: :attr:`biggest`, smaller towards the end.

        The last tasks shrink with what is left (guided self-scheduling) so
        that the workers finish at about the same time instead of one
        working through a whole task while the others wait.
        """
        return max(1, min(self.biggest, -(-self.left // (2 * self.lanes))))


class _Batch:
    """One ingest's recordings on their way: scanned, sent to the workers, taken in order.

    The first pass (each file's conveyor, recorded time and content hash,
    :func:`group_by_conveyor`) runs on the workers in tasks of up to
    :data:`SCAN_CHUNK` files. While it runs, the new files it has found go
    to the workers already, in the order given: they do not wait for the
    whole batch to be scanned, which only the order of monitoring needs.
    Once all is scanned, the rest goes in each conveyor's recorded order,
    and the health models take their recordings in that order as results
    come back (results that arrive early wait here).

    One window of tasks runs across conveyors, so that the workers do not
    wait at each conveyor's end; the last tasks shrink (:class:`_Window`);
    once everything is sent, finished recordings are stored while the
    workers read the last ones, and the local pool is told to shut down
    before the last transaction.
    """

    def __init__(
        self,
        ex: Executor,
        files: Sequence[str],
        profiles: dict[str, ConveyorProfile],
        store: Store,
        window: _Window,
        open_conveyor: Callable[[ConveyorProfile], _Conveyor],
        column_map: ColumnMap | None,
        summary: IngestSummary,
        tick: Callable[[], None],
        names: Mapping[str, str] | None = None,
    ) -> None:
        self.ex = ex
        self.names = dict(names or {})
        self.profiles = profiles
        self.store = store
        self.window = window
        self.open_conveyor = open_conveyor
        self.column_map = column_map
        self.summary = summary
        self.tick = tick
        self.here = isinstance(ex, InlineExecutor)
        conveyors = list(profiles)
        # at most SCAN_CHUNK files a task, and at least two tasks a worker
        step = max(16, min(SCAN_CHUNK, -(-len(files) // (2 * window.lanes))))
        self.scans: deque[Future[tuple[dict[str, list[RecordingFile]], list[tuple[str, str]]]]]
        self.scans = deque(
            ex.submit(group_by_conveyor, files[k : k + step], conveyors)
            for k in range(0, len(files), step)
        )
        self.seen: set[str] = set()  # contents of this batch (sha256)
        self.sha: dict[str, str] = {}  # file -> content hash
        self.found: dict[str, list[RecordingFile]] = {}  # new files by conveyor, as given
        # health models are opened when their first recording is sent and let go
        # when their last is taken: a fleet's are not all in memory at once
        self.open: dict[str, _Conveyor] = {}
        self.why: dict[str, str] = {}  # conveyors the store refused, and why
        self.unsent: deque[tuple[str, str]] = deque()  # (conveyor, file)
        self.pending: deque[tuple[str, list[str], Calibration | None, Future[list[Prepared]]]] = (
            deque()
        )
        self.ready: dict[str, tuple[Prepared, Calibration | None]] = {}
        self.untaken: dict[str, deque[str]] = {}  # recorded order, once all is scanned
        self.undated: set[str] = set()  # files without a recorded time
        self.suspects: dict[str, set[str]] = {}  # names with a stored partial, by conveyor

    def run(self) -> None:
        """Scan, send, take and store everything.

        Raises
        ------
        StoreError
            When a recording was left neither stored nor counted (a fault of
            this code, said rather than passed over; ingest again).
        """
        while self.scans:
            while self.scans and self.scans[0].done():
                self._scanned(*self.scans.popleft().result())
            if not self.scans:
                break
            self._send()
            waiting: list[Future[Any]] = [self.scans[0]]
            if self.pending:
                waiting.append(self.pending[0][3])
            wait(waiting, return_when=FIRST_COMPLETED)
            while self.pending and self.pending[0][3].done():
                self._receive()
        self._plan()
        if not self.here:
            self._send()
        for cid in list(self.untaken):
            self._take(cid)  # what arrived while the scan ran
        while True:
            if self.here:  # one at a time: a calibration learned is used by the next one
                self._send()
            if not self.pending:
                break
            cid = self._receive()
            if not self.here:
                self._send()  # the freed place first: monitoring may store a group now
            self._take(cid)
            for conv in self.open.values():
                if conv.stale():
                    conv.flush()
        left = len(self.ready) + sum(len(v) for v in self.untaken.values())
        if left:
            raise StoreError(
                f"ingest: {left} recording(s) were neither stored nor counted (a fault of "
                "chaintwin; what was stored is whole): ingest the same files again"
            )

    def _scanned(self, part: dict[str, list[RecordingFile]], bad: list[tuple[str, str]]) -> None:
        """Take one task's scan: refusals, duplicates, and new files to send."""
        for f, error in bad:
            self._refuse(f, error)
        known = self.store.known(item.sha256 for items in part.values() for item in items)
        for cid, items in part.items():
            for item in items:
                if item.sha256 in known or item.sha256 in self.seen:
                    self.summary.duplicates += 1  # stored, or twice in this batch
                    self.tick()
                    continue
                self.seen.add(item.sha256)
                self.sha[item.path] = item.sha256
                if cid in self.why:
                    self._refuse(item.path, self.why[cid], profile=True)
                    continue
                self.found.setdefault(cid, []).append(item)
                self.unsent.append((cid, item.path))

    def _refuse(self, f: str, error: str, *, profile: bool = False) -> None:
        self.tick()
        self.summary.refused += 1
        name = self.names.get(f)
        if name is not None:
            error = error.replace(f, name)
        self.summary.refusals.append({"file": name or f, "error": error})
        if profile:
            self.summary.profile_refused.add(name or f)

    def _plan(self) -> None:
        """All is scanned: each conveyor's recorded order; the rest is sent in it."""
        unsent = {f for _, f in self.unsent}
        self.unsent = deque()
        for cid, items in self.found.items():
            order, missing = order_recordings([(item.path, item.recorded_at) for item in items])
            self.undated |= missing
            self.untaken[cid] = deque(order)
            named = [self.names.get(f, f) for f in order]
            self.suspects[cid] = self.store.partial_files(cid, named)
            self.unsent.extend((cid, f) for f in order if f in unsent)
        self.window.left = len(self.unsent)

    def _conveyor(self, cid: str) -> _Conveyor | None:
        """The conveyor's health model, opened now if need be (None: the store refused it)."""
        conv = self.open.get(cid)
        if conv is not None:
            return conv
        try:
            conv = self.open[cid] = self.open_conveyor(self.profiles[cid])
            return conv
        except StoreError as exc:  # e.g. monitored with another version of the profile
            self.why[cid] = str(exc)
        # nothing of it was sent yet: all its files are refused
        for _, f in (x for x in self.unsent if x[0] == cid):
            self._refuse(f, self.why[cid], profile=True)
        self.unsent = deque(x for x in self.unsent if x[0] != cid)
        if self.untaken:  # planned: what is left to send is known
            self.window.left = len(self.unsent)
        self.found.pop(cid, None)
        self.untaken.pop(cid, None)
        return None

    def _send(self) -> None:
        """Fill the window: tasks of one conveyor's consecutive files each."""
        while len(self.pending) < self.window.tasks and self.unsent:
            cid = self.unsent[0][0]
            conv = self._conveyor(cid)
            if conv is None:
                continue
            chunk: list[str] = []
            size = self.window.size()
            while self.unsent and self.unsent[0][0] == cid and len(chunk) < size:
                chunk.append(self.unsent.popleft()[1])
            self.window.left = max(0, self.window.left - len(chunk))
            # a window of files in flight rather than all at once: memory stays
            # bounded, and once a calibration is learned the files submitted
            # after it are weighed in the workers with it
            cal = conv.monitor.calibration
            prof, with_cal = shared(self.ex, conv.profile), shared(self.ex, cal)
            fut = self.ex.submit(prepare_many, chunk, prof, self.column_map, with_cal)
            self.pending.append((cid, chunk, cal, fut))

    def _receive(self) -> str:
        """The first task's results (waited for), kept to be taken in their turn."""
        cid, chunk, cal, fut = self.pending.popleft()
        for f, prepared in zip(chunk, fut.result(), strict=True):
            self.ready[f] = (prepared, cal)  # a refused one is counted in its turn
        return cid

    def _take(self, cid: str) -> None:
        """Monitor the conveyor's next recordings in recorded order, as far as they are here."""
        order = self.untaken.get(cid)
        conv = self.open.get(cid)
        if order is None or conv is None:
            return  # the scan is still running, or nothing of it was sent yet
        while order and order[0] in self.ready:
            f = order.popleft()
            prepared, cal = self.ready.pop(f)
            if prepared.recording is None:
                self._refuse(f, prepared.error or "refused")
                continue
            self.tick()
            rec = prepared.recording
            if f in self.undated:
                rec = undated(rec)
            if f in self.names:  # stored and reported under its name, not its path
                rec = replace(rec, source=self.names[f])
            if rec is not prepared.recording:
                prepared = prepared._replace(recording=rec)
            if rec.source in self.suspects.get(cid, ()):
                conv.suspects.add(rec.source)  # may replace a stored partial recording
            conv.take(prepared, self.sha[f], cal)
        if not order:
            del self.untaken[cid]
            del self.open[cid]
            if not self.untaken and isinstance(self.ex, ProcessPoolExecutor):
                # nothing more for the workers: they exit while this stores (the
                # pool's own shut-down at the end of ingest then waits for nothing)
                self.ex.shutdown(wait=False)
            conv.close()
        elif not self.unsent and len(conv.finished) >= max(
            self.window.biggest, sum(len(c) for _, c, _, _ in self.pending)
        ):
            conv.flush()  # while the workers read the last recordings


def _window(ex: Executor, workers: int | None, total: int) -> _Window:
    """The window of tasks for an executor and ``total`` recordings.

    In this process, one recording at a time: nothing to save on messages,
    and a learned calibration is taken up by the very next recording.
    Otherwise :data:`IN_FLIGHT_PER_WORKER` tasks of up to :data:`CHUNK`
    recordings per worker (a Dask cluster's worker threads, asked of its
    scheduler); a cluster without workers yet gets :data:`DASK_IN_FLIGHT`.
    """
    if isinstance(ex, InlineExecutor):
        return _Window(tasks=1, biggest=1, lanes=1, left=total)
    n = lanes(ex, workers)
    if n < 1:
        n = DASK_IN_FLIGHT // IN_FLIGHT_PER_WORKER
    return _Window(tasks=IN_FLIGHT_PER_WORKER * n, biggest=CHUNK, lanes=n, left=total)


def ingest(
    files: Sequence[str],
    profiles: dict[str, ConveyorProfile],
    store: Store,
    *,
    settings: MonitorSettings | None = None,
    workers: int | None = None,
    scheduler: str | None = None,
    column_map: ColumnMap | None = None,
    progress: Callable[[int, int], None] | None = None,
    commit_group: int = COMMIT_GROUP,
    names: Mapping[str, str] | None = None,
    refit: bool = True,
) -> IngestSummary:
    """Run the whole pipeline over recordings into the store.

    Parameters
    ----------
    files : sequence of str
        Recording files (any order; each conveyor's are taken in recorded order).
    profiles : dict
        Profiles by id; recordings are matched by their ``conveyor``.
    store : Store
        Where results go.
    settings : MonitorSettings, optional
        Baseline size and alarm rule.
    workers : int, optional
        Local worker processes.
    scheduler : str, optional
        Dask scheduler address.
    column_map : ColumnMap, optional
        For exports named otherwise.
    progress : callable, optional
        Called with (done, total).
    commit_group : int
        Most recordings stored in one transaction (1: each on its own).
    names : mapping, optional
        The name a file is stored and reported under, by its path as given
        (the store's ``file`` column, the results' ``file``, the refusals);
        default the path itself. The live service names a drive's recording,
        spooled to a temporary file, ``opcua://<conveyor>/<counter>``.
    refit : bool
        Refit each ingested conveyor's forecasts and wear rates once its
        recordings are stored (:func:`~chaintwin.store.derived.refit`), so
        that pages read them current. False: the caller refits (the live
        service, in the background).

    Returns
    -------
    IngestSummary
    """
    started = datetime.now(UTC)
    settings = settings or MonitorSettings()
    summary = IngestSummary()
    total, done = len(files), 0

    def tick() -> None:
        nonlocal done
        done += 1
        if progress is not None:
            progress(done, total)

    # a file given twice is read once (its content could change in between)
    unique = list(dict.fromkeys(files))
    for _ in range(len(files) - len(unique)):
        summary.duplicates += 1
        tick()
    try:
        with executor(workers, scheduler) as ex:
            _Batch(
                ex,
                unique,
                profiles,
                store,
                _window(ex, workers, total),
                lambda prof: _Conveyor(store, prof, settings, summary, max(1, commit_group), refit),
                column_map,
                summary,
                tick,
                names,
            ).run()
    except KeyboardInterrupt as exc:  # Ctrl-C, or SIGTERM through the command line
        exc.add_note(
            f"ingest stopped: {summary.processed} recording(s) stored with their results, "
            f"{summary.waiting} stored waiting for a calibration; run the same ingest again "
            "to finish (what is stored is skipped)"
        )
        raise
    summary.seconds = (datetime.now(UTC) - started).total_seconds()
    return summary
