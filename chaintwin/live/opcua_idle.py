"""asyncua's server, quiet while nothing changes.

Two parts of asyncua's server wake up many times a second on their own,
whether or not anything happens:

* one loop per subscription, every publishing interval, to find (nearly
  always) nothing to send: with 20 clients at 0.5 s, 40 wake-ups a second.
  :class:`QuietSubscription` keeps asyncua's publishing (the same
  ``publish_results``, the same notification messages at the same interval
  boundaries) but sleeps until a monitored item queues a value, an event or
  a status change, or the keep-alive falls due; the intervals slept through
  count towards the keep-alive as asyncua counts them. A subscription that
  has something to send but no Publish request to send it with ticks every
  interval, as asyncua's does (its lifetime count runs on);
* one watchdog per session, every second, that closes a session idle past
  its timeout (the session's own timeout loop does the same):
  :func:`quiet_session_watchdogs` has it look every :data:`WATCHDOG_S` (or
  half the session timeout, when shorter).

:func:`quiet_subscriptions` and :func:`quiet_session_watchdogs` put them
into a server: documented patches of asyncua's internals, tested against
the versions in :data:`TESTED` (outside them the server keeps asyncua's own
loops and says so in the log).
"""

from __future__ import annotations

import asyncio
import importlib.metadata
import logging
import math
import time
from typing import Any

from asyncua import ua
from asyncua.server.internal_subscription import InternalSubscription
from asyncua.server.server import Server
from asyncua.server.subscription_service import SubscriptionService

__all__ = [
    "TESTED",
    "WATCHDOG_S",
    "QuietSubscription",
    "QuietSubscriptionService",
    "quiet_session_watchdogs",
    "quiet_subscriptions",
]

log = logging.getLogger("chaintwin.live")

TESTED = ((2, 1), (2, 2))
"""asyncua versions the patch is tested against: from the first (included) to the
second (excluded), as ``pyproject.toml`` pins them."""

WATCHDOG_S = 30.0
"""How often a session's watchdog looks whether the session outlived its timeout, s
(asyncua's: 1 s)."""


class QuietSubscription(InternalSubscription):
    """asyncua's server-side subscription, its loop asleep while there is nothing to send.

    Made by :class:`QuietSubscriptionService` from the subscription asyncua
    created (its class swapped before its loop first ran).
    """

    _wake: asyncio.Event

    def _busy(self) -> bool:
        """Whether the next interval may have to send something (asyncua's loop then runs
        every interval, as it would)."""
        return bool(
            self._startup
            or self._triggered_datachanges
            or self._triggered_events
            or self._triggered_statuschanges
            or self._keep_alive_count >= self.data.RevisedMaxKeepAliveCount
        )

    async def _subscription_loop(self) -> None:
        """Publish at the publishing interval's boundaries, as asyncua does, but sleep through
        the intervals with nothing to send and no keep-alive due."""
        period = self.data.RevisedPublishingInterval / 1000.0
        ts = time.monotonic()
        try:
            await self.publish_results()
            while not self._closing:
                self._wake.clear()
                if not self._busy():
                    # asyncua counts an interval without notifications towards the keep-alive
                    # at each boundary and sends it at the count's maximum: sleep until then
                    left = max(1, self.data.RevisedMaxKeepAliveCount - self._keep_alive_count)
                    due = ts + left * period
                    try:
                        async with asyncio.timeout(max(due - time.monotonic(), 0.0)):
                            await self._wake.wait()
                    except TimeoutError:
                        pass
                    # the boundaries passed while asleep, each counted as asyncua's loop would
                    passed = max(0, min(left, math.ceil((time.monotonic() - ts) / period)) - 1)
                    self._keep_alive_count += passed
                    ts += passed * period
                next_ts = ts + period
                ts = next_ts
                await asyncio.sleep(max(next_ts - time.monotonic(), 0.0))
                await self.publish_results()
        except asyncio.CancelledError:
            self.logger.info("exiting _subscription_loop for %s", self.data.SubscriptionId)
            raise
        except Exception:
            self.logger.exception("Exception in subscription loop")
            raise

    async def _enqueue_event(
        self,
        mid: int,
        eventdata: ua.MonitoredItemNotification | ua.EventFieldList,
        size: int,
        queue: dict[int, list[Any]],
    ) -> None:
        await super()._enqueue_event(mid, eventdata, size, queue)
        self._wake.set()

    async def enqueue_statuschange(self, code: ua.StatusCode) -> None:
        await super().enqueue_statuschange(code)
        self._wake.set()

    async def set_publishing_mode(self, enabled: bool) -> None:
        await super().set_publishing_mode(enabled)
        self._wake.set()


