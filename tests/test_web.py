"""The web service over HTTP: a real uvicorn server on a real store (SQLite and PostgreSQL).

The store holds a conveyor whose rail friction rises from its third day, so
that an alarm is open for the dashboard to show and a maintainer to
acknowledge.
"""

from __future__ import annotations

import itertools
import json
import re
import socket
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any
from urllib.parse import quote

import httpx
import pytest
import uvicorn
from conftest import REFERENCE_PROFILE

from chaintwin.calibrating.procedure import calibrate
from chaintwin.cli.app import main
from chaintwin.diagnose.records import MonitorSettings
from chaintwin.ingest.pipeline import ingest
from chaintwin.read.profile import load_profile
from chaintwin.read.writer import write_recording
from chaintwin.simulate.faults import Fault
from chaintwin.simulate.fleet import generate
from chaintwin.simulate.virtual import run_virtual
from chaintwin.store import migrate
from chaintwin.store.store import Store
from chaintwin.validate import load_recording
from chaintwin.web import create_app
from chaintwin.web.access import create_token

PROFILE = load_profile(REFERENCE_PROFILE)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Recordings of one conveyor, friction rising from day 2, and its calibration runs."""
    folder = tmp_path_factory.mktemp("fleet")
    generate(
        PROFILE, folder, days=6, per_day=5, faults=[Fault("friction", 0.8)], onset_day=2, seed=5
    )
    return folder


def start_server(app: Any) -> tuple[str, uvicorn.Server, threading.Thread]:
    """Serve ``app`` with uvicorn in a thread on a free port; its base URL."""
    port = _free_port()
    server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + 20
    while not server.started:
        assert time.monotonic() < deadline, "the server did not start"
        time.sleep(0.02)
    return f"http://127.0.0.1:{port}", server, thread


class Served:
    """A store served by uvicorn in a thread, with a token per role."""

    def __init__(self, url: str, fleet: Path) -> None:
        self.url = url
        self.clients: list[httpx.Client] = []
        self.store = Store(url)
        cal_files = sorted((fleet / "calibration").glob("*.csv"))
        recs = [load_recording(f, profile=PROFILE).recording for f in cal_files]
        self.store.put_calibration(calibrate(recs, PROFILE))
        files = sorted(str(f) for f in fleet.glob("*.csv"))
        ingest(
            files, {PROFILE.id: PROFILE}, self.store, settings=MonitorSettings(baseline_n=10),
            workers=1,
        )  # fmt: skip
        self.tokens = {
            role: create_token(self.store, f"{role}-1", role)
            for role in ("viewer", "maintainer", "admin")
        }
        self.app = create_app(self.store, {PROFILE.id: PROFILE})
        self.base, self.server, self.thread = start_server(self.app)

    def client(self, role: str | None = None) -> httpx.Client:
        """A client with the role's token (closed with the server)."""
        headers = {} if role is None else {"Authorization": f"Bearer {self.tokens[role]}"}
        client = httpx.Client(base_url=self.base, headers=headers, timeout=30)
        self.clients.append(client)
        return client

    def close(self) -> None:
        for client in self.clients:
            client.close()
        self.server.should_exit = True
        self.thread.join(10)
        self.store.close()


