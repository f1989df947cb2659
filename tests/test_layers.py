"""The layers: written once in docs/design.md, checked by import-linter.

The contract in ``pyproject.toml`` must list the order the design page
shows, and must hold with no exceptions; a contract that names a layer out
of order, or a function-local import running upward, fails here as it
fails ``make test``.
"""

from __future__ import annotations

import ast
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _design_layers() -> list[str]:
    text = (ROOT / "docs" / "design.md").read_text(encoding="utf-8")
    section = text.split("### Layers", 1)[1]
    block = re.search(r"```text\n(.*?)```", section, re.S)
    assert block is not None, "docs/design.md: the Layers section has no ```text block"
    layers = []
    for line in block.group(1).splitlines():
        # a layer's parts, then two or more spaces and what they hold
        layers.append(re.split(r"\s{2,}", line.strip(), maxsplit=1)[0])
    return layers


def _contract() -> dict[str, object]:
    config = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    linter = config["tool"]["importlinter"]
    (contract,) = linter["contracts"]
    return dict(contract)


def test_the_contract_lists_the_order_the_design_page_shows() -> None:
    contract = _contract()
    assert contract["type"] == "layers"
    assert contract["layers"] == _design_layers()


def test_the_contract_lists_no_exceptions() -> None:
    contract = _contract()
    assert "ignore_imports" not in contract
    assert "unmatched_ignore_imports_alerting" not in contract


def test_every_part_of_the_package_is_in_a_layer() -> None:
    listed = {part.strip() for layer in _design_layers() for part in re.split(r"[|:]", layer)}
    package = ROOT / "chaintwin"
    parts = {p.name for p in package.iterdir() if (p / "__init__.py").is_file()}
    parts |= {p.stem for p in package.glob("*.py") if p.stem not in ("__init__", "__main__")}
    assert parts == listed


def _function_local(module: Path, imported: str) -> bool:
    """Whether ``module`` imports ``imported`` inside a function (and not at its top)."""
    tree = ast.parse(module.read_text(encoding="utf-8"))
    top = {n.module for n in tree.body if isinstance(n, ast.ImportFrom) and n.module is not None}
    local = {
        n.module
        for f in ast.walk(tree)
        if isinstance(f, ast.FunctionDef | ast.AsyncFunctionDef)
        for n in ast.walk(f)
        if isinstance(n, ast.ImportFrom) and n.module is not None
    }
    return imported in local and imported not in top


def test_the_checker_sees_function_local_imports() -> None:
    grimp = pytest.importorskip("grimp")
    module = ROOT / "chaintwin" / "calibrating" / "procedure.py"
    assert _function_local(module, "chaintwin.weigh.weigh")
    graph = grimp.build_graph("chaintwin", cache_dir=None)
    assert graph.direct_import_exists(
        importer="chaintwin.calibrating.procedure", imported="chaintwin.weigh.weigh"
    )


def test_the_layers_hold() -> None:
    linter = Path(sys.executable).parent / "lint-imports"
    if not linter.exists():
        pytest.skip("import-linter is not installed (the dev extra has it)")
    run = subprocess.run(
        [str(linter), "--no-cache", "--no-logo"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        check=False,
    )
    assert run.returncode == 0, run.stdout + run.stderr
    assert "1 kept, 0 broken" in run.stdout
