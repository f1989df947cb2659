"""The JSON API's answers on a demo-like store, captured once and compared ever after.

Run as a script (``python tests/api_golden.py``) it builds the store
``tests/fixtures/api-golden/store.sqlite`` (a conveyor whose rail friction
rises until its alarm opens, a healthy one, calibrations, acknowledgements,
comments, maintenance, a conveyor taken out of service and back, tokens and
their audit trail), then writes what every JSON endpoint answered on it to
``tests/fixtures/api-golden/answers.json``. ``tests/test_api_golden.py``
serves a copy of that store with the current code and compares each answer
field for field (types included: ``1`` is not ``1.0``).

The reading requests (``GET``) are compared exactly, but for the values that
depend on the process (the package's version, the store's path). The
changing requests (``POST``, ``DELETE``) are replayed on the copy in the same
order; the times they stamp (now), the ids they draw and the new token are masked.
"""

from __future__ import annotations

import contextlib
import json
import re
import shutil
import socket
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

HERE = Path(__file__).parent
GOLDEN = HERE / "fixtures" / "api-golden"
STORE = GOLDEN / "store.sqlite"
ANSWERS = GOLDEN / "answers.json"
TOKENS = GOLDEN / "tokens.json"

BELT = "white-belt-01"
INCLINE = "incline-line-02"

Request = tuple[str, str, dict[str, Any] | None, str]
"""Method, path (with its query), JSON body, role."""


def reading_requests(client: Any, tokens: dict[str, str]) -> list[Request]:
    """Every reading request: each JSON ``GET`` operation, with its variants."""
    h = {"Authorization": f"Bearer {tokens['viewer']}"}
    recordings = client.get(f"/api/v1/conveyors/{BELT}/recordings?limit=3", headers=h).json()
    cursor = recordings["next_cursor"]
    rid = recordings["items"][0]["recording_id"]
    out: list[Request] = [
        ("GET", "/api/v1/health", None, "viewer"),
        ("GET", "/api/v1/health", None, ""),
        ("GET", "/api/v1/store", None, "viewer"),
        ("GET", "/api/v1/conveyors", None, "viewer"),
        ("GET", "/api/v1/alarms", None, "viewer"),
        ("GET", "/api/v1/alarms?state=open", None, "viewer"),
        ("GET", "/api/v1/alarms?state=open&acknowledged=false", None, "viewer"),
        ("GET", "/api/v1/alarms?lifecycle=unacknowledged", None, "viewer"),
        ("GET", f"/api/v1/recordings/{rid}", None, "viewer"),
        ("GET", "/api/v1/tokens", None, "admin"),
        ("GET", "/api/v1/audit", None, "admin"),
        ("GET", "/api/v1/audit?limit=2", None, "admin"),
        (
            "GET",
            "/api/v1/alarm-kpis?since=2026-01-01T00:00:00Z&until=2026-03-01T00:00:00Z",
            None,
            "viewer",
        ),
    ]
    for cid in (BELT, INCLINE):
        out += [
            ("GET", f"/api/v1/conveyors/{cid}", None, "viewer"),
            ("GET", f"/api/v1/conveyors/{cid}/recordings?limit=3", None, "viewer"),
            ("GET", f"/api/v1/conveyors/{cid}/trends", None, "viewer"),
            ("GET", f"/api/v1/conveyors/{cid}/trends?max_points=20", None, "viewer"),
            ("GET", f"/api/v1/conveyors/{cid}/trends?feature=friction", None, "viewer"),
            (
                "GET",
                f"/api/v1/conveyors/{cid}/trends?feature=friction&feature=speed_loss",
                None,
                "viewer",
            ),
            ("GET", f"/api/v1/conveyors/{cid}/waterfall?recordings=2", None, "viewer"),
            (
                "GET",
                f"/api/v1/conveyors/{cid}/waterfall?recordings=2&kind=frequency",
                None,
                "viewer",
            ),
        ]
    out.append(
        ("GET", f"/api/v1/conveyors/{BELT}/recordings?limit=3&cursor={cursor}", None, "viewer")
    )
    return out


