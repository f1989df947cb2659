"""Condition monitoring: health model, X-of-Y rule, causes, state, CLI."""

from __future__ import annotations

import dataclasses
import json
import math
import pickle
from datetime import UTC, datetime, timedelta, timezone
from pathlib import Path

import numpy as np
import pytest
from conftest import REFERENCE_PROFILE

from chaintwin.calibrating.procedure import calibrate
from chaintwin.cli.app import EXIT_ALARM, main
from chaintwin.diagnose import baseline
from chaintwin.diagnose.baseline import at_mean_payload, payload_of
from chaintwin.diagnose.causes import resolve_causes
from chaintwin.diagnose.features import _line_sums, recording_features
from chaintwin.diagnose.forecasting import MIN_POINTS, forecast_feature
from chaintwin.diagnose.health import FeatureBaseline, fit_baseline, x_of_y
from chaintwin.diagnose.monitor import ConveyorMonitor
from chaintwin.diagnose.monitor_state import LEARNED, MonitorState
from chaintwin.diagnose.records import Alarm, Event, MonitorSettings, RecordingResult
from chaintwin.diagnose.spectra import Spectrum
from chaintwin.diagnose.state import (
    STATE_VERSION,
    acknowledge_alarm,
    add_maintenance,
    load_state,
)
from chaintwin.errors import MonitorError, StoreError
from chaintwin.identify.calibration import Calibration
from chaintwin.identify.signatures import drift_bases, fit_condition
from chaintwin.ingest.worker import prepare
from chaintwin.model.windows import window_integrals
from chaintwin.read.batch import order_recordings
from chaintwin.read.profile import load_profile
from chaintwin.read.writer import write_recording
from chaintwin.simulate.faults import Fault
from chaintwin.simulate.fleet import generate
from chaintwin.simulate.virtual import run_virtual
from chaintwin.validate import inspect_recording
from chaintwin.validate.checks import load_recording

PROFILE = load_profile(REFERENCE_PROFILE)
BASELINE = 10


# ---------------------------------------------------------------- hand-made cases
def test_x_of_y_rule_on_a_hand_made_sequence() -> None:
    seq = [True, False, False, True, False, True, False, False, False, False, False, True]
    # never 3 exceedances among 5 in a row
    assert x_of_y(seq, 3, 5) == [False] * len(seq)
    assert x_of_y(seq, 3, 6)[5] is True  # indices 0..5 hold 0, 3 and 5
    assert x_of_y(seq, 3, 6)[6] is False  # 0 left the window
    assert x_of_y([True] * 3, 3, 10) == [False, False, True]
    assert x_of_y([False, True], 1, 1) == [False, True]
    with pytest.raises(ValueError, match="X-of-Y"):
        x_of_y(seq, 4, 3)


def test_baseline_regresses_on_payload_and_leaves_out_outliers() -> None:
    rng = np.random.default_rng(0)
    payload = rng.uniform(10, 40, 40)
    values = 0.05 + 0.001 * payload + rng.normal(0, 0.002, 40)
    values[7] = 1.0  # a bad scope in the baseline
    fb = fit_baseline(values, payload, payload_dependent=True)
    assert fb is not None
    assert fb.outliers == 1
    assert fb.slope == pytest.approx(0.001, rel=0.15)
    assert fb.intercept == pytest.approx(0.05, abs=0.004)
    assert fb.scale == pytest.approx(0.002, rel=0.35)
    # a value 20 % above the line at 40 kg: far beyond 5 scales and beyond 10 %
    high = fb.check(1.2 * fb.expected(40.0), 40.0, 5.0, 0.10)
    assert high.exceeded and high.change == pytest.approx(0.2)
    # many scales above, but under the smallest relative change: no exceedance
    assert not fb.check(1.05 * fb.expected(40.0), 40.0, 5.0, 0.10).exceeded
    # a fall is never an exceedance
    assert not fb.check(0.5 * fb.expected(40.0), 40.0, 5.0, 0.10).exceeded
    # the line holds over the baseline's payloads and half their spread beyond: a payload
    # estimate far outside (a drifted weighing) takes the value at the nearer end
    assert fb.payload_range_kg is not None
    lo, hi = fb.payload_range_kg
    spread = float(np.ptp(np.delete(payload, 7)))
    assert hi - lo == pytest.approx(2.0 * spread)
    assert fb.expected(lo - 100.0) == fb.expected(lo) < fb.expected(0.5 * (lo + hi))
    assert fb.expected(hi + 100.0) == fb.expected(hi)
    assert FeatureBaseline.from_dict(json.loads(json.dumps(fb.to_dict()))) == fb
    flat = fit_baseline([1.0, 1.1, 0.9, 1.0, 1.05], [10, 20, 30, 40, 25], payload_dependent=False)
    assert flat is not None and flat.slope == 0.0 and flat.intercept == 1.0
    assert fit_baseline([1.0, np.nan, 2.0], [1, 2, 3], payload_dependent=False) is None


def test_a_spectral_line_s_hump_over_the_payload_is_followed_by_a_curve() -> None:
    """A belt mode the payload tunes through a line: its amplitude peaks over a band
    of payloads (the demo's short-fast-03: 0.12 Nm at 23-26 kg, 0.05 Nm at 14 and
    40 kg). A line cannot follow it: the hump's own healthy values exceeded it
    and opened a wrong ``sprocket`` alarm. The curve through the running medians
    follows it, and a real rise still stands out."""
    rng = np.random.default_rng(3)
    payload = rng.uniform(12.0, 41.0, 20)

    def hump(p: np.ndarray | float) -> np.ndarray:
        return 0.05 + 0.07 * np.exp(-(((np.asarray(p) - 24.0) / 4.0) ** 2))

    values = hump(payload) * (1.0 + rng.normal(0.0, 0.02, 20))
    line = fit_baseline(values, payload, payload_dependent=True)
    curved = fit_baseline(values, payload, payload_dependent=True, curve=True)
    assert line is not None and line.curve is None
    assert curved is not None and curved.curve is not None
    assert curved.scale < 0.5 * line.scale
    top = float(hump(24.0))
    # the line's expected value is half the hump's top, and its scale is the hump's
    # spread, so a worn sprocket's +60 % on the flank goes unseen; the curve expects
    # the top there, does not exceed on it, and sees the rise on the hump and its flank
    assert line.expected(24.0) < 0.6 * top
    flank = 1.6 * float(hump(38.0))
    assert not line.check(flank, 38.0, 3.0, 0.5).exceeded
    assert curved.check(flank, 38.0, 3.0, 0.5).exceeded
    assert curved.expected(24.0) == pytest.approx(top, rel=0.1)
    assert not curved.check(top, 24.0, 3.0, 0.5).exceeded
    assert curved.check(1.6 * top, 24.0, 3.0, 0.5).exceeded
    # beyond the baseline's payloads the curve holds its end values
    assert curved.expected(100.0) == curved.expected(float(payload.max()))
    # a drifting payload estimate widens the scale by half the curve's spread over
    # its band (on the flank, where the curve is steep)
    at = curved.expected(30.0) + 0.02
    plain, drifting = (
        curved.check(at, 30.0, 3.0, 0.5),
        curved.check(at, 30.0, 3.0, 0.5, payload_sigma_kg=4.0),
    )
    band = [curved.expected(q) for q in np.linspace(26.0, 34.0, 9)]
    assert drifting.z == pytest.approx(
        0.02 / math.hypot(curved.scale, 0.5 * (max(band) - min(band)))
    )
    assert drifting.z < plain.z
    # stored and read back; a baseline stored before curves existed reads as a line
    assert FeatureBaseline.from_dict(json.loads(json.dumps(curved.to_dict()))) == curved
    assert "curve" not in line.to_dict()
    # a feature that does follow a line keeps the line
    straight = 0.05 + 0.001 * payload + rng.normal(0.0, 0.002, 20)
    kept = fit_baseline(straight, payload, payload_dependent=True, curve=True)
    assert kept is not None and kept.curve is None