class QuietSubscriptionService(SubscriptionService):
    """asyncua's subscription service whose subscriptions are :class:`QuietSubscription`."""

    async def create_subscription(
        self,
        params: ua.CreateSubscriptionParameters,
        callback: Any,
        session_id: ua.NodeId,
        request_callback: Any = None,
    ) -> ua.CreateSubscriptionResult:
        result = await super().create_subscription(
            params, callback, session_id, request_callback=request_callback
        )
        sub = self.subscriptions[result.SubscriptionId]
        # asyncua created its loop's task; it has not run yet (no await since): replaced
        task = sub._task
        if task is not None:
            task.cancel()
        sub.__class__ = QuietSubscription
        quiet = sub  # now a QuietSubscription
        assert isinstance(quiet, QuietSubscription)
        quiet._wake = asyncio.Event()
        if task is not None:
            quiet._task = asyncio.create_task(quiet._subscription_loop())
        return result


def _version() -> tuple[int, ...]:
    text = importlib.metadata.version("asyncua")
    parts = []
    for part in text.split(".")[:2]:
        digits = "".join(ch for ch in part if ch.isdigit())
        parts.append(int(digits or 0))
    return tuple(parts)


def _tested() -> bool:
    low, high = TESTED
    return low <= _version() < high


def quiet_subscriptions(server: Server) -> bool:
    """Have ``server``'s new subscriptions sleep while they have nothing to send.

    Returns
    -------
    bool
        True when installed; False (asyncua's own loop kept, a warning logged)
        with an asyncua version outside :data:`TESTED`.
    """
    service = server.iserver.subscription_service
    if not _tested() or type(service) is not SubscriptionService:
        _untested("subscription loop")
        return False
    service.__class__ = QuietSubscriptionService
    return True


def _untested(what: str) -> None:
    low, high = TESTED
    log.warning(
        "OPC UA server: asyncua %s is not a version chaintwin's quiet %s is tested "
        "against (%s to below %s): asyncua's own kept",
        importlib.metadata.version("asyncua"),
        what,
        ".".join(map(str, low)),
        ".".join(map(str, high)),
    )


class _Connections(list[Any]):
    """asyncua's list of a listening server's connections, each new one's session
    watchdog set to :data:`WATCHDOG_S` (the connection joins the list before its first
    message, and the watchdog starts with its session)."""

    def append(self, protocol: Any) -> None:
        processor = getattr(protocol, "processor", None)
        if processor is not None and hasattr(processor, "_watchdog_interval"):
            processor._watchdog_interval = WATCHDOG_S
        super().append(protocol)


def quiet_session_watchdogs(server: Server) -> bool:
    """Have the session watchdogs of ``server`` (started: listening) look every
    :data:`WATCHDOG_S` instead of every second.

    Returns
    -------
    bool
        True when installed; False (asyncua's kept, a warning logged) with an
        asyncua version outside :data:`TESTED` or a server not listening.
    """
    bserver = getattr(server, "bserver", None)
    clients = getattr(bserver, "clients", None)
    if not _tested() or type(clients) is not list:
        _untested("session watchdog")
        return False
    bserver.clients = _Connections(clients)  # type: ignore[union-attr]
    return True
