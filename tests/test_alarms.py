"""Alarms: one per probable cause with its evidence, the ISA-18.2 lifecycle."""

from __future__ import annotations

import json
from datetime import UTC, datetime, timedelta
from pathlib import Path

import pytest

from chaintwin.diagnose.alarms import close_quiet_alarms, open_alarm
from chaintwin.diagnose.records import Acknowledgement, Alarm, Shelving

T0 = datetime(2026, 1, 5, 8, 0, tzinfo=UTC)


def _at(k: int) -> datetime:
    return T0 + timedelta(minutes=10 * k)


def _open(alarms: list[Alarm], feature: str, cause: str, k: int, **kw: object) -> Alarm:
    return open_alarm(
        alarms,
        conveyor="c1",
        feature=feature,
        cause=cause,
        change=0.5,
        when=_at(k),
        window=[False, True, True],
        window_times=[_at(k - 2).isoformat(), _at(k - 1).isoformat(), _at(k).isoformat()],
        **kw,  # type: ignore[arg-type]
    )


def test_features_of_one_cause_join_one_alarm_a_second_cause_opens_another() -> None:
    alarms: list[Alarm] = []
    first = _open(alarms, "impact_energy_max", "obstruction", 3, value=4.0, z=9.0)
    same = _open(alarms, "crest_factor", "obstruction", 4, value=7.5, z=6.0)
    again = _open(alarms, "impact_energy_max", "obstruction", 5, value=5.0, z=11.0)
    other = _open(alarms, "friction", "friction", 5, value=0.3, z=8.0)
    assert first is same is again
    assert other is not first
    assert len(alarms) == 2
    # the lead is the feature that opened it; the evidence lists each feature once
    assert first.feature == "impact_energy_max"
    assert first.since == _at(2).isoformat()
    assert [(e.feature, e.value, e.z) for e in first.evidence] == [
        ("impact_energy_max", 5.0, 11.0),
        ("crest_factor", 7.5, 6.0),
    ]
    assert first.evidence[1].since == _at(3).isoformat()
    assert first.last_seen == _at(5).isoformat()
    d = first.to_dict(now=_at(5))
    assert d["evidence"][1] == {
        "feature": "crest_factor",
        "kind": "statistical",
        "value": 7.5,
        "z": 6.0,
        "since": _at(3).isoformat(),
    }
    assert Alarm.from_dict(d).evidence == first.evidence


def test_a_grouped_alarm_closes_only_when_all_its_features_are_quiet() -> None:
    alarms: list[Alarm] = []
    a = _open(alarms, "impact_energy_max", "obstruction", 3)
    _open(alarms, "crest_factor", "obstruction", 3)
    quiet = [False] * 4
    close_quiet_alarms(
        alarms, {"impact_energy_max": quiet, "crest_factor": [True, *quiet[1:]]}, 4, _at(6)
    )
    assert a.is_open
    assert a.lifecycle(_at(6)) == "returned_unacknowledged"
    close_quiet_alarms(alarms, {"impact_energy_max": quiet, "crest_factor": quiet}, 4, _at(7))
    assert not a.is_open
    assert a.lifecycle(_at(7)) == "closed"
    # the cause may open again: a new alarm
    b = _open(alarms, "crest_factor", "obstruction", 8)
    assert b is not a and len(alarms) == 2


def test_lifecycle_words() -> None:
    alarms: list[Alarm] = []
    a = _open(alarms, "friction", "friction", 3)
    close_quiet_alarms(alarms, {"friction": [True]}, 4, _at(3))
    assert a.lifecycle(_at(3)) == "unacknowledged"
    a.acknowledged = Acknowledgement("ann", "seen", _at(4).isoformat())
    assert a.lifecycle(_at(4)) == "acknowledged"
    a.shelved = Shelving("ann", "repair planned", _at(4).isoformat(), _at(10).isoformat())
    assert a.lifecycle(_at(5)) == "shelved"
    assert not a.counts(_at(5))
    # the shelf ends by itself: the alarm returns to the state it had
    assert a.lifecycle(_at(10)) == "acknowledged"
    assert a.counts(_at(10))
    a.out_of_service, a.out_of_service_until = True, _at(20).isoformat()
    assert a.lifecycle(_at(11)) == "out_of_service"
    assert a.lifecycle(_at(21)) == "acknowledged"
    a.close(_at(22).isoformat(), "quiet")
    assert a.lifecycle(_at(23)) == "closed"
    assert not a.counts(_at(23))