def test_a_drifting_payload_estimate_widens_a_sloped_baseline_by_hand() -> None:
    """Errors in the regressor: the z-score is taken against hypot(scale, slope·sigma).

    A baseline 0.05 + 0.001·p ± 0.002 (by construction); at 20 kg a value
    0.012 above the line is 6 scales out. With a payload estimate that a
    loss drift may have moved by 10 kg (1 sigma), the expected value is
    uncertain by 0.010 too: z = 0.012 / hypot(0.002, 0.010) = 1.18, no
    exceedance; a rise three times as large still is one. A flat baseline
    does not depend on the payload, so the drift changes nothing there.
    """
    fb = FeatureBaseline(0.05, 0.001, 0.002, count=20, outliers=0, mean_payload_kg=20.0)
    value = fb.expected(20.0) + 0.012
    assert fb.check(value, 20.0, 5.0, 0.10).exceeded
    drifting = fb.check(value, 20.0, 5.0, 0.10, payload_sigma_kg=10.0)
    assert drifting.z == pytest.approx(0.012 / math.hypot(0.002, 0.010))
    assert not drifting.exceeded
    assert fb.check(fb.expected(20.0) + 0.06, 20.0, 5.0, 0.10, payload_sigma_kg=10.0).exceeded
    flat = FeatureBaseline(0.07, 0.0, 0.002, count=20, outliers=0, mean_payload_kg=20.0)
    assert flat.check(0.082, 20.0, 5.0, 0.10, payload_sigma_kg=10.0).exceeded
    assert flat.check(0.082, 20.0, 5.0, 0.10, payload_sigma_kg=10.0).z == pytest.approx(6.0)


def test_the_inertia_payload_s_drift_widens_a_baseline_regressed_on_it_by_hand() -> None:
    """The broadband residual regressed on the inertia payload: 0.006 + 0.00029·p
    ± 0.00046 Nm. A value 0.0040 above the line at 20 kg (34 %, beyond the
    smallest change of 30 %) is 8.7 scales out and exceeds; if the loss drift
    may have moved the inertia payload by 2.4 kg (1 sigma, the part of its
    uncertainty the drift adds: sqrt(3² - 1.8²) for an uncertainty of 3 kg,
    1.8 trusting the losses), z = 0.0040 / hypot(0.00046, 0.00029·2.4) = 4.8:
    no exceedance."""
    from chaintwin.diagnose.alarms import judge
    from chaintwin.diagnose.features import _drift_part

    assert _drift_part(3.0, 1.8) == pytest.approx(2.4)
    assert math.isnan(_drift_part(None, 1.8))
    fb = FeatureBaseline(0.006, 0.00029, 0.00046, count=20, outliers=0, mean_payload_kg=25.0)
    value = fb.expected(20.0) + 0.0040
    settings = MonitorSettings()
    when = datetime(2026, 3, 2, tzinfo=UTC)
    plain = {"residual_std": value, "payload_inertia_kg": 20.0}
    _, _, exceeded = judge({"residual_std": fb}, plain, {}, {}, settings, when)
    assert exceeded == ["residual_std"]
    drifting = plain | {"payload_inertia_drift_kg": _drift_part(3.0, 1.8)}
    _, change, exceeded = judge({"residual_std": fb}, drifting, {}, {}, settings, when)
    assert exceeded == [] and change["residual_std"] > 0.2
    assert fb.check(value, 20.0, 5.0, 0.3, payload_sigma_kg=2.4).z == pytest.approx(4.8, abs=0.05)


def test_a_loss_drift_allowance_is_a_bias_taken_off_before_the_noise_by_hand() -> None:
    """A flat baseline 1.0 ± 0.05; z 5, smallest rise 50 %.

    A value of 1.9 is 18 scales out and exceeds; if a loss drift within its
    range may have moved the value by 0.7, only (0.9 - 0.7)/0.05 = 4 scales
    are left and it does not; 2.0 leaves 6 and does. The reported z is the
    whole deviation's. No allowance (NaN: the fit gave none) changes nothing.
    """
    fb = FeatureBaseline(1.0, 0.0, 0.05, count=20, outliers=0, mean_payload_kg=20.0)
    assert fb.check(1.9, 20.0, 5.0, 0.5).exceeded
    held = fb.check(1.9, 20.0, 5.0, 0.5, drift_allowance=0.7)
    assert not held.exceeded
    assert held.z == pytest.approx(18.0)
    assert fb.check(2.0, 20.0, 5.0, 0.5, drift_allowance=0.7).exceeded
    assert fb.check(1.9, 20.0, 5.0, 0.5, drift_allowance=math.nan).exceeded
    # falls of a two-sided feature the same way
    assert fb.check(0.1, 20.0, 5.0, 0.5, two_sided=True).exceeded
    assert not fb.check(0.1, 20.0, 5.0, 0.5, two_sided=True, drift_allowance=0.7).exceeded


