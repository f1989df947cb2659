"""Forecasts computed once after ingest and read by the pages; all trends in one request.

The store is ``test_web``'s: a conveyor whose rail friction rises from its
third day, with the friction alarm open.
"""

from __future__ import annotations

import json
from datetime import datetime, timedelta
from pathlib import Path

import pytest
from test_web import CHROMIUM, PROFILE, Served, _error, fleet, log_in, served

from chaintwin.calibrating.procedure import calibrate
from chaintwin.diagnose import monitor_state
from chaintwin.diagnose.monitor_state import derived_of
from chaintwin.diagnose.records import MonitorSettings
from chaintwin.diagnose.state import json_ready
from chaintwin.ingest.pipeline import ingest
from chaintwin.live.refit import Refitter
from chaintwin.read.writer import write_recording
from chaintwin.report.data import conveyor_data
from chaintwin.simulate.virtual import run_virtual
from chaintwin.store import derived
from chaintwin.store.derived import read_derived
from chaintwin.store.store import Store
from chaintwin.validate import load_recording

__all__ = ["fleet", "served"]  # test_web's fixtures, used here


def _no_refit(monkeypatch: pytest.MonkeyPatch) -> None:
    """Make any refit fail: what is read must be what was stored after ingest."""

    def refused(state: object) -> dict[str, object]:
        raise AssertionError("forecasts refitted while serving a request")

    monkeypatch.setattr(monitor_state, "derived_of", refused)
    monkeypatch.setattr(derived, "derived_of", refused)


@pytest.mark.slow
def test_every_trend_in_one_request_as_each_alone_without_a_refit(
    served: Served, monkeypatch: pytest.MonkeyPatch
) -> None:
    viewer = served.client("viewer")
    base = f"/api/v1/conveyors/{PROFILE.id}"
    singles = {}
    detail = viewer.get(base).json()
    for name in detail["features"]:
        singles[name] = viewer.get(f"{base}/trends", params={"feature": name}).json()
    _no_refit(monkeypatch)
    assert viewer.get(base).json() == detail
    assert detail["open_alarms"]  # a conveyor in alarm
    assert detail["summary"]["forecasts_as_of"]["current"] is True
    assert detail["summary"]["forecasts_as_of"]["recordings_behind"] == 0
    # without feature: every feature's trend, each exactly as asked alone
    every = viewer.get(f"{base}/trends").json()
    assert set(every) == {"conveyor", "trends", "recordings", "max_points", "as_of"}
    assert [t["feature"] for t in every["trends"]] == detail["features"]
    assert {t["feature"]: t for t in every["trends"]} == singles
    assert every["recordings"] == detail["recordings"] and every["max_points"] == 1000
    assert every["as_of"] == detail["summary"]["forecasts_as_of"]
    # the friction forecast goes on while its alarm is open, the same in both answers
    friction = singles["friction"]["forecast"]
    assert friction is not None
    band = friction.pop("band")
    assert friction in detail["forecasts"]
    assert (band is None) == friction["crossed"]  # a limit crossed has no band ahead
    # several features: those asked, in the order asked
    other = detail["features"][-1]
    two = viewer.get(f"{base}/trends", params=[("feature", other), ("feature", "friction")])
    assert [t["feature"] for t in two.json()["trends"]] == [other, "friction"]
    message = _error(
        viewer.get(f"{base}/trends", params=[("feature", "friction"), ("feature", "nope")]),
        404,
        "not_found",
    )
    assert message.startswith("no feature 'nope' (tracked: ")
    # the page too is served from what was stored
    browser = served.client()
    assert browser.post("/login", data={"token": served.tokens["viewer"]}).status_code == 303
    assert browser.get(f"/conveyors/{PROFILE.id}").status_code == 200


