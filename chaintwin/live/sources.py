"""The contract of a live source, and the ingest queue every source hands its recordings to.

A source (a watched folder, a drive followed over OPC UA) finds recordings
and hands them to the :class:`Ingestor`: a file by its path
(:meth:`Ingestor.put_file`), a recording read from a drive through
:data:`Submit` (:meth:`Ingestor.submit`). The ingestor runs them one at a
time through the same pipeline as ``chaintwin ingest``
(:func:`chaintwin.ingest.pipeline.ingest`) in a worker thread, off the event
loop: read, validate, weigh, monitor, store. The store keeps each content
once; a refused file is recorded with its one-line reason
(:func:`~.ledger.record_refusal`) and not read again until its content changes.

Files are taken in recorded order, as ``chaintwin ingest`` takes a batch:
each file is held for the order window (``order_window_s``) after it is
found complete, and the files held are let through in recorded order
(:class:`ReorderWindow`). A file recorded before one already let through is
still stored, with the monitor's ``out_of_order`` warning.

A file that ends in motion (mid-cycle) when it is found complete may be a
file whose writer paused longer than the settle time: it waits
(:data:`PARTIAL_WAIT_S` after its last change) for the rest of it; the
watched folder hands it again when it changes, or when that time is up
(it is then stored as it is, with its ``incomplete_cycle`` warning).
"""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import heapq
import itertools
import logging
import os
import re
import tempfile
import time
from collections import deque
from collections.abc import Awaitable, Callable, Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Literal, Protocol

from chaintwin.diagnose.records import MonitorSettings
from chaintwin.errors import ChaintwinError, RecordingError
from chaintwin.read.formats import read_bytes
from chaintwin.read.profile import ConveyorProfile
from chaintwin.read.recording import Recording
from chaintwin.store.store import Store

from .ledger import is_refused, record_refusal
from .refit import Refitter

__all__ = [
    "DriveStateLike",
    "DriveStatusLike",
    "Ingestor",
    "Job",
    "Outcome",
    "ReorderWindow",
    "Submit",
    "stored_name",
]

log = logging.getLogger("chaintwin.live")

Submit = Callable[[Recording, str], Awaitable[None]]
"""``submit(recording, source_key)``: ingest one recording a live source read.

``source_key`` names where it came from (``"opcua:white-belt-01:1234"``).
Returns once the recording is stored, or refused and the refusal recorded;
never raises for a bad recording."""


class DriveStateLike(Protocol):
    """One drive followed over OPC UA (``chaintwin.live.opcua.DriveState``)."""

    endpoint: str
    connected: bool
    scopes_read: int
    missed: int
    last_error: str | None
    last_scope_at: datetime | None


class DriveStatusLike(Protocol):
    """The drives followed over OPC UA, by conveyor id (``chaintwin.live.opcua.DriveStatus``)."""

    @property
    def drives(self) -> Mapping[str, DriveStateLike]:
        """Each drive's state by conveyor id."""
        ...


def stored_name(source_key: str) -> str:
    """The stable name a live source's recording is stored and shown under.

    A drive's scope (``opcua:<conveyor>:<counter>``) becomes
    ``opcua://<conveyor>/<counter>``: the store's ``file`` column, the
    results, the refusals and the log name the drive and the scope, not the
    spool file it passed through. Other keys are kept as they are.
    """
    kind, sep, rest = source_key.partition(":")
    if kind == "opcua" and sep:
        conveyor, sep2, counter = rest.rpartition(":")
        if sep2 and conveyor:
            return f"opcua://{conveyor}/{counter}"
    return source_key


Status = Literal["stored", "waiting", "already_stored", "refused", "gone", "failed", "deferred"]

PARTIAL_WAIT_S = 60.0
"""How long a file that ends in motion waits for the rest of it after its last change, s."""


@dataclass(frozen=True, slots=True)
class Outcome:
    """What became of one recording.

    ``status``: ``stored`` (with its result), ``waiting`` (stored, waiting
    for its conveyor's calibration to be learned), ``already_stored`` (the
    same content was stored before), ``refused`` (``reason`` says why, in
    the CLI's words), ``gone`` (the file vanished before it was read),
    ``failed`` (the store could not be written: not the recording's fault,
    it is tried again later), ``deferred`` (a file that ends in motion,
    changed less than :data:`PARTIAL_WAIT_S` ago: not read yet, to be handed
    again in ``retry_in_s`` or when it changes).
    """

    status: Status
    sha256: str | None = None
    reason: str | None = None
    seconds: float = 0.0
    """Time from the recording being complete to its result stored, s."""
    cause: str | None = None
    """A refusal's cause: ``profile`` or ``recording`` (see :func:`~.ledger.record_refusal`)."""
    retry_in_s: float | None = None
    """``deferred``: hand the file again at the latest this long from now, s."""


