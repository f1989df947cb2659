"""Ingest: read, validate, weigh and monitor many recordings into the store.

The expensive part of a recording (reading, validation, weighing, features)
does not depend on the other recordings once the conveyor is calibrated, so
it runs in parallel: on a local process pool by default, on a Dask cluster
when given its scheduler address. Both are used through the same
``concurrent.futures`` interface (``distributed.Client.get_executor()``), so
the code path is the same. The health model of a conveyor then takes the
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
kill finishes the job.
"""

from __future__ import annotations

import os
import time
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Executor, Future, ProcessPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass, field
from datetime import UTC, datetime
from typing import Any

from chaintwin.diagnose.monitor import ConveyorMonitor, MonitorSettings
from chaintwin.errors import StoreError
from chaintwin.identify.calibration import Calibration
from chaintwin.read.batch import RecordingFile, group_by_conveyor, order_recordings
from chaintwin.read.columns import ColumnMap
from chaintwin.read.profile import ConveyorProfile
from chaintwin.read.recording import Recording

from . import forkserver
from .store import Finished, StateConflict, Store, Waiting
from .worker import Prepared, pin_threads, prepare, prepare_many

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


class InlineExecutor(Executor):
    """A ``concurrent.futures`` executor that runs each task in this process at once.

    One worker needs no pool: the pipeline then runs on one core with
    nothing sent between processes and no worker to start, by the same code
    path as on a pool or a cluster (the futures are done when returned).
    """

    def submit(self, fn: Callable[..., Any], /, *args: Any, **kwargs: Any) -> Future[Any]:
        """Run ``fn(*args, **kwargs)`` now; its result (or exception) in a done future."""
        fut: Future[Any] = Future()
        try:
            fut.set_result(fn(*args, **kwargs))
        except Exception as exc:  # handed to the caller through the future
            fut.set_exception(exc)
        return fut


def _inline(workers: int | None, scheduler: str | None) -> bool:
    """Whether the pipeline runs in this process: one local worker (given, or one core)."""
    return scheduler is None and (workers or os.cpu_count() or 1) == 1


@contextmanager
def executor(workers: int | None, scheduler: str | None) -> Iterator[Executor]:
    """A ``concurrent.futures`` executor: this process, a local process pool, or a Dask cluster.

    Parameters
    ----------
    workers : int, optional
        Local worker processes (default: the machine's cores); 1 runs the
        pipeline in this process (:class:`InlineExecutor`).
    scheduler : str, optional
        Address of a Dask scheduler (``tcp://host:8786``); the cluster's
        workers are used instead of local processes.

    Raises
    ------
    StoreError
        When the scheduler cannot be reached.
    """
    if _inline(workers, scheduler):
        yield InlineExecutor()
        return
    if scheduler is None:
        # forked from the fork server (forkserver.py says why), which may
        # have been started already by the command (forkserver.start)
        with ProcessPoolExecutor(
            max_workers=workers, mp_context=forkserver.context(), initializer=pin_threads
        ) as ex:
            yield ex
        return
    from distributed import Client

    try:
        client = Client(scheduler, timeout="10s")  # type: ignore[no-untyped-call]
    except (OSError, TimeoutError) as exc:
        raise StoreError(
            f"--scheduler {scheduler}: cannot reach the Dask scheduler ({exc})"
        ) from None
    try:
        yield client.get_executor()  # type: ignore[no-untyped-call]
    finally:
        client.close()  # type: ignore[no-untyped-call]


CHUNK = 8
"""Recordings per task sent to a worker (fewer, larger messages between processes)."""

IN_FLIGHT_PER_WORKER = 3
"""Tasks submitted ahead per local worker process."""

DASK_IN_FLIGHT = 64
"""Tasks submitted ahead to a Dask cluster (its size is not known here)."""

COMMIT_GROUP = 64
"""Most recordings stored in one transaction."""

