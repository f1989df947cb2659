"""The API's documentation pages, /docs (Swagger UI) and /redoc, drawn in Chromium offline.

Both load their JavaScript from the package (nothing from the network) and
show every operation of the OpenAPI document the app serves (3.1).
"""

from __future__ import annotations

from collections.abc import Iterator

import httpx
import pytest
from test_web import CHROMIUM, start_server

from chaintwin.store.store import Store
from chaintwin.web import create_app

pytestmark = pytest.mark.browser

METHODS = {"get", "put", "post", "delete", "patch", "head", "options", "trace"}


@pytest.fixture(scope="module")
def base(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """The web service over an empty store, served by uvicorn in a thread."""
    store = Store(f"sqlite:///{tmp_path_factory.mktemp('docs') / 'plant.db'}")
    url, server, thread = start_server(create_app(store))
    yield url
    server.should_exit = True
    thread.join(10)
    store.close()


def _operations(base: str) -> list[str]:
    """``METHOD /path`` of every operation in the served OpenAPI document."""
    doc = httpx.get(base + "/openapi.json", timeout=30).json()
    assert doc["openapi"].startswith("3.1")
    return sorted(
        f"{method.upper()} {path}"
        for path, item in doc["paths"].items()
        for method in item
        if method in METHODS
    )


def _open(page_name: str, base: str, ready: str, count: str) -> tuple[int, list[str]]:
    """Open a docs page in Chromium; the operations it shows and what it fetched off-site."""
    if not CHROMIUM.exists():
        pytest.fail("Chromium not found at /usr/bin/chromium: `make test` installs it")
    from playwright.sync_api import sync_playwright

    asked: list[str] = []  # off-site requests the page made
    refused: list[str] = []  # ... that the page's own policy stopped before the network
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=str(CHROMIUM))
        page = browser.new_page()
        local = (base, "data:", "blob:")
        page.on("request", lambda r: None if r.url.startswith(local) else asked.append(r.url))
        page.on(
            "requestfailed",
            lambda r: refused.append(r.url) if r.failure == "csp" else None,
        )
        page.goto(base + page_name)
        page.wait_for_selector(ready, state="attached", timeout=60000)
        shown = page.locator(count).count()
        browser.close()
    return shown, [url for url in asked if url not in refused]


def test_swagger_ui_shows_every_operation_offline(base: str) -> None:
    """/docs: Swagger UI 5 reads the 3.1 document and draws one block per operation."""
    operations = _operations(base)
    assert len(operations) > 10
    shown, elsewhere = _open("/docs", base, ".opblock", ".opblock")
    assert shown == len(operations)
    assert elsewhere == []


def test_redoc_shows_every_operation_offline(base: str) -> None:
    """/redoc: ReDoc lists one menu entry per operation."""
    operations = _operations(base)
    shown, elsewhere = _open(
        "/redoc", base, "[data-item-id*='operation/']", "li[data-item-id*='operation/']"
    )
    assert shown == len(operations)
    assert elsewhere == []
