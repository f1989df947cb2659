"""Weighing judged over randomly drawn conveyors, every realism effect on.

Runs scripts/evaluate_fidelity.py as the user guide documents it: 30 conveyors.
"""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "evaluate_fidelity.py"


def _script() -> ModuleType:
    spec = importlib.util.spec_from_file_location("evaluate_fidelity", SCRIPT)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


@pytest.mark.slow
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
    # both honest (the target: >= 90 % within 2u, none beyond 5u, at most 2 %
    # unweighable); empty runs stay honest where slow plateaus stick-slip because
    # the calibration falls back to losses linear in speed and says so. The
    # median uncertainty over the median error misses the 2.2 target with empty
    # runs (2.76: the ±10 % drift allowance is carried where no drift happened;
    # documented in the user guide): these bounds guard what is reached now.
    # With the set point's noise on in the evaluation (the speed controller's
    # answer to its encoder, in the set point and through the torque lag in the
    # actual torque) the ratios are 2.47 and 3.03 (2.47 and 3.09 with the
    # previous release's weighing on the same recordings). With the inertia
    # signature read from the ramps only (its plateau windows had added
    # precision that was noise) they are 3.14 and 3.38: the inertia payload's
    # stated uncertainty is now 10-25 % above its scatter, and the median error
    # fell (0.62 and 0.94 kg without drift)
    bounds = {"several_loads": (0.9, 0.0, 3.2), "one_load_several_speeds": (0.95, 0.0, 3.45)}
    # a calibration may only fail by being refused as physically impossible
    # (fidelity-09's several_loads fit losses of 23 Nm against its 10 Nm torque
    # limit): at most one of the 30 per protocol; its tests go unweighed
    failed = [r for r in data["rows"] if "error" in r]
    assert all("impossible calibration" in r["error"] for r in failed), failed[:1]
    for protocol, (within_2u, beyond_5u, inflation) in bounds.items():
        for drift in ("none", "drift10"):
            s = rows[protocol, drift, "unknown"]
            assert s["n"] == 180 and s["calibration_failures"] <= 6
            assert s["within_2u"] >= within_2u, s
            assert s["beyond_5u"] <= beyond_5u, s
            assert s["mu_median_rel_error"] < 0.02, s
            assert s["unweighable_share"] - s["calibration_failures"] / s["n"] <= 0.02, s
        both = rows[protocol, "both", "unknown"]
        assert both["u_over_error"] <= inflation, both
        # trusting the calibration's losses under drift is what is dishonest
        assert rows[protocol, "drift10", "trusted"]["beyond_5u"] > 0.2
    # the published one-speed method: honest, and where its uncertainty exceeds the
    # belt's own mass, no number at all (the largest error was 670 kg before)
    one = rows["one_load_one_speed", "both", "unknown"]
    assert one["within_2u"] >= 0.95 and one["beyond_5u"] == 0.0, one
    # (now mostly refused at calibration: 9 of its 30 calibrations fitted mu <= 0
    # or losses above the torque limit, numbers a calibration file cannot hold)
    unweighed = one["unweighable_share"] - one["calibration_failures"] / one["n"]
    assert one["max_kg"] < 200.0 and one["unweighable_share"] > 0.02 and unweighed < 0.15, one
    assert {t["protocol"] for t in data["targets"]} == {"several_loads", "one_load_several_speeds"}
    # a reference load measures the payload's torque: a belt mass 3 % off in the
    # profile hardly moves the weight (0.10 kg median: where the heavier belt leaves
    # a constant loss below zero, the calibration refits without it); empty runs
    # alone lean on the profile (0.78 kg)
    assert rows["several_loads", "none", "unknown"]["belt_mass_3pct_median_kg"] < 0.15
    assert rows["one_load_several_speeds", "none", "unknown"]["belt_mass_3pct_median_kg"] > 0.1


def test_stick_slip_on_a_slow_plateau_is_found_and_kept_out_of_mu() -> None:
    """Empty runs at 30/60/100 % on a drawn conveyor whose slow plateau stick-slips.

    The exactly determined three-speed fit reads the stick-slip as losses that
    fall with speed and puts μ 11 % off at ±0.2 %; the calibration finds the
    plateau, refits with losses linear in speed and widens μ by half the change.
    """
    from chaintwin.calibrating.procedure import calibrate, identification_profile
    from chaintwin.identify.regression import RigidModelRegression

    ef = _script()
    rng = np.random.default_rng(4242)  # a seed the evaluation does not use
    conv = [ef.draw_conveyor(rng, k) for k in range(30)][29]
    truth = conv.profile.model.friction
    recs = ef.calibration_runs(conv, 777 + 29)["one_load_several_speeds"]
    cal = calibrate(recs, conv.profile)
    codes = {w.code for w in cal.warnings}
    assert {"stick_slip", "losses_not_physical"} <= codes
    assert cal.case == "one_load_several_speeds" and "BmC" in cal.parameters.fixed
    mu, sd = cal.parameters["mu"], cal.parameters.stderr("mu")
    assert abs(mu - truth) <= 2.0 * sd and abs(mu / truth - 1.0) < 0.05
    plain = RigidModelRegression().fit(recs, identification_profile(conv.profile)).parameters_
    assert abs(plain["mu"] - truth) > 5.0 * plain.stderr("mu")  # what the check repairs


