"""One verdict in every view: ``health``, ``ne107`` and their ``since`` times.

A property test drives random sequences of recordings (a conveyor whose rail
friction rises), acknowledgements, shelving, maintenance and out-of-service
windows through the web API on a real store, and after every step reads the
verdict from each view (the API's conveyor list and detail, the fleet page
and the conveyor page, the report's data, ``/metrics``): they agree, and
they say what the step did (maintenance: ``relearning`` at once, ...).
"""

from __future__ import annotations

import re
import shutil
import warnings
from collections.abc import Iterator
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
from conftest import REFERENCE_PROFILE
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st
from test_web import start_server

from chaintwin.calibrating.procedure import calibrate
from chaintwin.diagnose.records import MonitorSettings
from chaintwin.diagnose.verdict import HEALTH, NE107, NE107_OF, verdict
from chaintwin.ingest.pipeline import ingest
from chaintwin.live.metrics import Metrics
from chaintwin.read.profile import load_profile
from chaintwin.report.data import conveyor_data
from chaintwin.simulate.faults import Fault
from chaintwin.simulate.fleet import generate
from chaintwin.store.store import Store
from chaintwin.validate import load_recording
from chaintwin.web import create_app
from chaintwin.web.access import create_token

PROFILE = load_profile(REFERENCE_PROFILE)
CID = PROFILE.id
SETTINGS = MonitorSettings(baseline_n=10)
VERDICT = ("health", "health_since", "ne107", "ne107_since")


def test_every_health_has_its_ne107_category() -> None:
    assert set(NE107_OF) == set(HEALTH)
    assert set(NE107_OF.values()) == set(NE107)
    assert verdict(None).to_dict() == {
        "health": "no_data",
        "health_since": None,
        "ne107": "check_function",
        "ne107_since": None,
        "health_index": None,
        "deviation": None,
        "worst_feature": None,
    }


class Plant:
    """Template stores (calibrated, the baseline learned) and the recordings still to come."""

    def __init__(self, root: Path) -> None:
        folder = root / "recordings"
        generate(
            PROFILE, folder, days=6, per_day=5, faults=[Fault("friction", 0.8)], onset_day=2, seed=5
        )
        files = sorted(str(f) for f in folder.glob("*.csv"))
        cal = sorted((folder / "calibration").glob("*.csv"))
        calibration = calibrate(
            [load_recording(f, profile=PROFILE).recording for f in cal], PROFILE
        )
        # two starts: the friction on its way up (baseline of 10 and 5 more), an alarm open
        self.templates: list[tuple[Path, list[str]]] = []
        db = root / "rising.db"
        store = Store(f"sqlite:///{db}")
        store.put_calibration(calibration)
        ingest(files[:15], {CID: PROFILE}, store, settings=SETTINGS, workers=1)
        self.tokens = {r: create_token(store, f"{r}-1", r) for r in ("viewer", "maintainer")}
        store.close()
        self.templates.append((db, files[15:]))
        alarmed = root / "alarmed.db"
        shutil.copy(db, alarmed)
        store = Store(f"sqlite:///{alarmed}")
        ingest(files[15:21], {CID: PROFILE}, store, settings=SETTINGS, workers=1)
        assert [a for a in store.alarms(CID) if a.is_open], "no alarm open after 21 recordings"
        store.close()
        self.templates.append((alarmed, files[21:]))


@pytest.fixture(scope="module")
def plant(tmp_path_factory: pytest.TempPathFactory) -> Plant:
    return Plant(tmp_path_factory.mktemp("verdict"))