@dataclass
class Job:
    """A recording to ingest: a file, from a source, complete since ``ready_at``."""

    path: str
    source: str
    ready_at: float = field(default_factory=time.monotonic)
    """When the recording was complete (settled, or read from the drive), monotonic s."""
    done: asyncio.Future[Outcome] | None = None
    spooled: bool = False
    """A file this service wrote (a drive's recording): removed once ingested."""

    @property
    def name(self) -> str:
        """What the recording is stored and shown as: the file's path, or for a
        spooled recording its source's stable name (:func:`stored_name`)."""
        return stored_name(self.source) if self.spooled else self.path


_SAFE = re.compile(r"[^A-Za-z0-9._-]+")

OrderKey = tuple[str, str, int]
"""A held file's place: (recorded time in UTC, ISO 8601; path; arrival number)."""


def recorded_key(path: str) -> str | None:
    """A file's recorded time in UTC (ISO 8601) for ordering, or None when it has none.

    None also when its metadata cannot be read: the ingest then says why
    (one line, in the refusals), so nothing is said here.
    """
    from chaintwin.read.formats import read_metadata

    try:
        when = read_metadata(path).recorded_at
    except (ChaintwinError, OSError):
        return None
    return None if when is None else when.astimezone(UTC).isoformat()


class ReorderWindow:
    """Files held for a time window and let through in recorded order.

    Each file is held ``window_s`` from when it is added. When the earliest
    added of those still held has waited that long, it is let through with
    every held file recorded before it, in recorded order (ties by path,
    then by arrival). So files that arrive within the window of each other
    come out in recorded order, each after at most ``window_s``; a file that
    arrives after one recorded later was let through comes out in its turn
    (the monitor then flags it ``out_of_order``). Files without a recorded
    time are not held.

    Parameters
    ----------
    window_s : float
        How long a file is held, s.
    """

    def __init__(self, window_s: float) -> None:
        self.window_s = window_s
        self._heap: list[tuple[OrderKey, Job]] = []
        self._due: deque[tuple[float, OrderKey]] = deque()  # by arrival: deadlines ascend
        self._serial = itertools.count()

    def __len__(self) -> int:
        return len(self._heap)

    def add(self, job: Job, recorded: str, now: float) -> None:
        """Hold a job whose file was recorded at ``recorded`` (UTC ISO 8601); ``now``
        monotonic s."""
        key = (recorded, job.path, next(self._serial))
        heapq.heappush(self._heap, (key, job))
        self._due.append((now + self.window_s, key))

    def next_due(self) -> float | None:
        """When the next file is let through (monotonic s), None when none is held."""
        return self._due[0][0] if self._due else None

    def release(self, now: float) -> list[Job]:
        """The jobs to let through at ``now`` (monotonic s), in recorded order."""
        out: list[Job] = []
        while self._due and self._due[0][0] <= now:
            _deadline, key = self._due.popleft()
            while self._heap and self._heap[0][0] <= key:
                out.append(heapq.heappop(self._heap)[1])
        return out

    def drain(self) -> list[Job]:
        """Every job held, in recorded order (emptied)."""
        out = [job for _key, job in sorted(self._heap)]
        self._heap.clear()
        self._due.clear()
        return out