COMMIT_EVERY_S = 2.0
"""A group is stored at the latest this long after its first recording, s."""


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
    ) -> None:
        self.store = store
        self.profile = profile
        self.settings = settings
        self.summary = summary
        self.group = group
        store.put_profile(profile)  # refused when the stored health model has another profile
        mon, self.version = store.monitor(profile, settings)
        self.monitor = mon or ConveyorMonitor(profile, settings, store.calibration(profile.id))
        self.opened = {a["id"] for a in self.monitor.alarms}
        # this run's recordings taken by monitoring but not yet stored (file -> input)
        self.inputs: dict[str, Prepared] = {}
        self.digests: dict[str, str] = {}
        # the calibration each recording's features were computed with
        self.weighed_with: dict[str, Calibration | None] = {}
        # recordings stored while they wait for a learned calibration (file -> recording, sha)
        self.carried: dict[str, tuple[Recording, str]] = {}
        self._carry()
        self.finished: list[Finished] = []
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
        if (
            len(self.finished) >= self.group
            or time.monotonic() - self.group_started > COMMIT_EVERY_S
        ):
            self.flush()

    def _process(self, item: Prepared) -> None:
        rec = item.recording
        assert rec is not None
        features = item.features
        if features is not None and not _same(
            self.weighed_with.get(rec.source), self.monitor.calibration
        ):
            features = None  # computed with another calibration: the monitor computes them
        for res in self.monitor.process(rec, self.digests[rec.source], features=features):
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
        self.inputs = {}
        self.weighed_with = {}
        self.finished = []

    def _again(self) -> None:
        """Another ingest advanced this conveyor: take this run's recordings on its model."""
        mon, self.version = self.store.monitor(self.profile, self.settings)
        if mon is None:  # pragma: no cover - a row never disappears
            raise StoreError(f"the health model of '{self.profile.id}' vanished") from None
        self.monitor = mon
        self.opened |= {a["id"] for a in mon.alarms}  # not this run's news
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
        """Store what is left; count the alarms this ingest opened."""
        self.flush()
        self.summary.new_alarms += len({a["id"] for a in self.monitor.alarms} - self.opened)


SCAN_CHUNK = 32
"""Files per task of the first pass (conveyor, recorded time, content hash)."""


def _scan(
    ex: Executor, files: Sequence[str], conveyors: list[str], chunk: int
) -> tuple[dict[str, list[RecordingFile]], list[tuple[str, str]]]:
    """:func:`group_by_conveyor` over the executor, chunk by chunk, merged in the order given."""
    futures = [
        ex.submit(group_by_conveyor, files[k : k + chunk], conveyors)
        for k in range(0, len(files), chunk)
    ]
    groups: dict[str, list[RecordingFile]] = {}
    refused: list[tuple[str, str]] = []
    for fut in futures:
        part, bad = fut.result()
        for cid, items in part.items():
            groups.setdefault(cid, []).extend(items)
        refused += bad
    return groups, refused


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


