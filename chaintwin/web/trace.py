"""What pauses the web server: a maintainers' tool for the polling tail.

With ``CHAINTWIN_TRACE_SLOW_MS=N`` in the environment, ``chaintwin serve``
writes one line to stderr (``trace ...``) for

* every request slower than N ms: its path, status, total time, and how
  much of that time the process spent in garbage collections and how late
  its event loop was meanwhile;
* every garbage collection of the oldest generation, and any other one
  taking N/4 ms or more: generation, objects tracked, milliseconds;
* every stall of the event loop of N/4 ms or more (a task that should wake
  every 10 ms woke late: something held the loop or the GIL);
* every ``malloc_trim`` of the live service (its duration);
* every new connection to the database (the pool opens one beyond those it
  keeps when more requests than that use the store at once, and closes it
  after: on PostgreSQL each one starts a server process).

``benchmarks/bench_serve.py --trace-ms N --server-log FILE`` turns it on
and keeps the server's stderr. It costs a little (a callback per
collection, a wake-up every 10 ms), so it is off unless asked for.
"""

from __future__ import annotations

import asyncio
import gc
import threading
import time
from typing import Any

from starlette.types import ASGIApp, Message, Receive, Scope, Send

from chaintwin.live.tracing import slow_ms, trace_line

__all__ = ["SlowTrace", "slow_ms", "watch_connections"]

_LAG_PERIOD_S = 0.010


class _Clock:
    """Cumulative garbage-collection and loop-lag time, ms, since start."""

    def __init__(self, threshold_ms: float) -> None:
        self.threshold = threshold_ms
        self.gc_ms = 0.0
        self.lag_ms = 0.0
        self._started: float | None = None
        self._lock = threading.Lock()
        gc.callbacks.append(self._gc)

    def _gc(self, phase: str, info: dict[str, Any]) -> None:
        now = time.perf_counter()
        if phase == "start":
            self._started = now
            return
        if self._started is None:
            return
        ms = 1e3 * (now - self._started)
        self._started = None
        with self._lock:
            self.gc_ms += ms
        gen = int(info.get("generation", -1))
        if gen == 2 or ms >= self.threshold / 4:
            tracked = len(gc.get_objects(generation=2)) if gen == 2 else -1
            trace_line(
                f"gc generation={gen} ms={ms:.1f} collected={info.get('collected')} "
                f"old_objects={tracked} frozen={gc.get_freeze_count()}"
            )

    async def watch_loop(self) -> None:
        while True:
            t0 = time.perf_counter()
            await asyncio.sleep(_LAG_PERIOD_S)
            late = 1e3 * (time.perf_counter() - t0 - _LAG_PERIOD_S)
            if late > 1.0:
                with self._lock:
                    self.lag_ms += late
            if late >= self.threshold / 4:
                trace_line(f"loop late ms={late:.1f}")


class SlowTrace:
    """An ASGI middleware writing a ``trace`` line for each slow request (see the module)."""

    def __init__(self, app: ASGIApp, threshold_ms: float) -> None:
        self.app = app
        self.threshold = threshold_ms
        self.clock = _Clock(threshold_ms)
        self._watching: asyncio.Task[None] | None = None

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        if self._watching is None:
            self._watching = asyncio.get_running_loop().create_task(self.clock.watch_loop())
        t0 = time.perf_counter()
        gc0, lag0 = self.clock.gc_ms, self.clock.lag_ms
        status = 0

        async def sending(message: Message) -> None:
            nonlocal status
            if message["type"] == "http.response.start":
                status = int(message["status"])
            await send(message)

        try:
            await self.app(scope, receive, sending)
        finally:
            ms = 1e3 * (time.perf_counter() - t0)
            if ms >= self.threshold:
                gc_ms, lag_ms = self.clock.gc_ms - gc0, self.clock.lag_ms - lag0
                trace_line(
                    f"slow {scope['method']} {scope['path']} status={status} ms={ms:.1f} "
                    f"gc_ms={gc_ms:.1f} loop_late_ms={lag_ms:.1f} "
                    f"threads={threading.active_count()}"
                )


def watch_connections(engine: Any) -> None:
    """Write a ``trace`` line for each new connection of ``engine``'s pool, and its time."""
    from sqlalchemy import event

    started: dict[int, float] = {}

    @event.listens_for(engine, "do_connect")
    def _before(_dialect: Any, record: Any, _args: Any, _kwargs: Any) -> None:
        started[id(record)] = time.perf_counter()

    @event.listens_for(engine, "connect")
    def _after(_connection: Any, record: Any) -> None:
        t0 = started.pop(id(record), None)
        ms = -1.0 if t0 is None else 1e3 * (time.perf_counter() - t0)
        status = engine.pool.status() if hasattr(engine.pool, "status") else ""
        trace_line(f"db connect ms={ms:.1f} pool: {status}")
