"""The fleet's rows with each conveyor's verdict, for the fleet page and API.

The verdict (:func:`chaintwin.diagnose.verdict.verdict`: ``health``,
``ne107``, their ``since`` times, the health index) is read through a
:class:`~chaintwin.store.verdicts.VerdictCache`, so that polling the fleet
reads one small row per conveyor beside :func:`~chaintwin.store.queries.fleet_rows`.
"""

from __future__ import annotations

import threading
from typing import Any

import orjson

from chaintwin.diagnose.verdict import Verdict, verdict
from chaintwin.store.queries import fleet_rows
from chaintwin.store.store import Store
from chaintwin.store.verdicts import VerdictCache

__all__ = ["FleetHealth"]


class FleetHealth:
    """The fleet's rows with each conveyor's verdict, kept per store signature."""

    def __init__(self) -> None:
        self.cache = VerdictCache()
        self._lock = threading.Lock()
        self._snapshot: tuple[str, list[dict[str, Any]], bytes] | None = None

    def snapshot(self, store: Store, key: str) -> tuple[list[dict[str, Any]], bytes]:
        """The fleet's rows and their JSON for the store's signature ``key``.

        Read again only when ``key`` changes (:func:`~chaintwin.store.queries.store_signature`:
        results are only ever added, and every change of alarms or health models
        raises a model's version), so the 50 dashboards polling a fleet that
        did not change cost one signature read each. Treat the rows as read-only.
        """
        with self._lock:
            known = self._snapshot
        if known is not None and known[0] == key:
            return known[1], known[2]
        rows = self.rows(store)
        body = orjson.dumps(rows)
        with self._lock:
            self._snapshot = (key, rows, body)
        return rows, body

    def verdict(self, store: Store, conveyor: str) -> Verdict:
        """One conveyor's verdict, as the fleet's rows give it (``no_data`` without a model).

        Worked out once per version of its health model: a conveyor's page
        and ``GET /api/v1/conveyors/{id}`` read the same as the fleet.
        """
        return self.cache.verdict(store, conveyor) or verdict(None)

    def rows(self, store: Store) -> list[dict[str, Any]]:
        """:func:`~chaintwin.store.queries.fleet_rows` with the verdict's fields
        (:meth:`~chaintwin.diagnose.verdict.Verdict.to_dict`)."""
        verdicts = self.cache.verdicts(store)
        out = []
        for row in fleet_rows(store):
            row.update((verdicts.get(row["id"]) or verdict(None)).to_dict())
            out.append(row)
        return out