def test_a_two_valued_baseline_keeps_both_values_and_neither_exceeds() -> None:
    # a line sum at 3.8 mNm in 14 healthy scopes and 8.5 mNm in 6 (a line falling on
    # or beside a bin): by the MAD alone the high ones were outliers and exceeded later
    rng = np.random.default_rng(3)
    values = np.r_[rng.normal(0.0038, 0.0002, 14), rng.normal(0.0085, 0.0003, 6)]
    rng.shuffle(values)
    fb = fit_baseline(values, np.full(20, 20.0), payload_dependent=False)
    assert fb is not None and fb.outliers == 0
    q25, q75 = np.percentile(values, [25, 75])
    assert fb.scale == pytest.approx((q75 - q25) / 1.349)
    assert not fb.check(0.0090, 20.0, 5.0, 0.5).exceeded
    # the high level in a fifth of the scopes only: left out of the line and scale as
    # outliers, but a value the baseline itself reached twice is no exceedance
    few = np.r_[rng.normal(0.0038, 0.0002, 16), [0.0085, 0.0080, 0.0087, 0.0084]]
    fb4 = fit_baseline(few, np.full(20, 20.0), payload_dependent=False)
    assert fb4 is not None and fb4.outliers == 4
    assert fb4.top_residual == pytest.approx(0.0085 - fb4.intercept)
    assert not fb4.check(0.0084, 20.0, 5.0, 0.5).exceeded
    assert fb4.check(0.0100, 20.0, 5.0, 0.5).exceeded
    # a two-sided feature (a line the fault can first cancel): a fall counts as a rise does
    level = fit_baseline(rng.normal(0.20, 0.002, 20), np.full(20, 20.0), payload_dependent=False)
    assert level is not None
    assert not level.check(0.16, 20.0, 5.0, 0.08).exceeded  # one-sided: only rises
    fell = level.check(0.16, 20.0, 5.0, 0.08, two_sided=True)
    assert fell.exceeded and fell.change == pytest.approx(-0.2, abs=0.02)
    assert level.lower_limit(5.0, 0.08) < 0.19 < level.expected(20.0)
    assert not level.check(0.195, 20.0, 5.0, 0.08, two_sided=True).exceeded
    # on a sloped line a fall is not judged: the payload estimate it follows drifts both ways
    loads = rng.uniform(5.0, 25.0, 20)
    sloped = fit_baseline(0.004 + 0.0004 * loads, loads, payload_dependent=True)
    assert sloped is not None and sloped.slope > 0.0
    assert not sloped.check(0.5 * sloped.expected(15.0), 15.0, 5.0, 0.08, two_sided=True).exceeded
    # a normal spread: both estimates are its sigma, the scale is not inflated
    normal = fit_baseline(rng.normal(1.0, 0.01, 200), np.full(200, 20.0), payload_dependent=False)
    assert normal is not None and normal.scale == pytest.approx(0.01, rel=0.15)


def test_forecast_of_a_linear_trend_brackets_the_true_crossing() -> None:
    t0 = datetime(2026, 1, 1, tzinfo=UTC)
    rng = np.random.default_rng(1)
    times = [t0 + timedelta(days=0.5 * k) for k in range(40)]
    values = [1.0 + 0.01 * 0.5 * k + rng.normal(0, 0.005) for k in range(40)]
    fc = forecast_feature("friction", times, values, 1.3)
    assert fc is not None
    true = t0 + timedelta(days=30.0)  # 1 + 0.01 d = 1.3
    assert fc.earliest <= true <= (fc.latest or true)
    assert abs((fc.crosses_at - true).total_seconds()) < 2 * 86400
    assert fc.slope_per_day == pytest.approx(0.01, rel=0.1)
    flat = [1.0 + rng.normal(0, 0.005) for _ in range(40)]
    assert forecast_feature("friction", times, flat, 1.3) is None


def test_the_load_part_is_taken_out_at_the_weighed_payload_without_the_regressor() -> None:
    # friction = 1.0 + 0.002·(payload − 25) on the baseline; a recording whose
    # signatures disagreed has no payload_inertia_kg, but the monitor weighed it by
    # inertia (payload_kg 35, warning weighed_by_inertia)
    fb = FeatureBaseline(
        intercept=0.95, slope=0.002, scale=0.01, count=20, outliers=0, mean_payload_kg=25.0
    )
    result = {
        "features": {"friction": 1.30, "payload_inertia_kg": None},
        "payload_kg": 35.0,
        "warnings": [{"code": "weighed_by_inertia", "message": "..."}],
    }
    load, source = payload_of("friction", fb, result)
    assert (load, source) == (35.0, "weighed_by_inertia")
    # 1.30 − 0.002·(35 − 25) = 1.28
    assert at_mean_payload("friction", fb, result["features"], load) == pytest.approx(1.28)
    # the regressor when the recording holds it
    held = result | {"features": {"friction": 1.30, "payload_inertia_kg": 15.0}}
    assert payload_of("friction", fb, held) == (15.0, "payload_inertia_kg")
    assert at_mean_payload("friction", fb, held["features"]) == pytest.approx(1.32)
    # the payload as weighed (no inertia warning), and neither known
    assert payload_of("friction", fb, result | {"warnings": []}) == (35.0, "weighed")
    load, source = payload_of("friction", fb, result | {"payload_kg": None})
    assert math.isnan(load) and source == "payload_inertia_kg"
    assert math.isnan(at_mean_payload("friction", fb, result["features"], load))
    # a baseline without a load part needs no payload: the value as it is
    flat = dataclasses.replace(fb, slope=0.0)
    assert payload_of("friction", flat, result | {"payload_kg": None})[1] == "none"
    assert at_mean_payload("friction", flat, result["features"]) == 1.30


def test_a_shaft_comb_leaves_its_largest_line_out_and_a_tooth_pass_sum_does_not() -> None:
    """Lines of 1, 2, 3 and 10 mNm on a 1 Hz grid: the comb sums 6 mNm (the
    10 mNm line left out), the same lines as a plain line sum 16 mNm; a comb of
    two lines (fewer than COMB_MIN_LINES) keeps both."""
    x = np.arange(0.0, 100.0, 1.0)
    amplitude = np.zeros_like(x)
    for at, a in ((10.0, 0.001), (20.0, 0.002), (30.0, 0.003), (40.0, 0.010)):
        amplitude[int(at)] = a
    spec = Spectrum(x, amplitude, "frequency", 1.0, "torque", 1400.0)
    lines = [10.0, 20.0, 30.0, 40.0]
    sums = _line_sums(spec, {"comb_rotor": lines, "tooth_pass": lines}, ["comb_rotor"])
    assert sums["comb_rotor"] == pytest.approx(0.006)
    assert sums["tooth_pass"] == pytest.approx(0.016)
    two = _line_sums(spec, {"comb_rotor": [30.0, 40.0]}, ["comb_rotor"])
    assert two["comb_rotor"] == pytest.approx(0.013)


def test_causes_name_the_specific_fault() -> None:
    assert resolve_causes(["friction"]) == {"friction": "friction"}
    assert resolve_causes(["friction", "tooth_pass"]) == {
        "friction": "elongation",
        "tooth_pass": "elongation",
    }
    assert resolve_causes(["residual_std"]) == {"residual_std": "bearing"}
    assert resolve_causes(["residual_std", "comb_stage2_shaft"]) == {
        "residual_std": "gear",
        "comb_stage2_shaft": "gear",
    }
    assert resolve_causes(["comb_stage3_shaft", "belt_bump"])["comb_stage3_shaft"] == (
        "obstruction"
    )
    assert resolve_causes(["speed_loss", "friction"]) == {
        "speed_loss": "lubrication",
        "friction": "friction",
    }
    # the impacts' cause explains what it explains: a rail obstacle's knocks raise a peak
    knocks = resolve_causes(["unexplained_peak", "crest_factor"], "obstruction")
    assert knocks == {"unexplained_peak": "obstruction", "crest_factor": "obstruction"}
    events = resolve_causes(["unexplained_peak", "crest_factor"], "payload_event")
    assert events["unexplained_peak"] == "bearing"  # an event of operation explains nothing
    # so does an alarm still open: the obstacle found days ago still knocks
    assert resolve_causes(["unexplained_peak"], None, {"obstruction"}) == {
        "unexplained_peak": "obstruction"
    }
    assert resolve_causes(["unexplained_peak"], None, {"friction"}) == {
        "unexplained_peak": "bearing"
    }


