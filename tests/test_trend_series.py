"""Trends computed once: stored after ingest, served byte for byte as built, never stale.

The store is ``test_web``'s (its own copy here): a conveyor whose rail
friction rises from its third day, with the friction alarm open, on SQLite
and PostgreSQL.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import orjson
import pytest
from test_web import PROFILE, Served, _error, fleet, served

from chaintwin.diagnose.records import MonitorSettings
from chaintwin.ingest.pipeline import ingest
from chaintwin.live.refit import Refitter
from chaintwin.read.writer import write_recording
from chaintwin.report import trend_series
from chaintwin.report.trend_series import built_from, read_series, stored_from
from chaintwin.simulate.virtual import run_virtual
from chaintwin.web.routes import conveyors

__all__ = ["fleet", "served"]  # test_web's fixtures, used here


def _key(served: Served) -> str:
    """The fingerprint of what the conveyor's trends are built from now."""
    store = served.store
    profile = store.profile(PROFILE.id)
    assert profile is not None
    return built_from(store, PROFILE.id, profile, store.state(PROFILE.id))


class _Builds:
    """Counts the trends built from the results by the endpoint."""

    def __init__(self, monkeypatch: pytest.MonkeyPatch) -> None:
        self.count = 0
        built = conveyors.conveyor_data_of

        def counting(*args: Any, **kwargs: Any) -> Any:
            self.count += 1
            return built(*args, **kwargs)

        monkeypatch.setattr(conveyors, "conveyor_data_of", counting)


def _answers(served: Served, asks: dict[str, list[tuple[str, str]]]) -> dict[str, bytes]:
    viewer = served.client("viewer")
    base = f"/api/v1/conveyors/{PROFILE.id}/trends"
    out = {}
    for name, params in asks.items():
        response = viewer.get(base, params=params)
        assert response.status_code == 200, response.text
        out[name] = response.content
    return out


def _built(
    served: Served, asks: dict[str, list[tuple[str, str]]], monkeypatch: pytest.MonkeyPatch
) -> dict[str, bytes]:
    """The answers built from the results (the stored trends not read)."""
    with monkeypatch.context() as m:
        m.setattr(trend_series, "current_series", lambda *_a, **_k: None)
        return _answers(served, asks)


