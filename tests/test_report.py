"""HTML reports from the results store, and the end-to-end demo."""

from __future__ import annotations

import base64
import io
import math
import re
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import EXAMPLES
from matplotlib.image import imread

from chaintwin.cli.app import main
from chaintwin.diagnose.spectra import Spectrum
from chaintwin.read.profile import load_profile
from chaintwin.report.figures import campbell_peaks
from chaintwin.report.html import CONVEYOR_SECTIONS, FLEET_SECTIONS
from chaintwin.simulate.faults import Fault
from chaintwin.simulate.fleet import generate

HEALTHY = "white-belt-01"
FAULTY = "short-fast-03"


@pytest.fixture(scope="module")
def plant_db(tmp_path_factory: pytest.TempPathFactory) -> str:
    """Two conveyors ingested into a SQLite store: one healthy, one whose friction rises."""
    root = tmp_path_factory.mktemp("reportplant")
    (root / "profiles").mkdir()
    files: list[str] = []
    for k, (cid, faults) in enumerate(((HEALTHY, []), (FAULTY, [Fault("friction", 0.6)]))):
        src = EXAMPLES / "profiles" / f"{cid}.yaml"
        shutil.copy(src, root / "profiles" / src.name)
        out = generate(
            load_profile(src), root / cid, days=6, per_day=6, faults=faults, onset_day=3, seed=k
        )
        files += sorted(str(f) for f in out.folder.glob("*.csv"))
        cal = sorted(str(f) for f in (out.folder / "calibration").glob("*.csv"))
        db = f"sqlite:///{root / 'plant.db'}"
        assert main(["calibrate", "--profile", str(src), *cal, "--db", db]) == 0
    args = ["ingest", *files, "--profiles", str(root / "profiles"), "--db", db]
    assert main([*args, "--workers", "1", "--json"]) == 0  # baseline: the default 20
    return db


def _section(html: str, ident: str) -> str:
    m = re.search(rf'<section id="{ident}">(.*?)</section>', html, re.S)
    assert m is not None, f"section {ident} missing"
    return m.group(1)


def _pngs(fragment: str) -> list[np.ndarray]:
    """The PNG plots embedded in a fragment, decoded."""
    out = []
    for data in re.findall(r'src="data:image/png;base64,([^"]+)"', fragment):
        out.append(imread(io.BytesIO(base64.b64decode(data)), format="png"))
    return out


def _self_contained(html: str) -> None:
    # nothing fetched from elsewhere: no external scripts, styles, images or fonts
    assert not re.search(r'(src|href)="(https?:)?//', html)
    assert "<script" not in html
    assert "@import" not in html and "url(" not in html


