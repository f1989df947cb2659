"""The alpha-lambda table of the remaining-life forecasts, pooled over monitoring runs.

Run::

    PYTHONPATH=. python scripts/remaining_life_table.py runs/*.json \
        [--json docs/evaluation/fidelity-remaining-life.json]

Each argument is a JSON the monitoring evaluation wrote
(``scripts/evaluate_fidelity.py monitoring ... --json FILE``; runs with
``--only`` hold the same sequences as the whole run). Their sequences are
pooled (a sequence in two files counts once) and judged per method of
:data:`fidelity_monitoring.METHODS` and per lambda
(:func:`fidelity_monitoring.life_summary`); printed as markdown tables, the
totals and per fault type.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

from fidelity_monitoring import FAULT_TYPES, METHODS, life_summary


def _pct(n: int, d: int) -> str:
    return f"{n}/{d} ({n / d:.0%})" if d else "-"


def _ratio(x: float | None) -> str:
    return "-" if x is None else f"{x:.2f}"


def tables(rows: list[dict[str, Any]]) -> tuple[str, dict[str, Any]]:
    """The markdown tables and the JSON-ready summaries of the pooled sequences."""
    found = {m: life_summary(rows, m) for m in METHODS}
    lines = [
        "| forecast | λ | alarmed sequences | with a forecast (crossed) | within ±20 % "
        "| within, true life ≥ 5 recordings | band covers the truth | median expected/true |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for m in METHODS:
        for x in found[m]:
            lines.append(
                f"| {m} | {x['lambda']} | {x['sequences']} | {x['forecasts']} ({x['crossed']}) "
                f"| {_pct(x['within'], x['sequences'])} "
                f"| {_pct(x['resolvable_within'], x['resolvable'])} "
                f"| {_pct(x['covered'], x['forecasts'])} | {_ratio(x['median_ratio'])} |"
            )
    lines += [
        "",
        "| fault | λ | "
        + " | ".join(f"{m}: within, covered, expected/true" for m in METHODS)
        + " |",
        "|---|---|" + "---|" * len(METHODS),
    ]
    for f in FAULT_TYPES:
        for i, lam in enumerate(x["lambda"] for x in found["alarm"]):
            cells = []
            for m in METHODS:
                c = found[m][i]["by_fault"].get(f)
                cells.append(
                    "-"
                    if c is None
                    else f"{c['within']}/{c['sequences']}, {c['covered']}/{c['forecasts']}, "
                    f"{_ratio(c['median_ratio'])}"
                )
            if any(c != "-" for c in cells):
                lines.append(f"| {f} | {lam} | " + " | ".join(cells) + " |")
    return "\n".join(lines), found


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", type=Path)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    rows: dict[tuple[Any, ...], dict[str, Any]] = {}
    for path in args.runs:
        for r in json.loads(path.read_text(encoding="utf-8"))["sequences"]:
            if r.get("fault") is None or "error" in r:
                continue
            rows[(r.get("seed"), r["conveyor"], r["fault"])] = r
    pooled = list(rows.values())
    text, found = tables(pooled)
    print(
        f"{len(pooled)} fault sequences, "
        f"{sum(1 for r in pooled if r.get('remaining_life'))} judged (alarmed after the onset)"
    )
    print(text)
    if args.json is not None:
        out = {
            "runs": [str(p) for p in args.runs],
            "sequences": [
                {
                    k: r.get(k)
                    for k in ("seed", "conveyor", "fault", "sample_time_ms", "onset", "first_alarm")
                }
                | {"feature": r.get("feature"), "remaining_life": r.get("remaining_life")}
                for r in pooled
            ],
            "remaining_life": found,
        }
        args.json.write_text(json.dumps(out, indent=1) + "\n", encoding="utf-8")


if __name__ == "__main__":
    main()
