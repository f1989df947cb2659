"""The fleet's rows with each conveyor's health index, for the fleet page and API.

The health index (:func:`chaintwin.diagnose.monitor_state.health_index`)
needs a conveyor's health model, which can be large (its history): it is
worked out once per version of the model (every stored result,
acknowledgement and maintenance raises the version) and kept in the
process, so that polling the fleet reads one small row per conveyor
(``monitor_states``' ids and versions) beside :func:`~chaintwin.store.queries.fleet_rows`.
"""

from __future__ import annotations

import math
import threading
from typing import Any

import orjson
from sqlalchemy import select
from sqlalchemy.orm import Session

from chaintwin.diagnose.monitor_state import MonitorState, deviations, health_index
from chaintwin.diagnose.records import NOT_COUNTED
from chaintwin.errors import ChaintwinError
from chaintwin.store.queries import fleet_rows
from chaintwin.store.schema import MonitorStateRow
from chaintwin.store.store import Store

__all__ = ["FleetHealth", "health_label"]


def health_label(row: dict[str, Any]) -> str:
    """``alarm``, ``learning`` or ``ok`` (the ``health`` field of the fleet's rows)."""
    if row["open_alarms"]:
        return "alarm"
    if row["status"] in (None, "baseline", "learning"):
        return "learning"
    return "ok"


class FleetHealth:
    """Each conveyor's largest deviation and worst feature, by health-model version."""

    def __init__(self) -> None:
        self._known: dict[str, tuple[int, float | None, str | None]] = {}
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

    def deviations(self, store: Store) -> dict[str, tuple[float | None, str | None]]:
        """Per conveyor: its largest normalised deviation and that feature (None: none yet)."""
        with Session(store.engine) as s:
            query = select(MonitorStateRow.conveyor_id, MonitorStateRow.version)
            versions = {str(c): int(v) for c, v in s.execute(query).all()}
        out: dict[str, tuple[float | None, str | None]] = {}
        for cid, version in versions.items():
            with self._lock:
                known = self._known.get(cid)
            if known is None or known[0] != version:
                known = (version, *self._worst(store, cid))
                with self._lock:
                    self._known[cid] = known
            out[cid] = (known[1], known[2])
        return out

    @staticmethod
    def _worst(store: Store, conveyor: str) -> tuple[float | None, str | None]:
        with Session(store.engine) as s:
            row = s.get(MonitorStateRow, conveyor)
            data = None if row is None else dict(row.state)
        if data is None:
            return None, None
        try:
            state = MonitorState.from_dict(data, source=f"conveyor {conveyor}")
        except (ChaintwinError, KeyError, TypeError, ValueError):
            return None, None  # a damaged model: the conveyor's page says why
        devs = {k: v for k, v in deviations(state).items() if math.isfinite(v)}
        if not devs:
            return None, None
        worst = max(devs, key=lambda k: devs[k])
        return devs[worst], worst

    def rows(self, store: Store) -> list[dict[str, Any]]:
        """:func:`~chaintwin.store.queries.fleet_rows` with ``health``, ``health_index``,
        ``deviation`` and ``worst_feature``."""
        devs = self.deviations(store)
        out = []
        for row in fleet_rows(store):
            deviation, worst = devs.get(row["id"], (None, None))
            row["health"] = health_label(row)
            row["deviation"] = deviation
            row["worst_feature"] = worst
            standing = [a for a in row["open_alarms"] if a["lifecycle"] not in NOT_COUNTED]
            row["health_index"] = health_index(deviation, len(standing))
            out.append(row)
        return out
