"""How often the monitoring evaluation's scopes can see a rail obstacle at all.

Run::

    python scripts/obstacle_exposure.py [--seeds 20261125 7 11 13 17] [--json out.json]

For the ``rail_obstacle`` sequences of the monitoring evaluation's two
designs (run A: 1 conveyor per fault type, 80 recordings; the 200-recording
design: 8 per fault type), drawn exactly as ``scripts/fidelity_monitoring.py``
draws them (no simulation): the belt loop, the belt speed at nominal motor
speed, the scope's constant-speed run, the belt that passes in it per scope,
the hits expected over all recordings after the onset (one per loop of
travel) and the belt revolutions a pool of :data:`POOL` scopes covers. The
obstacle rule needs at least 2 knocks in a pool.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import evaluate_fidelity as ef
import fidelity_monitoring as fm

from chaintwin.diagnose.impacts import POOL

DESIGNS = {"A": (1, 80, 1, 3), "200": (8, 200, 12, 6)}
"""Per design: conveyors per fault type, recordings, healthy and declined sequences."""


def exposure(seeds: list[int]) -> list[dict[str, Any]]:
    """One row per rail-obstacle sequence of each design and seed."""
    out = []
    for design, (per_fault, n, healthy, declined) in DESIGNS.items():
        for seed in seeds:
            rng = np.random.default_rng(seed + 17)
            lo, hi = round(0.4 * n), round(0.6 * n)
            plan = [f for f in fm.FAULT_TYPES for _ in range(per_fault)]
            plan += ["healthy"] * healthy + ["declined"] * declined
            for k, series in enumerate(plan):
                incline = fm.DECLINED_DEG if series == "declined" else ef.INCLINE_DEG
                conv = ef.draw_conveyor(rng, 100 + k, incline_deg=incline)
                onset = int(rng.integers(lo, hi + 1)) if series not in fm.HEALTHY_KINDS else 0
                if series != "rail_obstacle":
                    continue
                d = conv.design
                loop = 2.0 * d["length_m"]
                speed = 1400.0 * 2.0 * math.pi / 60.0 / d["ratio"] * d["pitch_diameter_m"] / 2.0
                window = 2048 * conv.sample_time_s
                ramp = min(0.5, window / 8)
                hold = max(0.5, window - 2 * ramp - 0.6)  # as fidelity_monitoring's set points
                per_scope = hold * speed
                out.append(
                    {
                        "design": design,
                        "seed": seed,
                        "conveyor": conv.profile.id,
                        "sample_time_ms": conv.sample_time_s * 1e3,
                        "loop_m": loop,
                        "belt_speed_m_s": speed,
                        "constant_run_s": hold,
                        "belt_per_scope_m": per_scope,
                        "hits_after_onset": (n - onset) * per_scope / loop,
                        "pool_revolutions": POOL * per_scope / loop,
                    }
                )
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[20261125, 7, 11, 13, 17])
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args(argv)
    rows = exposure(args.seeds)
    for r in rows:
        print(
            f"{r['design']:>3s} seed {r['seed']} {r['conveyor']} {r['sample_time_ms']:.0f} ms: "
            f"loop {r['loop_m']:.1f} m, {r['belt_speed_m_s']:.3f} m/s, "
            f"{r['belt_per_scope_m']:.2f} m per scope, {r['hits_after_onset']:.2f} hits after "
            f"the onset, a pool covers {r['pool_revolutions']:.2f} revolutions"
        )
    if args.json is not None:
        args.json.write_text(json.dumps({"pool": POOL, "sequences": rows}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
