"""Ingest: read, validate, weigh and monitor many recordings into the store.

The expensive part of a recording (reading, validation, weighing, features)
does not depend on the other recordings once the conveyor is calibrated, so
it runs in parallel: on a local process pool by default, on a Dask cluster
when given its scheduler address. Both are used through the same
``concurrent.futures`` interface (``distributed.Client.get_executor()``), so
the code path is the same. The health model of a conveyor then takes the
recordings one by one in recorded order, in this process, and each recording
is stored in its own transaction (:meth:`Store.commit_recording`).

A conveyor without a calibration in the store (``calibrate --db``) learns one
from its first recordings; until then its recordings are read in parallel but
weighed here, one by one.

Refused files never stop the batch; a file already stored (same content) is
counted as a duplicate and skipped; running ingest again after a crash or a
kill finishes the job.
"""

from __future__ import annotations

import multiprocessing
import os
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Executor, Future, ProcessPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass, field
from datetime import UTC, datetime
from typing import Any

from chaintwin.diagnose.features import RecordingFeatures, recording_features
from chaintwin.diagnose.monitor import ConveyorMonitor, MonitorSettings
from chaintwin.errors import ChaintwinError, EstimationError, StoreError
from chaintwin.identify.calibration import Calibration
from chaintwin.read.batch import group_by_conveyor, order_recordings
from chaintwin.read.columns import ColumnMap
from chaintwin.read.profile import ConveyorProfile
from chaintwin.read.recording import Recording
from chaintwin.validate.checks import load_recording

from .store import StateConflict, Store

__all__ = ["IngestSummary", "executor", "ingest", "prepare"]


@dataclass
class IngestSummary:
    """What an ingest did (``ingest --json``)."""

    processed: int = 0
    duplicates: int = 0
    refused: int = 0
    warnings: int = 0
    new_alarms: int = 0
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
            "seconds": self.seconds,
        }


def _pin_threads() -> None:
    """One BLAS thread per worker process (DESIGN.md: small matrices oversubscribe)."""
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, "1")


@contextmanager
def executor(workers: int | None, scheduler: str | None) -> Iterator[Executor]:
    """A ``concurrent.futures`` executor: a local process pool, or a Dask cluster.

    Parameters
    ----------
    workers : int, optional
        Local worker processes (default: the machine's cores).
    scheduler : str, optional
        Address of a Dask scheduler (``tcp://host:8786``); the cluster's
        workers are used instead of local processes.

    Raises
    ------
    StoreError
        When the scheduler cannot be reached.
    """
    if scheduler is None:
        # workers come from a fork server started afresh, not forked from this
        # process: a forked worker would inherit the store's open database
        # connections and, outliving a killed ingest, hold its transaction open
        ctx = multiprocessing.get_context("forkserver")
        ctx.set_forkserver_preload(["chaintwin.store.ingest"])
        with ProcessPoolExecutor(
            max_workers=workers, mp_context=ctx, initializer=_pin_threads
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


def prepare(
    path: str,
    profile: ConveyorProfile,
    column_map: ColumnMap | None,
    calibration: Calibration | None,
) -> tuple[Recording | None, RecordingFeatures | None, str | None]:
    """Read, validate and (with a calibration) weigh one recording: the parallel part.

    Returns
    -------
    (Recording or None, RecordingFeatures or None, error or None)
    """
    try:
        rec = load_recording(path, profile=profile, column_map=column_map).recording
    except ChaintwinError as exc:
        return None, None, str(exc)
    if calibration is None:
        return rec, None, None
    try:
        return rec, recording_features(rec, calibration), None
    except EstimationError:
        return rec, None, None  # the monitor reports it in its own words


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

    Returns
    -------
    IngestSummary
    """
    started = datetime.now(UTC)
    settings = settings or MonitorSettings()
    summary = IngestSummary()
    groups, refused = group_by_conveyor(files, profiles)
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

    for prof in profiles.values():
        if prof.id in groups:
            store.put_profile(prof)
    with executor(workers, scheduler) as ex:
        for cid, items in groups.items():
            prof = profiles[cid]
            sha: dict[str, str] = {}
            for item in items:
                if item.sha256 in known:
                    summary.duplicates += 1
                    tick()
                else:
                    known.add(item.sha256)  # the same content twice in one batch
                    sha[item.path] = item.sha256
            order, _missing = order_recordings(
                [(item.path, item.recorded_at) for item in items if item.path in sha]
            )
            fresh = [(f, sha[f]) for f in order]
            cal = store.calibration(cid)
            mon, version = store.monitor(prof, settings)
            if mon is None:
                mon = ConveyorMonitor(prof, settings, cal)
            use = mon.calibration
            futures: list[Future[tuple[Any, Any, Any]]] = [
                ex.submit(prepare, f, prof, column_map, use) for f, _sha in fresh
            ]
            opened = {a["id"] for a in mon.alarms}
            waiting: dict[str, tuple[Recording, str]] = {}
            for (f, digest), fut in zip(fresh, futures, strict=True):
                rec, feats, error = fut.result()
                tick()
                if rec is None:
                    summary.refused += 1
                    summary.refusals.append({"file": f, "error": error or "refused"})
                    continue
                waiting[rec.source] = (rec, digest)
                while True:
                    results = mon.process(rec, digest, features=feats)
                    try:
                        for res in results:
                            r_rec, r_sha = waiting.pop(res.file)
                            if res.error is not None:
                                summary.refused += 1
                                summary.refusals.append({"file": res.file, "error": res.error})
                            version = store.commit_recording(r_rec, r_sha, res, mon, version)
                            if res.error is None:
                                summary.processed += 1
                                summary.warnings += len(res.warnings)
                        break
                    except StateConflict:
                        # another ingest advanced this conveyor: go again from its model
                        mon, version = store.monitor(prof, settings)
                        if mon is None:  # pragma: no cover - a row never disappears
                            raise StoreError(f"the health model of '{cid}' vanished") from None
                        if store.known([digest]):
                            summary.duplicates += 1
                            waiting.pop(rec.source, None)
                            break
                        waiting[rec.source] = (rec, digest)
            summary.new_alarms += len({a["id"] for a in mon.alarms} - opened)
    summary.seconds = (datetime.now(UTC) - started).total_seconds()
    return summary
