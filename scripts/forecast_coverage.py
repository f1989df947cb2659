"""Prediction-interval coverage and remaining-life hits over virtual degradation runs.

docs/methods/forecasts.md. Each run: the virtual conveyor (reference profile,
every realism switch on, loss drift) records 6 times a day for 30 days; from
day 3 its rail friction rises linearly to +20 % on the last day (the friction
alarm fires some 10 days into the rise, so that 20 recordings before it the
rise is already in the data: with a faster rise, 20 recordings before the
alarm are before the fault, and nothing can forecast it). It is
calibrated on its own calibration runs and monitored (baseline of 10
recordings); the friction feature (at the baseline's mean payload, as the
monitor's forecasts take it) is forecast with
:func:`chaintwin.diagnose.forecasting.forecast_feature`.

Printed:

* **coverage**: from origins every 10 monitored recordings, the model the
  backtest picks forecasts 10 even steps ahead; the share of the actual even
  series that lies inside the 90 % prediction interval (target 85-95 %);
* **remaining life**: forecast 20 recordings before the friction alarm
  fired, whether the alarm's time lies in the reported band
  [earliest, latest] (latest None: open-ended); target 80 % of the runs.

Run: ``PYTHONPATH=. python scripts/forecast_coverage.py [runs]`` (some
20-40 s per run).
"""

from __future__ import annotations

import sys
import tempfile
from datetime import datetime
from pathlib import Path

import numpy as np

from chaintwin.calibrating.procedure import calibrate
from chaintwin.diagnose.baseline import at_mean_payload
from chaintwin.diagnose.features import feature_spec
from chaintwin.diagnose.forecasting import forecast_feature, forecast_path, resample_even
from chaintwin.diagnose.monitor import ConveyorMonitor
from chaintwin.diagnose.records import MonitorSettings
from chaintwin.read.profile import load_profile
from chaintwin.simulate.faults import Fault
from chaintwin.simulate.fleet import generate
from chaintwin.validate.checks import load_recording

PROFILE = load_profile("chaintwin/examples/profiles/white-belt-01.yaml")
FEATURE = "friction"
SETTINGS = MonitorSettings(baseline_n=10)
AHEAD = 10
ORIGIN_EVERY = 10
RUL_LEAD = 20
DAYS = 30
PER_DAY = 6
ONSET_DAY = 3
SEVERITY = 0.2


def degradation_run(seed: int, root: Path) -> tuple[list[datetime], list[float], float, int | None]:
    """Times and friction values of the monitored recordings, the limit, the alarm's index."""
    out = generate(
        PROFILE,
        root / f"run{seed}",
        days=DAYS,
        per_day=PER_DAY,
        faults=[Fault("friction", SEVERITY)],
        onset_day=ONSET_DAY,
        seed=seed,
    )
    cal_files = sorted((out.folder / "calibration").glob("*.csv"))
    cal = calibrate([load_recording(f, profile=PROFILE).recording for f in cal_files], PROFILE)
    mon = ConveyorMonitor(PROFILE, SETTINGS, cal)
    results = []
    for f in sorted(out.folder.glob("*.csv")):
        results += mon.process(load_recording(f, profile=PROFILE).recording, f.name)
    results += mon.finish()
    assert mon.baselines is not None
    fb = mon.baselines[FEATURE]
    spec = feature_spec(FEATURE)
    rows = [r for r in results if r.status == "monitored" and r.recorded_at]
    times = [datetime.fromisoformat(r.recorded_at or "") for r in rows]
    values = [at_mean_payload(FEATURE, fb, r.features) for r in rows]
    alarm = next(
        (k for k, r in enumerate(rows) if any(c["feature"] == FEATURE for c in r.causes)), None
    )
    return times, values, fb.limit(SETTINGS.z_limit, spec.min_rel), alarm


def coverage(times: list[datetime], values: list[float]) -> tuple[int, int]:
    """Points inside the 90 % interval and points forecast, over the run's origins."""
    t0 = times[0]
    t = np.array([(x - t0).total_seconds() / 86400.0 for x in times])
    v = np.asarray(values)
    ok = np.isfinite(v)
    t, v = t[ok], v[ok]
    inside = total = 0
    for origin in range(20, len(t) - AHEAD, ORIGIN_EVERY):
        _grid, series, step = resample_even(t[:origin], v[:origin])
        _model, _mae, _mean, lower, upper = forecast_path(series, AHEAD)
        # the actual values on the same even grid, continued
        _full_grid, full, _ = resample_even(t, v, step)
        n = series.shape[0]
        actual = full[n : n + AHEAD]
        k = actual.shape[0]
        inside += int(np.count_nonzero((actual >= lower[:k]) & (actual <= upper[:k])))
        total += k
    return inside, total


def main() -> None:
    runs = int(sys.argv[1]) if len(sys.argv) > 1 else 10
    inside = total = hits = judged = 0
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(runs):
            times, values, limit, alarm = degradation_run(100 + seed, Path(tmp))
            i, n = coverage(times, values)
            inside += i
            total += n
            line = f"run {seed}: coverage {i}/{n}"
            if alarm is not None and alarm - RUL_LEAD >= 12:
                origin = alarm - RUL_LEAD
                fc = forecast_feature(FEATURE, times[:origin], values[:origin], limit)
                judged += 1
                at = times[alarm]
                hit = (
                    fc is not None and fc.earliest <= at and (fc.latest is None or at <= fc.latest)
                )
                hits += int(hit)
                band = (
                    "no forecast"
                    if fc is None
                    else f"[{fc.earliest:%m-%d %H:%M}, "
                    f"{'open' if fc.latest is None else format(fc.latest, '%m-%d %H:%M')}] "
                    f"({fc.model})"
                )
                line += f"; alarm {at:%m-%d %H:%M}, band {band}: {'hit' if hit else 'miss'}"
            else:
                line += "; no alarm far enough in to judge the remaining life"
            print(line, flush=True)
    print(f"90 % interval coverage: {inside}/{total} = {inside / max(total, 1):.1%}")
    print(f"remaining life in band: {hits}/{judged} = {hits / max(judged, 1):.0%}")


if __name__ == "__main__":
    main()
