"""Accuracy benchmark of identification and dynamic weighing.

On the virtual conveyor with all realism on (noise, quantisation, elastic
belt, stick-slip, polygon effect, gear mesh ripple), healthy and with the same
losses at calibration and at weighing, for each bundled profile and at 6 ms
and 12 ms sample time, under two calibration protocols:

* P1: three empty-tray recordings at nominal speed (the published method);
* P2: the same plus one recording with a 50 kg reference load.

It weighs payloads 0 to 100 kg in 10 kg steps (complete cycles) in two
modes, ``trusted`` (the calibration's losses: right here, as the plant's
losses did not drift) and ``default`` (a ±10 % loss drift allowed for, what
``weigh`` does by default), and prints the largest and mean absolute error,
the largest error in units of the reported uncertainty, and how many were
unweighable. Then: μ and BmB identified from recordings at several known
loads and speeds; what a 10 % and 30 % friction rise at unchanged payload
gives (trusting the losses it is unweighable; by default the payload leans
on the inertia signature); the time per recording of identification and
weighing.

Run: ``.venv/bin/python benchmarks/bench_weigh.py`` (about 10 s).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from chaintwin.calibrating.procedure import calibrate
from chaintwin.identify.regression import RigidModelRegression
from chaintwin.read.profile import ConveyorProfile, load_profile
from chaintwin.read.recording import Recording
from chaintwin.simulate.faults import Fault
from chaintwin.simulate.virtual import run_virtual
from chaintwin.validate import Inspection, inspect_recording
from chaintwin.weigh import LossDrift, reweigh, weigh

PROFILES = Path(__file__).resolve().parents[1] / "chaintwin" / "examples" / "profiles"
NAMES = ("white-belt-01", "incline-line-02", "short-fast-03")
PAYLOADS = tuple(range(0, 101, 10))
MODES = ("default", "trusted")


def inspected(
    profile: ConveyorProfile, payload: float, seed: int, ts: float, **kw: object
) -> Inspection:
    run = run_virtual(profile, payload_kg=payload, seed=seed, sample_time_s=ts, **kw)  # type: ignore[arg-type]
    return inspect_recording(run.recording, profile)


def record(
    profile: ConveyorProfile, payload: float, seed: int, ts: float, **kw: object
) -> Recording:
    return inspected(profile, payload, seed, ts, **kw).recording


def main() -> None:
    rows = []
    timings_weigh: list[float] = []
    timings_cal: list[float] = []
    for name in NAMES:
        prof = load_profile(PROFILES / f"{name}.yaml")
        for ts in (0.006, 0.012):
            empty = [record(prof, 0.0, 100 + k, ts, calibration=True) for k in range(3)]
            ref = record(prof, 50.0, 110, ts, calibration=True)
            tests = [inspected(prof, float(p), 1000 + p, ts) for p in PAYLOADS]
            for proto, cal_recs in (("P1", empty), ("P2", [*empty, ref])):
                t0 = time.perf_counter()
                cal = calibrate(cal_recs, prof)
                timings_cal.append((time.perf_counter() - t0) / len(cal_recs))
                results = []
                for rec in tests:
                    t0 = time.perf_counter()
                    results.append(weigh(rec, cal))
                    timings_weigh.append(time.perf_counter() - t0)
                for mode in MODES:
                    errs, zs, none = [], [], 0
                    for p, res in zip(PAYLOADS, results, strict=True):
                        if mode == "trusted":
                            res = reweigh(res, LossDrift())
                        if res.payload_kg is None or res.uncertainty_kg is None:
                            none += 1
                            continue
                        errs.append(res.payload_kg - p)
                        zs.append(abs(res.payload_kg - p) / res.uncertainty_kg)
                    e = np.abs(errs)
                    rows.append(
                        (
                            name,
                            ts,
                            proto,
                            mode,
                            float(e.max()) if e.size else np.nan,
                            float(e.mean()) if e.size else np.nan,
                            float(max(zs)) if zs else np.nan,
                            none,
                            cal.sensitivity_rel_uncertainty,
                        )
                    )

    print("Weighing 0-100 kg in 10 kg steps, all realism on, complete cycles")
    print(
        f"{'profile':16s} {'Ts':>5s} {'prot':4s} {'mode':8s} {'max|err| kg':>11s} "
        f"{'mean kg':>8s} {'max z':>6s} {'unweighable':>11s} {'S unc.':>7s}"
    )
    for name, ts, proto, mode, mx, mean, z, none, s_unc in rows:
        print(
            f"{name:16s} {ts * 1e3:4.0f}ms {proto:4s} {mode:8s} {mx:11.2f} {mean:8.2f} "
            f"{z:6.1f} {none:11d} {s_unc:7.2%}"
        )
    for proto, target in (("P1", 2.0), ("P2", 0.5)):
        worst = max(r[4] for r in rows if r[2] == proto and r[3] == "trusted")
        verdict = "meets" if worst <= target else "MISSES"
        print(f"{proto} trusted: largest error {worst:.2f} kg, target <= {target} kg: {verdict}")
    worst_z = max(r[6] for r in rows if r[3] == "default")
    print(f"default: largest error {worst_z:.1f} reported uncertainties (honest: within 3)")

    print("\nIdentification from 6 recordings at loads 0/30/60/90 kg and 50-100 % speed (6 ms)")
    print(f"{'profile':16s} {'mu err':>8s} {'BmB err':>8s} {'J_d err':>8s}")
    shares = [(0, 1.0), (30, 1.0), (60, 1.0), (90, 1.0), (0, 0.5), (60, 0.6)]
    for name in NAMES:
        prof = load_profile(PROFILES / f"{name}.yaml")
        model = prof.model
        assert model is not None
        nominal = prof.motor.nominal_speed_rpm or 1400.0
        recs = [
            record(prof, float(load), 200 + k, 0.006, calibration=True, speed_rpm=nominal * s)
            for k, (load, s) in enumerate(shares)
        ]
        p = RigidModelRegression().fit(recs, prof).parameters_
        jd = prof.motor.inertia_kgm2 + prof.gear.inertia_kgm2
        print(
            f"{name:16s} {p['mu'] / model.friction - 1:8.2%} "
            f"{p['BmB'] / model.loss_viscous_nm_s_rad - 1:8.2%} {p['J_d'] / jd - 1:8.2%}"
        )
    print("targets: mu within 3 %, BmB within 10 %")

    print("\nFriction rise at unchanged payload (P2 calibration, 6 ms)")
    print(
        f"{'profile':16s} {'rise':>5s} {'payload':>7s} {'friction':>9s} {'inertia':>8s} "
        f"{'reported':>9s} outcome"
    )
    for name in NAMES:
        prof = load_profile(PROFILES / f"{name}.yaml")
        cal = calibrate(
            [
                record(prof, float(x), 300 + k, 0.006, calibration=True)
                for k, x in enumerate((0, 0, 0, 50))
            ],
            prof,
        )
        for rise in (0.1, 0.3):
            for payload in (20.0, 60.0):
                rec = inspected(prof, payload, 400, 0.006, faults=[Fault("friction", rise)])
                res = weigh(rec, cal)
                sig = res.signatures
                assert sig is not None
                inertia = sig.inertia_kg if sig.inertia_kg is not None else np.nan
                trusted = reweigh(res, LossDrift())
                for mode, r in (("default", res), ("trusted", trusted)):
                    got = "-" if r.payload_kg is None else f"{r.payload_kg:.2f}"
                    outcome = ("unweighable" if r.payload_kg is None else "weighed") + f" ({mode})"
                    print(
                        f"{name:16s} {rise:5.0%} {payload:7.0f} {sig.friction_kg:9.2f} "
                        f"{inertia:8.2f} {got:>9s} {outcome}"
                    )

    print("\nTime per recording (median)")
    print(f"identify/calibrate: {np.median(timings_cal) * 1e3:.1f} ms")
    print(f"weigh:              {np.median(timings_weigh) * 1e3:.1f} ms")


if __name__ == "__main__":
    main()
