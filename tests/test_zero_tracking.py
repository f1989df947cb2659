"""Zero tracking: known runs measure the loss drift; the allowance follows what the
losses can have moved since, in ``weigh``, in ingest (through a restart) and in the
``monitor --state`` files."""

from __future__ import annotations

import dataclasses
import importlib.util
import json
import math
import sys
from collections.abc import Callable
from datetime import UTC, datetime, timedelta
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest
from conftest import REFERENCE_PROFILE

from chaintwin.calibrating import calibrate
from chaintwin.cli.app import main
from chaintwin.diagnose.state import STATE_FORMAT, load_state
from chaintwin.identify.calibration import Calibration
from chaintwin.identify.defaults import LOSS_DRIFT_REL
from chaintwin.identify.zero_reference import ZeroReference
from chaintwin.ingest import ingest
from chaintwin.read.profile import ConveyorProfile, load_profile
from chaintwin.read.recording import Recording
from chaintwin.read.writer import write_recording
from chaintwin.simulate.virtual import run_virtual
from chaintwin.store.store import Store
from chaintwin.validate import inspect_recording
from chaintwin.weigh import LossDrift, Signatures, weigh
from chaintwin.weigh.zero_tracking import NO_REFERENCE, ZeroTracker, known_run_drift

PROFILE = load_profile(REFERENCE_PROFILE)
TRACKING = PROFILE.model_copy(update={"zero_tracking": True})
"""The profile with zero tracking from known runs switched on (experimental, opt-in)."""
SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "evaluate_fidelity.py"
DAY0 = datetime(2030, 3, 4, 6, 0, tzinfo=UTC)


def _recording(
    payload: float, seed: int, at: datetime, scale: float, *, known: bool = False
) -> Recording:
    rec = run_virtual(PROFILE, payload_kg=payload, seed=seed, recorded_at=at, loss_scale=scale)
    meta = dataclasses.replace(rec.recording.metadata, payload_kg=payload if known else None)
    return dataclasses.replace(rec.recording, metadata=meta, source=f"rec-{seed}.csv")


@pytest.fixture(scope="module")
def cal() -> Calibration:
    recs = [
        run_virtual(PROFILE, payload_kg=p, seed=900 + k, calibration=True).recording
        for k, p in enumerate([0.0, 0.0, 0.0, 40.0])
    ]
    return calibrate(recs, PROFILE)


def test_a_known_empty_run_measures_the_simulated_loss_drift(cal: Calibration) -> None:
    """Known answer: the virtual conveyor's losses scaled by 1.06 and 0.95."""
    for seed, scale in ((31, 1.06), (32, 0.95), (33, 1.0)):
        rec = _recording(0.0, seed, DAY0, scale, known=True)
        w = weigh(inspect_recording(rec, PROFILE), cal)
        assert w.signatures is not None
        found = known_run_drift(w.signatures, 0.0)
        assert found is not None
        delta, var = found
        assert abs(delta - (scale - 1.0)) <= max(3.0 * math.sqrt(var), 0.01), (scale, delta, var)
        assert math.sqrt(var) < 0.02  # far tighter than the blanket ±10 %


def _sig(delta: float, payload: float, rng: np.random.Generator, inertia_sd: float) -> Signatures:
    """Signatures as a recording with drift δ and the given payload reads them (k_f 40 kg)."""
    k_f, f_sd = 40.0, 0.2
    return Signatures(
        friction_kg=payload + delta * k_f + rng.normal(0, f_sd),
        friction_var=f_sd**2,
        inertia_kg=payload + rng.normal(0, inertia_sd),
        inertia_var=inertia_sd**2,
        covariance=0.0,
        drift_friction_kg=k_f,
    )


def test_without_known_runs_the_allowance_narrows_when_stable_and_widens_when_moving() -> None:
    rng = np.random.default_rng(3)
    tracker = ZeroTracker()
    at = DAY0
    assert tracker.allowance(at)[0] == LossDrift.unknown()
    for _ in range(25):  # stable: the losses where the calibration left them
        tracker.observe(_sig(0.0, rng.uniform(0.0, 50.0), rng, 0.8), at)
        at += timedelta(hours=3)
    stable = tracker.allowance(at)[0]
    assert stable.sigma < 0.5 * LOSS_DRIFT_REL
    for _ in range(12):  # the losses move by +9 %
        tracker.observe(_sig(0.09, rng.uniform(0.0, 50.0), rng, 0.8), at)
        at += timedelta(hours=3)
    moving = tracker.allowance(at)[0]
    assert moving.sigma > 2.0 * stable.sigma
    assert moving.sigma == pytest.approx(LOSS_DRIFT_REL) or moving.sigma > 0.05


