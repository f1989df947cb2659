"""Re-score the remaining-life forecast from the monitoring evaluation's cache, in seconds.

Run::

    PYTHONPATH=. python scripts/life_replay.py runs/cache/*.json [--check] [--per-fault] \
        [--list] [--markdown FILE] [--json FILE]

Each argument is a cache the monitoring evaluation wrote
(``scripts/evaluate_fidelity.py monitoring ... --life-cache FILE``): per
alarmed fault sequence and lambda, what the monitor's forecast and the
hindsight forecast were given (the recordings' times, values at the mean
payload, margins, exceedances, the healthy value and the limit), the true
remaining life, and how the forecasts of the run were judged. The forecasts
are made again with the package's :func:`~chaintwin.diagnose.prognosis.
forecast_alarm` as it is now and judged as the evaluation judges them
(:func:`fidelity_monitoring.life_summary`): within +-20 % of the true
remaining life, the band covering it, and the band's width over the true
remaining life (:data:`METHODS`: the monitor's forecast, the line alone
after the change point as before the curve, the window forecast as the run
judged it, and the trend known in hindsight). A sequence in two caches (the
same seed's runs with another ``--per-fault`` share their first conveyor)
counts once. ``--list`` prints every forecast (earliest < expected < latest,
``*`` where the band holds the truth), ``--markdown`` writes the tables of
the evaluation page, ``--check`` compares the forecasts made now with those
the run judged (the same code must give the same answers). ``plain`` is the monitor's forecast
with every exceedance counting (a cache written before the recordings' ``confirm`` and
``caught`` were kept reads so throughout).
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from fidelity_monitoring import _judged, hindsight_forecast, life_summary

from chaintwin.diagnose.prognosis import forecast_alarm

Variant = Callable[[dict[str, Any]], dict[str, Any] | None]


def alarm(
    entry: dict[str, Any], curved: bool = True, confirmed: bool = True
) -> dict[str, Any] | None:
    """The monitor's forecast (as :func:`chaintwin.diagnose.baseline.forecasts` makes it).

    ``curved`` False: the line alone after the change point (the forecast before the curve).
    ``confirmed`` False: every exceedance counts and every rule met opens the alarm, as the
    forecast did before it counted them as the monitor does (a cache without ``confirm`` and
    ``noted`` is read so too).
    """
    a = entry["alarm"]
    if a is None or not a["forecastable"]:
        return None
    fc = forecast_alarm(
        entry["feature"],
        [datetime.fromisoformat(t) for t in a["times"]],
        a["values"],
        a["margins"],
        a["exceeded"],
        a["healthy"],
        x=a["x"],
        y=a["y"],
        limit=a["limit"],
        curved=curved,
        confirm=a.get("confirm") if confirmed else None,
        caught=a.get("caught") if confirmed else None,
        noted=a.get("noted") if confirmed else None,
    )
    return None if fc is None else fc.to_dict()


def hindsight(entry: dict[str, Any]) -> dict[str, Any] | None:
    """The forecast with the rise fitted up to the recordings after the alarm."""
    a = entry["alarm"]
    return hindsight_forecast(
        entry["feature"], entry["hindsight"], a["x"] if a else 3, a["y"] if a else 10
    )


def rows_of(entries: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The evaluation's sequence rows (``fault`` and ``remaining_life``) re-scored now."""
    rows: dict[tuple[Any, ...], dict[str, Any]] = {}
    for e in entries:
        key = (e["seed"], e["conveyor"], e["fault"])
        row = rows.setdefault(key, {"fault": e["fault"], "remaining_life": [], "key": key})
        args = (e["lambda"], e["recording"], e["feature"], e["true_days"])
        judged = _judged(alarm(e), *args)
        judged["hindsight"] = _judged(hindsight(e), *args)
        judged["window"] = e["judged"]["window"]
        judged["line"] = _judged(alarm(e, curved=False), *args)
        judged["plain"] = _judged(alarm(e, confirmed=False), *args)
        judged["before"] = e["judged"]
        row["remaining_life"].append(judged)
    return list(rows.values())


