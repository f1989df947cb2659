"""Regenerate the bundled example recordings with the virtual conveyor.

Run from the repository root: ``.venv/bin/python scripts/make_examples.py``.
Seeds are fixed, so the files only change when the simulator does.
"""

from __future__ import annotations

from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from chaintwin.read.profile import ConveyorProfile, load_profile
from chaintwin.read.writer import format_recording, write_recording
from chaintwin.simulate.faults import Fault
from chaintwin.simulate.virtual import default_setpoints, run_virtual

ROOT = Path(__file__).resolve().parents[1] / "chaintwin" / "examples"
PROFILES = ROOT / "profiles"
OUT = ROOT / "recordings"

VENDOR_HEADER = (
    "Zeit [ms];Drehzahl Sollwert [1/min];Istwert Drehzahl [1/min];Lage Sollwert [Inc];"
    "Lage Istwert [Inc];Momentsollwert [%];Moment Istwert [%];Digitaleingaenge"
)


def main() -> None:
    white = load_profile(PROFILES / "white-belt-01.yaml")
    incline = load_profile(PROFILES / "incline-line-02.yaml")
    short = load_profile(PROFILES / "short-fast-03.yaml")
    day = datetime(2026, 11, 21, 8, 0, tzinfo=UTC)

    def at(hour: int, minute: int) -> datetime:
        return day.replace(hour=hour, minute=minute)

    back = default_setpoints(short, duration_s=2048 * 0.006, direction=-1)
    runs: list[tuple[str, ConveyorProfile, dict[str, Any]]] = [
        ("white-belt-01-cal-empty.csv", white, {"payload_kg": 0.0, "calibration": True}),
        ("white-belt-01-cal-50kg.csv", white, {"payload_kg": 50.0, "calibration": True}),
        ("white-belt-01-40kg.csv", white, {"payload_kg": 40.0}),
        ("white-belt-01-1ms.csv", white, {"payload_kg": 20.0, "sample_time_s": 0.001}),
        ("incline-line-02-12ms.csv", incline, {"payload_kg": 25.0, "sample_time_s": 0.012}),
        ("short-fast-03-backward.csv", short, {"payload_kg": 15.0, "setpoints": back}),
        (
            "short-fast-03-bearing.csv",
            short,
            {"payload_kg": 15.0, "faults": [Fault("bearing", 0.8)]},
        ),
    ]
    OUT.mkdir(exist_ok=True)
    for k, (name, profile, kwargs) in enumerate(runs):
        when = at(7 + k // 2, 10 * (k % 2))
        run = run_virtual(profile, source=name, seed=11 + k, recorded_at=when, **kwargs)
        write_recording(run.recording, OUT / name)
        print(f"wrote {OUT / name}")

    # a vendor export: German headers, ';' and ',' decimals, time in ms
    run = run_virtual(white, payload_kg=30.0, seed=41, recorded_at=at(12, 0))
    text = format_recording(run.recording, units={"time": "ms"}, dialect=";")
    lines = text.split("\n")
    head = next(i for i, line in enumerate(lines) if line.startswith("time ["))
    lines[head] = VENDOR_HEADER
    vendor = ROOT / "vendor" / "white-belt-01-vendor-export.csv"
    vendor.parent.mkdir(exist_ok=True)
    vendor.write_text("\n".join(lines), encoding="utf-8")
    print(f"wrote {vendor}")


if __name__ == "__main__":
    main()