def test_the_history_narrows_by_its_own_scatter_not_the_claimed_variance() -> None:
    """Known answer: each difference claims ±5 kg of inertia noise (the calibration's
    model error, the same in every recording) but scatters by 0.3 kg (δ to ±0.8 %
    with k_f 40 kg): a stable history narrows to the floor, a +6 % move widens it."""
    rng = np.random.default_rng(8)

    def sig(delta: float, payload: float) -> Signatures:
        s = _sig(delta, payload, rng, 0.3)
        return dataclasses.replace(s, inertia_var=5.0**2)

    tracker = ZeroTracker()
    at = DAY0
    for _ in range(30):
        tracker.observe(sig(0.0, rng.uniform(0.0, 50.0)), at)
        at += timedelta(hours=3)
    stable = tracker.allowance(at, known_runs=False)[0]
    assert stable.sigma < 0.03
    for _ in range(8):
        tracker.observe(sig(0.06, rng.uniform(0.0, 50.0)), at)
        at += timedelta(hours=3)
    moving = tracker.allowance(at, known_runs=False)[0]
    assert abs(0.06 - moving.mean) <= 1.5 * moving.sigma


def test_known_runs_are_not_carried_to_an_inertia_signature_that_misreads_the_payload() -> None:
    """Loaded recordings whose inertia signature reads half the payload (claiming ±1 kg)
    disagree with the known empty runs beyond any warm-up: their allowance is the
    history's, not the known runs' (a correct inertia signature keeps the tracked one)."""
    for share, tracked in ((0.5, False), (1.0, True)):
        rng = np.random.default_rng(9)
        tracker = ZeroTracker()
        for d in range(8):
            start = DAY0 + timedelta(days=d)
            assert tracker.learn_known(_sig(0.0, 0.0, rng, 1.0), 0.0, start)
            for hours in (3, 7, 13):
                payload = rng.uniform(20.0, 60.0)
                s = _sig(0.0, payload, rng, 1.0)
                s = dataclasses.replace(s, inertia_kg=share * payload + rng.normal(0.0, 1.0))
                tracker.observe(s, start + timedelta(hours=hours))
        at = DAY0 + timedelta(days=7, hours=15)
        drift, since = tracker.allowance(at)
        assert since == pytest.approx(15 * 3600.0)
        history = tracker.allowance(at, known_runs=False)[0]
        assert (drift == history) is not tracked, (share, drift, history)


def _daily(
    tracker: ZeroTracker,
    delta_of: Callable[[float], float],
    first: int,
    last: int,
    rng: np.random.Generator,
    inertia_sd: float = 5.0,
) -> list[float]:
    """Known empty runs at 06:00, weighings at 09, 13 and 19 h of days ``first`` to
    ``last - 1``: the true drift's z-scores against the allowance."""
    z = []
    for d in range(first, last):
        start = DAY0 + timedelta(days=d)
        t = (start - DAY0).total_seconds()
        known = _sig(delta_of(t), 0.0, rng, inertia_sd)
        assert tracker.learn_known(known, 0.0, start)
        for hours in (3, 7, 13):
            at = start + timedelta(hours=hours)
            true = delta_of((at - DAY0).total_seconds())
            drift, since = tracker.allowance(at)
            assert since == pytest.approx(hours * 3600.0)
            z.append((true - drift.mean) / drift.sigma)
            tracker.observe(_sig(true, rng.uniform(0.0, 50.0), rng, inertia_sd), at)
    return z


def test_a_slow_drift_is_tracked_within_its_allowance() -> None:
    rng = np.random.default_rng(4)
    tracker = ZeroTracker()
    z = _daily(tracker, lambda t: 0.07 * math.sin(2 * math.pi * t / (7 * 86400.0)), 0, 20, rng)
    assert max(abs(v) for v in z) < 4.0
    assert np.mean(np.abs(z) <= 2.0) >= 0.9
    # and far tighter than the default once the sequence has been learned
    assert tracker.allowance(DAY0 + timedelta(days=19, hours=7))[0].sigma < 0.5 * LOSS_DRIFT_REL


