"""Server-sent events: ``GET /api/v1/events`` tells the pages when the store changed.

One :class:`ChangeFeed` per process polls the store's
:func:`~chaintwin.store.queries.store_signature` once per :data:`POLL_S`
while at least one client listens (and not at all otherwise), and wakes every
listening stream when it changes, whichever process or command stored the
change (``ingest``, an upload, the live service, an acknowledgement from the
CLI). The pages then fetch what they show from the JSON API again.

A stream sends

* ``retry: 2000`` (reconnect after 2 s),
* ``event: ready`` with the store's signature when it opens,
* ``event: update`` whenever the signature changes, its data
  ``{"id", "results", "states", "conveyors", "open_alarms", "changed"}``
  (``changed``: ``results``, ``alarms``, ``conveyors``),
* a comment every :data:`KEEPALIVE_S` (proxies close idle connections),

and ends after :data:`STREAM_S` so that a stopping server is not held up by
its listeners; the browser's ``EventSource`` reconnects with
``Last-Event-ID``, and a change made meanwhile is sent at once.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
from collections.abc import AsyncIterator
from typing import Any

from fastapi.concurrency import run_in_threadpool
from sqlalchemy.exc import SQLAlchemyError

from chaintwin.store.queries import Signature, store_signature
from chaintwin.store.store import Store

__all__ = ["KEEPALIVE_S", "POLL_S", "STREAM_S", "ChangeFeed", "event_stream"]

POLL_S = 1.0
"""How often the store is looked at while clients listen, s."""

KEEPALIVE_S = 10.0
"""A comment line this often keeps an idle stream open through proxies, s."""

STREAM_S = 15.0
"""A stream ends after this long and the browser reconnects (a stop waits at most this), s."""

RETRY_MS = 2000
"""The reconnect delay the stream asks the browser for, ms."""


class ChangeFeed:
    """The store's signature, polled once per ``poll_s`` for every listener of a process.

    Parameters
    ----------
    store : Store
        The results store.
    poll_s : float
        Polling period while anyone listens, s.
    """

    def __init__(self, store: Store, poll_s: float = POLL_S) -> None:
        self.store = store
        self.poll_s = poll_s
        self.signature: Signature | None = None
        self.listeners = 0
        self.polls = 0
        self._changed: asyncio.Event | None = None
        self._task: asyncio.Task[None] | None = None

    async def _read(self) -> Signature:
        self.polls += 1
        return await run_in_threadpool(store_signature, self.store)

    async def _poll(self) -> None:
        while self.listeners > 0:
            await asyncio.sleep(self.poll_s)
            try:
                new = await self._read()
            except (SQLAlchemyError, OSError):  # a store briefly away: try again next time
                continue
            if new != self.signature:
                self.signature = new
                if self._changed is not None:
                    self._changed.set()
                self._changed = asyncio.Event()
        self._task = None

    async def subscribe(self) -> Signature:
        """Count a listener in (starts the polling); the current signature."""
        self.listeners += 1
        if self.signature is None:
            self.signature = await self._read()
        if self._changed is None:
            self._changed = asyncio.Event()
        if self._task is None or self._task.done():
            self._task = asyncio.create_task(self._poll())
        return self.signature

    def unsubscribe(self) -> None:
        """Count a listener out (the polling stops with the last one)."""
        self.listeners = max(0, self.listeners - 1)

    async def next(self, seen: Signature, timeout: float) -> Signature | None:
        """The signature once it differs from ``seen``; None after ``timeout`` s without."""
        if self.signature is not None and self.signature != seen:
            return self.signature
        changed = self._changed
        if changed is None:
            return None
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(changed.wait(), timeout)
        return self.signature if self.signature != seen else None


def _parse(text: str) -> Signature | None:
    """A signature from its :attr:`Signature.id` (None: not one)."""
    parts = text.split(".")
    if len(parts) != 4 or not all(p.isdigit() for p in parts):
        return None
    a, b, c, d = (int(p) for p in parts)
    return Signature(a, b, c, d)


def _event(name: str, sig: Signature, before: Signature | None) -> str:
    data: dict[str, Any] = {
        "id": sig.id,
        "results": sig.results,
        "states": sig.states,
        "conveyors": sig.conveyors,
        "open_alarms": sig.open_alarms,
        "changed": sig.changes(before),
    }
    return f"id: {sig.id}\nevent: {name}\ndata: {json.dumps(data)}\n\n"


async def event_stream(
    feed: ChangeFeed, last_id: str | None, seconds: float = STREAM_S
) -> AsyncIterator[str]:
    """The text of one client's event stream (see the module notes).

    Parameters
    ----------
    feed : ChangeFeed
        The process's feed.
    last_id : str or None
        The ``Last-Event-ID`` the browser reconnected with.
    seconds : float
        How long the stream lasts, s.
    """
    loop = asyncio.get_running_loop()
    end = loop.time() + seconds
    seen = await feed.subscribe()
    try:
        yield f"retry: {RETRY_MS}\n\n"
        if last_id is not None and last_id != seen.id:
            yield _event("update", seen, _parse(last_id))
        else:
            yield _event("ready", seen, None)
        while (left := end - loop.time()) > 0:
            new = await feed.next(seen, min(KEEPALIVE_S, left))
            if new is None:
                yield ": keep-alive\n\n"
                continue
            yield _event("update", new, seen)
            seen = new
    finally:
        feed.unsubscribe()