@pytest.fixture(scope="module", params=["sqlite", "postgresql"])
def served(
    request: pytest.FixtureRequest, fleet: Path, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[Served]:
    if request.param == "sqlite":
        url = f"sqlite:///{tmp_path_factory.mktemp('web') / 'plant.db'}"
    else:
        import os

        import psycopg

        base: str = request.getfixturevalue("postgres")
        name = f"web{os.getpid()}_{int(time.time() * 1e6) % 10**9}"
        with psycopg.connect(base, autocommit=True) as c:
            c.execute(f"CREATE DATABASE {name}")
        url = base.rsplit("/", 1)[0] + "/" + name
    s = Served(url, fleet)
    yield s
    s.close()


def log_in(page: Any, served: Served, role: str) -> None:
    """Log the browser page in through the login form with the role's token."""
    page.goto(served.base + "/login")
    page.fill("#token", served.tokens[role])
    page.click("form.login button")
    page.wait_for_url(served.base + "/")


def expect_connected(page: Any, timeout_s: float = 30.0) -> None:
    """Wait until the page's event stream is open (``window.chaintwin.connected``)."""
    deadline = time.monotonic() + timeout_s
    while not page.evaluate("window.chaintwin.connected === true"):
        assert time.monotonic() < deadline, f"{page.url}: its event stream did not open"
        page.wait_for_timeout(50)


def _error(response: httpx.Response, status: int, code: str) -> str:
    assert response.status_code == status, response.text
    body = response.json()
    assert set(body) == {"error"} and set(body["error"]) == {"code", "message"}
    assert body["error"]["code"] == code
    message: str = body["error"]["message"]
    return message


@pytest.mark.slow
def test_reading_the_api_needs_a_token_and_pages_through_results(served: Served) -> None:
    anon = served.client()
    health = anon.get("/api/v1/health").json()
    assert health["status"] == "ok" and health["store"]["conveyors"] == 1
    assert health["store"]["revision"] == migrate.HEAD_REVISION
    _error(anon.get("/api/v1/store"), 401, "unauthorized")
    _error(anon.get("/api/v1/conveyors"), 401, "unauthorized")
    with httpx.Client(base_url=served.base, headers={"Authorization": "Bearer ct_nope"}) as bad:
        _error(bad.get("/api/v1/conveyors"), 401, "unauthorized")

    viewer = served.client("viewer")
    assert viewer.get("/api/v1/store").json()["results"] == 30
    (row,) = viewer.get("/api/v1/conveyors").json()
    assert row["id"] == PROFILE.id
    assert row["health"] == "alarm" and row["open_alarms"][0]["cause"] == "friction"
    assert row["ne107"] == "failure"
    assert row["health_since"] == min(a["since"] for a in row["open_alarms"])
    assert row["last_recorded_at"] and row["payload_kg"] is not None
    detail = viewer.get(f"/api/v1/conveyors/{PROFILE.id}").json()
    assert detail["calibration"]["case"] == "several_loads"
    notes = detail["calibration"]["warnings"]
    assert isinstance(notes, list) and all(set(w) == {"code", "message"} for w in notes)
    assert "friction" in detail["features"] and detail["recordings"] == 30
    # the health index: the largest feature deviation, at least 1 with the alarm open
    assert row["worst_feature"] == "friction" and row["deviation"] > 1.0
    assert row["health_index"] == pytest.approx(max(1.0, row["deviation"]))
    assert detail["deviation"] == pytest.approx(row["deviation"], rel=1e-9)
    assert detail["health_index"] == pytest.approx(row["health_index"], rel=1e-9)
    # the verdict is the same in both; status is the latest result's in both
    verdict = ("health", "health_since", "ne107", "ne107_since", "worst_feature")
    assert {k: detail[k] for k in verdict} == {k: row[k] for k in verdict}
    assert detail["status"] == row["status"] == "monitored"
    _error(viewer.get("/api/v1/conveyors/nope"), 404, "not_found")

    # cursor pagination, newest first, every result once
    seen: list[dict[str, Any]] = []
    cursor = None
    while True:
        params: dict[str, Any] = {"limit": 7} | ({"cursor": cursor} if cursor else {})
        page = viewer.get(f"/api/v1/conveyors/{PROFILE.id}/recordings", params=params).json()
        seen += page["items"]
        cursor = page["next_cursor"]
        if cursor is None:
            break
    times = [r["recorded_at"] for r in seen]
    assert len(seen) == 30 and times == sorted(times, reverse=True)
    assert len({r["recording_id"] for r in seen}) == 30
    assert all(r["stored_at"] for r in seen)
    since = times[9]
    recent = viewer.get(
        f"/api/v1/conveyors/{PROFILE.id}/recordings", params={"since": since}
    ).json()
    assert [r["recorded_at"] for r in recent["items"]] == times[:10]
    _error(
        viewer.get(f"/api/v1/conveyors/{PROFILE.id}/recordings", params={"cursor": "!!"}),
        400,
        "bad_request",
    )

    trend = viewer.get(
        f"/api/v1/conveyors/{PROFILE.id}/trends", params={"feature": "friction"}
    ).json()
    assert len(trend["points"]) == 30 and trend["limit"] > trend["expected"]
    assert trend["alarms"] and any(p["exceeded"] for p in trend["points"])
    _error(
        viewer.get(f"/api/v1/conveyors/{PROFILE.id}/trends", params={"feature": "x"}),
        404,
        "not_found",
    )

    rec = viewer.get(f"/api/v1/recordings/{seen[0]['recording_id']}").json()
    series = rec["series"]
    assert 0 < len(series["time_s"]) <= 1000
    assert len(series["model_torque_nm"]) == len(series["torque_nm"]) == len(series["time_s"])
    assert rec["result"]["recording_id"] == seen[0]["recording_id"]

    opened = viewer.get("/api/v1/alarms", params={"state": "open"}).json()
    assert opened and all(a["status"] == "open" for a in opened)
    assert viewer.get("/api/v1/alarms", params={"state": "closed"}).json() == []

    schema = anon.get("/openapi.json").json()
    assert "/api/v1/conveyors/{conveyor_id}/recordings" in schema["paths"]
    docs = anon.get("/docs").text
    assert re.findall(r'(?:src|href)="(https?:)', docs) == []  # nothing from the network
    assert anon.get("/static/plotly/plotly.min.js").status_code == 200


def test_changes_need_their_role_and_are_audited(served: Served, fleet: Path) -> None:
    viewer, maintainer, admin = (served.client(r) for r in ("viewer", "maintainer", "admin"))
    alarm = viewer.get("/api/v1/alarms", params={"state": "open"}).json()[0]
    path = f"/api/v1/alarms/{alarm['id']}/acknowledge"
    _error(viewer.post(path, json={"why": "seen"}), 403, "forbidden")
    _error(maintainer.post(path, json={}), 422, "invalid")
    done = maintainer.post(path, json={"why": "rails to be cleaned on Friday"}).json()
    assert done["acknowledged"]["by"] == "maintainer-1"
    _error(maintainer.post(path, json={"why": "again"}), 400, "bad_request")
    acked = viewer.get("/api/v1/alarms", params={"acknowledged": "true"}).json()
    assert [a["id"] for a in acked] == [alarm["id"]]

    # uploads: a new recording, one already stored, one refused
    new = run_virtual(PROFILE, payload_kg=20.0, seed=99).recording
    new_file = write_recording(new, fleet.parent / "new.csv")
    old_file = sorted(fleet.glob("*.csv"))[0]
    files = [
        ("files", ("new.csv", new_file.read_bytes(), "text/csv")),
        ("files", (old_file.name, old_file.read_bytes(), "text/csv")),
        ("files", ("<b>bad</b>.csv", b"not a recording\n", "text/csv")),
    ]
    _error(viewer.post("/api/v1/recordings", files=files), 403, "forbidden")
    out = maintainer.post("/api/v1/recordings", files=files).json()["files"]
    assert [f["status"] for f in out] == ["stored", "already_stored", "refused"]
    assert out[0]["recording_id"] and len(out[0]["recording_id"]) == 64
    assert out[2]["reason"] and "<b>bad</b>.csv" in out[2]["reason"]
    again = maintainer.post("/api/v1/recordings", files=files[:1]).json()["files"]
    assert again[0]["status"] == "already_stored"
    _error(maintainer.post("/api/v1/recordings", data={"x": "1"}), 422, "invalid")
    assert viewer.get("/api/v1/store").json()["results"] == 31

    # maintenance restarts the baseline and closes the alarm
    when = "2027-01-01T00:00:00+00:00"
    body = {"kind": "cleaning", "why": "rails cleaned", "at": when}
    _error(viewer.post(f"/api/v1/conveyors/{PROFILE.id}/maintenance", json=body), 403, "forbidden")
    event = maintainer.post(f"/api/v1/conveyors/{PROFILE.id}/maintenance", json=body).json()
    assert event["kind"] == "cleaning" and event["by"] == "maintainer-1"
    assert viewer.get("/api/v1/alarms", params={"state": "open"}).json() == []

    # tokens and the audit log: admins only; no token appears in clear
    _error(maintainer.get("/api/v1/audit"), 403, "forbidden")
    log = admin.get("/api/v1/audit").json()
    assert {"acknowledge", "upload", "maintenance"} <= {e["action"] for e in log}
    made = admin.post("/api/v1/tokens", json={"name": "screen", "role": "viewer"}).json()
    assert made["token"].startswith("ct_")
    _error(admin.post("/api/v1/tokens", json={"name": "screen", "role": "viewer"}), 409, "conflict")
    with httpx.Client(
        base_url=served.base, headers={"Authorization": f"Bearer {made['token']}"}
    ) as screen:
        assert screen.get("/api/v1/conveyors").status_code == 200
        admin.post("/api/v1/tokens/screen/revoke")
        _error(screen.get("/api/v1/conveyors"), 401, "unauthorized")
    listed = json.dumps(admin.get("/api/v1/tokens").json())
    assert "ct_" not in listed
    if served.url.startswith("sqlite:///"):
        raw = Path(served.url.removeprefix("sqlite:///")).read_bytes()
        for token in [*served.tokens.values(), made["token"]]:
            assert token.encode() not in raw


def test_too_large_an_upload_is_refused_with_413(served: Served) -> None:
    base, server, thread = start_server(create_app(served.store, max_upload_mb=0.001))
    headers = {"Authorization": f"Bearer {served.tokens['maintainer']}"}
    try:
        with httpx.Client(base_url=base, headers=headers, timeout=30) as c:
            big = [("files", ("big.csv", b"x" * 5000, "text/csv"))]
            _error(c.post("/api/v1/recordings", files=big), 413, "too_large")
            assert c.get("/api/v1/store").json()["results"] >= 30  # nothing lost
    finally:
        server.should_exit = True
        thread.join(10)


def _csrf(page: str) -> str:
    found = re.search(r'name="csrf-token" content="([^"]+)"', page)
    assert found is not None
    return found.group(1)


def test_the_browser_logs_in_with_a_cookie_and_every_change_carries_csrf(
    served: Served,
) -> None:
    if not served.url.startswith("sqlite"):
        pytest.skip("the pages read the same store whichever database holds it")
    with httpx.Client(base_url=served.base, timeout=30) as browser:
        first = browser.get("/")
        assert first.status_code == 303 and first.headers["location"] == "/login"
        refused = browser.post("/login", data={"token": "ct_wrong"})
        assert refused.status_code == 401 and "unknown, revoked or expired" in refused.text
        ok = browser.post("/login", data={"token": served.tokens["maintainer"]})
        assert ok.status_code == 303
        cookie = ok.headers["set-cookie"].lower()
        assert "httponly" in cookie and "samesite=strict" in cookie
        fleet_page = browser.get("/")
        assert fleet_page.status_code == 200 and PROFILE.id in fleet_page.text
        assert "/static/plotly/plotly.min.js" in fleet_page.text
        page = browser.get(f"/conveyors/{PROFILE.id}")
        assert page.status_code == 200 and 'id="trends"' in page.text
        csrf = _csrf(page.text)
        # the pages' own API calls use the cookie; a change without the CSRF header is refused
        assert browser.get("/api/v1/conveyors").status_code == 200
        body = {"kind": "other", "why": "look"}
        _error(browser.post(f"/api/v1/conveyors/{PROFILE.id}/maintenance", json=body), 403, "csrf")
        # a form posted without its CSRF token is refused, with it accepted
        form = {"kind": "other", "why": "<script>alert(1)</script>"}
        no_csrf = browser.post(f"/conveyors/{PROFILE.id}/maintenance", data=form)
        assert no_csrf.status_code == 403
        done = browser.post(f"/conveyors/{PROFILE.id}/maintenance", data=form | {"csrf": csrf})
        assert done.status_code == 303
        alarms_page = browser.get("/alarms").text
        assert "<script>alert(1)</script>" not in alarms_page
        upload_page = browser.get("/upload")
        assert upload_page.status_code == 200
        out = browser.post("/logout", data={"csrf": csrf})
        assert out.status_code == 303
        assert browser.get("/").status_code == 303
    # a viewer sees no upload page
    with httpx.Client(base_url=served.base, timeout=30) as viewer:
        viewer.post("/login", data={"token": served.tokens["viewer"]})
        assert viewer.get("/upload").status_code == 403
        assert viewer.get("/audit").status_code == 403


def test_ids_and_comments_are_shown_escaped(served: Served) -> None:
    if not served.url.startswith("sqlite"):
        pytest.skip("escaping does not depend on the database")
    evil = PROFILE.model_copy(update={"id": '<img src=x onerror="alert(1)">&'})
    served.store.put_profile(evil)
    with httpx.Client(base_url=served.base, timeout=30) as browser:
        browser.post("/login", data={"token": served.tokens["admin"]})
        fleet_page = browser.get("/").text
        assert '<img src=x onerror="alert(1)">' not in fleet_page
        assert "&lt;img src=x onerror=&#34;alert(1)&#34;&gt;&amp;" in fleet_page
        audit_page = browser.get("/audit")
        assert audit_page.status_code == 200 and "<script>" not in audit_page.text
    # the calibration's warnings are shown on the conveyor's page, escaped
    import dataclasses

    from chaintwin.read.recording import RecordingWarning

    cal = served.store.calibration(PROFILE.id)
    assert cal is not None
    note = RecordingWarning("friction_unchecked", "<script>alert(2)</script> 28.0 kg per 10 %")
    served.store.put_calibration(dataclasses.replace(cal, profile=evil, warnings=(note,)))
    with httpx.Client(base_url=served.base, timeout=30) as browser:
        browser.post("/login", data={"token": served.tokens["viewer"]})
        page = browser.get("/conveyors/" + quote(evil.id, safe=""))
        assert page.status_code == 200
        assert "calibration: friction_unchecked: &lt;script&gt;alert(2)" in page.text
        assert "<script>alert(2)" not in page.text


def test_results_without_a_time_come_last_and_page_through(served: Served) -> None:
    from sqlalchemy import select, update
    from sqlalchemy.orm import Session

    from chaintwin.store.queries import results_page
    from chaintwin.store.schema import ResultRow

    with Session(served.store.engine) as s, s.begin():
        ids = list(s.scalars(select(ResultRow.id).order_by(ResultRow.id).limit(3)))
        s.execute(update(ResultRow).where(ResultRow.id.in_(ids)).values(recorded_at=None))
    seen = []
    cursor = None
    while True:
        page = results_page(served.store, PROFILE.id, limit=4, cursor=cursor)
        seen += page.items
        if page.next_cursor is None:
            break
        cursor = page.next_cursor
    total = served.store.counts()["results"]
    assert len(seen) == total and len({r["recording_id"] for r in seen}) == total
    times = [r["recorded_at"] for r in seen if r["recorded_at"] is not None]
    # the untimed ones (their stored result keeps its time: the row's column is what sorts)
    assert times == sorted(times, reverse=True)
    with Session(served.store.engine) as s:
        untimed = len(list(s.scalars(select(ResultRow.id).where(ResultRow.recorded_at.is_(None)))))
    assert untimed >= 3
    dated = results_page(served.store, PROFILE.id, since="2000-01-01", limit=1000).items
    assert len(dated) == total - untimed


def _sse(lines: Iterator[str]) -> Iterator[tuple[str, dict[str, Any]]]:
    """Events (name, data) from a server-sent event stream's lines (comments skipped)."""
    name, data = "message", ""
    for line in lines:
        if line.startswith("event: "):
            name = line.removeprefix("event: ")
        elif line.startswith("data: "):
            data = line.removeprefix("data: ")
        elif line == "" and data:
            yield name, json.loads(data)
            name, data = "message", ""


def test_the_event_stream_tells_of_stored_results_and_alarm_changes(
    served: Served, fleet: Path, tmp_path: Path
) -> None:
    anon = served.client()
    _error(anon.get("/api/v1/events"), 401, "unauthorized")
    viewer, maintainer = served.client("viewer"), served.client("maintainer")
    new = run_virtual(PROFILE, payload_kg=31.0, seed=123).recording
    new_file = write_recording(new, tmp_path / "late.csv")
    with viewer.stream("GET", "/api/v1/events") as stream:
        assert stream.status_code == 200
        assert stream.headers["content-type"].startswith("text/event-stream")
        events = _sse(stream.iter_lines())
        name, ready = next(events)
        assert name == "ready" and ready["changed"] == []
        # a second listener shares the one poll of the store
        with viewer.stream("GET", "/api/v1/events") as other:
            others = _sse(other.iter_lines())  # kept: a closed iterator closes the stream
            assert next(others)[0] == "ready"
            feed = served.app.state.web.extra["feed"]
            assert feed.listeners == 2
            poller, polls = feed._task, feed.polls
            deadline = time.monotonic() + 30
            while feed.polls - polls < 2:  # two rounds of the poll while both listen
                assert time.monotonic() < deadline, "the feed did not poll the store"
                time.sleep(0.02)
            assert feed._task is poller  # one poll of the store for both listeners
        files = [("files", ("late.csv", new_file.read_bytes(), "text/csv"))]
        stored = maintainer.post("/api/v1/recordings", files=files).json()["files"]
        assert stored[0]["status"] == "stored"
        name, update = next(events)
        assert name == "update" and "results" in update["changed"]
        assert update["results"] > ready["results"] and update["id"] != ready["id"]
        body = {"kind": "other", "why": "checked after the late recording"}
        assert maintainer.post(f"/api/v1/conveyors/{PROFILE.id}/maintenance", json=body).is_success
        name, changed = next(events)
        assert name == "update" and changed["changed"] == ["alarms"]
        assert changed["results"] == update["results"]
    # a browser reconnecting with the last id it saw is told at once what it missed
    with viewer.stream("GET", "/api/v1/events", headers={"Last-Event-ID": ready["id"]}) as again:
        name, missed = next(_sse(again.iter_lines()))
        assert name == "update" and missed["id"] == changed["id"]
        assert set(missed["changed"]) == {"results", "alarms"}
    # the session cookie opens the stream too
    with httpx.Client(base_url=served.base, timeout=30) as browser:
        browser.post("/login", data={"token": served.tokens["viewer"]})
        with browser.stream("GET", "/api/v1/events") as stream:
            assert stream.status_code == 200
            assert next(_sse(stream.iter_lines()))[0] == "ready"


def test_the_fleet_answers_304_until_the_store_changes(served: Served, tmp_path: Path) -> None:
    viewer, maintainer = served.client("viewer"), served.client("maintainer")
    first = viewer.get("/api/v1/conveyors")
    etag = first.headers["etag"]
    assert first.status_code == 200 and etag.startswith('W/"')
    assert first.headers["cache-control"] == "no-cache"
    again = viewer.get("/api/v1/conveyors", headers={"If-None-Match": etag})
    assert again.status_code == 304 and again.content == b"" and again.headers["etag"] == etag
    assert viewer.get("/api/v1/conveyors", headers={"If-None-Match": "*"}).status_code == 304
    other = viewer.get("/api/v1/conveyors", headers={"If-None-Match": 'W/"0.0.0.0"'})
    assert other.status_code == 200 and other.json() == first.json()
    # no token: 401 whatever the tag
    _error(
        served.client().get("/api/v1/conveyors", headers={"If-None-Match": etag}),
        401,
        "unauthorized",
    )
    # a stored result changes the tag and the rows
    new = run_virtual(PROFILE, payload_kg=12.0, seed=777).recording
    files = [
        ("files", ("etag.csv", write_recording(new, tmp_path / "e.csv").read_bytes(), "text/csv"))
    ]
    assert (
        maintainer.post("/api/v1/recordings", files=files).json()["files"][0]["status"] == "stored"
    )
    changed = viewer.get("/api/v1/conveyors", headers={"If-None-Match": etag})
    assert changed.status_code == 200 and changed.headers["etag"] != etag
    assert changed.json() != first.json()  # the new latest result
    # so does a maintenance event (the health model's version)
    etag = changed.headers["etag"]
    body = {"kind": "other", "why": "etag"}
    assert maintainer.post(f"/api/v1/conveyors/{PROFILE.id}/maintenance", json=body).is_success
    after = viewer.get("/api/v1/conveyors", headers={"If-None-Match": etag})
    assert after.status_code == 200 and after.headers["etag"] != etag


@pytest.fixture(scope="module")
def rising(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Served]:
    """A conveyor whose friction rises slowly from day 2: forecast, not yet in alarm.

    A drawing (seed) in which the rise is significant by the last recording: in some
    (seed 5 since the set point carries its noise) the forecaster does not yet see one."""
    folder = tmp_path_factory.mktemp("rising")
    generate(
        PROFILE, folder, days=6, per_day=5, faults=[Fault("friction", 0.04)], onset_day=2, seed=9
    )
    s = Served(f"sqlite:///{tmp_path_factory.mktemp('rising-db') / 'plant.db'}", folder)
    yield s
    s.close()


def test_trends_carry_the_monitors_forecast_with_its_band(rising: Served) -> None:
    viewer = rising.client("viewer")
    base = f"/api/v1/conveyors/{PROFILE.id}"
    detail = viewer.get(base).json()
    (forecast,) = [f for f in detail["forecasts"] if f["feature"] == "friction"]
    assert forecast["crossed"] is False
    trend = viewer.get(f"{base}/trends", params={"feature": "friction"}).json()
    # the existing fields stay; the forecast is the monitor's, with its band beside it
    assert {"points", "expected", "limit", "alarms", "unit", "cause"} <= set(trend)
    got = trend["forecast"]
    band = got.pop("band")
    assert got == forecast
    assert got["limit"] == pytest.approx(trend["limit"])
    assert 0.0 < trend["health_index"] < 1.0  # rising, not at the limit yet
    assert band["level"] == pytest.approx(0.9) and 2 < len(band["at"]) <= 120
    lo, mid, hi = band["lower"], band["mean"], band["upper"]
    assert all(a <= b <= c for a, b, c in zip(lo, mid, hi, strict=True))
    assert band["at"][0] >= trend["points"][-1]["recorded_at"][:10]
    assert band["at"][0] <= forecast["earliest"] <= forecast["crosses_at"] <= band["at"][-1]
    assert max(hi) >= got["limit"] > mid[0]
    other = viewer.get(f"{base}/trends", params={"feature": "speed_loss"}).json()
    assert other["forecast"] is None
    # no alarm: the fleet's health index is the worst feature's deviation, below 1
    (row,) = viewer.get("/api/v1/conveyors").json()
    assert row["open_alarms"] == [] and row["health"] == (
        "watch" if row["health_index"] >= 0.7 else "ok"
    )
    assert row["ne107"] == ("maintenance_required" if row["health"] == "watch" else "normal")
    assert row["health_index"] == row["deviation"] == pytest.approx(detail["deviation"])
    worst = viewer.get(f"{base}/trends", params={"feature": row["worst_feature"]}).json()
    assert worst["health_index"] == pytest.approx(row["health_index"], rel=1e-9)
    assert 0.3 < row["health_index"] < 1.0  # friction on its way up


def test_the_spectrum_waterfall_of_the_latest_recordings(served: Served) -> None:
    viewer = served.client("viewer")
    base = f"/api/v1/conveyors/{PROFILE.id}"
    w = viewer.get(f"{base}/waterfall", params={"recordings": 5}).json()
    assert w["kind"] == "order" and len(w["x"]) == 400
    assert len(w["recordings"]) + len(w["left_out"]) == 5 and w["recordings"]
    # the latest recordings monitored, oldest first (the page draws the newest on top)
    names = [name for _rid, name, _at in served.store.recording_index(PROFILE.id)[-5:]]
    assert [r["file"] for r in w["recordings"]] == [n for n in names if n not in w["left_out"]]
    assert all(len(r["recording_id"]) == 64 for r in w["recordings"])
    rows = w["amplitude_nm"]
    assert len(rows) == len(w["recordings"]) and all(len(r) == 400 for r in rows)
    values = [a for r in rows for a in r if a is not None]
    assert values and min(values) >= 0.0 and max(values) > 0.0
    assert w["lines"] and all(0.0 < x < w["x"][-1] + 1.0 for x in w["lines"].values())
    # downsampled by the largest amplitude per bin: the highest line keeps its height
    from chaintwin.diagnose.spectra import order_spectrum
    from chaintwin.store.queries import recording_by_hash

    found = recording_by_hash(served.store, w["recordings"][-1]["recording_id"])
    assert found is not None
    sp = order_spectrum(found[1])
    top = 2 * w["x"][-1] - w["x"][-2]  # the axis' upper edge
    inside = [float(a) for x, a in zip(sp.x, sp.amplitude, strict=True) if x <= top]
    assert max(a for a in rows[-1] if a is not None) == pytest.approx(max(inside), rel=1e-9)
    freq = viewer.get(f"{base}/waterfall", params={"kind": "frequency", "recordings": 3}).json()
    assert freq["x_unit"] == "Hz" and freq["x"][-1] > w["x"][-1]
    _error(viewer.get(f"{base}/waterfall", params={"kind": "bad"}), 422, "invalid")
    _error(viewer.get("/api/v1/conveyors/nope/waterfall"), 404, "not_found")
    _error(served.client().get(f"{base}/waterfall"), 401, "unauthorized")


def test_token_commands(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    db = f"sqlite:///{tmp_path / 't.db'}"
    assert (
        main(["token", "create", "--db", db, "--name", "wall", "--role", "viewer", "--json"]) == 0
    )
    made = json.loads(capsys.readouterr().out)
    assert made["name"] == "wall" and made["role"] == "viewer" and made["token"].startswith("ct_")
    assert main(["token", "create", "--db", db, "--name", "wall"]) == 2
    assert "exists already" in capsys.readouterr().err
    assert main(["token", "create", "--db", db, "--name", "x", "--role", "boss"]) == 2
    assert main(["token", "list", "--db", db, "--json"]) == 0
    (listed,) = json.loads(capsys.readouterr().out)
    assert listed["active"] and "token" not in listed
    assert main(["token", "revoke", "wall", "--db", db]) == 0
    assert "token 'wall' revoked" in capsys.readouterr().out
    assert main(["token", "list", "--db", db, "--json"]) == 0
    assert json.loads(capsys.readouterr().out)[0]["active"] is False
    assert main(["token", "revoke", "nope", "--db", db]) == 2


@pytest.mark.browser
def test_in_a_browser_a_trend_shows_its_forecast_band(rising: Served) -> None:
    """The conveyor page draws the monitor's forecast and its 90 % band on the trend."""
    if not CHROMIUM.exists():
        pytest.fail("Chromium not found at /usr/bin/chromium: `make test` installs it")
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=str(CHROMIUM))
        page = browser.new_page()
        log_in(page, rising, "viewer")
        page.goto(f"{rising.base}/conveyors/{PROFILE.id}")
        chart = "#trends .trend[data-feature=friction]"
        page.wait_for_selector(f"{chart} .main-svg", timeout=30000)
        names = page.evaluate(f"document.querySelector('{chart}').data.map((t) => t.name)")
        assert "forecast" in names and any("90 % band" in n for n in names)
        assert page.locator("#forecasts tbody tr").count() == 1
        browser.close()


@pytest.mark.browser
def test_in_a_browser_a_missing_tlf_or_payload_is_said_in_words(rising: Served) -> None:
    """No empty chart: where nothing has a TLF (or a payload) the chart says why in words.

    The API's answers are the server's own with ``tlf`` and ``payload_kg`` made
    null, as for conveyors whose latest recordings could not be weighed.
    """
    if not CHROMIUM.exists():
        pytest.fail("Chromium not found at /usr/bin/chromium: `make test` installs it")
    from playwright.sync_api import Route, sync_playwright

    def unweighed(route: Route) -> None:
        answer = route.fetch()
        body = answer.json()
        rows = body["items"] if isinstance(body, dict) else body
        for row in rows:
            row["tlf"] = row["payload_kg"] = None
        route.fulfill(response=answer, json=body)

    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=str(CHROMIUM))
        page = browser.new_page()
        log_in(page, rising, "viewer")
        # as served: the TLF drawn
        page.wait_for_selector("#tlf-chart .main-svg")
        page.route("**/api/v1/conveyors", unweighed)
        page.route("**/api/v1/conveyors/*/recordings?limit=1000", unweighed)
        page.reload()
        page.wait_for_selector("#tlf-chart.absent")
        text = page.inner_text("#tlf-chart")
        assert text.startswith("No TLF to draw: no conveyor's latest recording has one.")
        assert f"{PROFILE.id} (its payload could not be weighed" in text
        assert page.locator("#tlf-chart .main-svg").count() == 0
        page.goto(f"{rising.base}/conveyors/{PROFILE.id}")
        page.wait_for_selector("#payloads.absent", timeout=30000)
        assert page.inner_text("#payloads").startswith("No payload to draw: none of its latest")
        assert page.locator("#payloads .main-svg").count() == 0
        browser.close()


