"""Forecasts computed once: a conveyor's derived health, kept in ``derived_health``.

A conveyor's trend forecasts (each a model fit and its backtests, seconds on
a long history) and wear rates are computed from its health model after
ingest (:func:`refit`: once per conveyor and ``ingest``; in the live service
by :class:`~chaintwin.live.refit.Refitter`, at most
:data:`~chaintwin.live.refit.REFIT_EVERY_S` behind) and stored with the
fingerprint of the model's inputs (:func:`~chaintwin.diagnose.monitor_state.derived_inputs`).
Pages and the API read them (:func:`read_derived`), never refit them: what
they show may be behind the newest recording by what the refit has not yet
reached, and says so (``as_of``). Ingest and the live service then store the
conveyor's trends as well (``chaintwin.report.trend_series.refit_with_trends``,
a layer above this one), which the trends endpoint reads only while no newer
result has come (else it builds them: never stale points).
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

from chaintwin.diagnose.monitor_state import MonitorState, derived_inputs, derived_of

from .schema import DerivedHealthRow
from .store import Store
from .upsert import upsert_conveyor_row

__all__ = ["Derived", "read_derived", "refit"]


@dataclass(frozen=True)
class Derived:
    """A conveyor's stored derived health.

    Attributes
    ----------
    content : dict
        :func:`~chaintwin.diagnose.monitor_state.derived_of` (``forecasts``
        with their bands, ``wear``) and ``newest``, the content hash of the
        newest result it was computed from.
    inputs : str
        Fingerprint of the health model it was computed from.
    latest : str or None
        recorded_at (ISO 8601) of the newest result it was computed from.
    computed_at : str
        When it was computed (UTC, ISO 8601).
    """

    content: dict[str, Any]
    inputs: str
    latest: str | None
    computed_at: str

    def as_of(self, state: MonitorState, inputs: str | None = None) -> dict[str, Any]:
        """How current it is for ``state``: ``computed_at``, ``latest``, ``current``
        (computed from this very model) and ``recordings_behind`` (results the
        model took after the newest it was computed from; all the model keeps
        when that one is no longer among them). ``inputs``: ``derived_inputs(state)``
        when the caller has it."""
        current = self.inputs == (derived_inputs(state) if inputs is None else inputs)
        behind = 0
        if not current:
            keys = [_key(h) for h in state.history]
            newest = self.content.get("newest")
            behind = len(keys) - 1 - keys.index(newest) if newest in keys else len(keys)
        return {
            "computed_at": self.computed_at,
            "latest": self.latest,
            "current": current,
            "recordings_behind": behind,
        }


def _key(result: dict[str, Any]) -> str:
    """What names a result in a health model's history (its recording's content hash)."""
    return str(result.get("sha256") or result.get("file"))


def _latest(state: MonitorState) -> str | None:
    times = [str(h["recorded_at"]) for h in state.history if h.get("recorded_at")]
    return max(times) if times else None


def read_derived(store: Store, conveyor: str) -> Derived | None:
    """A conveyor's stored derived health (None: never computed).

    Raises
    ------
    StoreError
        When the database fails.
    """
    with store.reading(f"the derived health of '{conveyor}'") as s:
        row = s.get(DerivedHealthRow, conveyor)
        if row is None:
            return None
        return Derived(dict(row.content), row.inputs, row.latest, row.computed_at)


def refit(store: Store, conveyor: str, state: MonitorState | None = None) -> Derived | None:
    """Compute a conveyor's forecasts and wear rates from its stored health model; store them.

    Nothing is computed when the stored ones were computed from the same
    inputs. ``state``: the conveyor's health model as stored (read when None).

    Returns
    -------
    Derived or None
        What is stored now; None when the conveyor has no health model.

    Raises
    ------
    StoreError
        When the database fails or the stored model is damaged.
    """
    if state is None:
        state = store.state(conveyor)
        if state is None:
            return None
    return _refit_derived(store, conveyor, state)


def _refit_derived(store: Store, conveyor: str, state: MonitorState) -> Derived:
    """:func:`refit`'s forecasts and wear rates."""
    inputs = derived_inputs(state)
    known = read_derived(store, conveyor)
    if known is not None and known.inputs == inputs:
        return known
    content = derived_of(state)
    content["newest"] = _key(state.history[-1]) if state.history else None
    found = Derived(content, inputs, _latest(state), datetime.now(UTC).isoformat())
    values = {
        "inputs": found.inputs,
        "latest": found.latest,
        "computed_at": found.computed_at,
        "content": found.content,  # null for NaN: the column's serializer
    }
    upsert_conveyor_row(store, DerivedHealthRow, conveyor, values, what="the derived health")
    return found
