"""Watched folders: every recording file that appears, read once it is complete.

A folder is scanned in full when it is taken up (files that arrived while
the service was down are caught up), then followed with watchfiles
(inotify; ``poll=True`` polls, for network shares where events do not
arrive), recursively, with a full rescan every :data:`RESCAN_S` as a safety
net. A file is handed to the ingest queue once its size and modification
time have stayed the same for the settle time (counted from its last
modification on a local file system, from when it was first seen when
polling a share, whose clock may differ); names ending in ``.part``
or ``.tmp`` are ignored until renamed, and only recording files are taken:
those matching a registered format's pattern (``*.csv`` and those of the
formats added, :func:`~chaintwin.read.formats.recording_patterns`; as
``chaintwin ingest DIR`` takes them). A file the ingest defers (it ends
in motion: its writer may have paused) is handed again when it changes, or
after the time asked (:meth:`FolderSource.defer`).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import os
import time
from collections import OrderedDict
from collections.abc import Awaitable, Callable
from pathlib import Path

from chaintwin.read.formats import is_recording_name

__all__ = [
    "IGNORED_SUFFIXES",
    "MAX_REMEMBERED",
    "MAX_TICK_S",
    "RESCAN_S",
    "FolderSource",
    "is_candidate",
]

log = logging.getLogger("chaintwin.live")

IGNORED_SUFFIXES = (".part", ".tmp")
"""Names still being written (ignored until renamed)."""

RESCAN_S = 300.0
"""A full rescan of a followed folder this often, s (events lost on a network share)."""

MAX_REMEMBERED = 2_000
"""The files handed over that a folder remembers (the latest; about 250 bytes each,
0.5 MB): older ones found again by a rescan are looked up in the store by path."""

MAX_TICK_S = 1.0
"""The candidates are looked at again at the latest after this long, s (else when the
next one will have settled, or a new one is seen)."""


def is_candidate(path: str) -> bool:
    """Whether a file name is a recording to read (a registered format's pattern,
    ``*.csv`` and others; not ``.part``/``.tmp``)."""
    name = os.path.basename(path).lower()
    return not name.endswith(IGNORED_SUFFIXES) and is_recording_name(name)


class FolderSource:
    """One watched folder.

    Parameters
    ----------
    root : Path
        The folder (followed recursively).
    settle_s : float
        A file is read once its size and modification time have not changed
        for this long, s.
    poll : bool
        Poll the folder instead of waiting for file-system events.
    enqueue : callable
        ``await enqueue(path, ready_at)`` hands a complete file to the ingest
        queue (``ready_at``: monotonic time it was found complete).
    known : callable, optional
        ``known(paths)``: which of these files the store has stored or
        refused (:func:`~.ledger.known_paths`; called in a worker thread).
        A rescan does not hand those again that the folder no longer
        remembers; without it, a rescan hands every file it does not
        remember (the ingest then finds them stored by their content).
    """

    def __init__(
        self,
        root: Path,
        settle_s: float,
        poll: bool,
        enqueue: Callable[[str, float], Awaitable[None]],
        known: Callable[[list[str]], set[str]] | None = None,
    ) -> None:
        self.root = root
        self.settle_s = settle_s
        self.poll = poll
        self.enqueue = enqueue
        self.known = known
        self.key = f"folder:{root}"
        # path -> (size, mtime_ns, since): candidates watched until they settle
        self.pending: dict[str, tuple[int, int, float]] = {}
        # path -> (size, mtime_ns) handed over, the latest MAX_REMEMBERED; not handed
        # again unless changed
        self.handed: OrderedDict[str, tuple[int, int]] = OrderedDict()
        self.changed = asyncio.Event()  # a file was added to the candidates
        # path -> (size, mtime_ns, monotonic s): deferred files, not handed again before
        # that time unless they change
        self.deferred: dict[str, tuple[int, int, float]] = {}

    def forget(self, path: str) -> None:
        """Let a file be handed again at the next scan (its ingest failed)."""
        self.handed.pop(path, None)

    def defer(self, path: str, seconds: float) -> None:
        """Hand a file again once it has changed and settled, or in ``seconds`` as it is."""
        try:
            st = os.stat(path)
        except OSError:  # gone
            return
        self.handed.pop(path, None)
        self.deferred[path] = (st.st_size, st.st_mtime_ns, time.monotonic() + seconds)
        self._add([path])

    def _remember(self, path: str, key: tuple[int, int]) -> None:
        """Note a file handed over; forget the oldest beyond :data:`MAX_REMEMBERED`."""
        self.handed.pop(path, None)
        self.handed[path] = key
        while len(self.handed) > MAX_REMEMBERED:
            self.handed.popitem(last=False)

    def _rescan(self) -> list[str]:
        """A full rescan's candidates (in a worker thread): every file, less those the
        folder no longer remembers that the store has (asked by path)."""
        found = self._scan()
        present = set(found)
        # forget files that are gone: memory follows what the folder holds
        for gone in [p for p in self.handed if p not in present]:
            del self.handed[gone]
        unknown = [p for p in found if p not in self.handed and p not in self.pending]
        if not unknown or self.known is None:
            return found
        try:
            stored = self.known(unknown)
        except Exception as exc:  # the store is away: the ingest sorts them out
            log.error("rescan of %s: cannot ask the store (%s)", self.root, exc)
            return found
        return [p for p in found if p not in stored or p in self.handed]

    def _scan(self) -> list[str]:
        out: list[str] = []
        for folder, _dirs, names in os.walk(self.root):
            out.extend(os.path.join(folder, n) for n in names if is_candidate(n))
        return out

    def _add(self, paths: list[str]) -> None:
        now = time.monotonic()
        for p in paths:
            if p not in self.pending:
                self.pending[p] = (-1, -1, now)
        if paths:
            self.changed.set()

    def _settled(self) -> tuple[list[str], float | None]:
        """Stat the candidates (in a worker thread).

        Returns
        -------
        (list of str, float or None)
            The files unchanged for the settle time, and when the next of the
            others will have been (monotonic s; None: no other).
        """
        now = time.monotonic()
        ready: list[str] = []
        due: float | None = None
        for path, (size, mtime, since) in list(self.pending.items()):
            try:
                st = os.stat(path)
            except OSError:  # gone (renamed, deleted)
                self.pending.pop(path, None)
                continue
            key = (st.st_size, st.st_mtime_ns)
            if key != (size, mtime):
                # unchanged since its last write: the modification time, on a local
                # file system (the same clock); on a share (--poll) since seen, as the
                # server's clock may differ from this one
                age = 0.0 if self.poll else max(0.0, time.time() - st.st_mtime_ns / 1e9)
                since = now - min(age, self.settle_s)
                self.pending[path] = (*key, since)
            held = self.deferred.get(path)
            if held is not None and held[:2] != key:
                del self.deferred[path]  # changed since: settles as any file
            elif held is not None and now < held[2]:
                due = min(due if due is not None else math.inf, held[2])
                continue
            elif held is not None:
                del self.deferred[path]  # waited long enough: handed as it is
            if now - since >= self.settle_s:
                del self.pending[path]
                if self.handed.get(path) != key:
                    self._remember(path, key)
                    ready.append(path)
            else:
                due = min(due if due is not None else math.inf, since + self.settle_s)
        ready.sort()
        return ready, due

    async def run(self, stop: asyncio.Event) -> None:
        """Follow the folder until ``stop``."""
        from watchfiles import Change, awatch

        if not self.root.is_dir():
            raise FileNotFoundError(f"--watch {self.root}: no such folder")
        watching = asyncio.Event()

        async def watch() -> None:
            async for changes in awatch(
                self.root,
                stop_event=stop,
                force_polling=self.poll,
                poll_delay_ms=500,
                recursive=True,
                debounce=200,
                step=50,
                rust_timeout=1000,
            ):
                watching.set()
                self._add([p for c, p in changes if c != Change.deleted and is_candidate(p)])

        watcher = asyncio.create_task(watch())
        # the watcher first, then the scan: a file arriving in between is seen by either
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(watching.wait(), 0.3)
        self._add(await asyncio.to_thread(self._scan))
        log.info("following %s (%d file(s) found)", self.root, len(self.pending))
        last_scan = time.monotonic()
        try:
            while not stop.is_set():
                self.changed.clear()
                ready, due = await asyncio.to_thread(self._settled)
                for path in ready:
                    await self.enqueue(path, time.monotonic())
                if watcher.done():
                    watcher.result()  # the watcher failed: say why
                    break
                if time.monotonic() - last_scan > RESCAN_S:
                    self._add(await asyncio.to_thread(self._rescan))
                    last_scan = time.monotonic()
                # until the next file settles, a new one is seen, or a second at most
                wait = MAX_TICK_S if due is None else due - time.monotonic()
                waits = {
                    asyncio.ensure_future(stop.wait()),
                    asyncio.ensure_future(self.changed.wait()),
                }
                _done, rest = await asyncio.wait(
                    waits,
                    timeout=min(MAX_TICK_S, max(0.0, wait)),
                    return_when=asyncio.FIRST_COMPLETED,
                )
                for w in rest:
                    w.cancel()
        finally:
            watcher.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await watcher
