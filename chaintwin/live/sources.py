"""The contract of a live source, and the ingest queue every source hands its recordings to.

A source (a watched folder, a drive followed over OPC UA) finds recordings
and hands them to the :class:`Ingestor`: a file by its path
(:meth:`Ingestor.put_file`), a recording read from a drive through
:data:`Submit` (:meth:`Ingestor.submit`). The ingestor runs them one at a
time through the same pipeline as ``chaintwin ingest``
(:func:`chaintwin.store.ingest.ingest`) in a worker thread, off the event
loop: read, validate, weigh, monitor, store. The store keeps each content
once; a refused file is recorded with its one-line reason
(:func:`~.ledger.record_refusal`) and not read again until its content changes.
"""

from __future__ import annotations

import asyncio
import hashlib
import itertools
import logging
import re
import tempfile
import time
from collections.abc import Awaitable, Callable, Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path
from typing import Literal, Protocol

from chaintwin.diagnose.records import MonitorSettings
from chaintwin.errors import ChaintwinError
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


Status = Literal["stored", "waiting", "already_stored", "refused", "gone", "failed"]


@dataclass(frozen=True, slots=True)
class Outcome:
    """What became of one recording.

    ``status``: ``stored`` (with its result), ``waiting`` (stored, waiting
    for its conveyor's calibration to be learned), ``already_stored`` (the
    same content was stored before), ``refused`` (``reason`` says why, in
    the CLI's words), ``gone`` (the file vanished before it was read),
    ``failed`` (the store could not be written: not the recording's fault,
    it is tried again later).
    """

    status: Status
    sha256: str | None = None
    reason: str | None = None
    seconds: float = 0.0
    """Time from the recording being complete to its result stored, s."""
    cause: str | None = None
    """A refusal's cause: ``profile`` or ``recording`` (see :func:`~.ledger.record_refusal`)."""


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
    """

    PROFILES_REFRESH_S = 30.0
    """How long the store's profiles are cached, s."""

    def __init__(
        self,
        store: Store,
        profiles: Mapping[str, ConveyorProfile],
        settings: MonitorSettings | None = None,
        on_outcome: Callable[[Job, Outcome], None] | None = None,
    ) -> None:
        self.store = store
        self.profiles = dict(profiles)
        self.settings = settings or MonitorSettings()
        self.on_outcome = on_outcome
        self.refitter: Refitter | None = None
        """Refits the forecasts of the conveyors ingested, in the background
        (None: each ingest refits its conveyor itself)."""
        self.queue: asyncio.Queue[Job] = asyncio.Queue()
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
        """Queue a complete file (the caller does not wait for it)."""
        await self.queue.put(Job(path, source, ready_at or time.monotonic()))

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
        from chaintwin.read.reader import parse_metadata

        try:
            conveyor = parse_metadata(Path(job.path).read_bytes(), job.name).conveyor
        except (ChaintwinError, OSError):
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

    def ingest_one(self, job: Job) -> Outcome:
        """Ingest one file as ``chaintwin ingest`` would (in a worker thread)."""
        from chaintwin.store.ingest import ingest

        try:
            try:
                raw = Path(job.path).read_bytes()
            except FileNotFoundError:
                return Outcome("gone")
            sha = hashlib.sha256(raw).hexdigest()
            del raw
            if self.store.known([sha]):
                return Outcome("already_stored", sha)
            if is_refused(self.store, sha):
                return Outcome("refused", sha, "refused before (unchanged since)")
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

    def close(self) -> None:
        """Remove the spool folder; end the worker thread."""
        import shutil

        self._thread.shutdown(wait=True)
        shutil.rmtree(self._spool, ignore_errors=True)
