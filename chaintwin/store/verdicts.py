"""Each conveyor's verdict read from the store, kept per version of its health model.

The verdict (:func:`chaintwin.diagnose.verdict.verdict`) needs a conveyor's
health model, which can be large (its history): :class:`VerdictCache` works
it out once per version of the model (every stored result, acknowledgement,
shelving and maintenance raises the version) and keeps it in the process, so
that the fleet's views and ``/metrics`` read one small row per conveyor
(``monitor_states``' ids and versions) to know whether it still holds.
"""

from __future__ import annotations

import threading

from sqlalchemy import select

from chaintwin.diagnose.monitor_state import MonitorState
from chaintwin.diagnose.verdict import Verdict, verdict
from chaintwin.errors import ChaintwinError

from .schema import MonitorStateRow
from .store import Store

__all__ = ["VerdictCache", "conveyor_verdict"]


def conveyor_verdict(store: Store, conveyor: str) -> Verdict:
    """A conveyor's verdict from its stored health model (``no_data`` without a readable one,
    or with one made with another version of its profile, as
    :func:`~chaintwin.report.data.conveyor_data` reads it)."""
    with store.session() as s:
        row = s.get(MonitorStateRow, conveyor)
        data = None if row is None else dict(row.state)
    if data is None:
        return verdict(None)
    try:
        state = MonitorState.from_dict(data, source=f"conveyor {conveyor}")
    except (ChaintwinError, KeyError, TypeError, ValueError):
        return verdict(None)  # a damaged model: the conveyor's page says why
    profile = store.profile(conveyor)
    if profile is None or state.profile_sha256 != profile.content_hash():
        return verdict(None)  # made with another profile: the page says so, as it reads it
    return verdict(state)


class VerdictCache:
    """Each conveyor's :class:`~chaintwin.diagnose.verdict.Verdict`, by health-model version."""

    def __init__(self) -> None:
        self._known: dict[str, tuple[int, Verdict]] = {}
        self._lock = threading.Lock()

    def verdicts(self, store: Store) -> dict[str, Verdict]:
        """Per conveyor with a health model: its verdict."""
        with store.session() as s:
            query = select(MonitorStateRow.conveyor_id, MonitorStateRow.version)
            versions = {str(c): int(v) for c, v in s.execute(query).all()}
        out: dict[str, Verdict] = {}
        for cid, version in versions.items():
            with self._lock:
                known = self._known.get(cid)
            if known is None or known[0] != version:
                known = (version, conveyor_verdict(store, cid))
                with self._lock:
                    self._known[cid] = known
            out[cid] = known[1]
        return out

    def verdict(self, store: Store, conveyor: str) -> Verdict | None:
        """One conveyor's verdict, as :meth:`verdicts` gives it (None: no health model);
        only its own model's version is read."""
        with store.session() as s:
            query = select(MonitorStateRow.version).where(MonitorStateRow.conveyor_id == conveyor)
            version = s.scalar(query)
        if version is None:
            return None
        with self._lock:
            known = self._known.get(conveyor)
        if known is None or known[0] != int(version):
            known = (int(version), conveyor_verdict(store, conveyor))
            with self._lock:
                self._known[conveyor] = known
        return known[1]
