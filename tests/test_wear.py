"""Usage-based wear: usage per recording, cumulative usage, wear rate per t·km."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import REFERENCE_PROFILE

from chaintwin.calibrating.procedure import calibrate
from chaintwin.diagnose.health import FeatureBaseline
from chaintwin.diagnose.monitor import ConveyorMonitor
from chaintwin.diagnose.records import MonitorSettings
from chaintwin.diagnose.wear import usage_summary, wear_rates
from chaintwin.read.profile import load_profile, parse_profile
from chaintwin.simulate.faults import Fault
from chaintwin.simulate.fleet import generate
from chaintwin.simulate.virtual import run_virtual
from chaintwin.validate.checks import load_recording
from chaintwin.weigh.tlf import belt_travel_m

PROFILE = load_profile(REFERENCE_PROFILE)
T0 = datetime(2026, 1, 1, tzinfo=UTC)
BASE = {"friction": FeatureBaseline(1.0, 0.0, 0.01, 20, 0, 20.0)}


def _history(usage_kg_m: float, rate_per_t_km: float, seed: int) -> list[dict[str, Any]]:
    """40 results, each carrying usage_kg_m; friction rises by rate per t·km plus noise."""
    rng = np.random.default_rng(seed)
    cum = np.cumsum(np.full(40, usage_kg_m)) / 1e6
    return [
        {
            "status": "monitored",
            "recorded_at": (T0 + timedelta(hours=4 * k)).isoformat(),
            "features": {
                "usage_kg_m": usage_kg_m,
                "friction": 1.0 + rate_per_t_km * cum[k] + rng.normal(0.0, 0.002),
                "payload_inertia_kg": 20.0,
            },
        }
        for k in range(40)
    ]


def test_wear_rate_is_per_usage_not_per_day() -> None:
    # two conveyors wearing alike per t·km; one carries twice as much per recording
    light = _history(2000.0, 0.5, 1)
    heavy = _history(4000.0, 0.5, 2)
    (r_light,) = wear_rates(BASE, light, "")
    (r_heavy,) = wear_rates(BASE, heavy, "")
    for r in (r_light, r_heavy):
        assert r["feature"] == "friction"
        assert abs(r["rate_per_t_km"] - 0.5) < 3 * r["rate_stderr"]
    # per day the heavy one rises twice as fast
    day_light = light[-1]["features"]["friction"] - light[0]["features"]["friction"]
    day_heavy = heavy[-1]["features"]["friction"] - heavy[0]["features"]["friction"]
    assert day_heavy / day_light == pytest.approx(2.0, rel=0.2)
    assert usage_summary(heavy) == {"total_t_km": pytest.approx(0.16), "recordings": 40}
    assert wear_rates(BASE, light[:5], "") == []  # too few results


def test_monitor_records_the_usage_of_each_recording(tmp_path: Path) -> None:
    out = generate(PROFILE, tmp_path / "runs", days=1, per_day=6, seed=9)
    cal_files = sorted((out.folder / "calibration").glob("*.csv"))
    cal = calibrate([load_recording(f, profile=PROFILE).recording for f in cal_files], PROFILE)
    mon = ConveyorMonitor(PROFILE, MonitorSettings(baseline_n=5), cal)
    total = 0.0
    for f in sorted(out.folder.glob("*.csv")):
        rec = load_recording(f, profile=PROFILE).recording
        (res,) = mon.process(rec, f.name) or [None]
        assert res is not None
        expected = (res.payload_kg or 0.0) * belt_travel_m(rec, cal.id_profile)
        assert res.features["usage_kg_m"] == pytest.approx(expected)
        assert expected > 0.0
        total += expected
    usage = mon.summary()["usage"]
    assert usage["total_t_km"] == pytest.approx(total / 1e6)
    assert usage["recordings"] == 6


def _friction_run(profile: Any, cal: Any) -> tuple[ConveyorMonitor, list[Any]]:
    """30 recordings, the rail friction rising linearly to +30 % from the 9th."""
    rng = np.random.default_rng(1)
    mon = ConveyorMonitor(profile, MonitorSettings(baseline_n=5, x=3, y=10), cal)
    results = []
    for k in range(30):
        rise = 0.3 * (k - 7) / 22
        run = run_virtual(
            PROFILE,
            payload_kg=float(rng.uniform(10.0, 40.0)),
            faults=[Fault("friction", rise)] if rise > 0 else [],
            seed=k,
            recorded_at=T0 + timedelta(hours=3 * k),
        )
        results += mon.process(run.recording, f"r{k:02d}")
    return mon, results + mon.finish()


def test_wear_that_usage_explains_is_expected_not_alarmed(tmp_path: Path) -> None:
    out = generate(PROFILE, tmp_path / "w", days=1, per_day=1, seed=3)
    cal_files = sorted((out.folder / "calibration").glob("*.csv"))
    cal = calibrate([load_recording(f, profile=PROFILE).recording for f in cal_files], PROFILE)
    mon, plain = _friction_run(PROFILE, cal)
    assert any(a.feature == "friction" for a in mon.alarms)
    # the usage since the baseline: the monitored recordings' usage summed, in t·km
    monitored = [r for r in plain if r.status == "monitored"]
    used = np.cumsum([r.features["usage_kg_m"] or 0.0 for r in monitored]) / 1e6
    got = [r.features["usage_since_baseline_t_km"] for r in monitored]
    assert got == pytest.approx(list(used))
    # a monitor that kept only its latest results (as the store keeps them) carries on
    # from the latest one's usage, not from the sum of what it kept
    mon.history = mon.history[-3:]
    mon._usage_kg_m = None
    assert mon._usage_so_far() == pytest.approx(used[-1] * 1e6)
    assert mon.baselines is not None
    fb = mon.baselines["friction"]
    weighed = [(r, u) for r, u in zip(monitored, used, strict=True) if r.payload_kg is not None]
    rise = max((r.features["friction"] - fb.expected(20.0)) / u for r, u in weighed)
    assert rise > 0.0
    data = PROFILE.model_dump(mode="json")
    # wear at twice the largest rise per t·km: expected, no friction alarm
    expected = parse_profile(data | {"expected_wear": {"friction": 2.0 * rise}}, "w.yaml")
    mon2, worn = _friction_run(expected, cal)
    assert not any(a.feature == "friction" for a in mon2.alarms)
    assert [r.features["friction"] for r in worn] == [r.features["friction"] for r in plain]
    # a tenth of it: the friction rises faster than the usage explains and alarms
    little = parse_profile(data | {"expected_wear": {"friction": 0.1 * rise}}, "w.yaml")
    mon3, _ = _friction_run(little, cal)
    assert any(a.feature == "friction" for a in mon3.alarms)
