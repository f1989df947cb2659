"""scripts/check_same.py's compare: what counts as the same stored results."""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path
from types import ModuleType
from typing import Any

import pytest

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "check_same.py"


@pytest.fixture(scope="module")
def check_same() -> ModuleType:
    spec = importlib.util.spec_from_file_location("check_same", SCRIPT)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules["check_same"] = module
    spec.loader.exec_module(module)
    return module


def _dump() -> dict[str, Any]:
    return {
        "inputs": {"a.csv": "00"},
        "results": [{"payload_kg": 28.5, "status": "ok", "features": {"friction": 1.02}}],
        "alarms": [{"id": "alarm-1", "cause": "friction", "change": 0.4}],
        "events": [],
        "warnings": [["c", "a.csv", "torque_saturated", "for 12 ms"]],
        "summary": {"processed": 1},
    }


def _write(path: Path, data: dict[str, Any]) -> Path:
    path.write_text(json.dumps(data))
    return path


@pytest.mark.slow
def test_tiny_differences_pass_and_larger_ones_fail(
    check_same: ModuleType, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    ref = _write(tmp_path / "ref.json", _dump())
    near = _dump()
    near["results"][0]["payload_kg"] *= 1 + 1e-12
    assert check_same.compare(ref, _write(tmp_path / "near.json", near), 1e-9) == 0
    far = _dump()
    far["alarms"][0]["change"] = 0.4 * (1 + 1e-6)
    assert check_same.compare(ref, _write(tmp_path / "far.json", far), 1e-9) == 1
    assert "largest relative difference 1e-06" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("where", "value"),
    [
        (("warnings", 0, 2), "irregular_sample_time"),
        (("alarms", 0, "cause"), "bearing"),
        (("results", 0, "status"), "alarm"),
    ],
)
def test_any_other_word_fails(
    check_same: ModuleType, tmp_path: Path, where: tuple[Any, ...], value: str
) -> None:
    ref = _write(tmp_path / "ref.json", _dump())
    other = _dump()
    node: Any = other
    for key in where[:-1]:
        node = node[key]
    node[where[-1]] = value
    assert check_same.compare(ref, _write(tmp_path / "other.json", other), 1e-9) == 1


def test_other_inputs_are_not_comparable(check_same: ModuleType, tmp_path: Path) -> None:
    other = _dump()
    other["inputs"] = {"a.csv": "01"}
    ref = _write(tmp_path / "ref.json", _dump())
    assert check_same.compare(ref, _write(tmp_path / "o.json", other), 1e-9) == 2


def test_rel_diff(check_same: ModuleType) -> None:
    nan = float("nan")
    assert check_same.rel_diff(nan, nan) == 0.0
    assert check_same.rel_diff(1.0, nan) == float("inf")
    assert check_same.rel_diff(2.0, 1.0) == 0.5