@pytest.mark.slow
def test_forecasts_are_refitted_after_ingest_and_say_how_far_behind(
    fleet: Path, tmp_path: Path
) -> None:
    with Store(f"sqlite:///{tmp_path / 'plant.db'}") as store:
        cal_files = sorted((fleet / "calibration").glob("*.csv"))
        recs = [load_recording(f, profile=PROFILE).recording for f in cal_files]
        store.put_calibration(calibrate(recs, PROFILE))
        files = sorted(str(f) for f in fleet.glob("*.csv"))
        settings = MonitorSettings(baseline_n=10)
        profiles = {PROFILE.id: PROFILE}
        summary = ingest(files, profiles, store, settings=settings, workers=1)
        assert summary.stored_for == {PROFILE.id}
        state = store.state(PROFILE.id)
        assert state is not None
        stored = read_derived(store, PROFILE.id)
        assert stored is not None
        # what was stored is what a fit of the stored model gives
        fitted = derived_of(state) | {"newest": state.history[-1]["sha256"]}
        assert stored.content == json.loads(json.dumps(json_ready(fitted)))
        assert any(f["feature"] == "friction" for f in stored.content["forecasts"])
        assert stored.latest == max(h["recorded_at"] for h in state.history)
        assert stored.as_of(state) | {"computed_at": None} == {
            "computed_at": None,
            "latest": stored.latest,
            "current": True,
            "recordings_behind": 0,
        }
        # a recording stored without a refit (as the live service stores them)
        late = run_virtual(PROFILE, payload_kg=38.0, seed=321).recording
        late_file = write_recording(late, tmp_path / "late.csv")
        one = ingest([str(late_file)], profiles, store, settings=settings, refit=False)
        assert one.processed == 1 and one.stored_for == {PROFILE.id}
        page = conveyor_data(store, PROFILE.id, waterfall=0, latest=False, stored_forecasts=True)
        behind = page.summary["forecasts_as_of"]
        assert behind["current"] is False and behind["recordings_behind"] == 1
        assert behind["computed_at"] == stored.computed_at
        assert page.forecasts == [
            {k: v for k, v in f.items() if k != "band"} for f in stored.content["forecasts"]
        ]
        # the live service's refitter brings it up to date in its next round
        refitter = Refitter(store, every_s=0.0)
        refitter.mark(one.stored_for)
        assert refitter.refit_marked() == [PROFILE.id]
        assert refitter.refit_marked() == []  # nothing marked since
        now = read_derived(store, PROFILE.id)
        state = store.state(PROFILE.id)
        assert now is not None and state is not None and now.as_of(state)["current"] is True
        assert now.content["newest"] == state.history[-1]["sha256"] != stored.content["newest"]
        # a report fits them itself rather than show stale ones
        ingest([str(write_recording(run_virtual(PROFILE, payload_kg=30.0, seed=322).recording,
                                    tmp_path / "later.csv"))],
               profiles, store, settings=settings, refit=False)  # fmt: skip
        report = conveyor_data(store, PROFILE.id, waterfall=0, latest=False)
        assert "forecasts_as_of" not in report.summary
        state = store.state(PROFILE.id)
        assert state is not None
        fresh = [
            {k: v for k, v in f.items() if k != "band"} for f in derived_of(state)["forecasts"]
        ]
        assert json.dumps(json_ready(report.forecasts)) == json.dumps(json_ready(fresh))
        assert read_derived(store, PROFILE.id) == now  # nothing written by a report