# ------------------------------------------------------------------ property-based
import schemathesis  # noqa: E402
from hypothesis import HealthCheck, settings  # noqa: E402


@pytest.fixture(scope="module")
def api_schema(fleet: Path, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Any]:
    from datetime import UTC, datetime

    from hypothesis import strategies as st
    from schemathesis.specs.openapi import formats

    s = Served(f"sqlite:///{tmp_path_factory.mktemp('schema') / 'plant.db'}", fleet)
    schema = schemathesis.openapi.from_url(f"{s.base}/openapi.json")
    schema.config.update(headers={"Authorization": f"Bearer {s.tokens['admin']}"})
    # the API refuses times outside 1970-01-01..2200-01-01 with 422, which JSON Schema's
    # date-time cannot say: the valid examples are drawn inside that span
    before = formats.STRING_FORMATS.get("date-time")
    span = st.datetimes(datetime(1971, 1, 1), datetime(2199, 1, 1), timezones=st.just(UTC))
    schemathesis.openapi.format("date-time", span.map(datetime.isoformat))
    yield schema
    if before is None:
        formats.unregister_string_format("date-time")
    else:
        formats.STRING_FORMATS["date-time"] = before
    s.close()


@pytest.mark.slow
def test_every_operation_answers_as_its_schema_says(
    api_schema: Any, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Property-based, from the OpenAPI schema: no 5xx, every response as declared.

    Run operation by operation with Hypothesis directly (schemathesis's
    pytest plugin does not support this pytest). The event stream is cut to
    half a second a call (it lasts 15 s when served).
    """
    from hypothesis import given
    from schemathesis.checks import positive_data_acceptance

    from chaintwin.web import events

    monkeypatch.setattr(events, "STREAM_S", 0.5)
    operations = [result.ok() for result in api_schema.get_all_operations()]
    assert len(operations) >= 13
    assert any(op.path == "/api/v1/events" for op in operations)
    for operation in operations:

        @given(case=operation.as_strategy())
        @settings(
            max_examples=5 if operation.path == "/api/v1/events" else 20,
            deadline=None,
            suppress_health_check=list(HealthCheck),
            database=None,
        )
        def check(case: Any) -> None:
            # a period whose since is after its until is refused (400): the schema
            # cannot say that one bound must follow the other
            kpis = case.operation.path == "/api/v1/alarm-kpis"
            case.call_and_validate(excluded_checks=[positive_data_acceptance] if kpis else None)

        check()


_NEEDS_STATE = {
    "DELETE": ("/api/v1/conveyors/{conveyor_id}/out-of-service",),
    "POST": (
        "/api/v1/alarms/{alarm_id}/acknowledge",
        "/api/v1/alarms/{alarm_id}/shelve",
        "/api/v1/alarms/{alarm_id}/unshelve",
    ),
}
"""The changes refused (400) in a state that does not allow them."""


def test_sequences_of_operations_answer_as_their_schema_says(
    api_schema: Any, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Stateful: schemathesis chains the operations by the links it infers (a token
    created, then revoked; an alarm listed, then acknowledged), every response as declared."""
    from schemathesis.checks import positive_data_acceptance
    from schemathesis.specs.openapi.checks import ensure_resource_availability

    from chaintwin.web import events

    monkeypatch.setattr(events, "STREAM_S", 0.5)

    class Machine(api_schema.as_state_machine()):  # type: ignore[misc]
        def validate_response(self, response: Any, case: Any, **kwargs: Any) -> None:
            # An upload answers each file, a refused one with `recording_id` null (no
            # recording was made); the link schemathesis infers from the answer follows
            # that null to GET /recordings/None, whose 404 it then takes for a recording
            # created and lost. Only there is that one check left out; the others run.
            excluded = []
            if (case.path_parameters or {}).get("recording_id") in (None, "None"):
                excluded = [ensure_resource_availability]
            # A change the conveyor's or alarm's state does not allow (back in service when
            # not out of it, unshelve when not shelved, acknowledge twice) is refused with
            # 400 and says why; the schema cannot say which state an operation needs, and
            # the links the typed answers give lead to such calls: that check is left out
            # there, the others run.
            # A page's cursor is opaque too: only one the service gave is accepted (a
            # made-up one is refused with 400 and told to start again); the schema can only
            # say it is a string, so a generated one is no valid request.
            needs_state = case.operation.path in _NEEDS_STATE.get(case.operation.method.upper(), ())
            if needs_state or (case.query or {}).get("cursor") is not None:
                excluded.append(positive_data_acceptance)
            case.validate_response(
                response, excluded_checks=excluded, recorder=self.recorder, **kwargs
            )

    Machine.run(
        settings=settings(
            max_examples=15,
            stateful_step_count=6,
            # the same sequences on every run: a finding is reproducible, never a coin toss
            derandomize=True,
            deadline=None,
            suppress_health_check=list(HealthCheck),
            database=None,
        )
    )


# ------------------------------------------------------------------ in a browser
CHROMIUM = Path("/usr/bin/chromium")


@pytest.mark.browser
def test_in_a_browser_log_in_see_charts_acknowledge_and_a_viewer_refused(
    fleet: Path, tmp_path: Path
) -> None:
    """Chromium (the distribution's, installed by the test setup) driven by Playwright."""
    if not CHROMIUM.exists():
        pytest.fail("Chromium not found at /usr/bin/chromium: `make test` installs it")
    from playwright.sync_api import expect, sync_playwright

    served = Served(f"sqlite:///{tmp_path / 'plant.db'}", fleet)
    outside: list[str] = []
    broken: list[str] = []
    try:
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=str(CHROMIUM))
            page = browser.new_page()
            page.on(
                "request",
                lambda r: None if r.url.startswith(served.base) else outside.append(r.url),
            )
            page.on("console", lambda m: broken.append(m.text) if m.type == "error" else None)
            page.goto(served.base + "/")
            assert page.url.endswith("/login")
            page.fill("#token", served.tokens["maintainer"])
            page.click("form.login button")
            page.wait_for_url(served.base + "/")
            page.wait_for_selector("#tlf-chart .main-svg")
            assert page.locator("#fleet tbody tr").count() == 1
            page.wait_for_selector("#health-chart .main-svg")
            index = float(page.inner_text("#fleet tbody tr .index"))
            assert index >= 1.0  # the friction alarm is open
            # a recording stored meanwhile (here by ingest, as the live service would)
            # changes the table through the event stream, without a reload
            row = page.locator("#fleet tbody tr")
            before = row.text_content()
            assert before
            page.evaluate("window.notReloaded = true")
            # the stream listens before the store changes (a change before it started is
            # shown by the page's first refresh on "ready", not counted as an update)
            expect_connected(page)
            late = run_virtual(PROFILE, payload_kg=38.0, seed=321).recording
            late_file = write_recording(late, tmp_path / "late.csv")
            summary = ingest([str(late_file)], {PROFILE.id: PROFILE}, served.store, workers=1)
            assert summary.refused == 0
            # (waited on by Playwright's assertions: its wait_for_function evaluates a
            # string, which the pages' CSP forbids)
            expect(row).not_to_have_text(before, timeout=15000)
            assert page.evaluate("window.notReloaded === true && window.chaintwin.updates >= 1")
            page.click(f"#fleet a:text('{PROFILE.id}')")
            page.wait_for_selector("#trends .trend .main-svg", timeout=30000)
            page.wait_for_selector("#latest .main-svg", timeout=30000)
            page.wait_for_selector("#waterfall .main-svg", timeout=30000)
            assert page.evaluate("document.getElementById('waterfall').data[0].type") == "heatmap"
            assert page.locator("#trends .trend").count() >= 3
            # acknowledge the open alarm as maintainer
            page.goto(served.base + "/alarms")
            page.fill("form.acknowledge input[name=why]", "rails to be cleaned")
            page.click("form.acknowledge button")
            page.wait_for_url(served.base + "/alarms")
            assert "acknowledged by maintainer-1" in page.content()
            # a viewer cannot open the upload page
            viewer = browser.new_page()
            log_in(viewer, served, "viewer")
            answer = viewer.goto(served.base + "/upload")
            assert answer is not None and answer.status == 403
            assert "needs the role maintainer" in viewer.content()
            # the alarm list follows a maintenance recorded elsewhere, without a reload
            viewer.goto(served.base + "/alarms")
            assert "acknowledged by maintainer-1" in viewer.inner_text("table.alarms tbody")
            viewer.evaluate("window.notReloaded = true")
            # so does the verdict on the conveyor's page: relearning at once, not at the
            # next recording
            convo = browser.new_page()
            convo.on("console", lambda m: broken.append(m.text) if m.type == "error" else None)
            log_in(convo, served, "viewer")
            convo.goto(served.base + f"/conveyors/{quote(PROFILE.id)}")
            assert convo.inner_text("strong.health") in ("alarm", "acknowledged")
            assert convo.inner_text("strong.ne107") == "failure"
            convo.evaluate("window.notReloaded = true")
            expect_connected(convo)
            expect_connected(viewer)
            body = {"kind": "cleaning", "why": "rails cleaned"}
            done = served.client("maintainer").post(
                f"/api/v1/conveyors/{PROFILE.id}/maintenance", json=body
            )
            assert done.is_success
            expect(viewer.locator("table.alarms tbody")).to_contain_text("closed", timeout=15000)
            assert viewer.evaluate("window.notReloaded === true")
            expect(convo.locator("strong.health")).to_have_text("relearning", timeout=15000)
            assert convo.inner_text("strong.ne107") == "check_function"
            assert convo.evaluate("window.notReloaded === true")
            # the API docs' Swagger UI starts under the same CSP (no inline script)
            viewer.on("console", lambda m: broken.append(m.text) if m.type == "error" else None)
            viewer.goto(served.base + "/docs")
            viewer.wait_for_selector("#swagger-ui .swagger-ui", timeout=30000)
            browser.close()
    finally:
        served.close()
    assert outside == [], "nothing may load from the network"
    assert broken == []