def test_a_payload_less_certain_than_the_belt_is_heavy_is_no_number() -> None:
    from chaintwin.weigh.drift import LossDrift
    from chaintwin.weigh.weigh import UNWEIGHABLE, Signatures, _combine

    loose = Signatures(183.0, 1050.0**2, None, None, 0.0, 0.0, moving_mass_kg=430.0)
    out = _combine(loose, LossDrift())
    assert out.payload_kg is None and out.uncertainty_kg is None
    assert [w.code for w in out.warnings] == [UNWEIGHABLE]
    assert "exceeds the belt's and tray's own mass (430 kg)" in out.warnings[0].message
    tight = Signatures(183.0, 40.0**2, None, None, 0.0, 0.0, moving_mass_kg=430.0)
    assert _combine(tight, LossDrift()).payload_kg == 183.0


def test_the_monitoring_evaluation_counts_the_weighing_s_promise_by_hand() -> None:
    """Three weighings at 0.5u, 2.5u and 6u and one unweighable recording, and a
    second sequence of one at 1u: pooled, 5 recordings, 1 unweighable, 2 of 4
    within 1u, 2 within 2u, 3 within 3u, one beyond 5u, on the first conveyor."""
    path = SCRIPT.parent / "fidelity_monitoring.py"
    spec = importlib.util.spec_from_file_location("fidelity_monitoring", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    first = module._promise(4, 1, [0.5, -2.5, 6.0])
    assert first == {
        "recordings": 4,
        "unweighable": 1,
        "weighed": 3,
        "within_1u": 1,
        "within_2u": 1,
        "within_3u": 2,
        "beyond_5u": 1,
        "largest_z": 6.0,
    }
    rows = [
        {"conveyor": "a", "weighing_before_fault": first},
        {"conveyor": "b", "weighing_before_fault": module._promise(1, 0, [1.0])},
        {"conveyor": "c", "error": "calibration: failed"},
    ]
    pooled = module.promise_summary(rows)
    assert (pooled["recordings"], pooled["unweighable"], pooled["weighed"]) == (5, 1, 4)
    assert (pooled["within_1u"], pooled["within_2u"], pooled["within_3u"]) == (2, 2, 3)
    assert pooled["beyond_5u"] == 1 and pooled["conveyors_beyond_5u"] == ["a"]
    assert (pooled["largest_z"], pooled["largest_z_conveyor"]) == (6.0, "a")


def _monitoring() -> ModuleType:
    path = SCRIPT.parent / "fidelity_monitoring.py"
    spec = importlib.util.spec_from_file_location("fidelity_monitoring", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_a_declined_conveyor_is_drawn_downhill_with_the_other_draws_unchanged() -> None:
    script = _script()
    usual = script.draw_conveyor(np.random.default_rng(5), 3)
    declined = script.draw_conveyor(np.random.default_rng(5), 3, incline_deg=(-15.0, -5.0))
    assert -15.0 <= declined.design["incline_deg"] <= -5.0
    same = ("length_m", "mass_per_m_kg", "teeth", "ratio", "mu", "direction", "sample_time_ms")
    assert {k: declined.design[k] for k in same} == {k: usual.design[k] for k in same}
    # the incline in motor terms carries the conveying direction's sign
    assert declined.profile.belt.incline_deg == pytest.approx(
        declined.design["incline_deg"] * declined.direction
    )


def test_the_monitoring_table_counts_alarms_where_there_is_no_fault_both_ways() -> None:
    """Two friction sequences (delays 4 and 10, one right; one with 3 alarm
    recordings in 2 alarms before its onset), a healthy one with 5 recordings
    in 1 alarm, a declined one quiet and a declined one not run."""
    module = _monitoring()

    def row(series: str, **kw: object) -> dict[str, object]:
        base: dict[str, object] = {
            "series": series,
            "fault": None if series in module.HEALTHY_KINDS else series,
            "first_alarm": None,
            "delay": None,
            "right": False,
            "false_alarms": 0,
            "false_alarm_groups": 0,
            "events_true": 0,
            "events_noted": 0,
        }
        return base | kw

    rows = [
        row("friction", first_alarm=104, delay=4, right=True),
        row("friction", first_alarm=110, delay=10, false_alarms=3, false_alarm_groups=2),
        row("healthy", false_alarms=5, false_alarm_groups=1, events_true=4, events_noted=2),
        row("declined"),
        {"series": "declined", "fault": None, "error": "calibration: failed"},
    ]
    found = {t["fault"]: t for t in module.table(rows)}
    friction = found["friction"]
    assert (friction["sequences"], friction["alarmed"], friction["right"]) == (2, 2, 1)
    assert friction["median_delay"] == 7.0
    assert (friction["false_alarms"], friction["false_alarm_groups"]) == (3, 2)
    assert friction["false_sequences"] == 1
    healthy = found["healthy"]
    assert (healthy["false_alarms"], healthy["false_alarm_groups"]) == (5, 1)
    assert (healthy["events_true"], healthy["events_noted"]) == (4, 2)
    declined = found["declined"]
    assert (declined["sequences"], declined["not_run"], declined["false_alarms"]) == (1, 1, 0)
    assert found["bearing"]["sequences"] == 0 and found["bearing"]["median_delay"] is None
    text = module.markdown(module.table(rows), "title")
    assert "| friction | 2 | 2 | 1 | 7.0 | 3 (1 seq.) | 2 |" in text
    assert "| healthy | 1 | - | - | - | 5 (1 seq.) | 1 |" in text
    assert "| declined | 1 | - | - | - | 0 (0 seq.) | 0 |" in text