def changing_requests(client: Any, tokens: dict[str, str]) -> list[Request]:
    """Every changing JSON request, replayed in this order on a copy of the store."""
    h = {"Authorization": f"Bearer {tokens['viewer']}"}
    alarms = client.get("/api/v1/alarms?state=open", headers=h).json()
    alarm = alarms[0]["id"]
    return [
        ("POST", f"/api/v1/alarms/{alarm}/comments", {"text": "seen on the round"}, "maintainer"),
        (
            "POST",
            f"/api/v1/alarms/{alarm}/shelve",
            {"why": "shift change", "minutes": 30},
            "maintainer",
        ),
        ("POST", f"/api/v1/alarms/{alarm}/unshelve", None, "maintainer"),
        (
            "POST",
            f"/api/v1/alarms/{alarm}/acknowledge",
            {"why": "rail cleaning planned"},
            "maintainer",
        ),
        (
            "POST",
            f"/api/v1/conveyors/{INCLINE}/out-of-service",
            {"why": "rebuild", "until": "2199-01-01T00:00:00Z"},
            "maintainer",
        ),
        ("DELETE", f"/api/v1/conveyors/{INCLINE}/out-of-service", None, "maintainer"),
        (
            "POST",
            f"/api/v1/conveyors/{BELT}/maintenance",
            {"kind": "cleaning", "why": "rail cleaned", "at": "2026-01-08T12:00:00Z"},
            "maintainer",
        ),
        ("POST", "/api/v1/tokens", {"name": "scada-2", "role": "viewer"}, "admin"),
        ("POST", "/api/v1/tokens/scada-2/revoke", None, "admin"),
        ("GET", "/api/v1/audit?limit=9", None, "admin"),
        ("GET", f"/api/v1/conveyors/{BELT}", None, "viewer"),
    ]


_TIME = re.compile(r"^\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d")


def mask(value: Any, *, times: bool) -> Any:
    """``value`` with what depends on the process masked (and, ``times``, every time)."""
    if isinstance(value, dict):
        out = {}
        for k, v in value.items():
            if k == "version" and isinstance(v, str):
                out[k] = "<version>"
            elif k == "url" and isinstance(v, str):
                out[k] = "<url>"
            elif times and k == "id" and isinstance(v, str):
                out[k] = "<id>"  # a new event's random id
            elif k == "token" and isinstance(v, str):
                out[k] = "<token>"
            else:
                out[k] = mask(v, times=times)
        return out
    if isinstance(value, list):
        return [mask(v, times=times) for v in value]
    if times and isinstance(value, str) and _TIME.match(value):
        return "<time>"
    return value


def typed(value: Any) -> Any:
    """``value`` with each number's type spelt out (JSON ``1`` and ``1.0`` differ)."""
    if isinstance(value, dict):
        return {k: typed(v) for k, v in value.items()}
    if isinstance(value, list):
        return [typed(v) for v in value]
    if isinstance(value, bool) or value is None or isinstance(value, str):
        return value
    if isinstance(value, int):
        return {"<int>": value}
    if isinstance(value, float):
        return {"<float>": value}
    return value


def answer(client: Any, tokens: dict[str, str], request: Request, *, times: bool) -> Any:
    """What the API answered a request: its status and its JSON, masked."""
    method, path, body, role = request
    headers = {"Authorization": f"Bearer {tokens[role]}"} if role else {}
    response = client.request(method, path, json=body, headers=headers)
    try:
        content = response.json()
    except ValueError:
        content = {"<not json>": response.headers.get("content-type")}
    return {"status": response.status_code, "json": mask(content, times=times)}


def answers(client: Any, tokens: dict[str, str]) -> Iterator[tuple[str, Any]]:
    """Each request's key and answer: the readings, then the changes in order."""
    for k, request in enumerate(reading_requests(client, tokens)):
        yield (
            f"read {k:02d} {request[0]} {request[1]} as {request[3] or 'nobody'}",
            answer(client, tokens, request, times=False),
        )
    for k, request in enumerate(changing_requests(client, tokens)):
        yield (
            f"change {k:02d} {request[0]} {request[1]} as {request[3]}",
            answer(client, tokens, request, times=True),
        )