def test_a_trend_reads_a_bounded_number_of_results_and_keeps_its_alarms(served: Served) -> None:
    viewer = served.client("viewer")
    base = f"/api/v1/conveyors/{PROFILE.id}/trends"
    full = viewer.get(base, params={"feature": "friction", "max_points": 100_000}).json()
    bounded = viewer.get(base, params={"feature": "friction", "max_points": 20}).json()
    stored = len(served.store.results(PROFILE.id))
    assert len(full["points"]) == full["recordings"] > 20  # more results than the bound
    assert all(p["represents"] == 1 for p in full["points"])
    points = bounded["points"]
    assert len(points) <= 20 and bounded["max_points"] == 20
    assert bounded["recordings"] == full["recordings"]  # counts every result still
    # the newest 10 in full, exactly as without a bound; the older ones thinned
    assert points[-10:] == full["points"][-10:]
    assert points[0] == full["points"][0] | {"represents": points[0]["represents"]}
    assert all(p["represents"] > 1 for p in points[:-10])
    assert sum(p["represents"] for p in points) <= stored
    older = {p["recorded_at"] for p in full["points"][:-10]}
    assert {p["recorded_at"] for p in points[:-10]} <= older
    # what is drawn beside the points is that of every result
    for key in ("alarms", "expected", "limit", "lower_limit", "health_index", "forecast"):
        assert bounded[key] == full[key], key
    assert bounded["alarms"]  # the friction alarm's marker
    assert full["max_points"] == 100_000
    # the default reads at most 1000; a bound below 20 is refused
    assert viewer.get(base, params={"feature": "friction"}).json()["max_points"] == 1000
    _error(viewer.get(base, params={"feature": "friction", "max_points": 5}), 422, "invalid")


