"""Profile the parallel step of ingest per recording (a script, not a test).

Scenario: the reference conveyor white-belt-01, ``DAYS`` x ``PER_DAY``
recordings at 6 ms with a growing friction fault (as
``benchmarks/bench_monitor.py``), written by
:func:`chaintwin.simulate.fleet.generate` into a temporary folder, and a
calibration made from its calibration recordings (setup, not profiled).
Then :func:`chaintwin.ingest.pipeline.prepare` (read + validate + weigh +
features) runs over every recording ``ROUNDS`` times under ``cProfile``
and the functions with the largest cumulative and own time are printed,
with the plain median time per recording of each stage beside them.

Run: ``.venv/bin/python benchmarks/profile_prepare.py [N_LINES]`` (about 20 s).
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"  # small least-squares fits: no BLAS thread oversubscription

import cProfile  # noqa: E402
import pstats  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

from chaintwin.calibrating.procedure import calibrate  # noqa: E402
from chaintwin.diagnose.features import recording_features  # noqa: E402
from chaintwin.ingest.pipeline import prepare  # noqa: E402
from chaintwin.read.profile import load_profile  # noqa: E402
from chaintwin.simulate.faults import Fault  # noqa: E402
from chaintwin.simulate.fleet import generate  # noqa: E402
from chaintwin.validate.checks import load_recording  # noqa: E402
from chaintwin.weigh import weigh  # noqa: E402

PROFILE = (
    Path(__file__).resolve().parents[1]
    / "chaintwin"
    / "examples"
    / "profiles"
    / "white-belt-01.yaml"
)
DAYS = 5
PER_DAY = 12
SAMPLE_TIME_S = 0.006
SEED = 11
ROUNDS = 3


def main() -> None:
    lines = int(sys.argv[1]) if len(sys.argv) > 1 else 40
    prof = load_profile(PROFILE)
    with tempfile.TemporaryDirectory(prefix="profile_prepare_") as tmp:
        folder = Path(tmp)
        generate(
            prof,
            folder,
            days=DAYS,
            per_day=PER_DAY,
            faults=[Fault("friction", 0.3)],
            onset_day=2,
            sample_time_s=SAMPLE_TIME_S,
            seed=SEED,
        )
        cal_files = sorted((folder / "calibration").glob("*.csv"))
        cal = calibrate([load_recording(p, profile=prof).recording for p in cal_files], prof)
        files = sorted(folder.glob("*.csv"))
        inspections = [load_recording(p, profile=prof) for p in files]
        for p in files[:3]:  # warm-up: imports, numba compilation, caches
            prepare(str(p), prof, None, cal)

        # plain timings per stage (best of ROUNDS per recording)
        stages = {
            "load_recording": lambda k: load_recording(files[k], profile=prof),
            "weigh": lambda k: weigh(inspections[k], cal),
            "recording_features": lambda k: recording_features(inspections[k], cal),
            "prepare": lambda k: prepare(str(files[k]), prof, None, cal),
        }
        best: dict[str, list[float]] = {name: [float("inf")] * len(files) for name in stages}
        for _ in range(ROUNDS):
            for k in range(len(files)):
                for name, fn in stages.items():
                    t0 = time.perf_counter()
                    fn(k)
                    best[name][k] = min(best[name][k], time.perf_counter() - t0)
        for name, values in best.items():
            print(f"{name:20s} median {statistics.median(values) * 1e3:7.2f} ms per recording")

        profiler = cProfile.Profile()
        profiler.enable()
        for _ in range(ROUNDS):
            for p in files:
                prepare(str(p), prof, None, cal)
        profiler.disable()
    stats = pstats.Stats(profiler).strip_dirs()
    print(f"\ncProfile of prepare() over {ROUNDS} x {len(files)} recordings, by cumulative time")
    stats.sort_stats("cumulative").print_stats(lines)
    print("by own time")
    stats.sort_stats("tottime").print_stats(lines)
    if os.environ.get("CALLERS"):
        stats.print_callers(os.environ["CALLERS"])


if __name__ == "__main__":
    main()
