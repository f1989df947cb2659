"""The live service's refits: forecasts computed in the background, not per recording.

Each recording the live service stores marks its conveyor; every
:data:`REFIT_EVERY_S` the marked conveyors' forecasts and wear rates are
refitted and their trends built (:func:`~chaintwin.report.trend_series.refit_with_trends`,
in a thread) and stored.
A page therefore shows forecasts at most :data:`REFIT_EVERY_S` plus one
refit round behind the newest recording (``forecasts_as_of`` says by how
many recordings), and a conveyor receiving a recording every few seconds
is refitted once per round, not once per recording.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import threading
from collections.abc import Iterable

from chaintwin.store.store import Store

__all__ = ["REFIT_EVERY_S", "Refitter"]

log = logging.getLogger("chaintwin.live")

REFIT_EVERY_S = 30.0
"""Seconds between refit rounds of the live service."""


class Refitter:
    """Conveyors whose forecasts are behind, refitted in rounds.

    Parameters
    ----------
    store : Store
        The results store.
    every_s : float
        Seconds between rounds, s.
    """

    def __init__(self, store: Store, every_s: float = REFIT_EVERY_S) -> None:
        self.store = store
        self.every_s = every_s
        self._marked: set[str] = set()
        self._lock = threading.Lock()
        self.rounds = 0
        """Rounds that refitted at least one conveyor."""

    def mark(self, conveyors: Iterable[str]) -> None:
        """Mark conveyors whose health model changed (any thread)."""
        with self._lock:
            self._marked.update(conveyors)

    def refit_marked(self) -> list[str]:
        """Refit the marked conveyors now (blocking); those refitted.

        A conveyor that fails is logged and marked again for the next round.
        """
        from chaintwin.report.trend_series import refit_with_trends

        with self._lock:
            todo, self._marked = sorted(self._marked), set()
        done = []
        for conveyor in todo:
            try:
                refit_with_trends(self.store, conveyor)
            except Exception as exc:  # a round goes on; the conveyor is tried again
                log.error("refitting the forecasts of %s: %s", conveyor, exc)
                self.mark([conveyor])
            else:
                done.append(conveyor)
        if done:
            self.rounds += 1
        return done

    async def run(self, stop: asyncio.Event) -> None:
        """Refit a round every :attr:`every_s` until ``stop``, then a last one."""
        while not stop.is_set():
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(stop.wait(), self.every_s)
            await asyncio.to_thread(self.refit_marked)