@pytest.mark.browser
def test_in_a_browser_the_page_of_a_conveyor_in_alarm_draws_every_trend(
    fleet: Path, tmp_path: Path
) -> None:
    """All trends come in one request and are updated in place on a new recording."""
    if not CHROMIUM.exists():
        pytest.fail("Chromium not found at /usr/bin/chromium: `make test` installs it")
    from playwright.sync_api import sync_playwright

    served = Served(f"sqlite:///{tmp_path / 'plant.db'}", fleet)
    asked: list[str] = []
    broken: list[str] = []
    try:
        viewer = served.client("viewer")
        detail = viewer.get(f"/api/v1/conveyors/{PROFILE.id}").json()
        assert detail["open_alarms"]
        features = detail["features"]
        assert len(features) >= 3
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=str(CHROMIUM))
            page = browser.new_page()
            page.on("request", lambda r: asked.append(r.url) if "/trends" in r.url else None)
            page.on("console", lambda m: broken.append(m.text) if m.type == "error" else None)
            page.on("pageerror", lambda e: broken.append(str(e)))
            log_in(page, served, "viewer")
            page.goto(f"{served.base}/conveyors/{PROFILE.id}")
            page.wait_for_function(
                "(n) => Array.from(document.querySelectorAll('#trends .trend'))"
                ".filter((d) => d.querySelector('.main-svg') || d.classList.contains('absent'))"
                ".length === n",
                arg=len(features),
                timeout=60000,
            )
            unwritten = page.evaluate(
                "Array.from(document.querySelectorAll('#trends .trend.absent'))"
                ".map((d) => d.textContent)"
            )
            assert unwritten == [] and broken == []
            drawn = page.evaluate(
                "Array.from(document.querySelectorAll('#trends .trend'))"
                ".map((d) => [d.dataset.feature, d.data[0].y.filter((v) => v !== null).length,"
                " d.data[0].x.length])"
            )
            assert [name for name, _n, _x in drawn] == features
            assert all(n > 0 for _name, n, _x in drawn), drawn
            assert len(asked) == 1 and asked[0].endswith(f"/{PROFILE.id}/trends")
            points = {name: x for name, _n, x in drawn}["friction"]
            # the page drawn to its end: it follows the store's changes from then on
            page.wait_for_selector("#latest .main-svg", timeout=60000)
            page.evaluate(
                "window.friction = document.querySelector('#trends .trend[data-feature=friction]')"
            )
            # a new recording: the charts are updated in place, not cleared and made anew
            newest = max(p["recorded_at"] for p in viewer.get(
                f"/api/v1/conveyors/{PROFILE.id}/trends", params={"feature": "friction"}
            ).json()["points"])  # fmt: skip
            at = datetime.fromisoformat(newest) + timedelta(hours=1)
            late = run_virtual(PROFILE, payload_kg=38.0, seed=321, recorded_at=at).recording
            ingest([str(write_recording(late, tmp_path / "late.csv"))], {PROFILE.id: PROFILE},
                   served.store, workers=1)  # fmt: skip
            page.wait_for_function(
                "(n) => window.friction.data[0].x.length > n",
                arg=points,
                timeout=30000,
            )
            assert page.evaluate(
                "window.friction === document.querySelector("
                "'#trends .trend[data-feature=friction]')"
            )
            assert page.locator("#trends .trend").count() == len(features)
            assert len(asked) == 2
            browser.close()
    finally:
        served.close()
    assert broken == []


def test_fleet_shows_the_stored_forecasts_without_a_refit(
    served: Served, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    from chaintwin.cli.app import main
    from chaintwin.cli.fleet_cmd import forecast_text

    stored = read_derived(served.store, PROFILE.id)
    assert stored is not None
    _no_refit(monkeypatch)
    assert main(["fleet", "--db", served.url, "--json"]) == 0
    (row,) = json.loads(capsys.readouterr().out)
    # the forecasts as stored after ingest, and the fleet's verdict and alarms beside them
    assert row["forecasts"] == json.loads(json.dumps(json_ready(stored.content["forecasts"])))
    assert row["forecasts_latest"] == stored.latest
    assert row["open_alarms"] and row["health"] == "alarm"
    (friction,) = [f for f in row["forecasts"] if f["feature"] == "friction"]
    assert friction["crossed"] is True  # the friction alarm is open: its limit was crossed
    monkeypatch.setenv("COLUMNS", "400")  # a line per conveyor
    assert main(["fleet", "--db", served.url, "--once"]) == 0
    out = capsys.readouterr().out
    said = f"friction crossed {friction['limit']:.4g} since {friction['crosses_at'][:16]}"
    assert said in out and f"as of {stored.latest[:16]}" in out
    assert forecast_text(row["forecasts"]) in out
    # the remaining life of the one to reach its limit first, with its 90 % interval
    ahead = [
        {"feature": "a", "cause": "x", "limit": 2.0, "crossed": False,
         "remaining_life_days": {"earliest": 3.0, "expected": 12.5, "latest": None}},
        {"feature": "b", "cause": "y", "limit": 1.0, "crossed": False,
         "remaining_life_days": {"earliest": 1.0, "expected": 4.25, "latest": 9.0}},
    ]  # fmt: skip
    assert forecast_text(ahead) == "b (y) reaches 1 in 4.2 d (90 %: 1.0 to 9.0 d)"
    assert forecast_text(ahead[:1]) == "a (x) reaches 2 in 12.5 d (90 %: 3.0 to beyond a year d)"
    assert forecast_text([]) == "no feature is forecast to reach its limit"
    assert forecast_text(None) == "no forecast stored yet"
