"""The ``monitoring`` part of the fidelity evaluation.

Run::

    OPENBLAS_NUM_THREADS=1 python scripts/evaluate_fidelity.py monitoring \
        [--per-fault 8] [--healthy 12] [--recordings 200] [--workers 2] \
        [--json docs/evaluation/fidelity-monitoring.json]

Conveyors are drawn from the weighing evaluation's design distribution
(every realism effect on, the richer plant, 1, 6 or 12 ms scopes). For each
of the seven fault types, ``--per-fault`` conveyors get a degradation
sequence of ``--recordings`` recordings: the fault's severity is 0 until an
onset drawn between recordings 80 and 120 (scaled with the length) and then
grows linearly to its end value (:data:`END_SEVERITY`) at the last
recording. ``--healthy`` more conveyors get healthy sequences with payload
events (:mod:`chaintwin.simulate.faults` ``payload_event`` at severity 1).
Every sequence has payloads drawn per recording (10-40 % of the conveyor's
largest), a slow +-10 % drift of the gear losses, belt positions that carry
on between recordings (the scope's position offset is arbitrary), and is
calibrated from the ``several_loads`` protocol's runs.

Printed per fault type: sequences alarmed after the onset, probable cause
right (the first alarm's first cause), median delay after the onset
(recordings), false alarms (alarms before the onset); for the healthy
sequences the alarms and the payload events noted; and how far a rail
obstacle moved the friction feature and the weighing (largest |z| of the
friction feature against its baseline after the onset, and the median
payload error before and after the onset); and how the weighings before
any fault (healthy sequences whole, fault sequences before their onset,
recordings with a payload event left out) kept their uncertainty's promise:
shares within 1, 2 and 3 reported standard uncertainties, how many beyond
5, and on which conveyors (the JSON's ``weighing``); and how good the
remaining-life forecast was, as prognostics judges it (the JSON's
``remaining_life``): on each alarmed fault sequence the true time to the
limit is the recording at which the alarm opened, and the alarmed feature's
forecast made :data:`LAMBDAS` of the way from the onset to that recording is
within +-20 % of the true remaining time or not (alpha-lambda accuracy);
the coverage is the share of those forecasts whose band holds the truth.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from datetime import UTC, datetime, timedelta
from typing import Any

import numpy as np

from chaintwin.calibrating.procedure import calibrate
from chaintwin.diagnose import baseline
from chaintwin.diagnose.features import feature_spec
from chaintwin.diagnose.health import FeatureBaseline
from chaintwin.diagnose.monitor import ConveyorMonitor
from chaintwin.diagnose.prognosis import RECENT, fit_rise, forecast_alarm
from chaintwin.diagnose.records import MonitorSettings
from chaintwin.errors import ChaintwinError
from chaintwin.simulate.faults import Fault, expected_causes, fault_type
from chaintwin.simulate.virtual import default_setpoints, run_virtual
from chaintwin.validate import inspect_recording

FAULT_TYPES = (
    "friction",
    "lubrication",
    "bearing",
    "gear_tooth",
    "rail_obstacle",
    "elongation",
    "sprocket",
)
"""The seven fault types (``rail_obstacle`` stands for the obstruction)."""

EXPECTED = expected_causes()
"""The probable cause each fault type should be given (the fault table's)."""

END_SEVERITY = {
    name: end
    for name in (*FAULT_TYPES, "payload_event")
    if (end := fault_type(name).end_severity) is not None
}
"""Severity at the last recording (the fault table's, on the scales of
:mod:`chaintwin.simulate.faults`)."""

DRIFT = 0.10
"""Amplitude of the slow gear-loss drift, 1."""

DECLINED_DEG = (-15.0, -5.0)
"""Incline of the declined healthy conveyors in the conveying direction, degrees."""

HEALTHY_KINDS = ("healthy", "declined")
"""Sequences without a fault: drawn conveyors, and conveyors conveying downhill."""

LAMBDAS = (0.5, 0.8)
"""Where the remaining life is judged: this share of the way from the onset to the alarm."""

ALPHA = 0.2
"""A remaining life counts as accurate within this share of the true one (alpha-lambda)."""

SPACING_DAYS = 3.0 / 24.0
"""Time between a sequence's recordings, days."""


def _sequence(task: dict[str, Any]) -> dict[str, Any]:
    """Simulate and monitor one sequence (runs in a worker process)."""
    conv = task["conveyor"]
    fault: str | None = task["fault"]
    healthy: bool = task.get("healthy", False)
    n: int = task["recordings"]
    onset: int = task["onset"]
    rng = np.random.default_rng(task["seed"])
    profile = conv.profile
    try:
        cal = calibrate(task["calibration"], profile)
    except ChaintwinError as exc:
        return {"fault": fault, "conveyor": profile.id, "error": f"calibration: {exc}"}
    monitor = ConveyorMonitor(profile, MonitorSettings(), cal)
    window = 2048 * conv.sample_time_s
    ramp = min(0.5, window / 8)
    setpoints = default_setpoints(
        profile,
        duration_s=window,
        ramp_s=ramp,
        hold_s=max(0.5, window - 2 * ramp - 0.6),
        direction=conv.direction,
    )
    start = datetime(2026, 3, 2, 6, 0, tzinfo=UTC)
    angle = float(rng.uniform(0.0, 2.0e4))
    phase = float(rng.uniform(0.0, 2.0 * math.pi))
    first_alarm: int | None = None
    first_cause: str | None = None
    first_feature: str | None = None
    false_alarms = 0
    false_by: dict[str, int] = {}
    false_recordings: list[dict[str, Any]] = []
    index_at: dict[str, int] = {}
    scales: list[float] = []
    events_true = events_noted = 0
    friction: list[tuple[int, float | None, float | None]] = []
    errors: list[tuple[int, float, float]] = []
    # the weighing's promise before any fault, without payload events
    promised = unweighable = 0
    promise_z: list[float] = []
    # the baselines as they stood at each recording (frozen values: a shallow copy)
    baselines_at: dict[int, dict[str, FeatureBaseline]] = {}
    for k in range(n):
        severity = 0.0
        if fault is not None and k >= onset:
            severity = END_SEVERITY[fault] * (k - onset + 1) / max(n - onset, 1)
        faults = [Fault(fault, severity)] if fault is not None and severity > 0 else []
        payload = float(rng.uniform(0.1, 0.4)) * conv.max_payload_kg
        scale = 1.0 + DRIFT * math.sin(2.0 * math.pi * k / n * 1.5 + phase)
        scales.append(scale)
        run = run_virtual(
            profile,
            payload_kg=payload,
            sample_time_s=conv.sample_time_s,
            faults=faults,
            seed=int(rng.integers(2**31)),
            setpoints=setpoints,
            recorded_at=start + timedelta(days=SPACING_DAYS * k),
            loss_scale=scale,
            initial_motor_angle=angle,
            source=f"{profile.id}-{k:03d}",
        )
        # unrecorded moves between scopes carry the belt on
        angle = float(run.simulation.position[-1]) + float(rng.uniform(0.0, 3000.0))
        events_true += run.truth["payload_event_s"] is not None
        for r in monitor.process(inspect_recording(run.recording, profile=profile)):
            idx = int(r.file.rsplit("-", 1)[1])
            index_at[r.recorded_at or ""] = idx
            baselines_at[idx] = dict(monitor.baselines or {})
            if r.alarm and not healthy and idx >= onset and first_alarm is None:
                first_alarm = idx
                first_cause = r.causes[0]["cause"] if r.causes else None
                first_feature = r.causes[0]["feature"] if r.causes else None
            if r.alarm and (healthy or idx < onset):
                false_alarms += 1
                for c in r.causes:
                    key = f"{c['cause']}:{c['feature']}"
                    false_by[key] = false_by.get(key, 0) + 1
                false_recordings.append(
                    {
                        "recording": idx,
                        "causes": [
                            {"cause": c["cause"], "feature": c["feature"], "change": c["change"]}
                            for c in r.causes
                        ],
                        "loss_scale": scales[idx],
                        "payload_kg": payload_truth(run.truth) if idx == k else None,
                        "payload_event": run.truth["payload_event_s"] is not None
                        if idx == k
                        else None,
                        "status": r.status,
                    }
                )
            events_noted += any(c["cause"] == "payload_event" for c in r.causes)
            if r.status == "monitored":
                feats = r.features or {}
                friction.append((idx, feats.get("friction"), feats.get("payload_inertia_kg")))
            if r.payload_kg is not None and r.uncertainty_kg:
                err = r.payload_kg - payload_truth(run.truth)
                errors.append((idx, err, err / r.uncertainty_kg))
            if (healthy or idx < onset) and run.truth["payload_event_s"] is None:
                promised += 1
                if r.payload_kg is None or not r.uncertainty_kg:
                    unweighable += 1
                else:
                    promise_z.append(errors[-1][2])
    z_after = _friction_z(monitor, friction, onset)
    # grouped alarms (one per cause) opened where there is no fault
    false_groups = [
        {"cause": a.cause, "feature": a.feature, "opened": index_at.get(a.opened_at or "")}
        for a in monitor.alarms
        if healthy or index_at.get(a.opened_at or "", n) < onset
    ]
    inputs: list[dict[str, Any]] = []
    life = _remaining_life(monitor, baselines_at, onset, first_alarm, first_feature, inputs)
    return {
        "fault": fault,
        "conveyor": profile.id,
        "sample_time_ms": conv.sample_time_s * 1e3,
        "onset": onset if fault is not None else None,
        "first_alarm": first_alarm,
        "delay": None if first_alarm is None else first_alarm - onset,
        "cause": first_cause,
        "feature": first_feature,
        "right": fault is not None and first_cause == EXPECTED.get(fault),
        "false_alarms": false_alarms,
        "false_alarm_causes": false_by,
        "false_alarm_groups": len(false_groups),
        "false_groups": false_groups,
        "false_recordings": false_recordings,
        "incline_deg": conv.design.get("incline_deg"),
        "events_true": events_true,
        "events_noted": events_noted,
        "friction_z_max_after_onset": z_after,
        "payload_error_before_kg": _median_abs([e for i, e, _ in errors if i < onset]),
        "payload_error_after_kg": _median_abs([e for i, e, _ in errors if i >= onset]),
        # in reported standard uncertainties: what the weighing promised
        "payload_z_before": _median_abs([z for i, _, z in errors if i < onset]),
        "payload_z_after": _median_abs([z for i, _, z in errors if i >= onset]),
        "weighing_before_fault": _promise(promised, unweighable, promise_z),
        "remaining_life": life,
        "forecast_inputs": inputs,
    }


METHODS = ("alarm", "window", "hindsight")
"""The remaining-life forecasts judged: ``alarm`` the monitor's (when the alarm rule
opens the alarm, from the rise after its change point), ``window`` the one before it
(the backtest's model over the last 30 steps against the baseline's limit at its mean
payload), ``hindsight`` the alarm's opening drawn from the rise fitted to the recordings
up to :data:`HINDSIGHT_AFTER` after the alarm (the trend known: how well the opening can
be told at all, the noise's and the X-of-Y rule's own spread left)."""

HINDSIGHT_AFTER = 10
"""Recordings after the alarm the hindsight trend is fitted to."""


def _judged(
    fc: dict[str, Any] | None, lam: float, k: int, feature: str, true_days: float
) -> dict[str, Any]:
    """One forecast against the truth: within +-:data:`ALPHA`, its band covering the truth."""
    life = (fc or {}).get("remaining_life_days") or {}
    expected, earliest, latest = (life.get(x) for x in ("expected", "earliest", "latest"))
    return {
        "lambda": lam,
        "recording": k,
        "feature": feature,
        "true_days": true_days,
        "expected_days": expected,
        "earliest_days": earliest,
        "latest_days": latest,
        "crossed": None if fc is None else fc["crossed"],
        "within": expected is not None and abs(expected - true_days) <= ALPHA * true_days,
        "covered": None
        if expected is None
        else earliest is not None
        and earliest <= true_days
        and (latest is None or true_days <= latest),
    }


def hindsight_forecast(
    feature: str, h: dict[str, Any] | None, x: int, y: int
) -> dict[str, Any] | None:
    """The alarm's opening after the last recording of ``h`` (:func:`_hindsight_inputs`), the
    trend fitted to the recordings after the alarm too."""
    if h is None:
        return None
    t0 = datetime.fromisoformat(h["times"][0])
    days = np.array(
        [(datetime.fromisoformat(t) - t0).total_seconds() / 86400 for t in h["whole_times"]]
    )
    v = np.asarray(h["whole_values"], dtype=np.float64)
    ok = np.isfinite(v)
    trend = fit_rise(days[ok], v[ok])
    if trend is None:
        return None
    fc = forecast_alarm(
        feature,
        [datetime.fromisoformat(t) for t in h["times"]],
        h["values"],
        h["margins"],
        h["exceeded"],
        h["healthy"],
        x=x,
        y=y,
        trend=trend,
        confirm=h.get("confirm"),
        caught=h.get("caught"),
        noted=h.get("noted"),
    )
    return None if fc is None else fc.to_dict()


def _alarm_inputs(
    feature: str,
    fb: FeatureBaseline | None,
    history: list[dict[str, Any]],
    since: str,
    monitor: ConveyorMonitor,
    steps: dict[str, FeatureBaseline],
) -> dict[str, Any] | None:
    """What :func:`chaintwin.diagnose.baseline.forecasts` hands ``forecast_alarm`` (the cache).

    The recordings' times (ISO), values at the mean payload, the last
    :data:`~chaintwin.diagnose.prognosis.RECENT` margins, the exceedances, the
    healthy value and the limit: a forecasting variant re-scored from these
    (``scripts/life_replay.py``) sees what the monitor's forecast saw.
    """
    if fb is None:
        return None
    rows = [
        h
        for h in history
        if h.get("status") == "monitored" and h.get("recorded_at") and h["recorded_at"] >= since
    ]
    if len(rows) < 8:
        return None
    spec = feature_spec(feature)
    vals, _ = baseline.values_at_mean_payload(feature, fb, rows)
    margins, _ = baseline.alarm_margins(feature, fb, rows[-RECENT:], monitor.settings.z_limit)
    confirm, caught = baseline.confirmations(rows, steps)
    return {
        "times": [h["recorded_at"] for h in rows],
        "values": [float(v) for v in vals],
        "margins": [float(m) for m in margins],
        "exceeded": [feature in (h.get("exceeded") or ()) for h in rows],
        "healthy": fb.expected(fb.mean_payload_kg),
        "limit": fb.limit(monitor.settings.z_limit, spec.min_rel),
        "x": monitor.settings.x,
        "y": monitor.settings.y,
        "forecastable": spec.cause is not None and feature not in baseline.NO_FORECAST,
        "confirm": confirm,
        "caught": caught,
        "noted": baseline.noted_events(feature, rows),
    }


def _hindsight_inputs(
    feature: str,
    fb: FeatureBaseline | None,
    history: list[dict[str, Any]],
    whole: list[dict[str, Any]],
    since: str,
    monitor: ConveyorMonitor,
    steps: dict[str, FeatureBaseline],
) -> dict[str, Any] | None:
    """What :func:`hindsight_forecast` is made from (kept in the cache)."""
    if fb is None:
        return None

    def monitored(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
        return [
            h
            for h in rows
            if h.get("status") == "monitored" and h.get("recorded_at") and h["recorded_at"] >= since
        ]

    past, every = monitored(history), monitored(whole)
    if len(past) < 8 or not every:
        return None
    vals, _ = baseline.values_at_mean_payload(feature, fb, past)
    v_all, _ = baseline.values_at_mean_payload(feature, fb, every)
    margins, exceeded = baseline.alarm_margins(feature, fb, past, monitor.settings.z_limit)
    confirm, caught = baseline.confirmations(past, steps)
    return {
        "times": [h["recorded_at"] for h in past],
        "values": [float(v) for v in vals],
        "margins": [float(m) for m in margins],
        "exceeded": [bool(e) for e in exceeded],
        "healthy": fb.expected(fb.mean_payload_kg),
        "whole_times": [h["recorded_at"] for h in every],
        "whole_values": [float(v) for v in v_all],
        "confirm": confirm,
        "caught": caught,
        "noted": baseline.noted_events(feature, past),
    }


def _remaining_life(
    monitor: ConveyorMonitor,
    baselines_at: dict[int, dict[str, FeatureBaseline]],
    onset: int,
    alarm: int | None,
    feature: str | None,
    inputs: list[dict[str, Any]] | None = None,
) -> list[dict[str, Any]]:
    """The alarmed feature's remaining life forecast at each of :data:`LAMBDAS`.

    The truth is the time from the forecast's recording to the recording at
    which the alarm opened. The forecast is the monitor's
    (:func:`chaintwin.diagnose.baseline.forecasts`) over the results up to
    that recording, with the baselines as they stood then. ``within`` says
    whether its expected remaining life is within +-:data:`ALPHA` of the
    truth (False without a forecast), ``covered`` whether the truth lies in
    its band (earliest .. latest; no latest: beyond the horizon, open).
    The other :data:`METHODS` are judged alike under their names. ``inputs``
    (when given) gets each lambda's forecast inputs (:func:`_alarm_inputs`,
    :func:`_hindsight_inputs`) beside the truth, for re-scoring variants.
    """
    if alarm is None or feature is None or alarm <= onset:
        return []
    rows = {int(h["file"].rsplit("-", 1)[1]): h for h in monitor.history if h.get("file")}
    since = monitor.baseline_since or ""
    out = []
    for lam in LAMBDAS:
        k = onset + round(lam * (alarm - onset))
        if k >= alarm or k not in rows or alarm not in rows:
            continue
        history = [h for i, h in sorted(rows.items()) if i <= k]
        whole = [h for i, h in sorted(rows.items()) if i <= alarm + HINDSIGHT_AFTER]
        true_days = (
            datetime.fromisoformat(rows[alarm]["recorded_at"])
            - datetime.fromisoformat(rows[k]["recorded_at"])
        ).total_seconds() / 86400.0
        found: dict[str, dict[str, Any] | None] = {}
        for method in ("alarm", "window"):
            found[method] = next(
                (
                    f
                    for f in baseline.forecasts(
                        baselines_at.get(k, {}),
                        history,
                        since,
                        monitor.settings.z_limit,
                        x=monitor.settings.x,
                        y=monitor.settings.y,
                        method=method,
                    )
                    if f["feature"] == feature
                ),
                None,
            )
        at_k = baselines_at.get(k, {})
        fb = at_k.get(feature)
        hindsight = _hindsight_inputs(feature, fb, history, whole, since, monitor, at_k)
        found["hindsight"] = hindsight_forecast(
            feature, hindsight, monitor.settings.x, monitor.settings.y
        )
        row = _judged(found["alarm"], lam, k, feature, true_days)
        for method in METHODS[1:]:
            row[method] = _judged(found[method], lam, k, feature, true_days)
        out.append(row)
        if inputs is not None:
            inputs.append(
                {
                    "lambda": lam,
                    "recording": k,
                    "onset": onset,
                    "alarm_recording": alarm,
                    "feature": feature,
                    "true_days": true_days,
                    "alarm": _alarm_inputs(feature, fb, history, since, monitor, at_k),
                    "hindsight": hindsight,
                    "judged": row,
                }
            )
    return out


def _ratio_median(made: list[dict[str, Any]]) -> float | None:
    """Median of expected over true remaining life."""
    r = [x["expected_days"] / x["true_days"] for x in made if x["true_days"] > 0]
    return float(np.median(r)) if r else None


def _life_counts(got: list[dict[str, Any]]) -> dict[str, Any]:
    made = [x for x in got if x["expected_days"] is not None]
    within = sum(1 for x in got if x["within"])
    covered = sum(1 for x in made if x["covered"])
    # +-ALPHA of the truth spans a whole recording only from 1/ALPHA recordings on
    wide = [x for x in got if x["true_days"] >= (1.0 / ALPHA - 1e-9) * SPACING_DAYS]
    return {
        "resolvable": len(wide),
        "resolvable_within": sum(1 for x in wide if x["within"]),
        "sequences": len(got),
        "forecasts": len(made),
        "within": within,
        "within_share": within / len(got) if got else None,
        "covered": covered,
        "coverage": covered / len(made) if made else None,
        "crossed": sum(1 for x in made if x["crossed"]),
        "median_ratio": _ratio_median(made),
    }


def life_summary(rows: list[dict[str, Any]], method: str = "alarm") -> list[dict[str, Any]]:
    """The alpha-lambda accuracy and the band's coverage per lambda (the JSON's ``remaining_life``).

    ``sequences``: alarmed fault sequences judged at that lambda;
    ``forecasts``: of them with a forecast of the alarmed feature;
    ``within``: forecasts within +-:data:`ALPHA` of the truth (its share is of
    ``sequences``: a missing forecast counts as a miss); ``covered``: truths
    inside the band (its share is of ``forecasts``); ``within_by_fault``:
    per fault type, [within, sequences]; ``crossed``: forecasts that said the
    limit was crossed already; ``median_ratio``: median expected over true
    remaining life; ``resolvable``: sequences whose true remaining life is at
    least 1/:data:`ALPHA` recordings (where +-:data:`ALPHA` spans a whole
    recording; a shorter one is hit only exactly), ``resolvable_within``: of
    them within; ``by_fault``: these counts per fault type. ``method``: one
    of :data:`METHODS`.
    """

    def pick(r: dict[str, Any], lam: float) -> list[dict[str, Any]]:
        return [
            x if method == "alarm" else x[method]
            for x in r.get("remaining_life", [])
            if x["lambda"] == lam and (method == "alarm" or method in x)
        ]

    out = []
    for lam in LAMBDAS:
        got = [x for r in rows for x in pick(r, lam)]
        by_fault = {
            f: [x for r in rows if r["fault"] == f for x in pick(r, lam)] for f in FAULT_TYPES
        }
        out.append(
            {"lambda": lam, "alpha": ALPHA, "method": method}
            | _life_counts(got)
            | {
                "within_by_fault": {
                    f: [sum(1 for x in mine if x["within"]), len(mine)]
                    for f, mine in by_fault.items()
                },
                "by_fault": {f: _life_counts(mine) for f, mine in by_fault.items() if mine},
            }
        )
    return out


def _promise(n: int, unweighable: int, z: list[float]) -> dict[str, Any]:
    """How a sequence's weighings before any fault kept their uncertainty's promise."""
    a = np.abs(np.asarray(z, dtype=np.float64))
    return {
        "recordings": n,
        "unweighable": unweighable,
        "weighed": int(a.shape[0]),
        "within_1u": int(np.sum(a <= 1.0)),
        "within_2u": int(np.sum(a <= 2.0)),
        "within_3u": int(np.sum(a <= 3.0)),
        "beyond_5u": int(np.sum(a > 5.0)),
        "largest_z": float(a.max()) if a.shape[0] else None,
    }


def payload_truth(truth: dict[str, Any]) -> float:
    """The simulated payload of a recording, kg."""
    return float(truth["payload_kg"])


def _median_abs(values: list[float]) -> float | None:
    return float(np.median(np.abs(values))) if values else None


def _friction_z(
    monitor: ConveyorMonitor, rows: list[tuple[int, float | None, float | None]], onset: int
) -> float | None:
    """Largest z of the friction feature against its baseline after the onset."""
    base = (monitor.baselines or {}).get("friction")
    if base is None:
        return None
    zs = [
        (v - base.expected(load)) / base.scale
        for i, v, load in rows
        if i >= onset and v is not None and load is not None and base.scale > 0
    ]
    zs = [z for z in zs if math.isfinite(z)]
    return max(zs) if zs else None


def run_monitoring(
    args: Any,
    draw_conveyor: Callable[..., Any],
    calibration_runs: Callable[..., dict[str, list[Any]]],
) -> dict[str, Any]:
    """Draw the conveyors, run every sequence, print the table; the JSON-ready result."""
    started = time.perf_counter()
    rng = np.random.default_rng(args.seed + 17)
    n = args.recordings
    lo, hi = round(0.4 * n), round(0.6 * n)
    tasks: list[dict[str, Any]] = []
    plan: list[str] = [f for f in FAULT_TYPES for _ in range(args.per_fault)]
    plan += ["healthy"] * args.healthy + ["declined"] * getattr(args, "declined", 0)
    only = set(getattr(args, "only", None) or [])
    for k, series in enumerate(plan):
        healthy = series in HEALTHY_KINDS
        if series == "declined":
            conv = draw_conveyor(rng, 100 + k, incline_deg=DECLINED_DEG)
        else:
            conv = draw_conveyor(rng, 100 + k)
        onset = int(rng.integers(lo, hi + 1)) if not healthy else 0
        if only and series not in only:
            continue  # drawn all the same: the others stay the whole run's
        seed = args.seed + 5000 + 17 * k
        tasks.append(
            {
                "conveyor": conv,
                "fault": "payload_event" if healthy else series,
                "series": series,
                "healthy": healthy,
                "recordings": n,
                "onset": onset,
                "seed": seed + 1,
                "calibration": calibration_runs(conv, seed)["several_loads"],
            }
        )
    if args.workers <= 1:  # in this process
        rows = [_run_task(task) for task in tasks]
    else:
        with ProcessPoolExecutor(args.workers) as ex:
            rows = list(ex.map(_run_task, tasks))
    seconds = time.perf_counter() - started
    rows = [r | {"seed": args.seed} for r in rows]
    cache = [
        {"seed": args.seed, "fault": r["fault"], "conveyor": r["conveyor"]}
        | {"sample_time_ms": r.get("sample_time_ms")}
        | x
        for r in rows
        for x in r.pop("forecast_inputs", [])
    ]
    if getattr(args, "life_cache", None) is not None:
        args.life_cache.parent.mkdir(parents=True, exist_ok=True)
        args.life_cache.write_text(json.dumps(cache, allow_nan=True))
    found = table(rows)
    _print(found, rows, args, seconds)
    return {
        "seed": args.seed,
        "table": found,
        "weighing": promise_summary(rows),
        "remaining_life": life_summary(rows),
        "remaining_life_before": life_summary(rows, "window"),
        "remaining_life_hindsight": life_summary(rows, "hindsight"),
        "sequences": rows,
        "seconds": seconds,
    }


def run_seeds(
    args: Any,
    draw_conveyor: Callable[..., Any],
    calibration_runs: Callable[..., dict[str, list[Any]]],
) -> dict[str, Any]:
    """:func:`run_monitoring` for each seed of ``args.seed_list`` (or ``args.seed``), pooled.

    The result holds each seed's run under ``runs`` and the table over all
    of them under ``table`` (with one seed: that seed's run, as before, plus
    ``runs`` and ``markdown``).
    """
    seeds = list(getattr(args, "seed_list", None) or [args.seed])
    runs = []
    for seed in seeds:
        args.seed = seed
        runs.append(run_monitoring(args, draw_conveyor, calibration_runs))
        print()
    rows = [r for run in runs for r in run["sequences"]]
    pooled = table(rows)
    title = (
        f"Monitoring over seeds {', '.join(str(s) for s in seeds)}: {args.per_fault} conveyors "
        f"per fault type, {args.healthy} healthy, {getattr(args, 'declined', 0)} declined, "
        f"{args.recordings} recordings each"
    )
    if len(seeds) > 1:
        print(f"pooled: {title}")
        print_table(pooled)
    out: dict[str, Any] = dict(runs[0]) if len(seeds) == 1 else {"seeds": seeds}
    out.update(
        table=pooled,
        runs=[{k: v for k, v in run.items() if k != "sequences"} for run in runs],
        sequences=rows,
        markdown=markdown(pooled, title),
        seconds=sum(float(run["seconds"]) for run in runs),
    )
    return out


def _run_task(task: dict[str, Any]) -> dict[str, Any]:
    row = _sequence(task)
    row["series"] = task["series"]
    if task["healthy"]:  # payload events only: any alarm is a false one
        row.update(fault=None, right=False, onset=None)
    return row


def table(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per fault type and kind of healthy sequence: the evaluation's table.

    ``false_alarms`` counts alarm recordings where there is no fault (before
    the onset; on a healthy sequence every one), ``false_alarm_groups`` the
    alarms (one per probable cause) opened there, ``false_sequences`` the
    sequences with any.
    """
    out = []
    for series in (*FAULT_TYPES, *HEALTHY_KINDS):
        everyone = [r for r in rows if r.get("series", r["fault"] or "healthy") == series]
        mine = [r for r in everyone if "error" not in r]
        delays = [r["delay"] for r in mine if r.get("delay") is not None]
        out.append(
            {
                "fault": series,
                "sequences": len(mine),
                "not_run": len(everyone) - len(mine),
                "alarmed": sum(1 for r in mine if r.get("first_alarm") is not None),
                "right": sum(1 for r in mine if r.get("right")),
                "median_delay": float(np.median(delays)) if delays else None,
                "false_alarms": sum(int(r["false_alarms"]) for r in mine),
                "false_alarm_groups": sum(int(r.get("false_alarm_groups", 0)) for r in mine),
                "false_sequences": sum(1 for r in mine if r["false_alarms"]),
                "events_true": sum(int(r["events_true"]) for r in mine),
                "events_noted": sum(int(r["events_noted"]) for r in mine),
            }
        )
    return out


def promise_summary(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """The weighings before any fault pooled over the sequences (the JSON's ``weighing``)."""
    keys = ("recordings", "unweighable", "weighed", "within_1u", "within_2u", "within_3u")
    done = [r["weighing_before_fault"] for r in rows if "weighing_before_fault" in r]
    out: dict[str, Any] = {k: sum(int(d[k]) for d in done) for k in (*keys, "beyond_5u")}
    worst = [
        (d["largest_z"], r["conveyor"])
        for r, d in ((r, r.get("weighing_before_fault")) for r in rows)
        if d and d["largest_z"] is not None
    ]
    out["largest_z"], out["largest_z_conveyor"] = max(worst) if worst else (None, None)
    out["conveyors_beyond_5u"] = sorted(
        r["conveyor"] for r in rows if r.get("weighing_before_fault", {}).get("beyond_5u", 0) > 0
    )
    return out


def _print_promise(rows: list[dict[str, Any]]) -> None:
    p = promise_summary(rows)
    n = max(p["weighed"], 1)
    print(
        f"weighing before any fault (no payload event): {p['recordings']} recordings, "
        f"{p['unweighable'] / max(p['recordings'], 1):.1%} unweighable; of {p['weighed']} "
        f"weighed {p['within_1u'] / n:.1%} / {p['within_2u'] / n:.1%} / "
        f"{p['within_3u'] / n:.1%} within 1u / 2u / 3u, {p['beyond_5u']} beyond 5u "
        f"(largest {_fmt(p['largest_z'], '.1f')}u, {p['largest_z_conveyor']}; "
        f"conveyors beyond 5u: {', '.join(p['conveyors_beyond_5u']) or 'none'})"
    )


def print_false(rows: list[dict[str, Any]]) -> None:
    """Every sequence with alarm recordings where there is no fault, and what alarmed."""
    print("alarms where there is no fault (recording: cause:feature change; loss scale, payload):")
    for r in rows:
        if "error" in r or not r["false_alarms"]:
            continue
        print(
            f"  seed {r.get('seed')} {r['conveyor']} {r.get('series')} "
            f"({r['sample_time_ms']:.0f} ms, incline {_fmt(r.get('incline_deg'))} deg, onset "
            f"{r['onset']}): {r['false_alarms']} recordings, {r['false_alarm_groups']} alarms "
            f"({', '.join(_group(g) for g in r['false_groups'])})"
        )
        for x in r["false_recordings"]:
            causes = ", ".join(
                f"{c['cause']}:{c['feature']} {_fmt(c['change'], '+.2f')}" for c in x["causes"]
            )
            print(
                f"    {x['recording']:3d}: {causes}; loss x{x['loss_scale']:.3f}, "
                f"payload {_fmt(x['payload_kg'])} kg"
                + (" (payload event)" if x["payload_event"] else "")
            )


def _group(g: dict[str, Any]) -> str:
    return f"{g['cause']}:{g['feature']} opened at {g['opened']}"


def markdown(found: list[dict[str, Any]], title: str) -> str:
    """The table as markdown (the user guide's "How good monitoring is")."""
    lines = [
        title,
        "",
        "| fault | sequences | alarmed | cause right | median delay | alarm recordings "
        "where no fault | alarms where no fault |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for t in found:
        healthy = t["fault"] in HEALTHY_KINDS
        lines.append(
            f"| {t['fault'].replace('_', ' ')} | {t['sequences']} | "
            f"{'-' if healthy else t['alarmed']} | {'-' if healthy else t['right']} | "
            f"{'-' if healthy else _fmt(t['median_delay'])} | {t['false_alarms']} "
            f"({t['false_sequences']} seq.) | {t['false_alarm_groups']} |"
        )
    return "\n".join(lines) + "\n"


def _fmt(x: float | None, spec: str = ".1f") -> str:
    return "-" if x is None else format(x, spec)


def print_table(found: list[dict[str, Any]]) -> None:
    """The table: ``false`` alarm recordings and ``groups`` alarms where there is no fault."""
    print(
        f"{'fault':14s} {'seq':>4s} {'alarmed':>8s} {'right':>6s} {'delay':>6s} {'false':>6s} "
        f"{'groups':>6s}"
    )
    for t in found:
        print(
            f"{t['fault']:14s} {t['sequences']:4d} {t['alarmed']:8d} {t['right']:6d} "
            f"{_fmt(t['median_delay']):>6s} {t['false_alarms']:6d} {t['false_alarm_groups']:6d}"
            + (f"  (not run: {t['not_run']})" if t["not_run"] else "")
        )


def _print(found: list[dict[str, Any]], rows: list[dict[str, Any]], args: Any, s: float) -> None:
    print(
        f"monitoring over random conveyors (seed {args.seed}): {args.per_fault} per fault type, "
        f"{args.healthy} healthy, {getattr(args, 'declined', 0)} healthy declined "
        f"({DECLINED_DEG[0]:.0f} to {DECLINED_DEG[1]:.0f} deg), {args.recordings} recordings "
        f"each, every realism effect on, loss drift +-{DRIFT:.0%}"
    )
    print_table(found)
    for t in found:
        if t["fault"] in HEALTHY_KINDS and t["sequences"]:
            print(
                f"{t['fault']} sequences: {t['events_true']} recordings with a payload event, "
                f"{t['events_noted']} recordings noted as payload_event"
            )
    print_false(rows)
    obstacle = [r for r in rows if r["fault"] == "rail_obstacle" and "error" not in r]
    if obstacle:
        print(
            "rail obstacle: friction feature's largest z after the onset; median |payload "
            "error| in kg and in reported uncertainties u, before and after the onset"
        )
        for r in obstacle:
            print(
                f"  {r['conveyor']} ({r['sample_time_ms']:.0f} ms): "
                f"z {_fmt(r['friction_z_max_after_onset'])}, "
                f"error {_fmt(r['payload_error_before_kg'], '.2f')} kg "
                f"({_fmt(r['payload_z_before'], '.2f')} u) before, "
                f"{_fmt(r['payload_error_after_kg'], '.2f')} kg "
                f"({_fmt(r['payload_z_after'], '.2f')} u) after"
            )
    _print_promise(rows)
    for method in METHODS:
        for x in life_summary(rows, method):
            print(
                f"remaining life ({method}) at lambda {x['lambda']}: {x['within']} of "
                f"{x['sequences']} alarmed sequences within +-{x['alpha']:.0%} "
                f"({_fmt(x['within_share'], '.0%')}), {x['forecasts']} with a forecast "
                f"({x['crossed']} crossed), band covering the truth in {x['covered']} "
                f"({_fmt(x['coverage'], '.0%')}), median expected/true "
                f"{_fmt(x['median_ratio'], '.2f')}; true remaining life of 1/alpha "
                f"recordings or more: {x['resolvable_within']} of {x['resolvable']} within"
            )
            for f, c in x["by_fault"].items():
                print(
                    f"    {f:14s} within {c['within']}/{c['sequences']}, covered "
                    f"{c['covered']}/{c['forecasts']}, median expected/true "
                    f"{_fmt(c['median_ratio'], '.2f')}"
                )
    print("missed or wrong:")
    for r in rows:
        if "error" in r:
            print(f"  {r['conveyor']} {r['fault']}: not run ({r['error']})")
        elif r["fault"] is not None and not r["right"]:
            print(
                f"  {r['conveyor']} {r['fault']} ({r['sample_time_ms']:.0f} ms): "
                f"first alarm {r['first_alarm']} (onset {r['onset']}), cause {r['cause']}"
                + (f" ({r['feature']})" if r["feature"] else "")
            )
    print(f"total run time {s:.0f} s")
