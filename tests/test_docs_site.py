"""The documentation site's generated pages (scripts/docs_hooks.py) say what the code says.

``make test`` builds the site strictly (``mkdocs build --strict``); these
check the generators' content against their sources: every command and
option of the Typer app in the CLI reference, every operation of the
OpenAPI document in the HTTP reference, an evaluation JSON's numbers in
its tables, and the nav pruning that lets pages of other branches be
listed before they exist.
"""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path
from types import ModuleType
from typing import Any

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def hooks() -> ModuleType:
    pytest.importorskip("mkdocs")
    spec = importlib.util.spec_from_file_location("docs_hooks", ROOT / "scripts" / "docs_hooks.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_cli_reference_lists_every_command_and_option(hooks: ModuleType) -> None:
    import typer

    from chaintwin.cli.app import app

    page = hooks.cli_reference()
    root = typer.main.get_command(app)
    ctx = root.context_class(root, info_name="chaintwin")
    seen = 0
    for name in root.list_commands(ctx):
        command = root.get_command(ctx, name)
        assert f"## `chaintwin {name}`" in page, name
        for param in command.params:
            for opt in param.opts:
                if opt.startswith("--"):
                    assert opt in page, f"{name} {opt}"
                    seen += 1
    assert seen > 100
    assert "`chaintwin token create`" in page
    assert "--max-file-mb" in page


def test_the_http_reference_lists_every_operation(hooks: ModuleType) -> None:
    doc = hooks.openapi_document()
    page = hooks.http_reference(doc)
    operations = [
        (method.upper(), path)
        for path, methods in doc["paths"].items()
        for method in methods
        if method in {"get", "post", "put", "patch", "delete"}
    ]
    assert len(operations) > 10
    for method, path in operations:
        assert f"## `{method} {path}`" in page
    assert page.count("\n## `") == len(operations)


def test_an_evaluation_json_becomes_its_tables(hooks: ModuleType) -> None:
    data: dict[str, Any] = {
        "seconds": 43.8694,
        "table": [
            {"fault": "friction", "alarmed": 7, "right": 6, "median_delay": 19.0},
            {"fault": "healthy", "alarmed": 0, "right": 0, "median_delay": None},
        ],
        "weighing": {"recordings": 7989, "largest_z": 2.508, "beyond": {"a|b": 1}},
    }
    page = hooks.evaluation_tables(json.loads(json.dumps(data)))
    assert "| seconds | 43.87 |" in page
    assert "| fault | alarmed | right | median_delay |" in page
    assert "| friction | 7 | 6 | 19 |" in page
    assert "| healthy | 0 | 0 | null |" in page
    assert "| recordings | 7989 |" in page
    assert "| a\\|b | 1 |" in page  # a pipe in a key cannot split the row


def test_nav_entries_of_missing_pages_are_left_out(hooks: ModuleType) -> None:
    nav = [
        {"Home": "index.md"},
        {"How-to": [{"Add a fault": "adding-a-fault.md"}, {"Runs": "how-to/runs.md"}]},
        {"Later": [{"Only missing": "missing.md"}]},
        {"Site": "https://example.org/"},
    ]
    kept = hooks._prune(nav, {"index.md", "how-to/runs.md"})
    assert kept == [
        {"Home": "index.md"},
        {"How-to": [{"Runs": "how-to/runs.md"}]},
        {"Site": "https://example.org/"},
    ]