def test_a_conveyors_page_with_more_results_than_its_bound_shows_the_same(
    served: Served, monkeypatch: pytest.MonkeyPatch
) -> None:
    from chaintwin.report.data import conveyor_data
    from chaintwin.web.routes import conveyors as api

    browser = served.client()
    login = browser.post("/login", data={"token": served.tokens["viewer"]})
    assert login.status_code == 303, login.text
    whole = browser.get(f"/conveyors/{PROFILE.id}").text
    detail = browser.get(f"/api/v1/conveyors/{PROFILE.id}").json()
    data = conveyor_data(served.store, PROFILE.id, waterfall=0)  # every result
    assert len(data.results) > 20
    monkeypatch.setattr(api, "PAGE_POINTS", 20)  # the newest 10 and 10 older ones
    bounded = browser.get(f"/conveyors/{PROFILE.id}").text
    assert bounded == whole
    assert f"{len(data.results)} recordings" in bounded
    assert f'<strong class="health">{data.status}</strong>' in bounded
    assert all(f"since {a.since}" in bounded for a in data.open_alarms())
    found = re.search(r"data-features='([^']*)'", bounded)
    assert found is not None
    features = json.loads(found.group(1).replace("&#34;", '"'))
    assert features == [t.name for t in data.trends]
    assert browser.get(f"/api/v1/conveyors/{PROFILE.id}").json() == detail
    assert detail["recordings"] == len(data.results)