def test_alarms_stored_before_evidence_rest_on_their_feature() -> None:
    old = {
        "id": "ab12cd34",
        "conveyor": "c1",
        "feature": "friction",
        "cause": "friction",
        "change": 0.4,
        "since": "2026-01-05T08:00:00+00:00",
        "opened_at": "2026-01-05T08:20:00+00:00",
        "last_seen": "2026-01-05T08:20:00+00:00",
        "status": "open",
        "acknowledged": None,
    }
    a = Alarm.from_dict(old)
    assert [(e.feature, e.since) for e in a.evidence] == [("friction", old["since"])]
    assert a.lifecycle(T0) == "unacknowledged"
    assert a.comments == [] and a.shelved is None


def test_a_feature_whose_cause_reads_otherwise_carries_or_merges_its_alarm() -> None:
    alarms: list[Alarm] = []
    gear = _open(alarms, "impact_energy_max", "gear", 3)
    _open(alarms, "crest_factor", "gear", 3)
    # the same features later read as an obstacle, no obstruction alarm open: relabelled
    again = _open(alarms, "crest_factor", "obstruction", 4)
    assert again is gear and gear.cause == "obstruction" and len(alarms) == 1
    # a third alarm of another cause, then one of its features reads as the obstacle:
    # both are one fault, one alarm (the other's id still names it)
    wear = _open(alarms, "residual_kurtosis", "bearing", 5)
    joined = _open(alarms, "residual_kurtosis", "obstruction", 6)
    assert joined is gear and alarms == [gear]
    assert gear.merged == [wear.id] and gear.answers_to(wear.id)
    assert [e.feature for e in gear.evidence] == [
        "impact_energy_max",
        "crest_factor",
        "residual_kurtosis",
    ]


def _state_file(tmp_path: Path) -> Path:
    from chaintwin.diagnose.state import empty_state, save_state

    alarms: list[Alarm] = []
    _open(alarms, "impact_energy_max", "obstruction", 3, value=4.0, z=9.0)
    _open(alarms, "crest_factor", "obstruction", 4, value=7.5, z=6.0)
    data = empty_state()
    data["conveyors"]["c1"] = {"alarms": [a.to_dict() for a in alarms]}
    path = tmp_path / "plant.state"
    save_state(path, data)
    return path