def test_an_oil_change_widens_the_allowance_within_a_day() -> None:
    """A −10 % step at 11:00 of day 9: the recordings after it (a conveyor whose inertia
    signature tells δ to ±2.5 % per recording) widen the allowance the same day, and the
    next morning's known run takes up the new losses."""
    rng = np.random.default_rng(5)
    tracker = ZeroTracker()
    step_at = 9 * 86400.0 + 5 * 3600.0  # day 9, 11:00 (the days start at 06:00)
    _daily(tracker, lambda t: 0.0, 0, 9, rng, inertia_sd=1.0)
    before = tracker.allowance(DAY0 + timedelta(days=8, hours=13))[0]
    z = _daily(tracker, lambda t: -0.10 if t >= step_at else 0.0, 9, 10, rng, inertia_sd=1.0)
    same_day = tracker.allowance(DAY0 + timedelta(days=9, hours=13))[0]
    assert same_day.sigma > 2.0 * before.sigma
    assert abs(-0.10 - same_day.mean) <= 2.0 * same_day.sigma
    assert abs(z[-1]) <= 3.0  # the day's last weighing already allowed for it
    start = DAY0 + timedelta(days=10)
    assert tracker.learn_known(_sig(-0.10, 0.0, rng, 1.0), 0.0, start)
    after, _ = tracker.allowance(start + timedelta(hours=7))
    assert after.mean == pytest.approx(-0.10, abs=0.015)
    assert after.sigma < same_day.sigma


def test_the_tracking_state_round_trips_and_refuses_damage() -> None:
    rng = np.random.default_rng(6)
    tracker = ZeroTracker()
    _daily(tracker, lambda t: 0.02, 0, 3, rng)
    data = json.loads(json.dumps(tracker.to_dict()))
    back = ZeroTracker.from_dict(data)
    at = DAY0 + timedelta(days=3, hours=5)
    assert back.allowance(at) == tracker.allowance(at)
    data["covariance"] = [[1.0]]
    with pytest.raises(ValueError, match="wrong size"):
        ZeroTracker.from_dict(data)


def _write(folder: Path, recs: list[Recording]) -> list[str]:
    return [str(write_recording(r, folder / r.source)) for r in recs]