def test_trend_rows_keep_the_newest_whole_and_thin_the_rest(tmp_path: Path) -> None:
    from sqlalchemy import insert

    from chaintwin.store.queries import trend_rows
    from chaintwin.store.schema import ConveyorRow, RecordingRow, ResultRow

    with Store(f"sqlite:///{tmp_path / 'long.db'}") as store:
        with store.engine.begin() as c:
            for cid in ("a", "b"):
                c.execute(
                    insert(ConveyorRow),
                    [{"id": cid, "profile": {}, "profile_sha256": "0" * 64}],
                )
            recs, res = [], []
            for k in range(1, 2001):  # two conveyors' results interleaved, as ingest stores them
                cid = "a" if k % 2 else "b"
                at = f"2026-01-01T00:00:00Z#{k:05d}"
                content: dict[str, Any] = {"file": f"{k}.csv", "recorded_at": at, "n": k}
                status = "monitored"
                if k == 1999:  # a refused result among the newest: left out, not counted
                    content["error"] = "refused"
                    status = "refused"
                recs.append(
                    {"id": k, "sha256": f"{k:064x}", "conveyor_id": cid, "file": f"{k}.csv",
                     "recorded_at": at, "meta": {}, "warnings": [], "samples": b""}
                )  # fmt: skip
                res.append(
                    {"id": k, "recording_id": k, "conveyor_id": cid, "recorded_at": at,
                     "status": status, "alarm": False, "payload_kg": None, "tlf": None,
                     "content": content, "stored_at": at}
                )  # fmt: skip
            c.execute(insert(RecordingRow), recs)
            c.execute(insert(ResultRow), res)
        got = trend_rows(store, "a", 100)
        ns = [r["n"] for r in got.results]
        assert got.total == 999  # 1000 of conveyor a, one refused
        assert len(ns) <= 100 and ns == sorted(ns)
        assert all(n % 2 == 1 for n in ns)  # conveyor a's only
        # the newest 50 (one of them refused) in full, standing for themselves
        assert ns[-49:] == [n for n in range(1901, 2001, 2) if n != 1999]
        assert got.represents[-49:] == [1] * 49
        # the older 950 thinned to at most 50, the first one kept; each stands for its stretch
        assert ns[0] == 1 and len(ns) - 49 <= 50
        assert sum(got.represents[:-49]) == 950
        assert max(b - a for a, b in itertools.pairwise(ns[:-48])) <= 2 * 950 / 50 + 2
        # the count (kept between calls) follows results added later, refused or not
        with store.engine.begin() as c:
            for k, status in ((2001, "refused"), (2003, "monitored")):
                at = f"2026-01-02T00:00:00Z#{k:05d}"
                content = {"file": f"{k}.csv", "recorded_at": at, "n": k}
                if status == "refused":
                    content["error"] = "refused"
                c.execute(
                    insert(RecordingRow),
                    [{"id": k, "sha256": f"{k:064x}", "conveyor_id": "a", "file": f"{k}.csv",
                      "recorded_at": at, "meta": {}, "warnings": [], "samples": b""}],
                )  # fmt: skip
                c.execute(
                    insert(ResultRow),
                    [{"id": k, "recording_id": k, "conveyor_id": "a", "recorded_at": at,
                      "status": status, "alarm": False, "payload_kg": None, "tlf": None,
                      "content": content, "stored_at": at}],
                )  # fmt: skip
        later = trend_rows(store, "a", 100)
        assert later.total == 1000 and later.results[-1]["n"] == 2003
        # a short history: every result, as Store.results gives them
        few = trend_rows(store, "b", 5000)
        assert [r["n"] for r in few.results] == [r["n"] for r in store.results("b")]
        assert few.total == 1000 and few.represents == [1] * 1000