@pytest.mark.slow
def test_conveyor_page_has_every_section_with_real_plots(
    plant_db: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "faulty.html"
    assert main(["report", "--db", plant_db, "--conveyor", FAULTY, "--out", str(out)]) == 0
    html = out.read_text(encoding="utf-8")
    _self_contained(html)
    found = re.findall(r'<section id="([a-z-]+)">', html)
    assert found == list(CONVEYOR_SECTIONS)
    # the waterfall section holds the waterfall and the speed sweep (Campbell plot)
    assert len(_pngs(_section(html, "waterfall"))) == 2 and "Campbell plot" in html
    for ident in ("trends", "payload-tlf", "residuals", "waterfall", "latest"):
        plots = _pngs(_section(html, ident))
        assert plots, f"no plot in {ident}"
        for img in plots:
            assert img.shape[0] > 150 and img.shape[1] > 300
            assert float(img[..., :3].std()) > 0.02, f"a blank plot in {ident}"
    # the friction rise: an open friction alarm, named in the summary and the alarm table
    assert "open alarm on friction" in _section(html, "summary")
    # both transport loss factors, labelled, with the published value beside them
    tlf_row = re.search(r"TLF ([0-9.]+) \(sprocket work\), ([0-9.]+) \(motor-shaft work\)", html)
    assert tlf_row is not None
    assert float(tlf_row.group(2)) > float(tlf_row.group(1)) > 0.0
    assert "published 0.01-0.02: not comparable" in html
    # the twin verified against the latest recording: REP of speed and torque per phase
    table = _section(html, "residuals").split("Verification of the twin, latest recording")
    assert len(table) == 2 and table[1].startswith(" (trapezoid")
    rows = dict(re.findall(r"<tr><td>([a-z ]+)</td>(.*?)</tr>", table[1]))
    assert {"whole movement", "accelerate fwd", "constant fwd", "decelerate fwd"} <= set(rows)
    cells = [float(x) for x in re.findall(r'<td class="num">([-0-9.]+)</td>', rows["constant fwd"])]
    # six numbers; the torque's mean REP within what the realism (noise, ringing) allows
    assert len(cells) == 6 and abs(cells[3]) < 20.0
    alarms = _section(html, "alarms")
    assert re.search(r"<td>friction</td><td>friction</td>", alarms)
    # one trend plot per tracked feature, friction among them
    assert 'alt="trend of friction"' in _section(html, "trends")
    # the residual table of the latest recording, per phase
    assert "constant" in _section(html, "residuals")


@pytest.mark.slow
def test_fleet_page_ranks_the_faulty_conveyor_first(plant_db: str, tmp_path: Path) -> None:
    assert main(["report", "--db", plant_db, "--all", "--out", str(tmp_path / "r")]) == 0
    pages = sorted(p.name for p in (tmp_path / "r").iterdir())
    assert pages == sorted(["fleet.html", f"{HEALTHY}.html", f"{FAULTY}.html"])
    fleet = (tmp_path / "r" / "fleet.html").read_text(encoding="utf-8")
    _self_contained(fleet)
    assert re.findall(r'<section id="([a-z-]+)">', fleet) == list(FLEET_SECTIONS)
    ranking = _section(fleet, "ranking-health")
    order = re.findall(r'<a href="([a-z0-9-]+)\.html">', ranking)
    assert order == [FAULTY, HEALTHY]
    assert 'class="status alarm"' in ranking and 'class="status ok"' in ranking
    assert _pngs(ranking) and _pngs(_section(fleet, "ranking-tlf"))
    # the alarm system: the faulty conveyor's alarms counted, the healthy one's none
    kpis = _section(fleet, "alarm-kpis")
    counts = dict(re.findall(r"<tr><td>([a-z0-9-]+)</td><td class=\"num\">(\d+)</td>", kpis))
    assert int(counts[FAULTY]) >= 1 and int(counts.get(HEALTHY, "0")) == 0
    assert int(counts["fleet"]) == int(counts[FAULTY]) + int(counts.get(HEALTHY, "0"))
    # conveyor pages link back to the fleet page
    assert 'href="fleet.html"' in (tmp_path / "r" / f"{HEALTHY}.html").read_text(encoding="utf-8")


@pytest.mark.slow
def test_report_escapes_user_text_and_refuses_bad_requests(
    plant_db: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    db = f"sqlite:///{tmp_path / 'copy.db'}"
    shutil.copy(plant_db.removeprefix("sqlite:///"), tmp_path / "copy.db")
    why = "<script>alert(1)</script> rails & rollers"
    args = ["maintenance", "--db", db, "--conveyor", HEALTHY, "--kind", "cleaning"]
    assert main([*args, "--by", "A. Fitter", "--why", why]) == 0
    out = tmp_path / "h.html"
    assert main(["report", "--db", db, "--conveyor", HEALTHY, "--out", str(out)]) == 0
    html = out.read_text(encoding="utf-8")
    assert "<script>" not in html
    assert "&lt;script&gt;alert(1)&lt;/script&gt; rails &amp; rollers" in _section(html, "alarms")
    capsys.readouterr()
    assert main(["report", "--db", db, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "--conveyor" in err and len(err.strip().splitlines()) == 1
    assert main(["report", "--db", db, "--conveyor", "nope", "--out", str(out)]) == 2
    assert "no conveyor 'nope'" in capsys.readouterr().err
    assert out.read_text(encoding="utf-8") == html  # the page there is left as it was


@pytest.mark.slow
def test_demo_runs_end_to_end(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "demo"
    args = ["demo", "--out", str(out), "--days", "4", "--per-day", "3", "--workers", "1"]
    assert main(args) == 0
    text = capsys.readouterr().out
    assert "the plant after the demo" in text
    pages = {p.name for p in (out / "reports").iterdir()}
    assert pages == {
        "fleet.html",
        "white-belt-01.html",
        "incline-line-02.html",
        "short-fast-03.html",
    }
    assert (out / "plant.db").exists()
    # it ends with the command that serves the store and a viewer token that works there
    assert f"chaintwin serve --db sqlite:///{out / 'plant.db'}" in text.replace("\n", "")
    import re

    from chaintwin.store.store import Store
    from chaintwin.web.access import verify_token

    found = re.search(r"ct_[A-Za-z0-9_-]{40,}", text)
    assert found is not None
    with Store(f"sqlite:///{out / 'plant.db'}", create=False) as store:
        info = verify_token(store, found.group(0))
        assert info is not None and info.role == "viewer"
    # a second run rebuilds the demo's own folder; a foreign folder is refused
    assert main(args) == 0
    foreign = tmp_path / "mine"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("keep me", encoding="utf-8")
    capsys.readouterr()
    assert main(["demo", "--out", str(foreign), "--days", "4"]) == 2
    assert "not a previous demo's" in capsys.readouterr().err
    assert (foreign / "notes.txt").read_text(encoding="utf-8") == "keep me"


def test_trend_points_lie_above_the_drawn_limit_exactly_when_judged_so(plant_db: str) -> None:
    from chaintwin.report.data import conveyor_data
    from chaintwin.store.store import Store

    with Store(plant_db) as store:
        judged = 0
        for cid in (HEALTHY, FAULTY):
            d = conveyor_data(store, cid, waterfall=0)
            for t in d.trends:
                if t.limit is None:  # no baseline (a mode resolvable in few recordings)
                    assert not any(t.exceeded)
                    continue
                for v, exc, early in zip(t.values, t.exceeded, t.before, strict=True):
                    if early or not np.isfinite(v):
                        continue
                    below = t.lower is not None and v < t.lower  # a two-sided feature's fall
                    assert (v > t.limit or below) == exc, (cid, t.name, v, t.limit, t.lower)
                    judged += 1
        assert judged > 100
        faulty = conveyor_data(store, FAULTY, waterfall=0)
        assert any(any(t.exceeded) for t in faulty.trends)  # the check saw exceedances


def test_page_names_are_distinct_and_never_the_fleet_page() -> None:
    from chaintwin.report.html import page_names

    names = page_names(["a/b", "a_b", "fleet", "Fleet", "x"])
    assert len(set(names.values())) == 5
    assert "fleet.html" not in {n.lower() for n in names.values()}
    assert names["x"] == "x.html"


def test_report_refuses_a_missing_or_empty_store(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    missing = tmp_path / "typo.db"
    assert main(["report", "--db", f"sqlite:///{missing}", "--fleet"]) == 2
    assert "there is no store" in capsys.readouterr().err
    assert not missing.exists()  # not created by the attempt
    from chaintwin.store.store import Store

    Store(f"sqlite:///{tmp_path / 'empty.db'}").close()
    assert main(["report", "--db", f"sqlite:///{tmp_path / 'empty.db'}", "--fleet"]) == 2
    assert "no conveyor yet" in capsys.readouterr().err


def test_demo_refuses_a_file_or_a_link_as_its_folder(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    a_file = tmp_path / "notes.txt"
    a_file.write_text("keep me", encoding="utf-8")
    assert main(["demo", "--out", str(a_file), "--days", "4"]) == 2
    assert "not a folder" in capsys.readouterr().err
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "keep.txt").write_text("keep me", encoding="utf-8")
    fake = tmp_path / "fake-demo"
    fake.mkdir()
    (fake / ".chaintwin-demo").write_text("", encoding="utf-8")
    (fake / "reports").symlink_to(mine)
    assert main(["demo", "--out", str(fake), "--days", "4"]) == 2
    assert "not the demo's own folder" in capsys.readouterr().err
    assert (mine / "keep.txt").read_text(encoding="utf-8") == "keep me"


def test_the_report_reads_the_stored_health_as_the_monitor_would_say_it(plant_db: str) -> None:
    """The page's summary, forecasts and baselines come from the stored state, equal to
    what the rebuilt monitor reports (the report no longer rebuilds it)."""
    from chaintwin.diagnose.monitor import ConveyorMonitor
    from chaintwin.report.data import conveyor_data
    from chaintwin.store.store import Store

    with Store(plant_db) as store:
        for cid in (HEALTHY, FAULTY):
            profile = store.profile(cid)
            state = store.state(cid)
            assert profile is not None and state is not None
            mon = ConveyorMonitor.from_state(state, profile)
            page = conveyor_data(store, cid, waterfall=0)
            said = mon.summary()
            verdict = page.verdict.to_dict()  # the monitor says the report's verdict
            assert {k: said[k] for k in verdict} == verdict
            assert page.summary == {k: v for k, v in said.items() if k not in verdict}
            assert page.forecasts == mon.forecasts()
            assert page.baseline_since == mon.baseline_since
            assert page.trends  # drawn with the stored baselines' limits
            assert page.calibration is not None and mon.calibration is not None
            assert page.calibration.to_dict() == mon.calibration.to_dict()
        assert page.summary["open_alarms"]  # the faulty conveyor's alarm is on the page


def test_campbell_peaks_are_the_lines_standing_out_of_the_floor() -> None:
    # a floor of 1 mNm with lines of 20 and 5 mNm at 37 and 80 Hz and one barely above it
    f = np.arange(0.0, 250.0, 0.5)
    amp = np.full(f.shape, 1e-3)
    for hz, a in ((37.0, 0.02), (80.0, 0.005), (120.0, 0.003)):
        amp[int(hz / 0.5)] = a
    sp = Spectrum(f, amp, "frequency", 0.5, "torque", 1400.0)
    where, height = campbell_peaks(sp)
    assert list(where) == [37.0, 80.0] and list(height) == [0.02, 0.005]


def test_a_missing_tlf_or_payload_is_said_in_words_never_an_empty_chart(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    import math
    from datetime import UTC, datetime, timedelta

    from chaintwin.report import figures
    from chaintwin.report.data import ConveyorData

    prof = load_profile(EXAMPLES / "profiles" / f"{HEALTHY}.yaml")
    t0 = datetime(2026, 1, 5, tzinfo=UTC)

    def data(results: list[dict[str, object]]) -> ConveyorData:
        times: list[datetime | None] = [t0 + timedelta(hours=k) for k in range(len(results))]
        return ConveyorData(prof, results, times, [], [], {}, [], [], None, None)

    unweighed = data([{"payload_kg": None, "tlf": None}] * 3)
    assert math.isnan(unweighed.recent_tlf())
    assert unweighed.tlf_absence() == (
        "none of its 3 recordings could be weighed (each recording's warnings say why); "
        "a TLF needs a weighed payload"
    )
    light = data([{"payload_kg": 0.5, "tlf": None}])
    assert (light.tlf_absence() or "").startswith("its weighed payloads are under 1 kg")
    assert data([]).tlf_absence() == "no recording yet"
    assert (
        data([{"payload_kg": 20.0, "tlf": None}, {"payload_kg": 21.0, "tlf": 1.5}]).tlf_absence()
        is None
    )
    # an empty panel says why in words
    said: list[str] = []
    monkeypatch.setattr(figures, "_words", lambda ax, text: said.append(text))
    assert figures.payload_tlf_figure(light) is not None
    assert said == ["no TLF: it needs a weighed payload of at least 1 kg\nand belt travel"]
    said.clear()
    assert figures.payload_tlf_figure(data([{"payload_kg": 20.0, "tlf": 1.5}])) is not None
    assert said == []
    # the fleet's TLF bars: only conveyors with one, no figure when none has
    assert figures.fleet_tlf_figure(["a", "b"], [math.nan, math.nan]) is None
    assert figures.fleet_tlf_figure(["a", "b"], [1.2, math.nan]) is not None


def _trends_one_by_one(
    results: list[dict[str, Any]],
    baselines: dict[str, Any],
    z_limit: float,
    since: str | None,
    wear: dict[str, float],
) -> list[tuple[str, list[int], list[float], list[bool], list[bool]]]:
    """The trends worked out one result and one value at a time (the reference)."""
    from chaintwin.diagnose.baseline import regressor_of
    from chaintwin.diagnose.features import feature_spec
    from chaintwin.report.data import _at_mean_payload

    def number(x: Any) -> float:
        return float(x) if isinstance(x, (int, float)) else math.nan

    names: list[str] = []
    for r in results:
        names += [k for k in r["features"] if k not in names and feature_spec(k).cause]
    out = []
    for name in names:
        idx, vals, pays, exc, before = [], [], [], [], []
        fb = baselines.get(name)
        for k, r in enumerate(results):
            f = r["features"]
            if name not in f:
                continue
            v, used = number(f[name]), number(f.get("usage_since_baseline_t_km"))
            if name in wear and math.isfinite(used):
                v -= wear[name] * used
            reg = None if fb is None else regressor_of(name, fb)
            pays.append(number(f.get(reg)) if reg else math.nan)
            idx.append(k)
            vals.append(v)
            exc.append(name in (r.get("exceeded") or ()))
            at = r.get("recorded_at")
            before.append(bool(r.get("status") == "baseline" or (since and at and at < since)))
        if fb is not None:
            moved = _at_mean_payload(
                fb, np.array(vals), np.array(pays), z_limit, feature_spec(name)
            )
            vals = [float(v) for v in moved]
        if any(math.isfinite(v) for v in vals):
            out.append((name, idx, vals, exc, before))
    return out


def test_trends_built_by_columns_are_those_worked_out_value_by_value(plant_db: str) -> None:
    """The faulty conveyor's real results, some of their features then missing, null,
    text or a flag, and an expected wear taken off: the same series either way."""
    from chaintwin.diagnose.monitor_state import read_health
    from chaintwin.report.data import _trend_names, _trends, conveyor_data
    from chaintwin.store.store import Store

    with Store(plant_db) as store:
        results = [r for r in store.results(FAULTY) if "error" not in r]
        state = store.state(FAULTY)
        assert state is not None
        health = read_health(state, derived={"forecasts": [], "wear": []})
        # the page's way (names only) names the trends the reports build
        named = conveyor_data(store, FAULTY, waterfall=0, latest=False, trends=False)
        built = conveyor_data(store, FAULTY, waterfall=0, latest=False)
    assert named.trends == [] and named.feature_names == built.feature_names
    assert len(built.trends) > 5
    args = (health.baselines, health.z_limit, health.baseline_since)
    wear = {"friction": 0.02}
    edited = [dict(r, features=dict(r["features"])) for r in results]
    for k, r in enumerate(edited):
        f = r["features"]
        if k % 7 == 3:
            f.pop("friction")  # absent: no point
        if k % 5 == 1:
            f["speed_loss"] = None  # null: a point of unknown value
        if k % 11 == 2:
            f["usage_since_baseline_t_km"] = "n/a"  # not a number: no wear taken off
        if k == 4:
            f["crest_factor"] = True
    for rows in (results, edited):
        got = _trends(rows, *args, wear)
        want = _trends_one_by_one(rows, *args, wear)
        assert [(t.name, t.index, t.exceeded, t.before) for t in got] == [
            (n, i, e, b) for n, i, _v, e, b in want
        ]
        for t, (_n, _i, values, _e, _b) in zip(got, want, strict=True):
            np.testing.assert_array_equal(t.values, values)  # NaN where the reference has it
        assert _trend_names(rows, health.baselines, health.z_limit, wear) == [t.name for t in got]
    changed = {t.name: t for t in _trends(edited, *args, wear)}
    assert len(changed["friction"].index) < len(results)
    assert np.isnan(changed["speed_loss"].values[1])