def test_weigh_tracks_the_known_runs_among_its_files(
    cal: Calibration, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cal_path = tmp_path / "cal.json"
    cal_path.write_text(json.dumps(cal.to_dict()))
    recs = [
        _recording(0.0, 41, DAY0, 1.07, known=True),
        _recording(25.0, 42, DAY0 + timedelta(hours=2), 1.07),
    ]
    files = _write(tmp_path, recs)
    capsys.readouterr()
    # given in another order: tracked in recorded order
    args = ["weigh", "--calibration", str(cal_path), files[1], files[0], "--json"]
    assert main([*args, "--zero-tracking"]) == 0
    out = json.loads(capsys.readouterr().out)
    weighed, known = out
    assert known["known_run"] is True and weighed["known_run"] is False
    assert weighed["since_known_run_s"] == pytest.approx(7200.0)
    assert weighed["loss_drift"]["mean"] == pytest.approx(0.07, abs=0.015)
    assert weighed["loss_drift"]["sigma"] < 0.5 * LOSS_DRIFT_REL
    assert abs(weighed["payload_kg"] - 25.0) <= 2.0 * weighed["uncertainty_kg"]
    assert main(["weigh", "--calibration", str(cal_path), files[1], "--json"]) == 0
    alone = json.loads(capsys.readouterr().out)[0]
    assert alone["loss_drift"] == {"mean": 0.0, "sigma": LOSS_DRIFT_REL}
    assert alone["since_known_run_s"] is None
    assert weighed["uncertainty_kg"] < alone["uncertainty_kg"]


def _days(first: int, last: int) -> list[Recording]:
    """Daily drift: +3 % at the 06:00 cold start fading over 3 h, a slow ±4 %; a known
    empty run at 06:00 and three weighings a day."""
    out = []
    for d in range(first, last):
        start = DAY0 + timedelta(days=d)
        slow = 0.04 * math.sin(2 * math.pi * d / 8.0)
        out.append(_recording(0.0, 100 + 10 * d, start, 1.03 + slow, known=True))
        for j, hours in enumerate((1.0, 4.0, 9.0)):
            cold = 0.03 * max(0.0, 1.0 - hours / 3.0)
            payload = 10.0 + 12.0 * j
            at = start + timedelta(hours=hours)
            out.append(_recording(payload, 101 + 10 * d + j, at, 1.0 + cold + slow))
    return out


def _ingest(
    url: str, cal: Calibration, batches: list[list[str]], profile: ConveyorProfile = TRACKING
) -> list[dict[str, object]]:
    """Ingest the batches into a new store, each by a new ``Store`` (a restart)."""
    store = Store(url)
    store.put_calibration(cal)
    store.close()
    for files in batches:
        store = Store(url)
        ingest(files, {profile.id: profile}, store, workers=1)
        store.close()
    store = Store(url)
    try:
        return store.results(PROFILE.id)
    finally:
        store.close()


def test_ingest_weighs_with_the_tracked_allowance_through_a_restart(
    cal: Calibration, tmp_path: Path
) -> None:
    """Daily drift and a known empty run each morning: the weighings after a restart
    are those of an ingest that never stopped, honest and tighter than the default."""
    first = _write(tmp_path, _days(0, 2))
    second = _write(tmp_path, _days(2, 4))
    restarted = _ingest(f"sqlite:///{tmp_path / 'a.db'}", cal, [first, second])
    store = Store(f"sqlite:///{tmp_path / 'a.db'}")
    state = store.state(PROFILE.id)
    store.close()
    assert state is not None and state.zero_tracking.at is not None
    straight = _ingest(f"sqlite:///{tmp_path / 'b.db'}", cal, [first + second])
    assert len(restarted) == len(straight) == 16
    for a, b in zip(restarted, straight, strict=True):
        assert a["file"] == b["file"]
        assert a["loss_drift"] == pytest.approx(b["loss_drift"], rel=1e-9, abs=1e-12)
        assert a["payload_kg"] == pytest.approx(b["payload_kg"], rel=1e-9)
    scored = [r for r in restarted if Path(str(r["file"])).name in _PAYLOADS]
    assert len(scored) == 12
    z = []
    for r in scored:
        drift = r["loss_drift"]
        assert isinstance(drift, dict) and drift["sigma"] < LOSS_DRIFT_REL
        since = r["since_known_run_s"]
        assert isinstance(since, float) and 0.0 < since <= 9 * 3600.0
        payload, u = r["payload_kg"], r["uncertainty_kg"]
        assert isinstance(payload, float) and isinstance(u, float), r["warnings"]
        z.append(abs(payload - _PAYLOADS[Path(str(r["file"])).name]) / u)
    assert max(z) <= 3.0
    assert np.mean(np.array(z) <= 2.0) >= 0.9


_PAYLOADS = {f"rec-{101 + 10 * d + j}.csv": 10.0 + 12.0 * j for d in range(0, 5) for j in range(3)}


def test_a_version_1_state_file_still_loads(
    cal: Calibration, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cal_path = tmp_path / "cal.json"
    cal_path.write_text(json.dumps(cal.to_dict()))
    files = _write(tmp_path, _days(0, 1))
    state = tmp_path / "state.json"
    profile = tmp_path / "tracking.yaml"
    profile.write_text(REFERENCE_PROFILE.read_text() + "\nzero_tracking: true\n")
    args = ["--calibration", str(cal_path), "--state", str(state), "--profile", str(profile)]
    assert main(["monitor", files[0], files[1], *args]) in (0, 1)
    data = json.loads(state.read_text())
    assert data["format_version"] == 2
    entry = data["conveyors"][PROFILE.id]
    assert entry["zero_tracking"]["at"] is not None
    # the same state as version 1 wrote it: no zero tracking
    del entry["zero_tracking"]
    data["format_version"] = 1
    state.write_text(json.dumps(data))
    assert load_state(state)["format"] == STATE_FORMAT
    assert main(["monitor", files[2], *args]) in (0, 1)
    again = json.loads(state.read_text())
    assert again["format_version"] == 2
    assert again["conveyors"][PROFILE.id]["zero_tracking"]["at"] is None  # nothing known yet


def test_the_reference_zero_recovers_a_line_and_the_scatter_beyond_the_readings() -> None:
    """Known answer: readings drawn about 0.01 − 0.0004·p with an extra 0.003 scatter."""
    rng = np.random.default_rng(11)
    sd, extra = 0.002, 0.003
    payloads = np.repeat([0.0, 20.0, 40.0], 40)
    truth = 0.01 - 0.0004 * payloads
    readings = truth + rng.normal(0, sd, payloads.size) + rng.normal(0, extra, payloads.size)
    ref = ZeroReference(
        tuple((float(p), float(d), sd**2) for p, d in zip(payloads, readings, strict=True))
    )
    zero, var = ref.zero(30.0)
    assert zero == pytest.approx(0.01 - 0.0004 * 30.0, abs=3.0 * math.sqrt(var))
    assert ref.model_sigma == pytest.approx(extra, rel=0.3)
    assert math.sqrt(var) < 0.005
    # one payload only: a constant, and no scatter beyond the readings
    flat = ZeroReference(((0.0, 0.004, 1e-4), (0.0, 0.006, 1e-4)))
    assert flat.zero(50.0)[0] == pytest.approx(0.005)
    assert flat.model_sigma == 0.0
    back = ZeroReference.from_dict(json.loads(json.dumps(ref.to_dict())))
    assert back == ref


def _evaluation() -> ModuleType:
    spec = importlib.util.spec_from_file_location("evaluate_fidelity", SCRIPT)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


@pytest.mark.slow
def test_without_drift_a_known_empty_run_tracks_zero_within_its_sigma_on_random_conveyors() -> None:
    """Known answer: the losses as calibrated (δ = 0) on conveyors drawn from the
    evaluation's design distribution with every realism effect on (about 30 s)."""
    ev = _evaluation()
    rng = np.random.default_rng(20261127)
    z = []
    for k in range(4):
        conv = ev.draw_conveyor(rng, k)
        runs = ev.calibration_runs(conv, 4000 + 100 * k)
        for protocol in ("several_loads", "one_load_several_speeds"):
            cal = calibrate(runs[protocol], conv.profile)
            assert cal.zero_reference is not None and cal.zero_reference.readings
            for j in range(2):
                rec = ev._run(conv, 0.0, 4050 + 100 * k + j, direction=conv.direction)
                res = weigh(inspect_recording(rec, conv.profile), cal)
                tracked = ZeroTracker().track(res, DAY0, 0.0, cal.zero_reference, known_runs=True)
                assert tracked.known_run
                z.append(abs(tracked.loss_drift.mean) / tracked.loss_drift.sigma)
    assert len(z) == 16
    assert max(z) <= 2.0, z
    assert np.mean(np.array(z) <= 1.0) >= 0.6, z


def test_a_calibration_without_a_reference_zero_loads_and_its_known_runs_warn(
    cal: Calibration,
) -> None:
    data = cal.to_dict()
    assert data["zero_reference"]["readings"]
    del data["zero_reference"]  # as calibrations were written before it
    old = Calibration.from_dict(data)
    assert old.zero_reference is None
    rec = _recording(0.0, 61, DAY0, 1.0, known=True)
    res = weigh(inspect_recording(rec, PROFILE), old)
    tracked = ZeroTracker().track(res, DAY0, 0.0, old.zero_reference, known_runs=True)
    assert tracked.known_run and NO_REFERENCE in {w.code for w in tracked.warnings}
    current = ZeroTracker().track(res, DAY0, 0.0, cal.zero_reference, known_runs=True)
    assert NO_REFERENCE not in {w.code for w in current.warnings}


def test_a_version_1_tracking_state_keeps_its_filter_and_relearns_its_rows() -> None:
    rng = np.random.default_rng(8)
    tracker = ZeroTracker()
    _daily(tracker, lambda t: 0.02, 0, 2, rng)
    data = tracker.to_dict()
    old = dict(data, version=1, warm=[r[:2] + r[3:] for r in data["warm"]])
    old["history"] = [r[:3] for r in data["history"]]
    del old["reference_var"]
    back = ZeroTracker.from_dict(old)
    assert back.state == tracker.state and back.at == tracker.at
    assert back.warm == [] and back.history == []


def test_by_default_known_runs_are_not_used(cal: Calibration, tmp_path: Path) -> None:
    """Zero tracking from known runs is opt-in: without the profile's switch ingest
    weighs a known empty run as one more recording and reports no time since it,
    and the tracker and ``weigh`` do the same without being asked."""
    files = _write(tmp_path, _days(0, 2))
    off = _ingest(f"sqlite:///{tmp_path / 'off.db'}", cal, [files], PROFILE)
    on = _ingest(f"sqlite:///{tmp_path / 'on.db'}", cal, [files], TRACKING)
    assert len(off) == len(on) == 8
    assert all(r["since_known_run_s"] is None for r in off)
    assert all(isinstance(r["loss_drift"], dict) for r in off)
    assert any(r["since_known_run_s"] is not None for r in on)
    # the history alone: centred on the calibration's losses, while the known runs
    # (at +3 % and more) move the tracked drift
    for r in off:
        drift = r["loss_drift"]
        assert isinstance(drift, dict) and drift["mean"] == 0.0
        assert 0.0 < drift["sigma"] <= LOSS_DRIFT_REL
    assert any(isinstance(r["loss_drift"], dict) and r["loss_drift"]["mean"] > 0.01 for r in on)
    rec = _recording(0.0, 71, DAY0, 1.07, known=True)
    w = weigh(inspect_recording(rec, PROFILE), cal)
    tracker = ZeroTracker()
    default = tracker.track(w, DAY0, 0.0, cal.zero_reference)
    assert not default.known_run and default.since_known_run_s is None
    assert tracker.at is None