def width(got: list[dict[str, Any]]) -> float | None:
    """Median band width (latest - earliest) over the true remaining life (no latest: inf)."""
    w = [
        (x["latest_days"] - x["earliest_days"]) / x["true_days"]
        if x["latest_days"] is not None
        else float("inf")
        for x in got
        if x["expected_days"] is not None and x["earliest_days"] is not None and x["true_days"] > 0
    ]
    return float(np.median(w)) if w else None


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("caches", nargs="+", type=Path)
    parser.add_argument("--check", action="store_true", help="compare with the run's forecasts")
    parser.add_argument("--per-fault", action="store_true", help="print per fault type too")
    parser.add_argument("--list", action="store_true", help="print every forecast, before and now")
    parser.add_argument("--markdown", type=Path, default=None, help="write the tables here")
    parser.add_argument("--json", type=Path, default=None, help="write the summaries here")
    args = parser.parse_args(argv)
    entries = [e for p in args.caches for e in json.loads(p.read_text())]
    seen: set[tuple[Any, ...]] = set()
    unique = []
    for e in entries:  # a sequence in two caches counts once
        key = (e["seed"], e["conveyor"], e["fault"], e["lambda"])
        if key not in seen:
            seen.add(key)
            unique.append(e)
    rows = rows_of(unique)
    out: dict[str, Any] = {}
    for method in METHODS:
        out[method] = life_summary(rows, method)
        for x in out[method]:
            got = _got(rows, method, x["lambda"])
            x["median_width"] = width(got)
            for f, c in x["by_fault"].items():
                c["median_width"] = width(_got(rows, method, x["lambda"], f))
            print(
                f"{method:9s} lambda {x['lambda']}: within {x['within']}/{x['sequences']}, "
                f"covered {x['covered']}/{x['forecasts']}, crossed {x['crossed']}, "
                f"median expected/true {_f(x['median_ratio'])}, "
                f"median width/true {_f(x['median_width'])}"
            )
            if args.per_fault:
                for f, c in x["by_fault"].items():
                    print(
                        f"    {f:14s} within {c['within']}/{c['sequences']}, covered "
                        f"{c['covered']}/{c['forecasts']}, median expected/true "
                        f"{_f(c['median_ratio'])}"
                    )
    if args.list:
        for r in rows:
            for y in r["remaining_life"]:
                b = y["line"]
                print(
                    f"{r['key'][0]} {r['key'][1]} {r['fault']:13s} {y['lambda']} "
                    f"{y['feature']:24s} "
                    f"true {y['true_days']:6.2f}  line {_band(b)}  plain {_band(y['plain'])}  "
                    f"now {_band(y)}  "
                    f"hindsight {_band(y['hindsight'])}"
                )
    if args.check:
        differ = 0
        for r in rows:
            for y in r["remaining_life"]:
                for m, now in (("alarm", y), ("hindsight", y["hindsight"])):
                    was = y["before"] if m == "alarm" else y["before"]["hindsight"]
                    if (was["expected_days"], was["earliest_days"], was["latest_days"]) != (
                        now["expected_days"],
                        now["earliest_days"],
                        now["latest_days"],
                    ):
                        differ += 1
                        print(f"differs: {r['key']} lambda {y['lambda']} {m}: {was} -> {now}")
        print(f"{differ} forecasts differ from the run's")
    if args.markdown is not None:
        args.markdown.write_text(markdown(out))
    if args.json is not None:
        args.json.write_text(json.dumps(out, indent=1))
    return 0


METHODS = ("alarm", "plain", "line", "window", "hindsight")
"""Judged: ``alarm`` the monitor's forecast now, ``plain`` the same with every exceedance
counting (plain X-of-Y, as before it counted them as the monitor does), ``line`` the line
alone after the change point (the forecast before the curve and the model error),
``window`` the forecast before the alarm's opening was predicted (as the run judged it),
``hindsight`` the trend fitted up to the recordings after the alarm."""


def _got(
    rows: list[dict[str, Any]], method: str, lam: float, fault: str | None = None
) -> list[dict[str, Any]]:
    return [
        y if method == "alarm" else y[method]
        for r in rows
        if fault is None or r["fault"] == fault
        for y in r["remaining_life"]
        if y["lambda"] == lam
    ]


def _pct(n: int, d: int) -> str:
    return f"{n}/{d} ({n / d:.0%})" if d else "-"


def markdown(out: dict[str, Any]) -> str:
    """The tables: per method and lambda, and the monitor's forecast per fault type."""
    lines = [
        "| forecast | λ | with a forecast (crossed) | within ±20 % "
        "| within, true life ≥ 5 recordings | band covers the truth "
        "| median expected/true | median band width/true |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for m in METHODS:
        for x in out[m]:
            lines.append(
                f"| {m} | {x['lambda']} | {x['forecasts']} ({x['crossed']}) "
                f"| {_pct(x['within'], x['sequences'])} "
                f"| {_pct(x['resolvable_within'], x['resolvable'])} "
                f"| {_pct(x['covered'], x['forecasts'])} | {_f(x['median_ratio'])} "
                f"| {_f(x['median_width'])} |"
            )
    lines += [
        "",
        "| fault | λ | alarm: within, covered, expected/true, width/true | plain | line |",
        "|---|---|---|---|---|",
    ]
    faults = sorted({f for x in out["alarm"] for f in x["by_fault"]})
    for f in faults:
        for a, p, b in zip(out["alarm"], out["plain"], out["line"], strict=True):
            cells = []
            for x in (a, p, b):
                c = x["by_fault"].get(f)
                cells.append(
                    "-"
                    if c is None
                    else f"{c['within']}/{c['sequences']}, {c['covered']}/{c['forecasts']}, "
                    f"{_f(c['median_ratio'])}, {_f(c['median_width'])}"
                )
            lines.append(f"| {f.replace('_', ' ')} | {a['lambda']} | {' | '.join(cells)} |")
    return "\n".join(lines) + "\n"


def _band(x: dict[str, Any]) -> str:
    if x["expected_days"] is None:
        return "          none          "
    return (
        f"{_f(x['earliest_days']):>6s}<{_f(x['expected_days']):>6s}<{_f(x['latest_days']):>6s}"
        f"{'*' if x['covered'] else ' '}"
    )


def _f(x: float | None) -> str:
    return "-" if x is None else f"{x:.2f}"


if __name__ == "__main__":
    sys.exit(main())