def _run(
    ex: Executor,
    plan: Sequence[tuple[ConveyorProfile, list[str]]],
    sha: dict[str, str],
    window: _Window,
    open_conveyor: Callable[[ConveyorProfile], _Conveyor],
    column_map: ColumnMap | None,
    summary: IngestSummary,
    tick: Callable[[], None],
) -> None:
    """Send the planned recordings to the workers and monitor what comes back.

    One window of tasks runs across conveyors: the next conveyor's first
    recordings are sent while the last ones of the one before are still
    being read, so that the workers do not wait at each conveyor's end.
    Results are taken in the order sent (each conveyor's in recorded
    order). Once everything is sent, finished recordings are stored while
    the workers read the last ones, so that little is left to store after
    the last result.
    """
    pending: deque[tuple[_Conveyor, list[str], Calibration | None, Future[list[Prepared]]]]
    pending = deque()
    unread: dict[_Conveyor, int] = {}  # recordings not yet taken
    todo = iter(plan)
    conv: _Conveyor | None = None
    files: list[str] = []
    at = 0  # next of files to send
    while True:
        while len(pending) < window.tasks:
            if at == len(files):  # the next conveyor
                step = next(todo, None)
                if step is None:
                    break
                prof, files = step
                at = 0
                try:
                    conv = open_conveyor(prof)
                except StoreError as exc:  # e.g. monitored with another version of the profile
                    for f in files:
                        tick()
                        summary.refused += 1
                        summary.refusals.append({"file": f, "error": str(exc)})
                    window.left -= len(files)
                    at = len(files)
                    continue
                unread[conv] = len(files)
            assert conv is not None
            chunk = files[at : at + window.size()]
            at += len(chunk)
            window.left -= len(chunk)
            # a window of files in flight rather than all at once: memory stays
            # bounded, and once a calibration is learned the files submitted
            # after it are weighed in the workers with it
            cal = conv.monitor.calibration
            fut = ex.submit(prepare_many, chunk, conv.profile, column_map, cal)
            pending.append((conv, chunk, cal, fut))
        if not pending:
            break
        taker, chunk, cal, fut = pending.popleft()
        for f, prepared in zip(chunk, fut.result(), strict=True):
            tick()
            if prepared.recording is None:
                summary.refused += 1
                summary.refusals.append({"file": f, "error": prepared.error or "refused"})
                continue
            taker.take(prepared, sha[f], cal)
        unread[taker] -= len(chunk)
        if unread[taker] == 0:
            if not pending and isinstance(ex, ProcessPoolExecutor):
                # nothing more for the workers: they exit while this stores
                ex.shutdown(wait=False)
            taker.close()
        elif window.left == 0 and len(taker.finished) >= max(
            window.biggest, sum(len(c) for _, c, _, _ in pending)
        ):
            taker.flush()  # while the workers read the last recordings


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

    Returns
    -------
    IngestSummary
    """
    started = datetime.now(UTC)
    settings = settings or MonitorSettings()
    summary = IngestSummary()
    with executor(workers, scheduler) as ex:
        # first pass, on the workers too: each file's conveyor, recorded time and
        # content hash, so that duplicates are skipped before any work
        groups, refused = _scan(ex, files, list(profiles), SCAN_CHUNK)
        for f, error in refused:
            summary.refused += 1
            summary.refusals.append({"file": f, "error": error})
        known = store.known(item.sha256 for items in groups.values() for item in items)
        total = sum(len(v) for v in groups.values())
        done = 0

        def tick() -> None:
            nonlocal done
            done += 1
            if progress is not None:
                progress(done, total)

        if _inline(workers, scheduler):
            # one recording at a time in this process: nothing to save on messages,
            # and a learned calibration is taken up by the very next recording
            window, biggest, lanes = 1, 1, 1
        else:
            lanes = workers or os.cpu_count() or 1
            window = IN_FLIGHT_PER_WORKER * lanes
            if scheduler is not None:
                window = max(window, DASK_IN_FLIGHT)
                lanes = max(lanes, window // IN_FLIGHT_PER_WORKER)
            biggest = CHUNK
        # each conveyor's files in recorded order, duplicates left out
        plan: list[tuple[ConveyorProfile, list[str]]] = []
        sha: dict[str, str] = {}
        for cid, items in groups.items():
            fresh: list[tuple[str, datetime | None]] = []
            for item in items:
                if item.sha256 in known:
                    summary.duplicates += 1
                    tick()
                else:
                    known.add(item.sha256)  # the same content twice in one batch
                    sha[item.path] = item.sha256
                    fresh.append((item.path, item.recorded_at))
            order, _missing = order_recordings(fresh)
            if order:
                plan.append((profiles[cid], order))
        _run(
            ex,
            plan,
            sha,
            _Window(window, biggest, lanes, sum(len(order) for _, order in plan)),
            lambda prof: _Conveyor(store, prof, settings, summary, max(1, commit_group)),
            column_map,
            summary,
            tick,
        )
    summary.seconds = (datetime.now(UTC) - started).total_seconds()
    return summary