class Views:
    """A copy of the template store served by the app; every view's verdict of the conveyor."""

    def __init__(self, plant: Plant, folder: Path, start: int) -> None:
        db = folder / "plant.db"
        shutil.copy(plant.templates[start][0], db)
        self.store = Store(f"sqlite:///{db}")
        self.app = create_app(self.store, {CID: PROFILE})
        self.base, self.server, self.thread = start_server(self.app)
        self.client = httpx.Client(base_url=self.base, timeout=60)
        self.viewer = {"Authorization": f"Bearer {plant.tokens['viewer']}"}
        self.maintainer = {"Authorization": f"Bearer {plant.tokens['maintainer']}"}
        answer = self.client.post(
            "/login", data={"token": plant.tokens["viewer"]}, follow_redirects=False
        )
        assert answer.status_code == 303, answer.text
        self.metrics = Metrics(self.store, lambda: 0.0)

    def close(self) -> None:
        self.client.close()
        self.server.should_exit = True
        self.thread.join(10)
        self.store.close()

    def post(self, path: str, body: dict[str, Any] | None = None) -> Any:
        answer = self.client.post(f"/api/v1{path}", json=body, headers=self.maintainer)
        assert answer.status_code == 200, answer.text
        return answer.json()

    def get(self, path: str) -> Any:
        answer = self.client.get(f"/api/v1{path}", headers=self.viewer)
        assert answer.status_code == 200, answer.text
        return answer.json()

    def all(self) -> dict[str, dict[str, Any]]:
        """The verdict as each view gives it."""
        (row,) = self.get("/conveyors")
        detail = self.get(f"/conveyors/{CID}")
        fleet = self.client.get("/").text
        page = self.client.get(f"/conveyors/{CID}").text
        report = conveyor_data(self.store, CID, waterfall=0).verdict.to_dict()
        metrics = self.metrics.text().decode()
        found = re.search(
            rf'chaintwin_conveyor_health{{conveyor="{CID}",health="(\w+)",ne107="(\w+)"}} 1\.0',
            metrics,
        )
        assert found is not None, metrics
        fleet_cell = re.search(r'<td class="health">(\w+)</td>', fleet)
        page_cells = re.search(
            r'<strong class="health">(\w+)</strong>.*?<strong class="ne107">(\w+)</strong>',
            page,
            re.S,
        )
        assert fleet_cell is not None and page_cells is not None
        return {
            "api list": {k: row[k] for k in (*VERDICT, "health_index")},
            "api detail": {k: detail[k] for k in (*VERDICT, "health_index")},
            "report": {k: report[k] for k in (*VERDICT, "health_index")},
            "metrics": {"health": found[1], "ne107": found[2]},
            "fleet page": {"health": fleet_cell[1]},
            "conveyor page": {"health": page_cells[1], "ne107": page_cells[2]},
            "status": {"list": row["status"], "detail": detail["status"]},
        }


@pytest.fixture
def views(plant: Plant, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Any]:
    made: list[Views] = []

    def make(start: int) -> Views:
        v = Views(plant, tmp_path_factory.mktemp("views"), start)
        made.append(v)
        return v

    yield make
    for v in made:
        v.close()


STEPS = st.lists(
    st.sampled_from(
        [
            "record",
            "record",
            "record",
            "record",
            "record",
            "acknowledge",
            "shelve",
            "unshelve",
            "maintenance",
            "out_of_service",
            "back_in_service",
        ]
    ),
    min_size=1,
    max_size=16,
)


