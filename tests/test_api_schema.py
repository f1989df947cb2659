"""The OpenAPI document describes every JSON answer, and every answer matches it.

Served: a copy of the golden store (``tests/fixtures/api-golden``: a conveyor
in alarm, a healthy one, tokens, audit entries), so that nothing is
simulated here. schemathesis draws a few requests per ``GET`` operation,
with the path parameters of real conveyors and recordings (and random ones:
their 404s must match the document too), and checks each answer against the
document: status, content type, headers and the body against its schema.
The response models are closed (``additionalProperties: false``), so a
field an answer has and its model lacks is a finding too.
"""

from __future__ import annotations

import json
import shutil
from collections.abc import Iterator
from datetime import UTC, datetime
from typing import Any

import pytest
from api_golden import BELT, INCLINE, STORE, TOKENS, serving

from chaintwin.store import migrate
from chaintwin.store.engine import engine_for
from chaintwin.store.store import Store
from chaintwin.web import create_app


@pytest.fixture(scope="module")
def base(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[str, dict[str, str]]]:
    """The golden store served by uvicorn: its base URL and a token per role."""
    path = tmp_path_factory.mktemp("schema") / "store.sqlite"
    shutil.copyfile(STORE, path)
    engine = engine_for(f"sqlite:///{path}")
    try:
        migrate.upgrade(engine)
    finally:
        engine.dispose()
    store = Store(f"sqlite:///{path}")
    try:
        with serving(create_app(store)) as client:
            yield str(client.base_url).rstrip("/"), json.loads(TOKENS.read_text())
    finally:
        store.close()


def _schemas(document: dict[str, Any], schema: dict[str, Any]) -> list[dict[str, Any]]:
    """The component schemas a response schema names (through arrays and unions)."""
    if "$ref" in schema:
        return [document["components"]["schemas"][schema["$ref"].rsplit("/", 1)[1]]]
    out = []
    for key in ("anyOf", "oneOf"):
        for s in schema.get(key, []):
            out += _schemas(document, s)
    if "items" in schema:
        out += _schemas(document, schema["items"])
    return out


def test_every_json_answer_is_described_with_its_fields(base: tuple[str, dict[str, str]]) -> None:
    import httpx

    document = httpx.get(f"{base[0]}/openapi.json", timeout=30).json()
    described = []
    for path, operations in document["paths"].items():
        for method, operation in operations.items():
            for status, response in operation["responses"].items():
                content = response.get("content", {}).get("application/json")
                if content is None:
                    continue
                named = _schemas(document, content["schema"])
                assert named, f"{method.upper()} {path} {status}: no model"
                for schema in named:
                    assert schema.get("properties"), f"{method.upper()} {path}: {schema}"
                if status == "200":
                    described.append(f"{method.upper()} {path}")
    assert len(described) >= 22, described  # every JSON operation of the API


def test_schemathesis_finds_nothing_over_every_get_operation(
    base: tuple[str, dict[str, str]],
) -> None:
    """A few examples per operation, real and random path parameters; no findings."""
    import httpx
    import schemathesis
    from hypothesis import HealthCheck, given, settings
    from hypothesis import strategies as st
    from schemathesis.checks import positive_data_acceptance
    from schemathesis.specs.openapi import formats

    url, tokens = base
    admin = {"Authorization": f"Bearer {tokens['admin']}"}
    page = httpx.get(f"{url}/api/v1/conveyors/{BELT}/recordings?limit=1", headers=admin).json()
    recording = page["items"][0]["recording_id"]
    schema = schemathesis.openapi.from_url(f"{url}/openapi.json")
    schema.config.update(headers=admin)
    # the API refuses times outside 1970-01-01..2200-01-01 (422): valid ones drawn inside
    before = formats.STRING_FORMATS.get("date-time")
    span = st.datetimes(datetime(1971, 1, 1), datetime(2199, 1, 1), timezones=st.just(UTC))
    schemathesis.openapi.format("date-time", span.map(datetime.isoformat))
    checked: list[str] = []
    try:
        for result in schema.get_all_operations():
            operation = result.ok()
            if operation.method.upper() != "GET" or operation.path == "/api/v1/events":
                continue  # the event stream (text/event-stream) is tested in test_web
            real: list[dict[str, Any] | None] = [None]
            if "{conveyor_id}" in operation.path:
                real = [{"conveyor_id": BELT}, {"conveyor_id": INCLINE}, None]
            elif "{recording_id}" in operation.path:
                real = [{"recording_id": recording}, None]
            for fixed in real:

                @given(case=operation.as_strategy(path_parameters=fixed))
                @settings(
                    max_examples=3,
                    deadline=None,
                    derandomize=True,  # the same requests on every run: a finding reproduces
                    suppress_health_check=list(HealthCheck),
                    database=None,
                )
                def check(case: Any) -> None:
                    # refused (400) though the schema allows them, as it cannot say so: a
                    # period whose since follows its until, a cursor this service never gave
                    kpis = case.operation.path == "/api/v1/alarm-kpis"
                    cursor = (case.query or {}).get("cursor") is not None
                    case.call_and_validate(
                        excluded_checks=[positive_data_acceptance] if kpis or cursor else None
                    )

                check()
            checked.append(operation.path)
    finally:
        if before is None:
            formats.unregister_string_format("date-time")
        else:
            formats.STRING_FORMATS["date-time"] = before
    assert len(checked) == 12, checked  # every JSON GET operation


def test_every_operation_but_health_needs_its_role(base: tuple[str, dict[str, str]]) -> None:
    """The role dependency: no token 401, too low a role 403, the role itself answered."""
    import httpx

    url, tokens = base
    document = httpx.get(f"{url}/openapi.json", timeout=30).json()
    needs = {
        "/api/v1/tokens": "admin",
        "/api/v1/audit": "admin",
    }
    real = {"{conveyor_id}": BELT, "{alarm_id}": "none", "{name}": "none"}
    asked = 0
    for path, operations in document["paths"].items():
        for method in operations:
            concrete = path
            for key, value in real.items():
                concrete = concrete.replace(key, value)
            concrete = concrete.replace("{recording_id}", "0" * 64)
            if path == "/api/v1/health":
                continue
            anonymous = httpx.request(method, url + concrete, timeout=30)
            assert anonymous.status_code == 401, (method, path, anonymous.text)
            assert anonymous.json()["error"]["code"] == "unauthorized"
            role = needs.get(path, "viewer" if method == "get" else "maintainer")
            if path.startswith("/api/v1/tokens"):
                role = "admin"
            lower = {"viewer": None, "maintainer": "viewer", "admin": "maintainer"}[role]
            if lower is not None:
                headers = {"Authorization": f"Bearer {tokens[lower]}"}
                refused = httpx.request(method, url + concrete, headers=headers, timeout=30)
                assert refused.status_code == 403, (method, path, lower, refused.text)
                assert f"this needs the role {role}" in refused.json()["error"]["message"]
            asked += 1
    assert asked >= 22