def _cli(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    from chaintwin.cli.app import main

    code = main(args)
    out, err = capsys.readouterr()
    return code, out, err


def test_cli_alarms_on_a_state_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    state = _state_file(tmp_path)
    st = ["--state", str(state)]
    code, out, _ = _cli(["alarms", "list", *st, "--json"], capsys)
    assert code == 0
    (alarm,) = json.loads(out)
    aid = alarm["id"]
    assert alarm["lifecycle"] == "unacknowledged"
    assert [e["feature"] for e in alarm["evidence"]] == ["impact_energy_max", "crest_factor"]
    assert _cli(["alarms", "acknowledge", aid, "--by", "ann", "--why", "WO 7", *st], capsys)[0] == 0
    code, out, _ = _cli(["alarms", "list", "--lifecycle", "acknowledged", "--json", *st], capsys)
    assert [a["id"] for a in json.loads(out)] == [aid]
    assert (
        _cli(
            ["alarms", "shelve", aid, "--by", "ann", "--why", "parts", "--minutes", "90", *st],
            capsys,
        )[0]
        == 0
    )
    code, out, _ = _cli(["alarms", "list", "--lifecycle", "shelved", "--json", *st], capsys)
    (shelved,) = json.loads(out)
    assert shelved["shelved_until"] is not None
    until = datetime.fromisoformat(shelved["shelved_until"])
    assert timedelta(minutes=89) < until - datetime.now(UTC) <= timedelta(minutes=90)
    assert _cli(["alarms", "unshelve", aid, "--by", "ann", *st], capsys)[0] == 0
    assert _cli(["alarms", "comment", aid, "rail bolt loose", "--by", "bob", *st], capsys)[0] == 0
    code, out, _ = _cli(["alarms", "list", "--status", "open", "--json", *st], capsys)
    (a,) = json.loads(out)
    assert a["lifecycle"] == "acknowledged"
    assert [(c["by"], c["text"]) for c in a["comments"]] == [("bob", "rail bolt loose")]
    # a conveyor out of service: its alarms read so, then back
    until_text = (datetime.now(UTC) + timedelta(hours=4)).isoformat()
    oos = ["out-of-service", "--conveyor", "c1", "--by", "ann", "--why", "chain swap"]
    assert _cli([*oos, "--until", until_text, *st], capsys)[0] == 0
    code, out, _ = _cli(["alarms", "list", "--lifecycle", "out_of_service", "--json", *st], capsys)
    assert [x["id"] for x in json.loads(out)] == [aid]
    assert _cli(["out-of-service", "--conveyor", "c1", "--by", "ann", "--end", *st], capsys)[0] == 0
    code, out, _ = _cli(["alarms", "list", "--json", *st], capsys)
    assert json.loads(out)[0]["lifecycle"] == "acknowledged"
    assert _cli(["alarms", "list", "--status", "closed", *st], capsys)[1].strip() == "no alarms"


def test_cli_alarm_mistakes_are_one_line_errors(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    state = _state_file(tmp_path)
    before = state.read_bytes()
    st = ["--state", str(state)]
    cases = [
        (
            ["alarms", "shelve", "nope", "--by", "a", "--why", "x", "--minutes", "5", *st],
            "no alarm 'nope'",
        ),
        (["alarms", "list", "--lifecycle", "sleeping", *st], "lifecycle 'sleeping' must be one of"),
        (["alarms", "list", "--status", "gone", *st], "status 'gone' must be open or closed"),
        (
            ["out-of-service", "--conveyor", "c9", "--by", "a", "--why", "x", *st],
            "no conveyor 'c9'",
        ),
        (
            [
                "out-of-service",
                "--conveyor",
                "c1",
                "--by",
                "a",
                "--why",
                "x",
                "--until",
                "soon",
                *st,
            ],
            "--until 'soon'",
        ),
    ]
    for args, says in cases:
        code, _, err = _cli(args, capsys)
        assert code == 2, args
        assert says in err and len(err.strip().splitlines()) == 1, err
    code, out, _ = _cli(["alarms", "list", "--json", *st], capsys)
    aid = json.loads(out)[0]["id"]
    code, _, err = _cli(
        ["alarms", "shelve", aid, "--by", "a", "--why", "x", "--minutes", "0", *st], capsys
    )
    assert code == 2 and "minutes 0 must be from 1" in err
    code, _, err = _cli(["alarms", "unshelve", aid, "--by", "a", *st], capsys)
    assert code == 2 and "is not shelved" in err
    assert state.read_bytes() == before  # nothing was changed by a refused command


def test_alarms_kept_before_grouping_group_by_cause_with_their_acknowledgement() -> None:
    from chaintwin.diagnose.alarms import group_by_cause

    def old(aid: str, feature: str, cause: str, k: int) -> Alarm:
        return Alarm(aid, "c1", feature, cause, 0.2, _at(k).isoformat(), _at(k).isoformat(),
                     _at(k).isoformat())  # fmt: skip

    first, second, third = (
        old("a1", "impact_energy_max", "obstruction", 1),
        old("a2", "crest_factor", "obstruction", 2),
        old("a3", "friction", "friction", 2),
    )
    second.acknowledged = Acknowledgement("ann", "seen", _at(3).isoformat())
    closed = old("a0", "crest_factor", "obstruction", 0)
    closed.close(_at(1).isoformat(), "quiet")
    alarms = [closed, first, second, third]
    for a in alarms:
        a.evidence = Alarm.from_dict(a.to_dict() | {"evidence": []}).evidence
    assert group_by_cause(alarms) == {"a2": "a1"}
    assert alarms == [closed, first, third]
    assert [e.feature for e in first.evidence] == ["impact_energy_max", "crest_factor"]
    assert first.merged == ["a2"] and first.answers_to("a2")
    assert first.acknowledged is not None and first.acknowledged.by == "ann"
    assert first.last_seen == _at(2).isoformat() and first.since == _at(1).isoformat()
    assert group_by_cause(alarms) == {}  # grouped once


def test_cli_alarms_on_a_store_are_audited(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """On a store (here the 0.1.0 fixture, upgraded), the commands change it and audit it."""
    import shutil

    from chaintwin.store.store import Store
    from chaintwin.web.access import audit_entries

    fixture = Path(__file__).parent / "fixtures" / "store-c909904.sqlite"
    shutil.copyfile(fixture, tmp_path / "plant.db")
    db = f"sqlite:///{tmp_path / 'plant.db'}"
    assert _cli(["db", "upgrade", "--db", db], capsys)[0] == 0
    code, out, _ = _cli(["alarms", "list", "--db", db, "--status", "closed", "--json"], capsys)
    (closed,) = json.loads(out)
    assert closed["lifecycle"] == "closed"
    aid = closed["id"]
    code, _, err = _cli(
        ["alarms", "shelve", aid, "--by", "a", "--why", "x", "--minutes", "5", "--db", db], capsys
    )
    assert code == 2 and "only open alarms are shelved" in err
    assert (
        _cli(
            ["alarms", "comment", aid, "cause found: dry rails", "--by", "ann", "--db", db], capsys
        )[0]
        == 0
    )
    until = (datetime.now(UTC) + timedelta(hours=2)).isoformat()
    oos = ["out-of-service", "--conveyor", "white-belt-01", "--by", "ann", "--why", "rail work"]
    assert _cli([*oos, "--until", until, "--db", db], capsys)[0] == 0
    store = Store(db)
    (alarm,) = store.alarms()
    assert [c.text for c in alarm.comments] == ["cause found: dry rails"]
    state = store.state("white-belt-01")
    assert state is not None and state.out_of_service is not None
    assert state.out_of_service["why"] == "rail work"
    actions = [(e["who"], e["action"]) for e in audit_entries(store)]
    assert actions[:2] == [("ann", "out_of_service"), ("ann", "comment")]
    store.close()


def test_an_exceedance_no_impact_search_could_explain_counts_once_confirmed() -> None:
    """3 of 10 on a flat baseline 0.006 +- 0.00046 Nm: 0.012 exceeds, 0.006 does not.

    Recordings whose torque could not be searched for events (``confirm``):
    an exceedance alone (an item caught for part of a 1 ms scope) never
    counts; one the next recording confirms counts both; one after a counted
    exceedance counts at once. Searched recordings count as before.
    """
    from chaintwin.diagnose.alarms import judge
    from chaintwin.diagnose.health import FeatureBaseline
    from chaintwin.diagnose.records import MonitorSettings

    fb = FeatureBaseline(0.006, 0.0, 0.00046, count=20, outliers=0, mean_payload_kg=25.0)
    settings = MonitorSettings()
    base = {"residual_std": fb}
    when = datetime(2026, 3, 2, tzinfo=UTC)

    def run(seq: list[tuple[float, bool]]) -> tuple[list[bool], list[list[str]]]:
        windows: dict[str, list[bool]] = {}
        times: dict[str, list[str | None]] = {}
        met_at = []
        for k, (value, confirm) in enumerate(seq):
            met, _, _ = judge(
                base,
                {"residual_std": value, "payload_inertia_kg": 25.0},
                windows,
                times,
                settings,
                when + timedelta(hours=k),
                confirm=confirm,
            )
            met_at.append(met)
        return windows["residual_std"], met_at

    hi, lo = 0.012, 0.006
    # three lone events on unsearched recordings: nothing counts, no alarm
    win, met = run([(hi, True), (lo, True), (hi, True), (lo, True), (hi, True), (lo, True)])
    assert win == [False] * 6 and not any(met)
    # the same on searched recordings: 3 of 10, met at the third
    win, met = run([(hi, False), (lo, False), (hi, False), (lo, False), (hi, False)])
    assert win == [True, False, True, False, True] and met[-1] == ["residual_std"]
    # a fault that grows on unsearched recordings: the second confirms the first
    win, met = run([(lo, True), (hi, True), (hi, True), (hi, True)])
    assert win == [False, True, True, True] and met[-1] == ["residual_std"] and not met[2]
    # after a searched exceedance, an unsearched one counts at once
    win, _ = run([(hi, False), (hi, True)])
    assert win == [True, True]


def test_caught_recordings_confirm_no_one() -> None:
    """3 of 10 on a flat baseline 0.006 +- 0.00046 Nm: 0.012 exceeds, 0.006 does not.

    Items caught in four recordings in a row (``caught``, the plateau's level
    stepped) exceed four times and count none: a caught recording is
    confirmed only by a neighbour that was not caught. Before the rule they
    confirmed each other (``confirm`` alone): counted from the second on, met
    at the third. A fault that grows and exceeds everywhere loses only the
    caught recordings that no clean neighbour confirms.
    """
    from chaintwin.diagnose.alarms import judge
    from chaintwin.diagnose.health import FeatureBaseline
    from chaintwin.diagnose.records import MonitorSettings

    fb = FeatureBaseline(0.006, 0.0, 0.00046, count=20, outliers=0, mean_payload_kg=25.0)
    settings = MonitorSettings()
    base = {"residual_std": fb}
    when = datetime(2026, 3, 2, tzinfo=UTC)

    def run(seq: list[tuple[float, bool, bool]]) -> tuple[list[bool], list[list[str]]]:
        windows: dict[str, list[bool]] = {}
        times: dict[str, list[str | None]] = {}
        met_at = []
        for k, (value, confirm, caught) in enumerate(seq):
            met, _, _ = judge(
                base,
                {"residual_std": value, "payload_inertia_kg": 25.0},
                windows,
                times,
                settings,
                when + timedelta(hours=k),
                confirm=confirm,
                caught=caught,
            )
            met_at.append(met)
        return windows["residual_std"], met_at

    hi, lo = 0.012, 0.006
    # four events in a row on unsearched (1 ms) recordings, each caught: nothing counts
    events = [(hi, True, True)] * 4 + [(lo, True, False)] * 2
    win, met = run(events)
    assert win == [False] * 6 and not any(met)
    # the same without the mark: they confirm each other, met at the third
    win, met = run([(v, c, False) for v, c, _ in events])
    assert win == [True, True, True, True, False, False] and met[2] == ["residual_std"]
    # on searched recordings (6 ms) caught ones count no more than unsearched ones
    win, met = run([(hi, False, True), (hi, False, True), (lo, False, False)])
    assert win == [False, False, False] and not any(met)
    # a clean exceedance confirms the caught one before it and counts itself
    win, _ = run([(hi, False, True), (hi, False, False)])
    assert win == [True, True]
    # a caught exceedance after a clean one counts (the clean one confirms it) ...
    win, _ = run([(hi, False, False), (hi, False, True)])
    assert win == [True, True]
    # ... but confirms no unsearched exceedance beside it: the first is confirmed
    # by no one, the third waits for the fourth
    win, _ = run([(hi, True, False), (hi, True, True), (hi, True, False), (hi, True, False)])
    assert win == [False, True, True, True]
