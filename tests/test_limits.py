"""Absolute limits from the profile: schema, rules and the monitor's alarms."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
from conftest import REFERENCE_PROFILE

from chaintwin.calibrating.procedure import calibrate
from chaintwin.diagnose.health import x_of_y
from chaintwin.diagnose.limits import judge_limits
from chaintwin.diagnose.monitor import ConveyorMonitor
from chaintwin.diagnose.records import Alarm, MonitorSettings
from chaintwin.errors import MonitorError, ProfileError
from chaintwin.read.profile import ConveyorProfile, LimitSpec, load_profile, parse_profile
from chaintwin.simulate.faults import Fault
from chaintwin.simulate.fleet import generate
from chaintwin.validate.checks import load_recording

PROFILE = load_profile(REFERENCE_PROFILE)
SETTINGS = MonitorSettings(baseline_n=5, x=3, y=10)


def _with_limits(limits: dict[str, object]) -> ConveyorProfile:
    data = PROFILE.model_dump(mode="json")
    data["limits"] = limits
    return parse_profile(data, "test.yaml")


def test_profile_limits_are_read_and_checked() -> None:
    prof = _with_limits({"friction": {"warn": 1.15, "alarm": 1.30}})
    assert prof.limits == {"friction": LimitSpec(warn=1.15, alarm=1.30, rule="x_of_y")}
    # the hash of a profile without the new keys is what it was
    data = PROFILE.model_dump(mode="json")
    assert "limits" not in data or data["limits"] is None
    assert parse_profile(data, "x.yaml").content_hash() == PROFILE.content_hash()
    assert prof.content_hash() != PROFILE.content_hash()
    with pytest.raises(ProfileError, match=r"limits\.friction"):
        _with_limits({"friction": {"warn": 1.4, "alarm": 1.3}})
    with pytest.raises(ProfileError, match=r"limits\.friction"):
        _with_limits({"friction": {}})
    with pytest.raises(ProfileError, match="rule"):
        _with_limits({"friction": {"alarm": 1.3, "rule": "sometimes"}})
    with pytest.raises(MonitorError, match=r"limits\.frction"):
        ConveyorMonitor(_with_limits({"frction": {"alarm": 1.3}}), SETTINGS)


@pytest.mark.parametrize("rule", ["immediate", "x_of_y"])
def test_rules_on_a_hand_made_sequence(rule: str) -> None:
    spec = LimitSpec(warn=1.15, alarm=1.30, rule=rule)  # type: ignore[arg-type]
    series = [1.0, 1.2, 1.35, 1.0, 1.4, 1.0, math.nan, 1.31, 1.0, 1.0]
    windows: dict[str, list[bool]] = {}
    times: dict[str, list[str | None]] = {}
    checks = [
        judge_limits({"friction": spec}, {"friction": v}, windows, times, SETTINGS, f"t{k}")[0]
        for k, v in enumerate(series)
    ]
    exceeded = [c.exceeded for c in checks]
    assert exceeded == [False, False, True, False, True, False, False, True, False, False]
    met = [c.met for c in checks]
    if rule == "immediate":
        assert met == exceeded  # the first recording over the limit alarms
    else:
        assert met == x_of_y(exceeded, 3, 10)  # as the statistical alarms do
        assert met.index(True) == 7
    codes = [None if c.warning is None else c.warning["code"] for c in checks]
    assert codes[1] == "limit_warn"
    assert codes[0] is None and codes[6] is None
    assert codes[2] == (None if rule == "immediate" else "limit_exceeded")
    assert windows["limit:friction"] == exceeded


def test_alarm_records_keep_their_rule() -> None:
    old = {
        "id": "ab",
        "conveyor": "c",
        "feature": "friction",
        "cause": "friction",
        "change": 0.2,
        "since": None,
        "opened_at": None,
        "last_seen": None,
        "status": "open",
        "acknowledged": None,
    }
    a = Alarm.from_dict(old)  # stored before rules existed
    assert (a.rule, a.kind, a.limit) == ("x_of_y", "statistical", None)
    b = Alarm.from_dict(old | {"rule": "immediate", "kind": "limit", "limit": 1.3})
    assert Alarm.from_dict(b.to_dict()) == b
    assert b.to_dict()["rule"] == "immediate"


@pytest.fixture(scope="module")
def friction_series(tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    root = tmp_path_factory.mktemp("limits")
    generate(PROFILE, root, days=4, per_day=4, faults=[Fault("friction", 0.6)], onset_day=2, seed=5)
    return sorted(root.glob("*.csv"))


@pytest.mark.parametrize("rule", ["immediate", "x_of_y"])
def test_monitor_alarms_on_a_limit(friction_series: list[Path], rule: str) -> None:
    cal_files = sorted((friction_series[0].parent / "calibration").glob("*.csv"))
    cal = calibrate([load_recording(f, profile=PROFILE).recording for f in cal_files], PROFILE)
    prof = _with_limits({"friction": {"warn": 1.1, "alarm": 1.2, "rule": rule}})
    mon = ConveyorMonitor(prof, SETTINGS, cal)
    results = []
    for f in friction_series:
        results += mon.process(load_recording(f, profile=prof).recording, f.name)
    results += mon.finish()
    values = [r.features.get("friction") if r.features else None for r in results]
    over = [v is not None and v > 1.2 for v in values]
    assert any(over), values
    first_over = over.index(True)
    limit_alarm = [any(c.get("rule") == rule for c in r.causes) for r in results]
    expected = over if rule == "immediate" else x_of_y(over, 3, 10)
    assert limit_alarm == expected
    assert limit_alarm.index(True) == (first_over if rule == "immediate" else expected.index(True))
    assert all(r.alarm for r, flag in zip(results, limit_alarm, strict=True) if flag)
    # one alarm per probable cause: the limit opened it, or joined the friction alarm a
    # baseline rule opened first as its evidence
    (alarm,) = [
        a
        for a in mon.open_alarms()
        if a.feature == "friction" or any(e.feature == "friction" for e in a.evidence)
    ]
    if alarm.kind == "limit":
        assert (alarm.feature, alarm.rule, alarm.limit) == ("friction", rule, 1.2)
    else:
        assert any(e.feature == "friction" and e.kind == "limit" for e in alarm.evidence), (
            alarm.evidence
        )


def test_a_key_with_a_line_break_gives_a_one_line_error() -> None:
    # found by tests/test_loader_fuzz.py: the field path named the key as written
    data = PROFILE.model_dump(mode="json") | {"be\nlt": 1}
    with pytest.raises(ProfileError) as info:
        parse_profile(data, "x.yaml")
    assert "\n" not in str(info.value) and "be\\nlt" in str(info.value)
    with pytest.raises(MonitorError) as err:
        ConveyorMonitor(_with_limits({"fric\ntion": {"alarm": 1.3}}), SETTINGS)
    assert "\n" not in str(err.value) and "fric\\ntion" in str(err.value)