def test_settings_are_checked() -> None:
    with pytest.raises(MonitorError, match="X <= Y"):
        MonitorSettings(x=4, y=3)
    with pytest.raises(MonitorError, match="at least 5"):
        MonitorSettings(baseline_n=2)


# ---------------------------------------------------------------- virtual series
def _series(folder: Path, faults: list[Fault], seed: int, days: int = 6) -> Path:
    generate(PROFILE, folder, days=days, per_day=6, faults=faults, onset_day=2, seed=seed)
    return folder


@pytest.fixture(scope="module")
def series(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("series")
    return {
        "healthy": _series(root / "healthy", [], 11),
        "friction": _series(root / "friction", [Fault("friction", 0.6)], 12),
        # a hit stands out from about severity 0.8 and the rate needs two or more
        # knocks pooled (one says nothing of a rate): a longer series reaches it
        "rail_obstacle": _series(root / "rail_obstacle", [Fault("rail_obstacle", 1.0)], 13, 14),
        "payload_step": _series(root / "payload_step", [Fault("payload_step", 1.0)], 14),
    }


@pytest.fixture(scope="module")
def cal(series: dict[str, Path]) -> Calibration:
    files = sorted((series["healthy"] / "calibration").glob("*.csv"))
    return calibrate([load_recording(f, profile=PROFILE).recording for f in files], PROFILE)


def _files(folder: Path) -> list[Path]:
    return sorted(folder.glob("*.csv"))


def _run(mon: ConveyorMonitor, files: list[Path]) -> list[RecordingResult]:
    out: list[RecordingResult] = []
    for f in files:
        out += mon.process(load_recording(f, profile=PROFILE).recording, f.name)
    return out + mon.finish()


def _onset(folder: Path) -> str:
    truth = [json.loads(x) for x in (folder / "truth.jsonl").read_text().splitlines()]
    return next(t["recorded_at"] for t in truth if any(v > 0 for v in t["faults"].values()))


@pytest.mark.slow
def test_condition_fit_s_loss_gradient_matches_a_refit_and_a_simulated_drift(
    cal: Calibration,
) -> None:
    """Two ways to the same number: how the condition fit moves with the losses.

    1. The fit's ``loss_gradient`` (one linear solve) against refitting the
       same windows with 5 % of what may drift added to their torque (the
       refit re-estimates its noise weights; of two readings of what drifts,
       the one that moves the speed-loss change more): within 5 %.
    2. The ``speed_loss_drift`` allowance (what a drift across ±10 % of the
       losses moves the speed loss by) against the speed loss of the same
       scope simulated with the plant's losses at 0.9 and at 1.1 of nominal:
       the same size within a factor of 1.5 (on a drawn conveyor whose
       calibration holds a negative constant loss it was 1.4x: see
       ``_condition_values``).
    """
    rec = run_virtual(PROFILE, payload_kg=20.0, seed=5, loss_scale=1.0).recording
    params = cal.parameters
    tray = PROFILE.tray_mass_kg
    wi = window_integrals(rec, PROFILE)
    fit = fit_condition(rec, PROFILE, params, tray, windows=wi, ramp_rate=cal.ramp_noise_rate)
    assert fit.loss_gradient is not None
    steps = []
    for basis in drift_bases(params.values):  # what may drift, in one or two readings
        column = basis[0] * wi.sign + basis[1] * wi.speed + basis[2] * wi.speed_sq
        moved = dataclasses.replace(wi, torque=wi.torque + 0.05 * column)
        refit = fit_condition(
            rec, PROFILE, params, tray, windows=moved, ramp_rate=cal.ramp_noise_rate
        )
        steps.append((refit.estimate - fit.estimate) / 0.05)
    # the reading that moves the speed-loss change more
    step = max(steps, key=lambda g: abs(float(g[2])))
    assert step == pytest.approx(fit.loss_gradient, rel=0.05, abs=1e-9)

    values = []
    for scale in (0.9, 1.1):
        run = run_virtual(PROFILE, payload_kg=20.0, seed=5, loss_scale=scale)
        values.append(
            recording_features(inspect_recording(run.recording, profile=PROFILE), cal).values
        )
    moved_by = abs(values[1]["speed_loss"] - values[0]["speed_loss"])
    allowance = 0.5 * (values[0]["speed_loss_drift"] + values[1]["speed_loss_drift"])
    assert 1 / 1.5 < moved_by / allowance < 1.5


def test_healthy_series_raises_no_alarm(series: dict[str, Path], cal: Calibration) -> None:
    mon = ConveyorMonitor(PROFILE, MonitorSettings(baseline_n=BASELINE), cal)
    results = _run(mon, _files(series["healthy"]))
    assert [r.status for r in results[:BASELINE]] == ["baseline"] * BASELINE
    assert all(r.status == "monitored" for r in results[BASELINE:])
    assert not any(r.alarm for r in results)
    assert mon.open_alarms() == []
    # the JSON fields, numbers where the recording tells
    d = results[-1].to_dict()
    assert {"file", "recorded_at", "alarm", "causes", "payload_kg", "tlf", "warnings"} <= set(d)
    assert 5.0 < d["payload_kg"] < 45.0


@pytest.mark.parametrize(
    ("name", "cause", "feature"),
    [
        ("friction", "friction", "friction"),
        ("rail_obstacle", "obstruction", "impact_hits_per_rev"),
    ],
)
def test_fault_series_alarm_with_the_right_cause(
    series: dict[str, Path], cal: Calibration, name: str, cause: str, feature: str
) -> None:
    mon = ConveyorMonitor(PROFILE, MonitorSettings(baseline_n=BASELINE), cal)
    results = _run(mon, _files(series[name]))
    alarms = [r for r in results if r.alarm]
    assert alarms, f"{name}: no alarm"
    first = alarms[0]
    assert (first.recorded_at or "") >= _onset(series[name])
    assert first.causes[0]["cause"] == cause
    assert first.causes[0]["since"] <= first.recorded_at
    if feature == "impact_hits_per_rev":
        # the hits make the residual impulsive too: those alarms name the obstacle
        impulsive = {feature, "residual_kurtosis", "crest_factor", "impact_count"}
        assert first.causes[0]["feature"] in impulsive | {"impact_rate_per_m"}
        # one fault, one alarm: the features that name the obstacle are its evidence
        grouped = [a for a in mon.alarms if feature in {e.feature for e in a.evidence}]
        assert [a.cause for a in grouped] == [cause]
        assert len(grouped[0].evidence) >= 2
        hits = next(e for e in grouped[0].evidence if e.feature == feature)
        assert hits.value is not None and hits.value > 0
        assert hits.since is not None
    else:
        assert first.causes[0]["feature"] == feature
        assert first.causes[0]["change"] > 0
        opened = mon.open_alarms()
        assert [a.cause for a in opened if a.feature == feature] == [cause]
    for c in {a.cause for a in mon.alarms}:
        assert sum(a.is_open and a.cause == c for a in mon.alarms) <= 1
    # from the alarm on, a friction rise must not read as payload: the
    # payload is the inertia signature's, within its uncertainty of the truth
    truth = {
        Path(t["file"]).name: t["payload_kg"]
        for t in map(json.loads, (series[name] / "truth.jsonl").read_text().splitlines())
    }
    later = [r for r in results if (r.recorded_at or "") > (first.recorded_at or "")]
    by_inertia = [r for r in later if "weighed_by_inertia" in {w["code"] for w in r.warnings}]
    assert later or name != "friction"  # the friction series alarms early enough to check
    assert len(by_inertia) >= len(later) // 2
    for r in by_inertia:
        if r.payload_kg is not None:
            assert r.uncertainty_kg is not None
            assert abs(r.payload_kg - truth[Path(r.file).name]) < 4 * r.uncertainty_kg, r.file


def test_the_friction_forecast_follows_the_fault_while_its_alarm_is_open(
    series: dict[str, Path], cal: Calibration
) -> None:
    """Once the friction alarm opens, the recordings are weighed by inertia (their
    signatures disagree: no ``payload_inertia_kg``); the friction forecast stays,
    crossed since the first recording that exceeded on friction, remaining life 0."""
    mon = ConveyorMonitor(PROFILE, MonitorSettings(baseline_n=BASELINE), cal)
    results = _run(mon, _files(series["friction"]))
    first = next(k for k, r in enumerate(results) if "friction" in r.exceeded)
    opened = next(
        k
        for k, r in enumerate(results)
        if r.alarm and any(c["feature"] == "friction" for c in r.causes)
    )
    later = results[opened:]
    assert any(
        (r.features or {}).get("payload_inertia_kg") is None for r in later
    )  # what made the forecast vanish
    history = mon.history
    # from the alarm on, once the models have their fewest values (MIN_POINTS monitored)
    start = max(opened, BASELINE + MIN_POINTS - 1)
    for k in (start, (start + len(history)) // 2, len(history) - 1):
        fcs = baseline.forecasts(
            mon.baselines, history[: k + 1], mon.baseline_since or "", mon.settings.z_limit
        )
        fc = next(f for f in fcs if f["feature"] == "friction")
        assert fc["crossed"] is True
        assert fc["crosses_at"] == results[first].recorded_at
        assert fc["remaining_life_days"] == {"earliest": 0.0, "expected": 0.0, "latest": 0.0}
        assert fc["payload_source"] in {"none", "payload_inertia_kg", "weighed_by_inertia"}
        assert sum(fc["payload_sources"].values()) >= k + 1 - BASELINE - 2
    assert any(f["feature"] == "friction" for f in mon.forecasts())
    # weighed by inertia, a recording has the TLF of that payload. Known answer: on the
    # flat conveyor the sprocket's work per metre is mu·g·(moving mass), so the TLF is
    # mu·m(m_p)/m_p (test_tlf), here with the truth's rail friction at the truth's
    # payload, the TLF moved by the weighing's payload error (its work stays the truth's)
    truth = {
        Path(t["file"]).name: t
        for t in map(json.loads, (series["friction"] / "truth.jsonl").read_text().splitlines())
    }
    weighed = [
        r
        for r in later
        if r.payload_kg is not None and "weighed_by_inertia" in {w["code"] for w in r.warnings}
    ]
    assert weighed
    for r in weighed:
        assert r.tlf is not None and r.uncertainty_kg is not None
        t = truth[Path(r.file).name]
        hand = t["friction"] * PROFILE.moving_mass_kg(t["payload_kg"]) / r.payload_kg
        # measured 1.03-1.08 of the hand value (the ramps' work beside the steady travel)
        assert r.tlf == pytest.approx(hand, rel=0.1), r.file


def test_state_round_trip_continues_where_it_stopped(
    series: dict[str, Path], cal: Calibration
) -> None:
    files = _files(series["friction"])
    whole = _run(ConveyorMonitor(PROFILE, MonitorSettings(baseline_n=BASELINE), cal), files)
    mon = ConveyorMonitor(PROFILE, MonitorSettings(baseline_n=BASELINE), cal)
    first = _run(mon, files[:20])
    state = json.loads(json.dumps(mon.to_state().to_dict()))
    again = ConveyorMonitor.from_state(state, PROFILE)
    second = _run(again, files[20:])
    split = first + second
    assert [r.alarm for r in split] == [r.alarm for r in whole]
    assert [r.exceeded for r in split] == [r.exceeded for r in whole]
    # the same recording again is recognised, the model left as it was
    dup = again.process(load_recording(files[-1], profile=PROFILE).recording, files[-1].name)
    assert dup[0].status == "duplicate"
    assert "already_processed" in [w["code"] for w in dup[0].warnings]
    assert len(again.history) == len(files)
    other = load_profile(REFERENCE_PROFILE).model_copy(update={"tray_mass_kg": 11.0})
    with pytest.raises(StoreError, match="another version of its profile"):
        ConveyorMonitor.from_state(state, other)


def test_late_baseline_rows_are_only_those_that_can_feed_a_fit(
    series: dict[str, Path], cal: Calibration
) -> None:
    # before: the health model kept every recording after its baseline as a
    # late-baseline row (the retired belt_bump is never finite, so a baseline
    # was always "missing"): about 2 kB more per recording for ever, in memory
    # and in the state stored with each recording
    files = _files(series["friction"])
    mon = ConveyorMonitor(PROFILE, MonitorSettings(baseline_n=BASELINE), cal)
    _run(mon, files[:20])
    assert mon.baselines is not None
    assert len(mon.late_rows) < 20 - BASELINE
    for row in mon.late_rows:
        missing = [k for k in row if k not in mon.baselines]
        assert any(math.isfinite(float(row[k] or math.nan)) for k in missing)
    # a state stored before that rule, with rows that can feed no fit: pruned on
    # loading, and the results are those of a model that keeps them
    state = json.loads(json.dumps(mon.to_state().to_dict()))
    junk = [
        {**h["features"], **{k: None for k in h["features"] if k not in mon.baselines}}
        for h in state["history"][BASELINE:]
    ]
    assert junk
    bloated = state | {"late_rows": state["late_rows"] + junk}
    pruned = ConveyorMonitor.from_state(bloated, PROFILE)
    assert len(pruned.late_rows) == len(state["late_rows"])
    kept = ConveyorMonitor.from_state(bloated, PROFILE)
    kept.late_rows = [dict(r) for r in bloated["late_rows"]]
    a, b = _run(pruned, files[20:]), _run(kept, files[20:])
    assert [r.to_dict() for r in a] == [r.to_dict() for r in b]
    assert pruned.baselines == kept.baselines


def test_maintenance_restarts_the_baseline_and_closes_alarms(
    series: dict[str, Path], cal: Calibration
) -> None:
    files = _files(series["friction"])
    mon = ConveyorMonitor(PROFILE, MonitorSettings(baseline_n=BASELINE), cal)
    before = _run(mon, files)
    assert mon.open_alarms()
    at = datetime.fromisoformat(before[-1].recorded_at or "") - timedelta(seconds=1)
    mon.add_event("repair", at, "A. Fitter", "rails cleaned")
    after = mon.process(load_recording(files[-1], profile=PROFILE).recording, "again")
    assert after[0].status == "baseline"
    assert "baseline_restarted" in [w["code"] for w in after[0].warnings]
    assert mon.open_alarms() == []
    closed = [a for a in mon.alarms if a.status == "closed"]
    assert closed and all("A. Fitter" in (a.closed_by or "") for a in closed)


def test_without_calibration_one_is_learned(series: dict[str, Path]) -> None:
    mon = ConveyorMonitor(PROFILE, MonitorSettings(baseline_n=BASELINE))
    files = _files(series["healthy"])
    waiting = []
    for f in files[: BASELINE - 1]:
        waiting += mon.process(load_recording(f, profile=PROFILE).recording)
    assert waiting == []
    assert [r.status for r in mon.finish()] == ["learning"] * (BASELINE - 1)
    results = mon.process(load_recording(files[BASELINE - 1], profile=PROFILE).recording)
    assert len(results) == BASELINE  # the waiting ones are monitored now
    assert mon.calibration_source == "learned"
    codes = {w["code"] for w in results[0].warnings}
    assert "payload_uncalibrated" in codes
    # friction is well learned: the learned model reads mu within 10 %
    assert mon.calibration is not None
    assert mon.calibration.parameters["mu"] == pytest.approx(0.23, rel=0.1)
    # its case says where it comes from, and which runs would make it a weighing one
    assert mon.calibration.case == "learned"
    note = mon.calibration.recommendation()
    assert note is not None and "both directions" in note
    assert "calibration_weak" in {w.code for w in mon.calibration.warnings}


# ---------------------------------------------------------------- command line
@pytest.mark.slow
def test_cli_monitor_state_fail_on_alarm_and_acknowledge(
    series: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    folder = series["friction"]
    cal_file = tmp_path / "cal.json"
    cal_files = [str(f) for f in sorted((folder / "calibration").glob("*.csv"))]
    assert (
        main(["calibrate", "--profile", REFERENCE_PROFILE, *cal_files, "--out", str(cal_file)]) == 0
    )
    capsys.readouterr()
    files = [str(f) for f in _files(folder)]
    state = tmp_path / "plant.state"
    args = ["monitor", "--profile", REFERENCE_PROFILE, "--calibration", str(cal_file)]
    args += ["--state", str(state), "--baseline", str(BASELINE)]
    assert main([*args, *files[:20], "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert len(out["recordings"]) == 20
    first_run = out["recordings"]
    assert out["conveyors"][0]["conveyor"] == "white-belt-01"
    code = main([*args, *files[20:], "--json", "--fail-on-alarm"])
    out = json.loads(capsys.readouterr().out)
    assert code == EXIT_ALARM
    alarms = out["conveyors"][0]["open_alarms"]
    assert alarms and alarms[0]["cause"] == "friction"
    # the verdict, as every view says it: an unacknowledged alarm, since it opened
    conveyor = out["conveyors"][0]
    assert conveyor["health"] == "alarm" and conveyor["ne107"] == "failure"
    assert conveyor["health_since"] == conveyor["ne107_since"] == min(a["since"] for a in alarms)
    assert conveyor["health_index"] >= 1.0
    assert any(r["alarm"] for r in out["recordings"])
    # the alarmed feature's forecast stays while its alarm is open: crossed, since when
    (friction,) = [f for f in out["conveyors"][0]["forecasts"] if f["feature"] == "friction"]
    assert friction["crossed"] is True
    assert friction["remaining_life_days"]["expected"] == 0.0
    recordings = first_run + out["recordings"]
    exceeded = [r["recorded_at"] for r in recordings if "friction" in r["exceeded"]]
    assert friction["crosses_at"] == exceeded[0]
    for a in alarms:
        assert (
            main(["acknowledge", a["id"], "--state", str(state), "--by", "me", "--why", "WO 17"])
            == 0
        )
    capsys.readouterr()
    # acknowledged alarms still stand (the fault is still there): scripts still fail
    assert main([*args, files[-1], "--json", "--fail-on-alarm"]) == EXIT_ALARM
    capsys.readouterr()
    for a in alarms:
        shelve = ["alarms", "shelve", a["id"], "--state", str(state), "--by", "me"]
        assert main([*shelve, "--why", "WO 17", "--minutes", "600"]) == 0
    capsys.readouterr()
    # nothing new, everything shelved: scripts pass
    assert main([*args, files[-1], "--json", "--fail-on-alarm"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["recordings"][0]["status"] == "duplicate"
    assert main([*args, files[-1]]) == 0
    text = " ".join(capsys.readouterr().out.split())  # as wrapped to the terminal's width
    assert (
        f"forecast: friction (friction) crossed {friction['limit']:.4g} since {exceeded[0][:16]}, "
        "remaining life 0"
    ) in text
    assert (
        load_state(state)["conveyors"]["white-belt-01"]["alarms"][0]["acknowledged"]["by"] == "me"
    )
    # maintenance: recorded with who and why
    assert (
        main(
            [
                "maintenance",
                "--state",
                str(state),
                "--conveyor",
                "white-belt-01",
                "--kind",
                "repair",
                "--by",
                "me",
                "--why",
                "rails",
            ]
        )
        == 0
    )
    events = load_state(state)["conveyors"]["white-belt-01"]["events"]
    assert events[0]["by"] == "me" and events[0]["kind"] == "repair"


def test_cli_refusals_are_one_line_and_keep_the_state(
    series: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = tmp_path / "bad.csv"
    bad.write_text("# conveyor: white-belt-01\ntime [s],speed [rpm]\n0,1\n", encoding="utf-8")
    foreign = tmp_path / "foreign.csv"
    foreign.write_text("# conveyor: other-line\ntime [s],speed [rpm],torque [Nm]\n0,1,2\n")
    good = [str(f) for f in _files(series["healthy"])[:3]]
    state = tmp_path / "s.state"
    code = main(
        [
            "monitor",
            "--profile",
            REFERENCE_PROFILE,
            "--state",
            str(state),
            "--json",
            str(bad),
            str(foreign),
            *good,
        ]
    )
    out = json.loads(capsys.readouterr().out)
    assert code == 2
    errors = {r["file"]: r["error"] for r in out["recordings"] if "error" in r}
    assert set(errors) == {str(bad), str(foreign)}
    assert "other-line" in errors[str(foreign)]
    assert "\n" not in errors[str(bad)]
    # the good recordings wait for a learned calibration, kept in the state
    saved = load_state(state)["conveyors"]["white-belt-01"]
    assert [p["file"] for p in saved["pending"]] == good
    # a damaged state is refused on one line and left as it was
    state.write_text("{not json", encoding="utf-8")
    assert main(["monitor", "--profile", REFERENCE_PROFILE, "--state", str(state), *good]) == 2
    assert "not valid JSON" in capsys.readouterr().err
    assert state.read_text(encoding="utf-8") == "{not json"
    assert main(["monitor", *good]) == 2
    assert "--profile" in capsys.readouterr().err


def test_cli_profiles_folder_serves_several_conveyors(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Recordings of two conveyors, mixed and unordered: each goes to its profile."""
    profiles = tmp_path / "profiles"
    profiles.mkdir()
    names = ("white-belt-01", "short-fast-03")
    for name in names:
        (profiles / f"{name}.yaml").write_bytes(
            (REFERENCE_PROFILE.parent / f"{name}.yaml").read_bytes()
        )
    t0 = datetime(2026, 3, 2, 8, 0, tzinfo=UTC)
    files = []
    for k in range(6):
        for j, name in enumerate(names):
            prof = load_profile(profiles / f"{name}.yaml")
            run = run_virtual(
                prof,
                payload_kg=10.0 + 5 * k,
                seed=100 * j + k,
                recorded_at=t0 + timedelta(hours=k),
                source=name,
            )
            path = tmp_path / f"{name}-{k}.csv"
            write_recording(run.recording, path)
            files.append(str(path))
    files.reverse()  # newest first: monitor sorts them by recorded_at
    code = main(["monitor", "--profiles", str(profiles), "--baseline", "5", "--json", *files])
    out = json.loads(capsys.readouterr().out)
    assert code == 0
    assert sorted(c["conveyor"] for c in out["conveyors"]) == sorted(names)
    for name in names:
        mine = [r for r in out["recordings"] if r["conveyor"] == name]
        assert len(mine) == 6
        times = [r["recorded_at"] for r in mine]
        assert times == sorted(times)
        assert [r["status"] for r in mine] == ["baseline"] * 5 + ["monitored"]
    summary = {c["conveyor"]: c for c in out["conveyors"]}
    assert summary["white-belt-01"]["calibration"] == "learned"


def test_a_load_placed_mid_cycle_is_reported_not_alarmed(
    series: dict[str, Path], cal: Calibration
) -> None:
    mon = ConveyorMonitor(PROFILE, MonitorSettings(baseline_n=BASELINE), cal)
    results = _run(mon, _files(series["payload_step"]))
    stepped = [r for r in results if any(c["cause"] == "payload_changed" for c in r.causes)]
    assert len(stepped) >= 10  # most recordings after the onset carry a step
    for r in stepped:
        assert "not_judged" in [w["code"] for w in r.warnings]
        assert r.exceeded == []
    assert not any(r.alarm for r in results)


def test_recordings_are_ordered_in_utc() -> None:
    a = datetime(2026, 3, 29, 9, 0, tzinfo=timezone(timedelta(hours=2)))  # 07:00 UTC
    b = datetime(2026, 3, 29, 8, 0, tzinfo=UTC)
    order, missing = order_recordings([("b", b), ("a", a), ("c", None)])
    # c has no time: it stays right after a, the file before it in the order given
    assert order == ["a", "c", "b"]
    assert missing == {"c"}


def test_a_calibration_given_later_takes_the_waiting_recordings(
    series: dict[str, Path], cal: Calibration
) -> None:
    files = _files(series["healthy"])
    mon = ConveyorMonitor(PROFILE, MonitorSettings(baseline_n=BASELINE))
    for f in files[:3]:
        assert mon.process(load_recording(f, profile=PROFILE).recording, f.name) == []
    # the same content again while waiting is not counted twice
    again = mon.process(load_recording(files[0], profile=PROFILE).recording, files[0].name)
    assert again[0].status == "duplicate"
    assert len(mon.pending) == 3
    state = json.loads(json.dumps(mon.to_state().to_dict()))
    loader = lambda p: load_recording(p, profile=PROFILE).recording  # noqa: E731
    back = ConveyorMonitor.from_state(state, PROFILE, loader=loader)
    assert [r.source for r in back.pending] == [str(f) for f in files[:3]]
    back.set_calibration(cal)
    flushed = back.flush_pending()
    assert [r.status for r in flushed] == ["baseline"] * 3
    assert back.pending == []


def test_maintenance_in_the_state_closes_alarms_at_once(
    series: dict[str, Path], cal: Calibration
) -> None:
    mon = ConveyorMonitor(PROFILE, MonitorSettings(baseline_n=BASELINE), cal)
    _run(mon, _files(series["friction"]))
    data = {"conveyors": {PROFILE.id: mon.to_state().to_dict()}}
    add_maintenance(data, PROFILE.id, "cleaning", "A. Fitter", "rails cleaned")
    alarms = data["conveyors"][PROFILE.id]["alarms"]
    assert alarms and all(a["status"] == "closed" for a in alarms)
    assert "A. Fitter" in alarms[0]["closed_by"]
    with pytest.raises(StoreError, match="closed"):
        acknowledge_alarm(data, alarms[0]["id"], "me", "late")
    with pytest.raises(StoreError, match="kind"):
        add_maintenance(data, PROFILE.id, "magic", "me", "")


def test_a_worker_s_features_equal_those_made_from_the_file_alone(
    series: dict[str, Path], cal: Calibration
) -> None:
    # the worker hands validation's segmentation on and sends the samples
    # packed; the features must be those of the recording read on its own
    for f in _files(series["friction"])[-3:]:
        item = prepare(str(f), PROFILE, None, cal)
        assert item.features is not None and item.recording is not None
        alone = recording_features(load_recording(f, profile=PROFILE), cal)
        assert pickle.dumps(item.features) == pickle.dumps(alone)


def test_an_inspection_is_monitored_without_segmenting_again(
    series: dict[str, Path], cal: Calibration, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Compute once: given validation's inspection, the monitor reuses its phases."""
    files = _files(series["healthy"])[:6]
    by_recording = _run(ConveyorMonitor(PROFILE, MonitorSettings(baseline_n=5), cal), files)
    inspections = [load_recording(f, profile=PROFILE) for f in files]

    def no_segmenting(*_args: object) -> None:
        raise AssertionError("segmented again")

    monkeypatch.setattr("chaintwin.diagnose.monitor.segment", no_segmenting)
    mon = ConveyorMonitor(PROFILE, MonitorSettings(baseline_n=5), cal)
    by_inspection: list[RecordingResult] = []
    for f, ins in zip(files, inspections, strict=True):
        by_inspection += mon.process(ins, f.name)
    by_inspection += mon.finish()
    assert [r.to_dict() for r in by_inspection] == [r.to_dict() for r in by_recording]


def test_state_alarm_and_event_records_round_trip_and_refuse_damage(
    series: dict[str, Path], cal: Calibration
) -> None:
    mon = ConveyorMonitor(PROFILE, MonitorSettings(baseline_n=BASELINE), cal)
    _run(mon, _files(series["friction"]))
    mon.add_event("cleaning", datetime(2030, 1, 1, tzinfo=UTC), "A. Fitter", "rails")
    state = mon.to_state()
    assert isinstance(state.alarms[0], Alarm) and isinstance(state.events[0], Event)
    assert state.version == STATE_VERSION
    own = {"conveyor", "profile_sha256", "settings", "pending", "version"}
    assert {f.name for f in dataclasses.fields(MonitorState)} - own == set(LEARNED)
    text = json.loads(json.dumps(state.to_dict()))
    back = MonitorState.from_dict(text)
    assert back.to_dict() == text
    assert back.alarms == state.alarms and back.events == state.events
    assert back.settings == mon.settings
    assert back.calibration is not None and mon.calibration is not None
    assert back.calibration.to_dict() == mon.calibration.to_dict()
    # a record that lost a field, or has a wrong type, is refused in one line
    broken = json.loads(json.dumps(text))
    del broken["alarms"][0]["feature"]
    with pytest.raises(StoreError, match="<state>: monitoring state of 'white-belt-01' is damaged"):
        MonitorState.from_dict(broken)
    broken = json.loads(json.dumps(text))
    broken["alarms"][0]["status"] = "maybe"
    with pytest.raises(StoreError, match="neither open nor closed"):
        ConveyorMonitor.from_state(broken, PROFILE)
    broken = json.loads(json.dumps(text))
    broken["events"][0]["applied"] = "yes"
    with pytest.raises(StoreError, match="'applied' must be true or false"):
        ConveyorMonitor.from_state(broken, PROFILE)
    # from a record, the new monitor does not share it with the old one
    again = ConveyorMonitor.from_state(state, PROFILE)
    again.alarms[0].cause = "changed"
    assert mon.alarms[0].cause != "changed"


def test_monitor_and_ingest_resume_and_order_alike(
    tmp_path: Path, series: dict[str, Path], cal: Calibration, capsys: pytest.CaptureFixture[str]
) -> None:
    from chaintwin.diagnose.session import resume
    from chaintwin.ingest.pipeline import ingest
    from chaintwin.store.store import Store

    # a recording without a recorded time is marked so by both commands
    files = [str(f) for f in _files(series["healthy"])[:6]]
    rec = load_recording(files[-1], profile=PROFILE).recording
    meta = dataclasses.replace(rec.metadata, recorded_at=None)
    write_recording(dataclasses.replace(rec, metadata=meta), tmp_path / "undated.csv")
    batch = [*files[:5], str(tmp_path / "undated.csv")]
    assert (
        main(["monitor", "--profile", str(REFERENCE_PROFILE), "--baseline", "5", "--json", *batch])
        == 0
    )
    by_file = {r["file"]: r for r in json.loads(capsys.readouterr().out)["recordings"]}
    assert "no_recorded_at" in [w["code"] for w in by_file[batch[-1]]["warnings"]]
    with Store(f"sqlite:///{tmp_path / 'store.db'}") as store:
        ingest(
            batch, {PROFILE.id: PROFILE}, store, settings=MonitorSettings(baseline_n=5), workers=1
        )
        stored = {r["file"]: r for r in store.results(PROFILE.id)}
        assert "no_recorded_at" in [w["code"] for w in stored[batch[-1]]["warnings"]]
    # a model made with a calibration from a file: the same one goes on, another
    # is refused for a state file and replaces it (baseline restarted) for a store
    settings = MonitorSettings(baseline_n=BASELINE)
    mon = ConveyorMonitor(PROFILE, settings, cal)
    _run(mon, _files(series["healthy"])[:3])
    same, flushed = resume(mon, PROFILE, settings, cal)
    assert same is mon and flushed == [] and len(mon.baseline_rows) == 3
    friction = sorted((series["friction"] / "calibration").glob("*.csv"))
    other = calibrate([load_recording(f, profile=PROFILE).recording for f in friction], PROFILE)
    with pytest.raises(StoreError, match="monitored with another calibration"):
        resume(mon, PROFILE, settings, other, other_calibration="refuse")
    moved, _ = resume(mon, PROFILE, settings, other, other_calibration="replace")
    assert moved.calibration is not None
    assert moved.calibration.to_dict()["parameters"] == other.to_dict()["parameters"]
    assert moved.baseline_rows == []


def test_a_conveyor_out_of_service_is_shown_not_judged_and_resumes_with_its_baseline(
    series: dict[str, Path], cal: Calibration
) -> None:
    files = _files(series["friction"])
    onset = _onset(series["friction"])
    mon = ConveyorMonitor(PROFILE, MonitorSettings(baseline_n=BASELINE), cal)
    # out of service from the fault's onset on, for a day: the friction rise is not judged
    start = datetime.fromisoformat(onset)
    mon.out_of_service = {
        "by": "ann",
        "why": "chain change",
        "from": start.isoformat(),
        "until": (start + timedelta(days=1)).isoformat(),
    }
    results = _run(mon, files)
    inside = [r for r in results if onset <= (r.recorded_at or "") < mon.out_of_service["until"]]
    assert inside
    for r in inside:
        assert "out_of_service" in [w["code"] for w in r.warnings]
        assert not r.alarm and r.exceeded == [] and r.features
        assert r.status == "monitored"
    baseline_rows = len(mon.baseline_rows)
    assert baseline_rows == BASELINE  # none of the window learned
    # after the window the same baseline judges again: the rise alarms
    after = [r for r in results if (r.recorded_at or "") >= mon.out_of_service["until"]]
    assert any(r.alarm for r in after)
    assert all(a.opened_at >= mon.out_of_service["until"] for a in mon.alarms if a.opened_at)
    # the window survives the state
    again = MonitorState.from_dict(mon.to_state().to_dict())
    assert again.out_of_service == mon.out_of_service


def test_the_unexplained_peak_leaves_out_0_hz_s_mainlobe_as_any_line_s() -> None:
    """A flat spectrum (1 everywhere, its baseline too) with a bump of 6 at a bin:
    within GUARD_BINS (4) of 0 Hz it is the trend's (what changed the plateau's level
    for a while), no peak (the ratio elsewhere: 1); at bin 6 it is the peak (6, at its
    order: 6 bins of 0.1 Hz at 10 Hz shaft speed, order 0.06)."""
    from chaintwin.diagnose.peaks import GUARD_BINS, unexplained_peak

    x = np.arange(0.0, 50.0, 0.1)
    base = np.ones_like(x)
    for k, expected in ((3, (1.0, None)), (GUARD_BINS, (1.0, None)), (6, (6.0, 0.06))):
        amp = base.copy()
        amp[k] = 6.0
        sp = Spectrum(
            x=x, amplitude=amp, kind="frequency", resolution=0.1, channel="torque", speed_rpm=600.0
        )
        ratio, order = unexplained_peak(sp, x, base, 0.5, np.asarray([]))
        assert ratio == pytest.approx(expected[0]), k
        if expected[1] is not None:
            assert order == pytest.approx(expected[1])