@pytest.mark.slow
def test_the_served_app_freezes_its_start_up_heap(tmp_path: Path) -> None:
    import subprocess
    import sys

    # in a process of its own: freezing is for good
    url = f"sqlite:///{tmp_path / 's.db'}"
    code = (
        "import gc, sys\n"
        "from chaintwin.store.store import Store\n"
        "from chaintwin.web.app import create_app, freeze_heap\n"
        f"app = create_app(Store({url!r}))\n"
        "assert 'chaintwin.report.data' not in sys.modules\n"
        "frozen = freeze_heap(app)\n"
        "assert 'chaintwin.report.data' in sys.modules\n"
        "assert frozen == gc.get_freeze_count() > 10000, frozen\n"
        "assert len(gc.get_objects(generation=2)) < frozen / 10\n"
        "print(frozen)\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=False
    )
    assert done.returncode == 0, done.stderr
    assert int(done.stdout) > 10000


def test_slow_requests_and_collections_are_traced_when_asked(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    import gc

    from chaintwin.web.trace import slow_ms

    for off in ("", "0", "soon"):  # off unless a positive number of ms is given
        monkeypatch.setenv("CHAINTWIN_TRACE_SLOW_MS", off)
        assert slow_ms() is None
    callbacks = list(gc.callbacks)
    monkeypatch.setenv("CHAINTWIN_TRACE_SLOW_MS", "0.001")  # every request is slow
    store = Store(f"sqlite:///{tmp_path / 'traced.db'}")
    base, server, thread = start_server(create_app(store))
    store.engine.dispose()  # the next request opens a new connection
    try:
        assert httpx.get(base + "/api/v1/health", timeout=30).status_code == 200
        assert httpx.get(base + "/api/v1/conveyors", timeout=30).status_code == 401
        gc.collect()  # a full collection: always written
    finally:
        server.should_exit = True
        thread.join(10)
        store.close()
        gc.callbacks[:] = callbacks
    lines = [line for line in capsys.readouterr().err.splitlines() if line.startswith("trace ")]
    slow = [line for line in lines if " slow GET " in line]
    assert any("/api/v1/health status=200 ms=" in line for line in slow), lines
    assert any("/api/v1/conveyors status=401" in line for line in slow), lines
    assert all("gc_ms=" in line and "loop_late_ms=" in line for line in slow)
    assert any(" gc generation=2 ms=" in line for line in lines), lines
    # the pool's new connections too
    assert any(" db connect ms=" in line for line in lines), lines


def test_serve_keeps_more_database_connections_than_the_default(tmp_path: Path) -> None:
    """As ``serve`` keeps them on PostgreSQL (a new connection costs 10-40 ms there);
    on SQLite it keeps fewer (``tests/test_live.py``: its memory)."""
    from chaintwin.cli.serve_cmd import SERVE_POOL_SIZE

    url = f"sqlite:///{tmp_path / 'pool.db'}"
    default, served_store = Store(url), Store(url, pool_size=SERVE_POOL_SIZE)
    try:
        assert default.engine.pool.size() == 5  # type: ignore[attr-defined]
        assert served_store.engine.pool.size() == SERVE_POOL_SIZE > 5  # type: ignore[attr-defined]
        # kept: connections used at once are not closed when they are given back
        held = [served_store.engine.connect() for _ in range(SERVE_POOL_SIZE)]
        for c in held:
            c.close()
        assert served_store.engine.pool.checkedin() == SERVE_POOL_SIZE  # type: ignore[attr-defined]
    finally:
        default.close()
        served_store.close()


def test_a_conveyors_page_detail_and_trends_read_through_one_connection(served: Served) -> None:
    """Each of the conveyor's reads shares one session: one connection checkout per
    request for them (beside the token's check), on SQLite and PostgreSQL alike."""
    from sqlalchemy import event

    from chaintwin.web.routes.conveyors import conveyor_data_of

    engine = served.store.engine
    taken: list[str] = []

    def checkout(*_args: Any) -> None:
        taken.append(threading.current_thread().name)

    viewer = served.client("viewer")
    browser = served.client()
    assert browser.post("/login", data={"token": served.tokens["viewer"]}).status_code == 303
    base = f"/api/v1/conveyors/{PROFILE.id}"
    requests = {
        "detail": lambda: viewer.get(base),
        "trends": lambda: viewer.get(f"{base}/trends"),
        "page": lambda: browser.get(f"/conveyors/{PROFILE.id}"),
    }
    for fetch in requests.values():  # warm: the verdict cache and the token key filled
        assert fetch().status_code == 200
    event.listen(engine, "checkout", checkout)
    try:
        data = conveyor_data_of(served.app.state.web, PROFILE.id)
        assert data.summary["forecasts"] and data.results  # forecasts, results, alarms ...
        assert len(taken) == 1, taken  # profile, results, model, forecasts, alarms, ...
        counts = {}
        for name, fetch in requests.items():
            taken.clear()
            assert fetch().status_code == 200
            counts[name] = len(taken)
    finally:
        event.remove(engine, "checkout", checkout)
    # the conveyor's reads one checkout, the token's (or the cookie's) check one more
    assert counts == {"detail": 2, "trends": 2, "page": 2}, counts
