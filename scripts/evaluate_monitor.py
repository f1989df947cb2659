"""Evaluate condition monitoring on virtual-conveyor time series.

For each series the virtual conveyor (all realism on, payload 10-40 kg drawn
per recording, gear losses drifting ±5 % with temperature) writes a
conveyor's recordings over simulated days with ``chaintwin.simulate.fleet``;
one series per degradation fault, growing linearly from a known onset day to
its final severity, and healthy ones. Each series is monitored from its
recordings (read back from the files, as ``chaintwin monitor`` does) and the
script prints, per series: onset, first alarm, severity at first alarm,
cause given, false alarms (alarm recordings before the onset, or any on a
healthy series) and the alarms (one per probable cause) opened there, and
writes them as JSON (``--json``, ``docs/evaluation/monitor.json`` by default).

Usage::

    python scripts/evaluate_monitor.py [--days 20] [--per-day 6] [--learned]
        [--profile chaintwin/examples/profiles/white-belt-01.yaml] [--keep DIR] [--json PATH]
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from datetime import datetime
from pathlib import Path

from chaintwin.calibrating.procedure import calibrate
from chaintwin.diagnose.monitor import ConveyorMonitor
from chaintwin.diagnose.records import MonitorSettings
from chaintwin.diagnose.state import json_ready
from chaintwin.read.profile import load_profile
from chaintwin.simulate.faults import Fault, expected_causes, fault_type
from chaintwin.simulate.fleet import generate
from chaintwin.validate.checks import load_recording

EXAMPLES = Path(__file__).resolve().parent.parent / "chaintwin" / "examples"
EVALUATION = Path(__file__).resolve().parent.parent / "docs" / "evaluation"
"""Where the evaluations write their JSON by default (the evaluation reports read it)."""


def _at_end(name: str) -> list[Fault]:
    """A fault at its end severity (the fault table's)."""
    end = fault_type(name).end_severity
    if end is None:
        raise SystemExit(f"fault '{name}' has no end severity in the fault table")
    return [Fault(name, end)]


SERIES: list[tuple[str, list[Fault], int]] = [
    ("healthy-a", [], 0),
    ("healthy-b", [], 0),
    *[
        (name, _at_end(name), 6)
        for name in (
            "friction",
            "lubrication",
            "bearing",
            "gear_tooth",
            "obstruction",
            "rail_obstacle",
            "elongation",
            "sprocket",
        )
    ],
    ("healthy-events", _at_end("payload_event"), 0),
]
"""(name, faults at their final severity, onset day)."""

EXPECTED = expected_causes()
"""The probable cause each fault should be given (the fault table's)."""


def run_series(
    name: str,
    faults: list[Fault],
    onset: int,
    folder: Path,
    args: argparse.Namespace,
    seed: int,
) -> dict[str, object]:
    profile = load_profile(args.profile)
    out = folder / name
    generate(
        profile,
        out,
        days=args.days,
        per_day=args.per_day,
        faults=faults,
        onset_day=onset,
        sample_time_s=args.sample_time,
        seed=seed,
    )
    truth = [json.loads(line) for line in (out / "truth.jsonl").read_text().splitlines()]
    by_file = {t["file"]: t for t in truth}
    cal = None
    if not args.learned:
        cal_recs = [
            load_recording(p, profile=profile).recording
            for p in sorted((out / "calibration").glob("*.csv"))
        ]
        cal = calibrate(cal_recs, profile)
    mon = ConveyorMonitor(profile, MonitorSettings(baseline_n=args.baseline), cal)
    files = sorted(p for p in out.glob("*.csv"))
    t0 = time.perf_counter()
    results = []
    for p in files:
        rec = load_recording(p, profile=profile).recording
        results += mon.process(rec)
    results += mon.finish()
    elapsed = (time.perf_counter() - t0) / max(len(files), 1)
    start = truth[0]["recorded_at"] if truth else None
    onset_at = None
    if faults:
        onset_at = next(
            (t["recorded_at"] for t in truth if any(v > 0 for v in t["faults"].values())), None
        )
    first = next((r for r in results if r.alarm), None)
    false_alarms = sum(
        1
        for r in results
        if r.alarm
        and (name not in EXPECTED or (onset_at is not None and (r.recorded_at or "") < onset_at))
    )
    # grouped alarms (one per conveyor and probable cause) opened where there is no fault
    false_groups = sum(
        1
        for a in mon.alarms
        if name not in EXPECTED or (onset_at is not None and (a.opened_at or "") < onset_at)
    )
    events_noted = sum(1 for r in results if any(c["cause"] == "payload_event" for c in r.causes))
    events_true = sum(1 for t in truth if t.get("payload_event_s"))
    sev = None
    cause = None
    if first is not None:
        t = by_file[Path(first.file).name]
        sev = max(t["faults"].values()) if t["faults"] else 0.0
        cause = first.causes[0]["cause"] if first.causes else None
    every = sorted({r.causes[0]["cause"] for r in results if r.alarm and r.causes})
    pairs: dict[str, int] = {}
    for r in results:
        for c in r.causes if r.alarm else []:
            key = f"{c['cause']}:{c['feature']}"
            pairs[key] = pairs.get(key, 0) + 1
    return {
        "every_cause": every,
        "pairs": pairs,
        "series": name,
        "start": start,
        "onset": onset_at,
        "first_alarm": None if first is None else first.recorded_at,
        "severity": sev,
        "cause": cause,
        "expected": EXPECTED.get(name),
        "false_alarms": false_alarms,
        "false_alarm_groups": false_groups,
        "events_noted": events_noted,
        "events_true": events_true,
        "recordings": len(results),
        "ms_per_recording": 1000.0 * elapsed,
        "first_causes": None if first is None else first.causes,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--days", type=int, default=20)
    ap.add_argument("--per-day", type=int, default=6)
    ap.add_argument("--baseline", type=int, default=20)
    ap.add_argument("--sample-time", type=float, default=0.006)
    ap.add_argument("--learned", action="store_true", help="no calibration file: learn one")
    ap.add_argument("--profile", default=str(EXAMPLES / "profiles" / "white-belt-01.yaml"))
    ap.add_argument("--keep", type=Path, default=None, help="write the series here and keep them")
    ap.add_argument("--only", nargs="*", default=None, help="series names to run")
    ap.add_argument(
        "--json",
        type=Path,
        default=EVALUATION / "monitor.json",
        help="write the series' results here [docs/evaluation/monitor.json]",
    )
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        folder = args.keep or Path(tmp)
        for k, (name, faults, onset) in enumerate(SERIES):
            if args.only and name not in args.only:
                continue
            rows.append(run_series(name, faults, onset, folder, args, seed=1000 + k))

    args.json.parent.mkdir(parents=True, exist_ok=True)
    settings = {
        k: getattr(args, k) for k in ("days", "per_day", "baseline", "sample_time", "learned")
    }
    args.json.write_text(
        json.dumps(json_ready({"settings": settings, "series": rows}), indent=1, allow_nan=False)
    )

    def day(iso: object) -> str:
        return "-" if iso is None else datetime.fromisoformat(str(iso)).strftime("%m-%d %H:%M")

    mode = "learned calibration" if args.learned else "calibration file (P2 + speeds)"
    print(
        f"Monitoring evaluation: {args.days} days x {args.per_day} recordings, "
        f"Ts {args.sample_time * 1000:.0f} ms, baseline {args.baseline}, {mode}"
    )
    print(
        f"{'series':12s} {'onset':>11s} {'first alarm':>11s} {'severity':>8s} "
        f"{'cause':>12s} {'right':>5s} {'false':>5s} {'groups':>6s} {'ms/rec':>6s}"
    )
    right = 0
    alarmed = 0
    for r in rows:
        ok = "-"
        if r["expected"] is not None:
            ok = "yes" if r["cause"] == r["expected"] else "NO"
            right += r["cause"] == r["expected"]
            alarmed += r["first_alarm"] is not None
        sev = "-" if r["severity"] is None else f"{r['severity']:.3f}"
        print(
            f"{r['series']:12s} {day(r['onset']):>11s} {day(r['first_alarm']):>11s} {sev:>8s} "
            f"{r['cause'] or '-':>12s} {ok:>5s} {r['false_alarms']:>5d} "
            f"{r['false_alarm_groups']:>6d} {r['ms_per_recording']:6.1f}"
        )
    faults = sum(1 for r in rows if r["expected"] is not None)
    healthy_false = sum(int(r["false_alarms"]) for r in rows if r["expected"] is None)
    healthy_groups = sum(int(r["false_alarm_groups"]) for r in rows if r["expected"] is None)
    print(
        f"alarmed {alarmed} of {faults} fault series, cause right for {right}; "
        f"false alarms on healthy series: {healthy_false} recordings, {healthy_groups} alarms"
    )
    for r in rows:
        if r["events_true"] or r["events_noted"]:
            print(
                f"{r['series']}: {r['events_true']} recordings with a simulated payload event, "
                f"{r['events_noted']} noted as payload_event"
            )
    print("probable causes given over each whole series (first cause of every alarm):")
    for r in rows:
        print(f"  {r['series']:12s} {', '.join(r['every_cause']) or '-'}")
    print("cause:feature named in alarm recordings (how many recordings):")
    for r in rows:
        pairs = ", ".join(f"{k} {v}" for k, v in sorted(r["pairs"].items()))
        print(f"  {r['series']:12s} {pairs or '-'}")
    print("first alarm, every cause named:")
    for r in rows:
        if r["first_causes"]:
            print(f"  {r['series']}: {r['first_causes']}")


if __name__ == "__main__":
    main()