def build(folder: Path) -> tuple[Path, dict[str, str]]:
    """The demo-like store in ``folder`` (its file) and a token per role."""
    from chaintwin.calibrating import calibrate
    from chaintwin.diagnose.records import MonitorSettings
    from chaintwin.examples import __file__ as examples
    from chaintwin.ingest.pipeline import ingest
    from chaintwin.read.profile import load_profile
    from chaintwin.simulate.faults import Fault
    from chaintwin.simulate.fleet import generate
    from chaintwin.store.store import Store
    from chaintwin.validate import load_recording
    from chaintwin.web import create_app
    from chaintwin.web.access import create_token

    profiles_dir = Path(examples).parent / "profiles"
    profiles = {p: load_profile(profiles_dir / f"{p}.yaml") for p in (BELT, INCLINE)}
    path = folder / "store.sqlite"
    store = Store(f"sqlite:///{path}")
    try:
        for cid, faults, days in ((BELT, [Fault("friction", 0.8)], 6), (INCLINE, [], 3)):
            out = folder / cid
            generate(profiles[cid], out, days=days, per_day=4, faults=faults, onset_day=2, seed=5)
            cal = sorted((out / "calibration").glob("*.csv"))
            recs = [load_recording(f, profile=profiles[cid]).recording for f in cal]
            store.put_calibration(calibrate(recs, profiles[cid]))
            files = sorted(str(f) for f in out.glob("*.csv"))
            ingest(files, profiles, store, settings=MonitorSettings(baseline_n=8), workers=1)
        tokens = {
            role: create_token(store, f"{role}-1", role)
            for role in ("viewer", "maintainer", "admin")
        }
        tokens[""] = ""
        # state for the readings: a commented alarm, a second admin token
        with serving(create_app(store, profiles)) as client:
            h = {"Authorization": f"Bearer {tokens['maintainer']}"}
            first = client.get("/api/v1/alarms?state=open", headers=h).json()
            assert first, "the friction fault opened no alarm"
            a = first[0]["id"]
            client.post(f"/api/v1/alarms/{a}/comments", json={"text": "noted"}, headers=h)
            client.post("/api/v1/tokens", json={"name": "scada-1", "role": "viewer"},
                        headers={"Authorization": f"Bearer {tokens['admin']}"})  # fmt: skip
    finally:
        store.close()
    return path, tokens


def capture() -> None:
    """Build the store and capture every answer (the fixture)."""
    from chaintwin.read.profile import load_profile
    from chaintwin.store.store import Store
    from chaintwin.web import create_app

    GOLDEN.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as folder:
        path, tokens = build(Path(folder))
        STORE.unlink(missing_ok=True)
        shutil.copyfile(path, STORE)
        TOKENS.write_text(json.dumps(tokens, indent=1) + "\n")
        served(STORE, tokens, ANSWERS, create_app, Store, load_profile)


@contextlib.contextmanager
def serving(app: Any) -> Iterator[Any]:
    """An httpx client of ``app`` served by uvicorn in a thread on a free port."""
    import httpx
    import uvicorn

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = int(s.getsockname()[1])
    server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + 30
    while not server.started:
        assert time.monotonic() < deadline, "the server did not start"
        time.sleep(0.02)
    try:
        with httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=60) as client:
            yield client
    finally:
        server.should_exit = True
        thread.join(10)


def served(
    path: Path, tokens: dict[str, str], into: Path | None, create_app: Any, store_cls: Any,
    load_profile: Any,
) -> dict[str, Any]:  # fmt: skip
    """Serve a copy of the store at ``path``; every answer (written to ``into`` if given)."""
    from chaintwin.examples import __file__ as examples

    profiles_dir = Path(examples).parent / "profiles"
    profiles = {p: load_profile(profiles_dir / f"{p}.yaml") for p in (BELT, INCLINE)}
    with tempfile.TemporaryDirectory() as folder:
        copy = Path(folder) / "store.sqlite"
        shutil.copyfile(path, copy)
        store = store_cls(f"sqlite:///{copy}")
        try:
            with serving(create_app(store, profiles)) as client:
                got = dict(answers(client, tokens))
        finally:
            store.close()
    if into is not None:
        into.write_text(json.dumps(got, indent=1, sort_keys=True) + "\n")
    return got


if __name__ == "__main__":
    sys.path.insert(0, str(HERE.parent))
    capture()
    print(f"wrote {STORE} and {ANSWERS}")