@pytest.mark.slow
def test_stored_trends_answer_as_built_and_a_new_result_is_never_shown_stale(
    served: Served, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    store = served.store
    viewer = served.client("viewer")
    detail = viewer.get(f"/api/v1/conveyors/{PROFILE.id}").json()
    assert detail["open_alarms"]  # a conveyor in alarm: its trends carry alarm markers
    other = detail["features"][-1]
    asks = {
        "all": [],
        "one": [("feature", "friction")],
        "two": [("feature", other), ("feature", "friction")],
        "twice": [("feature", "friction"), ("feature", "friction")],
    }
    # the ingest's refit stored the trends, built from what the store holds now
    key = _key(served)
    assert stored_from(store, PROFILE.id) == key
    builds = _Builds(monkeypatch)
    stored = _answers(served, asks)
    assert builds.count == 0  # every answer from the stored trends
    built = _built(served, asks, monkeypatch)
    assert builds.count == len(asks)
    assert stored == built  # byte for byte
    friction = orjson.loads(stored["one"])
    assert friction["alarms"] and friction["forecast"] is not None
    assert len(friction["points"]) == friction["recordings"] == 30
    # an unknown feature: the same 404 either way
    message = _error(
        viewer.get(
            f"/api/v1/conveyors/{PROFILE.id}/trends",
            params=[("feature", "friction"), ("feature", "nope")],
        ),
        404,
        "not_found",
    )
    assert message.startswith("no feature 'nope' (tracked: friction, ")
    # another max_points is built from the results
    builds.count = 0
    response = viewer.get(f"/api/v1/conveyors/{PROFILE.id}/trends", params={"max_points": 20})
    assert response.status_code == 200 and builds.count == 1
    assert orjson.loads(response.content)["max_points"] == 20

    # a recording stored without a refit (as the live service stores them): the
    # stored trends are behind it, so the endpoint builds them (never stale points)
    late = run_virtual(PROFILE, payload_kg=38.0, seed=321).recording
    late_file = write_recording(late, tmp_path / "late.csv")
    settings = MonitorSettings(baseline_n=10)
    one = ingest([str(late_file)], {PROFILE.id: PROFILE}, store, settings=settings, refit=False)
    assert one.processed == 1
    assert _key(served) != key and stored_from(store, PROFILE.id) == key
    # the detail (its bounded results kept in the process) counts the new one at once
    after = viewer.get(f"/api/v1/conveyors/{PROFILE.id}").json()
    assert after["recordings"] == detail["recordings"] + 1 == 31
    assert after["summary"]["forecasts_as_of"]["recordings_behind"] == 1
    builds.count = 0
    behind = _answers(served, asks)
    assert builds.count == len(asks)
    assert stored_from(store, PROFILE.id) == key  # a reader never replaces stored trends
    now = orjson.loads(behind["one"])
    assert now["recordings"] == len(now["points"]) == 31
    assert now["points"][:-1] == friction["points"]
    assert behind["all"] != stored["all"]
    # the live service's next refit round stores them again: read, not built
    refitter = Refitter(store, every_s=0.0)
    refitter.mark(one.stored_for)
    assert refitter.refit_marked() == [PROFILE.id]
    assert stored_from(store, PROFILE.id) == _key(served) != key
    as_of = viewer.get(f"/api/v1/conveyors/{PROFILE.id}").json()["summary"]["forecasts_as_of"]
    assert as_of["current"] is True and as_of["recordings_behind"] == 0
    builds.count = 0
    again = _answers(served, asks)
    assert builds.count == 0
    assert orjson.loads(again["one"])["points"] == now["points"]
    assert again == _built(served, asks, monkeypatch)


@pytest.mark.slow
def test_trends_of_a_store_written_before_them_are_built_once_and_stored(
    served: Served, monkeypatch: pytest.MonkeyPatch
) -> None:
    from sqlalchemy import delete

    from chaintwin.store.schema import TrendSeriesRow

    store = served.store
    with store.engine.begin() as c:  # as after the migration: none stored
        c.execute(delete(TrendSeriesRow))
    assert stored_from(store, PROFILE.id) is None
    builds = _Builds(monkeypatch)
    asks: dict[str, list[tuple[str, str]]] = {"all": [], "one": [("feature", "friction")]}
    first = _answers(served, asks)
    assert builds.count == 1  # the first built them, and stored them
    series = read_series(store, PROFILE.id)
    assert series is not None and series.built_from == _key(served)
    assert _answers(served, asks) == first
    assert builds.count == 1


def test_a_recording_superseded_without_a_new_result_is_a_change_of_what_they_are_built_from(
    served: Served,
) -> None:
    """A partial recording superseded by a complete one still waiting for its result adds no
    result and does not touch the health model, yet leaves the trends: the stored ones are
    then no longer current."""
    from sqlalchemy import select, update
    from sqlalchemy.orm import Session

    from chaintwin.store.schema import RecordingRow

    store = served.store
    before = _key(served)
    with Session(store.engine) as s, s.begin():
        first = s.scalar(
            select(RecordingRow.id)
            .where(RecordingRow.conveyor_id == PROFILE.id)
            .order_by(RecordingRow.id)
            .limit(1)
        )
        s.execute(update(RecordingRow).where(RecordingRow.id == first).values(superseded_by=first))
    try:
        assert _key(served) != before
    finally:
        with Session(store.engine) as s, s.begin():
            s.execute(
                update(RecordingRow).where(RecordingRow.id == first).values(superseded_by=None)
            )
    assert _key(served) == before


def test_a_conveyor_under_live_ingest_holds_one_entry_of_the_page_caches() -> None:
    """Each new version of a conveyor's reads replaces the one kept before it; other
    conveyors' entries stay until the cache is full (then the first kept goes)."""
    from chaintwin.report.data import _keep

    cache: dict[tuple[Any, ...], Any] = {}
    for version in range(5):
        _keep(cache, (("db", 0), "a", "profile", version), version, 3)
    _keep(cache, (("db", 0), "b", "profile", 0), "b", 3)
    assert cache == {(("db", 0), "a", "profile", 4): 4, (("db", 0), "b", "profile", 0): "b"}
    _keep(cache, (("db", 0), "c", "profile", 0), "c", 3)
    _keep(cache, (("db", 0), "d", "profile", 0), "d", 3)
    assert [k[1] for k in cache] == ["b", "c", "d"]