@settings(
    max_examples=25,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
@pytest.mark.slow
@given(start=st.sampled_from([0, 1]), steps=STEPS)
def test_every_view_gives_the_same_verdict_at_every_step(
    plant: Plant, views: Any, start: int, steps: list[str]
) -> None:
    v: Views = views(start)
    rest = list(plant.templates[start][1])
    out_of_service = False
    for step in ["start", *steps]:
        did = _do(v, step, rest, out_of_service)
        if did == "skip":
            continue
        if step == "out_of_service":
            out_of_service = True
        elif step == "back_in_service":
            out_of_service = False
        seen = _check_agreement(v.all(), step)
        health = seen["health"]
        event(f"{step} -> {health}")
        # what the step did, as the alarms and the model say it
        lifecycles = [a["lifecycle"] for a in v.get("/alarms?state=open") if a["conveyor"] == CID]
        if out_of_service:
            assert health == "out_of_service", (step, seen)
        elif {"unacknowledged", "returned_unacknowledged"} & set(lifecycles):
            assert health == "alarm", (step, seen, lifecycles)
        elif "acknowledged" in lifecycles:
            assert health == "acknowledged", (step, seen, lifecycles)
        elif step == "maintenance":  # at once, not at the next recording
            assert health == "relearning" and seen["ne107"] == "check_function", seen
            assert seen["health_since"] == did
        elif "shelved" in lifecycles and health not in ("relearning",):
            assert health == "shelved", (step, seen, lifecycles)
        else:
            assert health in ("ok", "watch", "relearning"), (step, seen, lifecycles)
        if health in ("ok", "watch"):
            assert (seen["health_index"] >= 0.7) == (health == "watch"), seen
        if health in ("relearning", "out_of_service"):
            assert seen["health_index"] is None, seen  # no stale deviation beside the verdict
        assert seen["ne107"] == NE107_OF[health]


def test_the_rolling_median_of_the_deviations_is_numpys_nanmedian() -> None:
    from chaintwin.diagnose.verdict import _nanmedian_rows

    rng = np.random.default_rng(1)
    windows = rng.normal(size=(500, 10))
    windows[rng.random(windows.shape) < 0.3] = np.nan
    windows[5] = np.nan
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # the all-NaN row
        expected = np.nanmedian(windows, axis=1)
    np.testing.assert_array_equal(_nanmedian_rows(windows), expected)
    assert _nanmedian_rows(np.array([[1.0, np.nan, 3.0, 10.0]]))[0] == 3.0


def _check_agreement(found: dict[str, dict[str, Any]], step: str) -> dict[str, Any]:
    status = found.pop("status")
    assert status["list"] == status["detail"] is not None, (step, status)  # the latest result's
    reference = found["api list"]
    for view, said in found.items():
        assert said == {k: reference[k] for k in said}, (step, view, said, reference)
    return reference


def _do(v: Views, step: str, rest: list[str], out_of_service: bool) -> str | None:
    """Carry out a step through the API; ``skip`` when it cannot be done now."""
    open_alarms = [a for a in v.get("/alarms?state=open") if a["conveyor"] == CID]
    if step == "start":
        return None
    if step == "record":
        if not rest:
            return "skip"
        ingest([rest.pop(0)], {CID: PROFILE}, v.store, settings=SETTINGS, workers=1)
        return None
    if step == "acknowledge":
        todo = [a for a in open_alarms if a["acknowledged"] is None]
        if not todo:
            return "skip"
        v.post(f"/alarms/{todo[0]['id']}/acknowledge", {"why": "seen"})
        return None
    if step == "shelve":
        todo = [a for a in open_alarms if a["lifecycle"] != "shelved"]
        if not todo or out_of_service:
            return "skip"
        v.post(f"/alarms/{todo[0]['id']}/shelve", {"why": "known", "minutes": 600})
        return None
    if step == "unshelve":
        todo = [a for a in open_alarms if a["lifecycle"] == "shelved"]
        if not todo:
            return "skip"
        v.post(f"/alarms/{todo[0]['id']}/unshelve")
        return None
    if step == "maintenance":
        if out_of_service:
            return "skip"
        last = v.get(f"/conveyors/{CID}/recordings?limit=1")["items"][0]["recorded_at"]
        at = (datetime.fromisoformat(last) + timedelta(minutes=1)).astimezone(UTC)
        event = v.post(
            f"/conveyors/{CID}/maintenance",
            {"kind": "repair", "why": "fixed", "at": at.isoformat()},
        )
        return str(event["at"])
    if step == "out_of_service":
        if out_of_service:
            return "skip"
        v.post(f"/conveyors/{CID}/out-of-service", {"why": "rebuilt"})
        return None
    if step == "back_in_service":
        if not out_of_service:
            return "skip"
        answer = v.client.delete(f"/api/v1/conveyors/{CID}/out-of-service", headers=v.maintainer)
        assert answer.status_code == 200, answer.text
        return None
    raise AssertionError(step)