class Ingestor:
    """One queue of recordings, ingested one at a time in a worker thread.

    Parameters
    ----------
    store : Store
        The results store.
    profiles : dict
        Profiles by conveyor id (``--profiles``); the store's own are used
        for conveyors not among them.
    settings : MonitorSettings, optional
        As ``chaintwin ingest`` takes them.
    on_outcome : callable, optional
        Called in the event loop with each job and its outcome (metrics, the
        sources' counts, waking the notifier).
    order_window_s : float
        Files (:meth:`put_file`) are held this long and taken in recorded
        order (:class:`ReorderWindow`), s; 0 takes them as they come. A
        drive's recordings (:meth:`submit`) are not held: a drive gives its
        scopes in order.
    partial_wait_s : float
        A file that ends in motion waits this long after its last change for
        the rest of it (:data:`PARTIAL_WAIT_S` in the live service), s; 0
        reads it at once (``chaintwin refused retry``).
    """

    PROFILES_REFRESH_S = 30.0
    """How long the store's profiles are cached, s."""

    def __init__(
        self,
        store: Store,
        profiles: Mapping[str, ConveyorProfile],
        settings: MonitorSettings | None = None,
        on_outcome: Callable[[Job, Outcome], None] | None = None,
        *,
        order_window_s: float = 0.0,
        partial_wait_s: float = 0.0,
    ) -> None:
        self.store = store
        self.profiles = dict(profiles)
        self.settings = settings or MonitorSettings()
        self.on_outcome = on_outcome
        self.refitter: Refitter | None = None
        """Refits the forecasts of the conveyors ingested, in the background
        (None: each ingest refits its conveyor itself)."""
        self.queue: asyncio.Queue[Job] = asyncio.Queue()
        self.window = ReorderWindow(order_window_s)
        self.partial_wait_s = partial_wait_s
        """A file ending in motion waits this long after its last change (0: never), s."""
        # path -> (content hash, monotonic s): when a file's content was first found
        # ending in motion (in the worker thread only)
        self._partial: dict[str, tuple[str, float]] = {}
        self._held = asyncio.Event()  # a file was added to the window
        self.busy = False
        self._stored_profiles: dict[str, ConveyorProfile] = {}
        self._profiles_at = -1e9
        self._spool = Path(tempfile.mkdtemp(prefix="chaintwin-spool-"))
        self._serial = itertools.count()
        # one thread of its own: the pipeline's memory stays in one allocator arena
        # (the loop's default pool spreads it over many, and the process grows)
        self._thread = ThreadPoolExecutor(max_workers=1, thread_name_prefix="chaintwin-ingest")

    # ---------------------------------------------------------------- sources' side
    async def put_file(self, path: str, source: str, ready_at: float | None = None) -> None:
        """Queue a complete file (the caller does not wait for it): held in the order
        window first, unless the window is 0 or the file has no recorded time."""
        job = Job(path, source, ready_at or time.monotonic())
        if self.window.window_s > 0:
            recorded = await asyncio.to_thread(recorded_key, path)
            if recorded is not None:
                self.window.add(job, recorded, time.monotonic())
                self._held.set()
                return
        await self.queue.put(job)

    def depth(self) -> int:
        """The recordings waiting to be ingested: queued, and the one in hand (not those
        held in the order window, which wait by design: ``len(window)``)."""
        return self.queue.qsize() + (1 if self.busy else 0)

    async def _let_through(self, stop: asyncio.Event) -> None:
        """Move the held files to the queue as their window ends, until ``stop``."""
        while not stop.is_set():
            due = self.window.next_due()
            self._held.clear()
            waits = {asyncio.ensure_future(stop.wait()), asyncio.ensure_future(self._held.wait())}
            timeout = None if due is None else max(0.0, due - time.monotonic())
            _done, rest = await asyncio.wait(
                waits, timeout=timeout, return_when=asyncio.FIRST_COMPLETED
            )
            for w in rest:
                w.cancel()
            for job in self.window.release(time.monotonic()):
                self.queue.put_nowait(job)

    async def submit(self, recording: Recording, source_key: str) -> None:
        """:data:`Submit`: ingest a recording a live source read; wait until it is stored.

        The recording is written in the data-contract format to a spool file
        and ingested as a file would be, so that a drive's recording and a
        file of the same recording are stored alike (and once).
        """
        from chaintwin.read.writer import write_recording

        ready = time.monotonic()
        # unique per call: the same scope submitted twice at once is two files
        path = self._spool / f"{_SAFE.sub('_', source_key)[-150:]}-{next(self._serial)}.csv"
        try:
            await asyncio.to_thread(write_recording, recording, path)
        except (ChaintwinError, OSError, ValueError) as exc:
            reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            log.warning(
                "refused %s: %s", source_key, reason, extra={"source": source_key, "reason": reason}
            )
            digest = hashlib.sha256(f"{source_key}\n{reason}".encode()).hexdigest()
            await asyncio.to_thread(
                record_refusal, self.store, digest, stored_name(source_key), source_key, reason
            )
            if self.on_outcome is not None:
                self.on_outcome(
                    Job(source_key, source_key, ready), Outcome("refused", None, reason)
                )
            return
        job = Job(str(path), source_key, ready, asyncio.get_running_loop().create_future(), True)
        await self.queue.put(job)
        assert job.done is not None
        await job.done

    # ---------------------------------------------------------------- the worker
    async def run(self, stop: asyncio.Event) -> None:
        """Ingest queued recordings until ``stop``; the recording in hand is finished first."""
        releaser = asyncio.create_task(self._let_through(stop))
        try:
            await self._work(stop)
        finally:
            releaser.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await releaser
            # the files held stay on disk: caught up by the folder's scan at the next start
            self.window.drain()

    async def _work(self, stop: asyncio.Event) -> None:
        while not stop.is_set():
            getter = asyncio.ensure_future(self.queue.get())
            stopper = asyncio.ensure_future(stop.wait())
            await asyncio.wait({getter, stopper}, return_when=asyncio.FIRST_COMPLETED)
            stopper.cancel()
            if not getter.done():
                getter.cancel()
                break
            job = getter.result()
            self.busy = True
            try:
                loop = asyncio.get_running_loop()
                outcome = await loop.run_in_executor(self._thread, self.ingest_one, job)
            except Exception as exc:  # the store failed: the recording is tried again later
                reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
                log.error("cannot ingest %s: %s", job.path, reason, extra={"source": job.source})
                outcome = Outcome("failed", None, reason)
            finally:
                self.busy = False
            if job.done is not None and not job.done.done():
                job.done.set_result(outcome)
            if self.on_outcome is not None:
                self.on_outcome(job, outcome)
        # what is still queued stays where it is (on disk, in the drive): caught up at start
        while not self.queue.empty():
            job = self.queue.get_nowait()
            if job.done is not None and not job.done.done():
                job.done.cancel()

    def set_profiles(self, profiles: Mapping[str, ConveyorProfile]) -> None:
        """Ingest with these profiles from now on (``--profiles`` read again)."""
        self.profiles = dict(profiles)
        self._profiles_at = -1e9  # the store's again too

    def _cause(self, job: Job, profile_refused: bool) -> tuple[str, str | None]:
        """Why a file was refused: ``(cause, conveyor)`` (see :func:`~.ledger.record_refusal`).

        ``profile`` when the conveyor the file names has no profile (adding
        one fixes it), or the store monitors it with another profile;
        ``recording`` otherwise.
        """
        from chaintwin.read.formats import parse_file_metadata

        try:
            conveyor = parse_file_metadata(read_bytes(job.path), job.name).conveyor
        except ChaintwinError:
            return "recording", None
        profiles = self.profiles_for()
        if conveyor is None and len(profiles) == 1:
            conveyor = next(iter(profiles))  # as ingest takes it
        if conveyor is not None and (profile_refused or conveyor not in profiles):
            return "profile", conveyor
        return "recording", conveyor

    def profiles_for(self) -> dict[str, ConveyorProfile]:
        """The profiles to ingest with: the store's, and ``--profiles`` over them."""
        if time.monotonic() - self._profiles_at > self.PROFILES_REFRESH_S:
            stored: dict[str, ConveyorProfile] = {}
            for cid in self.store.conveyors():
                if cid not in self.profiles and (p := self.store.profile(cid)) is not None:
                    stored[cid] = p
            self._stored_profiles = stored
            self._profiles_at = time.monotonic()
        return self._stored_profiles | self.profiles

    def _ends_in_motion(self, path: str) -> bool:
        """Whether a recording file ends in motion: its last movement phase, as
        validation segments it (:func:`~chaintwin.validate.phases.segment`; the
        ``incomplete_cycle`` warning). False when it cannot be read: the ingest
        then says why."""
        from chaintwin.read.formats import parse_file, parse_file_metadata
        from chaintwin.validate.phases import segment

        try:
            raw = read_bytes(path)
            conveyor = parse_file_metadata(raw, path).conveyor
            profile = None if conveyor is None else self.profiles_for().get(conveyor)
            phases = segment(parse_file(raw, path, profile=profile))
        except (ChaintwinError, OSError, ValueError):
            return False
        return bool(phases) and phases[-1].moving

    def _wait_for_rest(self, job: Job, sha: str) -> float | None:
        """How much longer a file that ends in motion waits for the rest of it, s, or
        None to read it now (complete, not a folder's file, or waited long enough)."""
        if job.spooled or self.partial_wait_s <= 0 or not self._ends_in_motion(job.path):
            self._partial.pop(job.path, None)
            return None
        now = time.monotonic()
        seen_sha, since = self._partial.get(job.path, (None, now))
        if seen_sha != sha:  # changed since: its wait starts again
            since = now
        left = self.partial_wait_s - (now - since)
        if left <= 0:
            self._partial.pop(job.path, None)
            return None
        self._partial[job.path] = (sha, since)
        return left

    def ingest_one(self, job: Job) -> Outcome:
        """Ingest one file as ``chaintwin ingest`` would (in a worker thread)."""
        from chaintwin.ingest.pipeline import ingest

        try:
            try:
                # the guarded way in: a pipe, device, socket or oversized file is
                # refused from what is opened, without waiting or reading it whole
                raw = read_bytes(job.path)
            except RecordingError as exc:
                if not os.path.lexists(job.path):
                    return Outcome("gone")
                if isinstance(exc.__cause__, OSError):
                    raise  # not readable now (permissions, I/O): failed, tried again later
                return self._refuse_unread(job, exc)
            sha = hashlib.sha256(raw).hexdigest()
            del raw
            if self.store.known([sha]):
                return Outcome("already_stored", sha)
            if is_refused(self.store, sha):
                return Outcome("refused", sha, "refused before (unchanged since)")
            left = self._wait_for_rest(job, sha)
            if left is not None:
                log.info(
                    "%s ends in motion: waiting up to %.0f s for the rest of it",
                    job.name,
                    left,
                    extra={"source": job.source, "file": job.name, "status": "deferred"},
                )
                return Outcome("deferred", sha, "ends in motion", retry_in_s=left)
            summary = ingest(
                [job.path],
                self.profiles_for(),
                self.store,
                settings=self.settings,
                workers=1,
                names={job.path: job.name} if job.spooled else None,
                refit=self.refitter is None,
            )
            if self.refitter is not None:
                self.refitter.mark(summary.stored_for)
            seconds = time.monotonic() - job.ready_at
            if summary.refusals:
                reason = summary.refusals[0]["error"]
                if job.spooled:
                    reason = reason.replace(job.path, job.name)
                log.warning(
                    "refused %s: %s",
                    job.name,
                    reason,
                    extra={"source": job.source, "file": job.name, "reason": reason},
                )
                cause, conveyor = self._cause(job, job.name in summary.profile_refused)
                record_refusal(
                    self.store, sha, job.name, job.source, reason, cause=cause, conveyor=conveyor
                )
                return Outcome("refused", sha, reason, seconds, cause)
            if summary.duplicates:
                return Outcome("already_stored", sha, None, seconds)
            status: Status = "waiting" if summary.waiting else "stored"
            log.info(
                "%s %s in %.3f s",
                status,
                job.name,
                seconds,
                extra={
                    "source": job.source,
                    "file": job.name,
                    "status": status,
                    "seconds": seconds,
                },
            )
            return Outcome(status, sha, None, seconds)
        finally:
            if job.spooled:
                Path(job.path).unlink(missing_ok=True)

    def _refuse_unread(self, job: Job, exc: RecordingError) -> Outcome:
        """Record the refusal of a file that was not read (no content to hash).

        It is kept under a digest of its name and reason, so that the same
        refusal is stored once; the folder hands the file again only once it
        changes.
        """
        reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        if job.spooled:
            reason = reason.replace(job.path, job.name)
        seconds = time.monotonic() - job.ready_at
        log.warning(
            "refused %s: %s",
            job.name,
            reason,
            extra={"source": job.source, "file": job.name, "reason": reason},
        )
        digest = hashlib.sha256(f"unread\n{job.name}\n{reason}".encode()).hexdigest()
        record_refusal(self.store, digest, job.name, job.source, reason)
        return Outcome("refused", None, reason, seconds, "recording")

    def close(self) -> None:
        """Remove the spool folder; end the worker thread."""
        import shutil

        self._thread.shutdown(wait=True)
        shutil.rmtree(self._spool, ignore_errors=True)
