"""Weighing judged over randomly drawn conveyors, every realism effect on.

Runs scripts/evaluate_fidelity.py as the user guide documents it: 30 conveyors.
"""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path
from types import ModuleType

import pytest

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "evaluate_fidelity.py"


def _script() -> ModuleType:
    spec = importlib.util.spec_from_file_location("evaluate_fidelity", SCRIPT)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def test_with_the_drift_allowance_the_uncertainty_is_honest_over_random_conveyors(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "fidelity.json"
    # the evaluation of the user guide, as documented (about 20 s)
    argv = ["weighing", "--json", str(out)]
    assert _script().main(argv) == 0
    printed = capsys.readouterr().out
    assert "several_loads" in printed and "sensitivity" in printed
    data = json.loads(out.read_text())
    rows = {(s["protocol"], s["drift"], s["mode"]): s for s in data["summary"]}
    assert len(data["conveyors"]) == 30
    # several_loads: honest (the target: >= 90 % within 2u, none beyond 5u,
    # at most 2 % unweighable); one_load_several_speeds falls short where the
    # slow plateaus meet Stribeck friction (documented in the user guide):
    # these bounds guard what is reached now
    bounds = {"several_loads": (0.9, 0.0, 2.4), "one_load_several_speeds": (0.85, 0.04, 2.2)}
    for protocol, (within_2u, beyond_5u, inflation) in bounds.items():
        for drift in ("none", "drift10"):
            s = rows[protocol, drift, "unknown"]
            assert s["n"] == 180 and s["calibration_failures"] == 0
            assert s["within_2u"] >= within_2u, s
            assert s["beyond_5u"] <= beyond_5u, s
            assert s["mu_median_rel_error"] < 0.02, s
            assert s["unweighable_share"] <= 0.02, s
        both = rows[protocol, "both", "unknown"]
        assert both["u_over_error"] <= inflation, both
        # trusting the calibration's losses under drift is what is dishonest
        assert rows[protocol, "drift10", "trusted"]["beyond_5u"] > 0.2
    assert {t["protocol"] for t in data["targets"]} == {"several_loads", "one_load_several_speeds"}
    # a reference load measures the payload's torque: a belt mass 3 % off in the
    # profile does not move the weight; empty runs alone lean on the profile
    assert rows["several_loads", "none", "unknown"]["belt_mass_3pct_median_kg"] < 0.05
    assert rows["one_load_several_speeds", "none", "unknown"]["belt_mass_3pct_median_kg"] > 0.1
