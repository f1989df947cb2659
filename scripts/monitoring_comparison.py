"""Two runs of the monitoring evaluation side by side: a pinned commit's and this one's.

Run::

    python scripts/monitoring_comparison.py --name A \
        --base base-A.json --new new-A.json [--into docs/evaluation/fidelity-monitoring.json]

Each JSON is what ``scripts/evaluate_fidelity.py monitoring --json`` wrote
for the same seeds and sizes, one with the code of a pinned commit
(``git worktree add`` it and run the script there), one with this code.
Printed: the pooled table of each (markdown: fault, sequences, alarmed, cause
right, median delay, alarm recordings and alarms where there is no fault),
side by side, and every sequence whose first alarm, cause or alarms without
a fault differ. ``--into`` adds both under ``comparisons.<name>`` of an
evaluation JSON (its other keys stay as they are): the tables, the sequences
that differ, and the sequences with alarms where there is no fault.
``--same-sequences`` compares only the sequences both runs hold (of the same
sizes; a run of a
few seeds or ``--only`` kinds against a larger one: each sequence is drawn
and simulated the same either way), the tables computed over those.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
from fidelity_monitoring import table as pooled_table

KEYS = ("first_alarm", "cause", "feature", "false_alarms", "false_alarm_groups")
"""What a sequence is compared by."""


def _key(row: dict[str, Any]) -> tuple[Any, Any]:
    return row.get("seed"), row["conveyor"]


def _fmt(x: Any) -> str:
    if x is None:
        return "-"
    return f"{x:.1f}" if isinstance(x, float) else str(x)


def side_by_side(base: list[dict[str, Any]], new: list[dict[str, Any]]) -> str:
    """The two pooled tables as one markdown table (base → new in each cell)."""
    lines = [
        "| fault | sequences | alarmed | cause right | median delay | alarm recordings "
        "where no fault | alarms where no fault |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for b, n in zip(base, new, strict=True):
        if not b["sequences"] and not n["sequences"]:
            continue
        healthy = b["fault"] in ("healthy", "declined")

        def cell(k: str, b: dict[str, Any] = b, n: dict[str, Any] = n) -> str:
            x, y = _fmt(b[k]), _fmt(n[k])
            return x if x == y else f"{x} → {y}"

        lines.append(
            f"| {b['fault'].replace('_', ' ')} | {n['sequences']} | "
            + " | ".join(
                "-" if healthy and k in ("alarmed", "right", "median_delay") else cell(k)
                for k in ("alarmed", "right", "median_delay", "false_alarms")
            )
            + f" | {cell('false_alarm_groups')} |"
        )
    return "\n".join(lines) + "\n"


def differences(base: list[dict[str, Any]], new: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Sequences whose first alarm, cause or alarms without a fault differ."""
    old = {_key(r): r for r in base}
    out = []
    for r in new:
        b = old.get(_key(r))
        if b is None or any(b.get(k) != r.get(k) for k in KEYS):
            out.append(
                {
                    "seed": r.get("seed"),
                    "conveyor": r["conveyor"],
                    "series": r.get("series"),
                    "sample_time_ms": r.get("sample_time_ms"),
                    "onset": r.get("onset"),
                    "base": None if b is None else {k: b.get(k) for k in KEYS},
                    "new": {k: r.get(k) for k in KEYS},
                }
            )
    return out


def with_false_alarms(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Sequences with alarms where there is no fault: what alarmed, and where."""
    return [
        {
            "seed": r.get("seed"),
            "conveyor": r["conveyor"],
            "series": r.get("series"),
            "sample_time_ms": r.get("sample_time_ms"),
            "false_alarms": r["false_alarms"],
            "false_groups": r.get("false_groups", []),
            "false_recordings": r.get("false_recordings", []),
        }
        for r in rows
        if "error" not in r and r.get("false_alarms")
    ]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--name", required=True, help="the comparison's name (e.g. A)")
    parser.add_argument("--base", type=Path, required=True, help="the pinned commit's JSON")
    parser.add_argument("--new", type=Path, required=True, help="this code's JSON")
    parser.add_argument("--commit", default=None, help="the pinned commit, for the record")
    parser.add_argument("--command", default=None, help="the evaluation's command, for the record")
    parser.add_argument("--into", type=Path, default=None, help="an evaluation JSON to add to")
    parser.add_argument(
        "--same-sequences", action="store_true", help="only the sequences both runs hold"
    )
    parser.add_argument("--note", default=None, help="what to know about the runs, for the record")
    args = parser.parse_args(argv)
    base = json.loads(args.base.read_text(encoding="utf-8"))
    new = json.loads(args.new.read_text(encoding="utf-8"))
    if args.same_sequences:
        both = {_key(r) for r in base["sequences"]} & {_key(r) for r in new["sequences"]}
        for run in (base, new):
            run["sequences"] = [r for r in run["sequences"] if _key(r) in both]
            run["table"] = pooled_table(run["sequences"])
    table = side_by_side(base["table"], new["table"])
    diff = differences(base["sequences"], new["sequences"])
    print(table)
    for d in diff:
        print(f"seed {d['seed']} {d['conveyor']} {d['series']}: {d['base']} -> {d['new']}")
    if args.into is not None:
        doc = json.loads(args.into.read_text(encoding="utf-8"))
        doc.setdefault("comparisons", {})[args.name] = {
            "commit": args.commit,
            "command": args.command,
            "note": args.note,
            "seeds": new.get("seeds", [new.get("seed")]),
            "base_table": base["table"],
            "table": new["table"],
            "differences": diff,
            "base_alarms_without_fault": with_false_alarms(base["sequences"]),
            "alarms_without_fault": with_false_alarms(new["sequences"]),
            "seconds": new.get("seconds"),
        }
        args.into.write_text(json.dumps(doc, indent=1, allow_nan=False), encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
