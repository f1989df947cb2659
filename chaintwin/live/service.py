"""The live service: sources, ingest queue, notifications and the web app in one asyncio loop.

:class:`LiveService` runs, until SIGTERM or Ctrl-C,

* each source (a watched folder, a drive or an OPC UA configuration) under
  its lease (:mod:`.ledger`): a source is followed by one ``serve`` process
  at a time, taken over by another when its holder dies;
* the :class:`~.sources.Ingestor` (one recording at a time, in a worker
  thread: the event loop stays free for the web requests);
* the :class:`~.notify.Notifier` (under the lease ``notify``);
* sample retention (``--keep-samples-days``);
* the web application under uvicorn (unless ``--no-web``).

On SIGTERM the sources stop, the recording in hand is finished and
committed, the leases are given back, the web server finishes its requests,
and the process exits 0. After a ``kill -9`` nothing is half-stored (a
recording is committed whole or not at all), and a restart catches up what
is still on disk (the full scan) without storing anything twice (the
store's content hashes).

Adding OPC UA (the ``--opcua`` option) is one call:
:meth:`LiveService.add_drives` with a coroutine function that follows the
drives until its stop event is set and a status object it keeps up to date.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import signal
import socket
import time
import uuid
from collections.abc import Awaitable, Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from chaintwin.diagnose.records import MonitorSettings
from chaintwin.read.profile import ConveyorProfile
from chaintwin.store.store import Store

from .ledger import (
    acquire_lease,
    forget_refusal,
    refusals,
    release_lease,
    source_records,
    update_source,
)
from .metrics import Metrics
from .refit import Refitter
from .sources import PARTIAL_WAIT_S, DriveStatusLike, Ingestor, Job, Outcome, Submit
from .watch import FolderSource

if TYPE_CHECKING:
    from .notify import MailSettings
    from .opcua import OpcuaConfig

__all__ = ["PROFILES_POLL_S", "LiveOptions", "LiveService", "Source", "read_profile_folder"]

log = logging.getLogger("chaintwin.live")

PROFILES_POLL_S = 2.0
"""How often the ``--profiles`` folder is looked at for changed files, s."""


def _folder_state(folder: Path) -> tuple[tuple[str, int, int], ...]:
    """The profile files of a folder: (name, size, modification time ns), sorted."""
    out: list[tuple[str, int, int]] = []
    for path in [*folder.glob("*.yaml"), *folder.glob("*.yml")]:
        try:
            st = path.stat()
        except OSError:
            continue
        out.append((path.name, st.st_size, st.st_mtime_ns))
    return tuple(sorted(out))


def read_profile_folder(
    folder: Path, previous: dict[Path, ConveyorProfile]
) -> dict[Path, ConveyorProfile]:
    """The profiles of a folder by file, read again; a file that became invalid keeps
    its previous profile (logged with the loader's one-line reason).

    Parameters
    ----------
    folder : Path
        The ``--profiles`` folder.
    previous : dict
        The profiles read last time, by file.

    Returns
    -------
    dict
        Each file's profile; a file whose id another file (earlier by name)
        has already is left out, logged.
    """
    from chaintwin.errors import ProfileError
    from chaintwin.read.profile import load_profile

    out: dict[Path, ConveyorProfile] = {}
    ids: dict[str, Path] = {}
    for path in sorted([*folder.glob("*.yaml"), *folder.glob("*.yml")]):
        try:
            profile = load_profile(path)
        except ProfileError as exc:
            kept = previous.get(path)
            log.warning(
                "profiles: %s; %s",
                str(exc).splitlines()[0],
                "its previous version stays in use" if kept else "it is not used until fixed",
                extra={"file": str(path)},
            )
            if kept is None:
                continue
            profile = kept
        if profile.id in ids:
            log.warning(
                "profiles: %s: id '%s' is also the id of %s; give each conveyor its own id",
                path,
                profile.id,
                ids[profile.id],
                extra={"file": str(path)},
            )
            continue
        ids[profile.id] = path
        out[path] = profile
    return out


Follow = Callable[[asyncio.Event], Awaitable[None]]
"""A source's body: follows the source until the event is set."""


@dataclass
class LiveOptions:
    """The live service's settings (``chaintwin serve``'s options)."""

    settle_s: float = 2.0
    order_window_s: float = 60.0
    """A file found in a folder is held this long, then taken in recorded order with
    the others held, s (:class:`~.sources.Ingestor`; 0: taken as found)."""
    poll: bool = False
    notify_urls: list[str] = field(default_factory=list)
    notify_secret: bytes | None = None
    mail: MailSettings | None = None
    """The e-mail channel of the notifications (``--notify-smtp``), if any."""
    public_url: str = "http://127.0.0.1:8000"
    keep_samples_days: float | None = None
    lease_s: float = 15.0
    """How long a lease lasts unless renewed (renewed every third of it), s."""
    holder: str = ""
    """This process's name in the leases (default: host, process id and a random part)."""
    profiles_dir: Path | None = None
    """``--profiles``: read again when its files change; the files refused for want of
    a profile are then read again (:meth:`LiveService.retry_refused`)."""


@dataclass
class Source:
    """A source the service follows under its lease."""

    key: str
    kind: str
    follow: Follow
    held: bool = False
    state: str = "waiting"
    error: str | None = None


class _Server:
    """uvicorn's server without its own signal handlers (the service has its own)."""

    def __init__(self, config: Any) -> None:
        import uvicorn

        class Quiet(uvicorn.Server):
            @contextlib.contextmanager
            def capture_signals(self) -> Iterator[None]:
                yield

        self.server = Quiet(config)


class LiveService:
    """One service process.

    Parameters
    ----------
    store : Store
        The results store (at the head revision: :class:`Store` refuses an
        older one with a message naming ``chaintwin db upgrade``).
    profiles : dict
        Profiles by conveyor id (``--profiles``).
    options : LiveOptions
        Settings.
    settings : MonitorSettings, optional
        Monitoring's settings (as ``chaintwin ingest`` takes them).
    """

    def __init__(
        self,
        store: Store,
        profiles: dict[str, ConveyorProfile],
        options: LiveOptions,
        settings: MonitorSettings | None = None,
    ) -> None:
        self.store = store
        self.options = options
        self.profiles = profiles
        """The ``--profiles`` in use by id (updated in place when the folder changes)."""
        self.profiles_now: dict[str, ConveyorProfile] = dict(profiles)
        """A copy of :attr:`profiles` replaced whole at each change: what another
        thread (the web's uploads) reads without seeing a change half made."""
        self.holder = (
            options.holder or f"{socket.gethostname()}:{os.getpid()}:{uuid.uuid4().hex[:6]}"
        )
        self.ingestor = Ingestor(
            store,
            profiles,
            settings,
            self._outcome,
            order_window_s=options.order_window_s,
            partial_wait_s=PARTIAL_WAIT_S,
        )
        self.refitter = Refitter(store)
        self.ingestor.refitter = self.refitter
        self.metrics = Metrics(store, self._queue_depth)
        self.sources: list[Source] = []
        self.folders: dict[str, FolderSource] = {}
        self.drive_status: DriveStatusLike | None = None
        self.stop = asyncio.Event()
        self.notifier: Any = None
        self.started_at = time.time()
        self._counts: dict[str, tuple[int, int]] = {}

    def use_profiles(self, fresh: dict[str, ConveyorProfile]) -> None:
        """Take these profiles from now on: the sources', the ingestor's and the web's uploads'."""
        self.profiles.clear()
        self.profiles.update(fresh)
        self.ingestor.set_profiles(fresh)
        self.profiles_now = dict(fresh)

    # ---------------------------------------------------------------- sources
    def add_folder(self, root: Path) -> None:
        """Follow a folder (recursively) under the lease ``folder:<absolute path>``."""
        from .ledger import known_paths

        folder = FolderSource(
            root.resolve(),
            self.options.settle_s,
            self.options.poll,
            self._enqueue_file(root),
            lambda paths: known_paths(self.store, paths),
        )
        self.folders[folder.key] = folder
        self.sources.append(Source(folder.key, "folder", folder.run))

    def _enqueue_file(self, root: Path) -> Callable[[str, float], Awaitable[None]]:
        key = f"folder:{root.resolve()}"

        async def enqueue(path: str, ready_at: float) -> None:
            await self.ingestor.put_file(path, key, ready_at)

        return enqueue

    @property
    def submit(self) -> Submit:
        """:data:`~.sources.Submit` for the drives' followers."""
        return self.ingestor.submit

    def add_drives(
        self,
        key: str,
        follow: Callable[[Submit, asyncio.Event], Awaitable[None]],
        status: DriveStatusLike | None = None,
    ) -> None:
        """Follow drives under the lease ``key`` (e.g. ``opcua:<conveyor>`` per drive).

        ``follow(submit, stop)`` follows the drives until ``stop`` is set,
        handing each scope to ``submit``; ``status`` (its
        :class:`DriveStatusLike`) is read by the metrics and the health. With
        ``chaintwin.live.opcua``::

            status = DriveStatus(drives={})
            service.add_drives(
                "opcua:" + conveyor,
                lambda submit, stop: follow_drives(config, submit, stop, status),
                status,
            )
        """

        async def body(stop: asyncio.Event) -> None:
            await follow(self.ingestor.submit, stop)

        if status is not None:
            self.drive_status = status
            self.metrics.drive_status = status
        self.sources.append(Source(key, "opcua", body))

    def add_opcua(self, config: OpcuaConfig) -> None:
        """Follow each drive of an OPC UA configuration under a lease of its own.

        One lease per drive (``opcua:<conveyor>``): several ``serve``
        processes on one store share the drives, and a drive whose holder
        died is taken over. The drives' states (connected, missed scopes) are
        one :class:`~.opcua.DriveStatus`, which the metrics and health read.
        """
        from .opcua import DriveStatus, OpcuaConfig, follow_drives  # asyncua: only when used

        status = DriveStatus(drives={})
        for drive in config.drives:
            one = OpcuaConfig(drives=[drive], reconnect=config.reconnect)

            async def follow(submit: Submit, stop: asyncio.Event, one: OpcuaConfig = one) -> None:
                await follow_drives(one, submit, stop, status)

            self.add_drives(f"opcua:{drive.conveyor}", follow, status)

    # ---------------------------------------------------------------- outcomes
    def _queue_depth(self) -> float:
        return float(self.ingestor.depth())

    def _outcome(self, job: Job, outcome: Outcome) -> None:
        kind = job.source.split(":", 1)[0]
        # a drive's recordings ("opcua:<conveyor>:<counter>") count for the drive
        owner = ":".join(job.source.split(":")[:2]) if kind == "opcua" else job.source
        ingested, refused = self._counts.get(owner, (0, 0))
        if outcome.status in ("stored", "waiting"):
            self.metrics.ingested.labels(kind).inc()
            self.metrics.latency.observe(outcome.seconds)
            ingested += 1
            if self.notifier is not None:
                self.notifier.wake.set()
        elif outcome.status == "refused" and outcome.reason != "refused before (unchanged since)":
            self.metrics.refused.labels(kind).inc()
            refused += 1
        elif outcome.status == "already_stored":
            self.metrics.duplicates.labels(kind).inc()
        elif outcome.status == "deferred":
            folder = self.folders.get(job.source)
            if folder is not None and outcome.retry_in_s is not None:
                folder.defer(job.path, outcome.retry_in_s)  # handed again then, or when changed
        elif outcome.status == "failed":
            folder = self.folders.get(job.source)
            if folder is not None:
                folder.forget(job.path)  # handed again at the next rescan
        self._counts[owner] = (ingested, refused)

    # ---------------------------------------------------------------- leases
    async def _hold(self, source: Source) -> None:
        """Follow a source whenever this process holds its lease."""
        lease_s = self.options.lease_s
        while not self.stop.is_set():
            got = await self._lease(source)
            if not got:
                source.state = "standby"
                await self._publish(source)
                await self._sleep(lease_s / 3)
                continue
            source.held, source.state, source.error = True, "following", None
            self.metrics.held.inc()
            log.info(
                "following %s", source.key, extra={"source": source.key, "holder": self.holder}
            )
            await self._publish(source)
            inner = asyncio.Event()
            task: asyncio.Future[None] = asyncio.ensure_future(source.follow(inner))
            lost = False
            while not self.stop.is_set() and not task.done():
                await self._sleep(lease_s / 3, task)
                if self.stop.is_set() or task.done():
                    break
                if not await self._lease(source):
                    lost = True
                    log.warning("lost the lease of %s: another process follows it", source.key)
                    break
                await self._publish(source)
            inner.set()
            try:
                await task
            except Exception as exc:
                source.state, source.error = "error", f"{type(exc).__name__}: {exc}"
                log.error("%s stopped: %s", source.key, source.error, extra={"source": source.key})
            self.metrics.held.dec()
            source.held = False
            if not lost:
                with contextlib.suppress(Exception):  # else it expires
                    await asyncio.to_thread(release_lease, self.store, source.key, self.holder)
            if source.state == "error":
                await self._publish(source)
                await self._sleep(min(30.0, lease_s))  # then try again
            else:
                source.state = "stopped" if self.stop.is_set() else "standby"
                await self._publish(source)

    async def _lease(self, source: Source) -> bool:
        """Take or renew a source's lease; False also when the store cannot be reached
        (the source is then left, as another process may take it once the lease expires)."""
        try:
            return await asyncio.to_thread(
                acquire_lease, self.store, source.key, self.holder, self.options.lease_s
            )
        except Exception as exc:
            source.error = f"the store: {exc}".splitlines()[0]
            log.error("cannot take the lease of %s: %s", source.key, source.error)
            return False

    async def _sleep(self, seconds: float, task: asyncio.Future[None] | None = None) -> None:
        waits: set[asyncio.Future[Any]] = {asyncio.ensure_future(self.stop.wait())}
        if task is not None:
            waits.add(task)
        _done, rest = await asyncio.wait(
            waits, timeout=seconds, return_when=asyncio.FIRST_COMPLETED
        )
        for w in rest:
            if w is not task:
                w.cancel()

    async def _publish(self, source: Source) -> None:
        """Write the source's state and counts to the store (for the health endpoint).

        A source following drives also writes one row per drive,
        ``opcua:<conveyor>``: connected or not, scopes missed, the last error,
        the recordings it gave; a drive that is a source of its own (each
        drive of ``--opcua``) writes its own row only.
        """
        rows: list[dict[str, Any]] = []
        if source.kind == "opcua" and self.drive_status is not None:
            # a drive followed under a lease of its own (``--opcua``: each drive) has
            # its row written by its own source: not once more by every other one
            sources = {s.key for s in self.sources}
            for conveyor, drive in sorted(self.drive_status.drives.items()):
                key = f"opcua:{conveyor}"
                if key in sources:
                    continue
                rows.append(
                    {
                        "key": key,
                        "holder": self.holder if source.held else None,
                        "state": "connected" if drive.connected else "disconnected",
                        "missed": drive.missed,
                        "last_error": drive.last_error,
                    }
                )
        own = None  # the source is one drive: its row carries the drive's counts
        if source.kind == "opcua" and self.drive_status is not None:
            own = self.drive_status.drives.get(source.key.split(":", 1)[-1])
        rows.append(
            {
                "key": source.key,
                "holder": self.holder if source.held else None,
                "state": source.state,
                "missed": None if own is None else own.missed,
                "last_error": source.error or (None if own is None else own.last_error),
            }
        )
        for row in rows:
            ingested, refused = self._counts.pop(row["key"], (0, 0))
            try:
                await asyncio.to_thread(
                    update_source,
                    self.store,
                    row["key"],
                    source.kind,
                    holder=row["holder"],
                    state=row["state"],
                    ingested=ingested,
                    refused=refused,
                    missed=row["missed"],
                    last_error=row["last_error"],
                )
            except Exception as exc:  # the store is away: the counts wait for the next time
                self._counts[row["key"]] = (ingested, refused)
                log.error("cannot write the state of %s: %s", row["key"], exc)

    # ---------------------------------------------------------------- health
    def health(self) -> dict[str, Any]:
        """Each source's state (the health endpoint with a token)."""
        local = {s.key: s for s in self.sources}
        out = []
        for rec in source_records(self.store):
            d = rec.to_dict()
            if rec.key in local:
                d["here"] = True
            out.append(d)
        drives = {}
        if self.drive_status is not None:
            for conveyor, st in self.drive_status.drives.items():
                drives[conveyor] = {
                    "endpoint": st.endpoint,
                    "connected": st.connected,
                    "scopes_read": st.scopes_read,
                    "missed": st.missed,
                    "last_error": st.last_error,
                    "last_scope_at": None
                    if st.last_scope_at is None
                    else st.last_scope_at.isoformat(),
                }
        return {
            "holder": self.holder,
            "queue_depth": int(self._queue_depth()),
            "sources": out,
            "drives": drives,
        }

    # ---------------------------------------------------------------- profiles
    async def retry_refused(self, conveyors: set[str]) -> list[str]:
        """Read again the files refused for want of a profile of these conveyors.

        Each refusal of cause ``profile`` (:func:`~.ledger.record_refusal`)
        of one of ``conveyors`` whose file is still there is dropped and the
        file queued; of several processes on one store, the one that drops a
        refusal reads the file. A drive's scope refused so cannot be read
        again (it was not kept): it stays refused.

        Returns
        -------
        list of str
            The files queued again.
        """
        if not conveyors:
            return []
        rows = await asyncio.to_thread(refusals, self.store, cause="profile", conveyors=conveyors)
        queued: list[str] = []
        for row in rows:
            if not await asyncio.to_thread(os.path.isfile, row.path):
                continue  # gone, or a drive's scope
            if not await asyncio.to_thread(forget_refusal, self.store, row.sha256):
                continue  # another process took it
            log.info(
                "reading %s again: a profile of '%s' was added or changed",
                row.path,
                row.conveyor,
                extra={"source": row.source, "file": row.path},
            )
            await self.ingestor.put_file(row.path, row.source)
            queued.append(row.path)
        return queued

    async def _follow_profiles(self, folder: Path) -> None:
        """Read ``--profiles`` again when its files change; retry what a new profile fixes.

        At start, the files refused for want of a profile that is there now
        (given, or in the store) are read again: the profile may have been
        added while the service was down.
        """
        by_file: dict[Path, ConveyorProfile] = {}
        try:
            state = await asyncio.to_thread(_folder_state, folder)
            by_file = await asyncio.to_thread(read_profile_folder, folder, by_file)
            known = set(await asyncio.to_thread(self.ingestor.profiles_for))
            await self.retry_refused(known)
        except Exception as exc:
            log.error("profiles: %s", str(exc).splitlines()[0] if str(exc) else exc)
        while not self.stop.is_set():
            await self._sleep(PROFILES_POLL_S)
            if self.stop.is_set():
                break
            try:
                now = await asyncio.to_thread(_folder_state, folder)
                if now == state:
                    continue
                state = now
                by_file = await asyncio.to_thread(read_profile_folder, folder, by_file)
                fresh = {p.id: p for p in by_file.values()}
                changed = {
                    cid
                    for cid, p in fresh.items()
                    if cid not in self.profiles
                    or self.profiles[cid].content_hash() != p.content_hash()
                }
                if not changed and set(fresh) == set(self.profiles):
                    continue
                self.use_profiles(fresh)
                log.info(
                    "profiles read again from %s: %s",
                    folder,
                    ", ".join(sorted(changed)) + " added or changed" if changed else "one removed",
                )
                await self.retry_refused(changed)
            except Exception as exc:
                log.error("profiles: %s", str(exc).splitlines()[0] if str(exc) else exc)

    # ---------------------------------------------------------------- running
    async def _retention(self) -> None:
        from .retention import drop_samples

        days = self.options.keep_samples_days
        assert days is not None
        while not self.stop.is_set():
            try:
                n = await asyncio.to_thread(drop_samples, self.store, days)
                if n:
                    log.info("dropped the samples of %d recording(s) older than %g days", n, days)
            except Exception as exc:
                log.error("retention: %s", exc)
            await self._sleep(3600.0)

    async def _memory(self) -> None:
        """Every :data:`~.memory.TRIM_EVERY_S`: glibc's free memory handed back to the
        system (:func:`~.memory.trim`); with ``CHAINTWIN_MEMORY_LOG=1`` the memory
        logged before and after (``memory`` in the JSON log)."""
        from .memory import TRIM_EVERY_S, trim, usage
        from .tracing import trace_trim

        logging_on = os.environ.get("CHAINTWIN_MEMORY_LOG", "") not in ("", "0")
        while not self.stop.is_set():
            await self._sleep(TRIM_EVERY_S)
            if self.stop.is_set():
                break
            pool = self.store.engine.pool
            before = usage(pool) if logging_on else {}
            t0 = time.perf_counter()
            await asyncio.to_thread(trim)
            trace_trim(time.perf_counter() - t0)
            if logging_on:
                after = usage(pool)
                log.info(
                    "memory: %s MB; after trimming: %s MB",
                    " ".join(f"{k} {v:.1f}" for k, v in before.items()),
                    " ".join(f"{k} {v:.1f}" for k, v in after.items()),
                    extra={"memory": {"before": before, "after": after}},
                )

    def _memory_snapshots(self, loop: asyncio.AbstractEventLoop) -> bool:
        """With ``CHAINTWIN_TRACEMALLOC_DIR`` set, trace allocations and dump a snapshot
        there on each SIGUSR1 (``snapshot-<n>.tracemalloc``, after a garbage collection).

        A maintainers' tool (``benchmarks/bench_live.py --tracemalloc``): tracing
        slows the service and costs memory of its own. ``CHAINTWIN_TRACEMALLOC_FRAMES``
        (8) is the depth of the tracebacks kept. Returns whether it is on.
        """
        folder = os.environ.get("CHAINTWIN_TRACEMALLOC_DIR")
        if not folder:
            return False
        import gc
        import tracemalloc

        tracemalloc.start(int(os.environ.get("CHAINTWIN_TRACEMALLOC_FRAMES", "8")))
        count = 0

        def dump() -> None:
            nonlocal count
            gc.collect()
            path = Path(folder) / f"snapshot-{count}.tracemalloc"
            count += 1
            tracemalloc.take_snapshot().dump(str(path))
            log.info("tracemalloc snapshot written to %s", path)

        with contextlib.suppress(NotImplementedError, RuntimeError, AttributeError):
            loop.add_signal_handler(signal.SIGUSR1, dump)
        return True

    def request_stop(self) -> None:
        """Stop: the sources first, then the recording in hand, then the web server."""
        if not self.stop.is_set():
            log.info("stopping: finishing the recording in hand")
        self.stop.set()

    async def run(self, web_config: Any | None = None) -> None:
        """Run everything until :meth:`request_stop` (SIGTERM, SIGINT)."""
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGTERM, signal.SIGINT):
            with contextlib.suppress(NotImplementedError, RuntimeError):
                loop.add_signal_handler(sig, self.request_stop)
        self._memory_snapshots(loop)
        from .memory import configure

        configure()  # glibc: large blocks handed back when freed, two heaps at most
        tasks: list[asyncio.Task[Any]] = [asyncio.create_task(self.ingestor.run(self.stop))]
        tasks.append(asyncio.create_task(self.refitter.run(self.stop)))
        tasks += [asyncio.create_task(self._hold(s)) for s in self.sources]
        if self.options.notify_urls or self.options.mail is not None:
            from .notify import Notifier

            assert self.options.notify_secret is not None or not self.options.notify_urls
            self.notifier = Notifier(
                self.store,
                self.options.notify_urls,
                self.options.notify_secret,
                self.options.public_url,
                self.metrics,
                self.options.mail,
            )
            notifier = self.notifier
            self.sources.append(Source("notify", "notify", notifier.run))
            tasks.append(asyncio.create_task(self._hold(self.sources[-1])))
        if self.options.keep_samples_days is not None:
            tasks.append(asyncio.create_task(self._retention()))
        if self.options.profiles_dir is not None:
            tasks.append(asyncio.create_task(self._follow_profiles(self.options.profiles_dir)))
        tasks.append(asyncio.create_task(self._memory()))
        server = None
        if web_config is not None:
            server = _Server(web_config).server
            tasks.append(asyncio.create_task(server.serve()))
            tasks[-1].add_done_callback(lambda _t: self.stop.set())  # the server ended
        try:
            await self.stop.wait()
        finally:
            self.stop.set()
            # the sources and the ingestor stop (the recording in hand is committed)
            await asyncio.gather(
                *(t for t in tasks if t is not tasks[-1] or server is None), return_exceptions=True
            )
            if server is not None:
                server.should_exit = True
                await asyncio.gather(tasks[-1], return_exceptions=True)
            self.ingestor.close()
            for sig in (signal.SIGTERM, signal.SIGINT):
                with contextlib.suppress(NotImplementedError, RuntimeError):
                    loop.remove_signal_handler(sig)
