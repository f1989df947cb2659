"""Fidelity evaluation of dynamic weighing and monitoring (see
``scripts/fidelity_monitoring.py``) over randomly drawn conveyors.

Run::

    OPENBLAS_NUM_THREADS=1 python scripts/evaluate_fidelity.py weighing \
        [--conveyors 30] [--seed 20261125] [--seeds 1] \
        [--json docs/evaluation/fidelity-weighing.json] [--markdown table.md] [--sequences]

(about 20 s for 30 conveyors on one idle core; ``--seeds N`` draws the
conveyors N times, seeds SEED to SEED+N-1, and pools them; the per-conveyor
lines are then left out).

Conveyors are drawn from the design distribution below (:func:`draw_conveyor`)
with seeds no test uses. Every realism effect of the virtual conveyor is on
(noise, quantisation, elastic belt, stick-slip, polygon effect, gear mesh
ripple, scope sampling without anti-alias filter), the torque set point's
noise included (the speed controller's answer to its encoder's counts and
noise, :data:`REALISM`), so each calibration chooses its torque channel
(``torque_channel`` of every row; the table counts the choices). Each conveyor is
calibrated under three protocols and weighs the same test recordings:

``one_load_one_speed``
    three empty runs at nominal speed in the conveying direction (the
    published method);
``one_load_several_speeds``
    empty runs at 30, 60 and 100 % speed in both directions;
``several_loads``
    the same plus one run with a reference load (half the largest payload).

Test recordings: payloads drawn over 0 to the conveyor's largest, in the
conveying direction, at the conveyor's scope sample time; once with the gear
losses of the calibration ("no drift") and once with them scaled by a
factor drawn in 0.9-1.1 per recording ("drift ±10 %").

Each test recording is weighed in two modes: ``unknown`` (a drift of ±10 %
allowed for, the default of ``weigh`` and the commands) and ``trusted``
(the calibration's losses: ``loss_drift=LossDrift()``, ``weigh
--loss-drift 0``).

It prints, per protocol, drift condition and mode: the largest, 99th-percentile
and median absolute error (kg); the share of errors within 1, 2 and 3
reported standard uncertainties and beyond 5; the median reported
uncertainty over the median absolute error (an honest Gaussian gives 1.48);
the share of recordings with no payload (unweighable); the error of the
identified friction coefficient; how far the payload moves when the
profile's belt mass is 3 % high; and per conveyor the largest error and its
payload sensitivity. The whole table is written as JSON.

Design distribution (uniform unless said): length 1.5-25 m, belt 1.5-10
kg/m, incline -15 to +12 degrees, 8-16 teeth, pitch diameter 0.05-0.25 m,
gear ratio 15-120 (log-uniform), efficiency 0.85-0.96, friction coefficient
0.12-0.40, tray 0-15 kg, largest payload 20-100 kg, conveying in the motor's
positive or negative direction (half each), scope sample time 1, 6 or 12
ms, motor 1400 rpm sized for the duty (nominal torque 1.4x the steady torque
at the largest payload plus the ramp torque, inertia scaling with torque).

The plant is richer than the model the estimators fit: the gear's
efficiency when the belt drives the motor is 75-100 % of the forward one,
the rail friction falls from static to kinetic over a Stribeck speed of
2-20 mm/s (log-uniform), and sprockets and shafts add 0-30 % of the motor's inertia that
the profile does not list. Test recordings go through a file as the drive
exports them, in rpm and % (even conveyors) or in SI units (odd ones), and
are read back.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from chaintwin.calibrating.procedure import calibrate
from chaintwin.diagnose.state import json_ready
from chaintwin.errors import ChaintwinError
from chaintwin.identify.calibration import Calibration
from chaintwin.physics import loss_torque_nm, payload_sensitivity_nm_kg
from chaintwin.read.profile import ConveyorProfile, parse_profile
from chaintwin.read.recording import Recording
from chaintwin.read.writer import write_recording
from chaintwin.simulate.virtual import Realism, default_setpoints, run_virtual
from chaintwin.units import RPM_TO_RAD_S, G
from chaintwin.validate import Inspection, load_recording
from chaintwin.weigh import reweigh, weigh
from chaintwin.weigh.drift import LossDrift

EVALUATION = Path(__file__).resolve().parent.parent / "docs" / "evaluation"
"""Where the evaluations write their JSON by default (the evaluation reports read it)."""

PROTOCOLS = ("one_load_one_speed", "one_load_several_speeds", "several_loads")
MODES = ("trusted", "unknown")
CONDITIONS = tuple((d, m) for d in ("none", "drift10", "both") for m in MODES)
"""Rows of the table: test condition (``both``: the two pooled) and weighing mode."""
TESTS_PER_DRIFT = 6
DRIFT_AMPLITUDE = 0.10
"""The drift condition's largest loss change, 1."""
LOW_SENSITIVITY_NM_KG = 1e-3
"""Below this payload sensitivity the friction signature carries no information, Nm/kg."""
TARGETS = {
    "several_loads": (0.5, 1.5),
    "one_load_several_speeds": (1.0, 1.5),
}
"""Largest error per conveyor, kg: (without drift, with drift)."""
SAMPLE_TIMES_S = (0.001, 0.006, 0.012)
SI_UNITS = {
    "speed": "rad/s",
    "speed_setpoint": "rad/s",
    "position": "rad",
    "position_setpoint": "rad",
    "torque": "Nm",
    "torque_setpoint": "Nm",
}
"""Units of an export in SI (the others keep the drive's rpm and %)."""


@dataclass
class Conveyor:
    """A drawn conveyor: its profile (truth in ``model:``) and test conditions."""

    profile: ConveyorProfile
    direction: int
    """Conveying direction in motor terms: +1 or -1."""
    sample_time_s: float
    max_payload_kg: float
    design: dict[str, float] = field(default_factory=dict)


REALISM = Realism(setpoint_noise=True)
"""Every realism effect of the virtual conveyor, the set point's noise included."""

INCLINE_DEG = (-15.0, 12.0)
"""The design distribution's incline in the conveying direction, degrees."""

RICHER = ("back_efficiency", "stribeck_speed_m_s", "unlisted_inertia_kgm2")
"""Plant effects beyond the identification model (``--without`` switches one off)."""


def draw_conveyor(
    rng: np.random.Generator,
    k: int,
    without: tuple[str, ...] = (),
    incline_deg: tuple[float, float] = INCLINE_DEG,
) -> Conveyor:
    """One conveyor from the design distribution (see the module docstring).

    ``without`` names effects of :data:`RICHER` (or ``export``: no SI
    exports) left out; the draws are the same either way. ``incline_deg``
    is the range of the incline in the conveying direction, degrees
    (negative: conveying downhill); another range draws the same number
    of values, so the other draws stay as they are.
    """
    length = rng.uniform(1.5, 25.0)
    mass_per_m = rng.uniform(1.5, 10.0)
    incline = rng.uniform(*incline_deg)
    teeth = int(rng.integers(8, 17))
    pitch_d = rng.uniform(0.05, 0.25)
    ratio = float(np.exp(rng.uniform(math.log(15.0), math.log(120.0))))
    eta = rng.uniform(0.85, 0.96)
    mu = rng.uniform(0.12, 0.40)
    tray = rng.uniform(0.0, 15.0)
    max_payload = rng.uniform(20.0, 100.0)
    direction = int(rng.choice([1, -1]))
    ts = float(rng.choice(SAMPLE_TIMES_S))
    rpm = 1400.0
    r = pitch_d / 2.0
    w = rpm * 2.0 * math.pi / 60.0
    moving = length * 2.0 * mass_per_m + tray + max_payload  # belt loop, tray, payload
    beta = math.radians(incline)
    force = G * moving * (mu * math.cos(beta) + abs(math.sin(beta)))
    steady = force * r / (ratio * eta)
    accel = moving * (r / ratio) ** 2 * w / 0.5 / eta  # a 0.5 s ramp
    nominal = max(0.3, 1.4 * (steady + accel))
    j_motor = 0.0022 * (nominal / 2.5) ** 1.1
    j_total = 1.05 * j_motor + moving * (r / ratio) ** 2
    scale = nominal / 2.5
    doc: dict[str, Any] = {
        # incline in motor terms: a conveyor conveying uphill in the motor's
        # negative direction has the incline's sign turned for positive motion
        "id": f"fidelity-{k:02d}",
        "belt": {
            "length_m": length,
            "mass_per_m_kg": mass_per_m,
            "incline_deg": incline * direction,
        },
        "sprocket": {"pitch_diameter_m": pitch_d, "teeth": teeth},
        "gear": {"ratio": ratio, "efficiency": eta, "inertia_kgm2": 0.05 * j_motor},
        "motor": {
            "inertia_kgm2": j_motor,
            "nominal_torque_nm": nominal,
            "nominal_speed_rpm": rpm,
            "torque_time_constant_s": 0.001,
        },
        "controller": {
            "cycle_s": 0.001,
            "position_gain_1_s": 20.0,
            "speed_gain_nm_s_rad": 0.2 * j_total / 0.0025,
            "speed_integral_time_s": 0.05,
            "torque_limit_nm": 3.0 * nominal,
        },
        "tray_mass_kg": tray,
        "model": {
            "friction": mu,
            "static_friction_ratio": rng.uniform(1.05, 1.4),
            "loss_constant_nm": 1.1e-4 * scale,
            "loss_viscous_nm_s_rad": 2.1e-3 * scale,
            "loss_quadratic_nm_s2_rad2": 2.0e-6 * scale,
            "belt_stiffness_n_m": 1.0e6 * 4.3 / length,
            "belt_damping_n_s_m": 200.0,
            # richer than the identification model: power flowing back through
            # the gear loses more, friction falls from static to kinetic over a
            # few cm/s, and sprockets and shafts add inertia the profile omits
            "back_efficiency": eta * rng.uniform(0.75, 1.0),
            "stribeck_speed_m_s": float(np.exp(rng.uniform(math.log(0.002), math.log(0.02)))),
            "unlisted_inertia_kgm2": rng.uniform(0.0, 0.3) * j_motor,
        },
    }
    for name in without:
        doc["model"].pop(name, None)
    profile = parse_profile(doc, f"drawn conveyor {k}")
    design = {
        "length_m": length,
        "mass_per_m_kg": mass_per_m,
        "incline_deg": incline,
        "teeth": teeth,
        "pitch_diameter_m": pitch_d,
        "ratio": ratio,
        "efficiency": eta,
        "mu": mu,
        "direction": direction,
        "sample_time_ms": ts * 1e3,
        "nominal_torque_nm": nominal,
        "max_payload_kg": max_payload,
        "export": "si" if k % 2 and "export" not in without else "rpm",
    }
    return Conveyor(profile, direction, ts, max_payload, design)


def _run(
    conv: Conveyor,
    payload: float,
    seed: int,
    *,
    direction: int,
    speed_share: float = 1.0,
    calibration: bool = False,
    loss_scale: float = 1.0,
) -> Recording:
    """One simulated recording that fits the scope window (2048 samples)."""
    window = 2048 * conv.sample_time_s
    ramp = min(0.5, window / 8)
    hold = max(0.5, window - 2 * ramp - 0.6)
    sp = default_setpoints(
        conv.profile,
        duration_s=window,
        speed_rpm=speed_share * 1400.0,
        ramp_s=ramp,
        hold_s=hold,
        direction=direction,
    )
    run = run_virtual(
        conv.profile,
        payload_kg=payload,
        sample_time_s=conv.sample_time_s,
        seed=seed,
        setpoints=sp,
        realism=REALISM,
        calibration=calibration,
        loss_scale=loss_scale,
        source=f"{conv.profile.id}-{seed}",
    )
    return run.recording


def calibration_runs(conv: Conveyor, seed: int) -> dict[str, list[Recording]]:
    """The calibration recordings of each protocol."""
    d = conv.direction
    one = [_run(conv, 0.0, seed + k, direction=d, calibration=True) for k in range(3)]
    speeds = [
        _run(
            conv, 0.0, seed + 10 + 2 * k + (s < 0), direction=s, speed_share=share, calibration=True
        )
        for k, share in enumerate((0.3, 0.6, 1.0))
        for s in (1, -1)
    ]
    ref = _run(conv, conv.max_payload_kg / 2, seed + 20, direction=d, calibration=True)
    return {
        "one_load_one_speed": one,
        "one_load_several_speeds": speeds,
        "several_loads": [*speeds, ref],
    }


def _tests(conv: Conveyor, seed: int) -> list[tuple[str, float, float, Inspection]]:
    """The test recordings: ``(condition, payload, loss scale, inspection)``, in order.

    ``none``: the calibration's losses; ``drift10``: each recording's losses
    scaled by 0.9-1.1 at random.
    """
    rng = np.random.default_rng(seed)
    tests: list[tuple[str, float, float, Inspection]] = []
    plan = [("none", 1.0)] * TESTS_PER_DRIFT
    plan += [("drift10", float(rng.uniform(0.9, 1.1))) for _ in range(TESTS_PER_DRIFT)]
    units = SI_UNITS if conv.design["export"] == "si" else None
    with tempfile.TemporaryDirectory() as folder:
        for j, (condition, scale) in enumerate(plan):
            payload = float(rng.uniform(0.0, conv.max_payload_kg))
            rec = _run(conv, payload, seed + 100 + j, direction=conv.direction, loss_scale=scale)
            # through a file as the drive exports it (rpm and % or SI), read back
            path = write_recording(rec, Path(folder) / f"test-{j}.csv", units=units)
            tests.append((condition, payload, scale, load_recording(path, profile=conv.profile)))
    return tests


def _belt_mass_error(profile: ConveyorProfile, recs: list[Recording]) -> Calibration | None:
    """The calibration made with the profile's belt mass 3 % high (None: it fails)."""
    belt = profile.belt.model_copy(update={"mass_per_m_kg": 1.03 * profile.belt.mass_per_m_kg})
    try:
        return calibrate(recs, profile.model_copy(update={"belt": belt}))
    except ChaintwinError:
        return None


def evaluate_conveyor(conv: Conveyor, seed: int) -> list[dict[str, Any]]:
    """Every weighing of one conveyor: a row per protocol, condition, mode and test.

    Modes: ``unknown`` (a drift of ±10 % allowed for, :meth:`LossDrift.unknown`,
    the default) and ``trusted`` (the calibration's losses).
    """
    tests = _tests(conv, seed)
    rows: list[dict[str, Any]] = []
    truth_mu = conv.profile.model.friction if conv.profile.model else float("nan")
    for protocol, recs in calibration_runs(conv, seed).items():
        try:
            cal = calibrate(recs, conv.profile)
        except ChaintwinError as exc:
            # refused: every test recording of this protocol goes unweighed
            for condition, payload, scale, _ins in tests:
                for mode_ in MODES:
                    rows.append(
                        {"conveyor": conv.profile.id, "protocol": protocol, "drift": condition}
                        | {"loss_scale": scale, "payload_true_kg": payload, "mode": mode_}
                        | {"payload_kg": None, "error": str(exc), "reason": str(exc)}
                        | {"torque_channel": None}
                    )
            continue
        mu_err = float(cal.parameters["mu"]) / truth_mu - 1.0
        heavy = _belt_mass_error(conv.profile, recs)
        for condition, payload, scale, ins in tests:
            base: dict[str, Any] = {
                "conveyor": conv.profile.id,
                "protocol": protocol,
                "case": cal.case,
                "drift": condition,
                "loss_scale": scale,
                "payload_true_kg": payload,
                "mu_rel_error": mu_err,
                "torque_channel": cal.torque_channel,
                "friction_unchecked": any(w.code == "friction_unchecked" for w in cal.warnings),
            }
            unknown = weigh(ins, cal)  # the default: ±10 % loss drift allowed for
            results = {"trusted": reweigh(unknown, LossDrift()), "unknown": unknown}
            if heavy is not None and condition == "none":
                # the profile's belt mass 3 % high, in calibration and weighing alike
                a, b = weigh(ins, heavy).payload_kg, unknown.payload_kg
                base["belt_mass_3pct_shift_kg"] = math.nan if a is None or b is None else a - b
            for mode, res in results.items():
                rows.append(
                    base
                    | {
                        "mode": mode,
                        "payload_kg": res.payload_kg,
                        "uncertainty_kg": res.uncertainty_kg,
                        "consistent": res.consistent,
                        "warnings": [w.code for w in res.warnings],
                        "reason": res.unweighable,
                        "friction_checked_rel": res.friction_checked_rel,
                    }
                )
    return rows


def summarise(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per protocol and drift condition: accuracy, honesty, unweighable share, mu error."""
    out = []
    for protocol, (drift, mode) in ((p, c) for p in PROTOCOLS for c in CONDITIONS):
        mine = [
            r
            for r in rows
            if r["protocol"] == protocol
            and (drift == "both" or r.get("drift") == drift)
            and r.get("mode") == mode
        ]
        if mine:
            weighed = [r for r in mine if r.get("payload_kg") is not None]
            err = np.array([r["payload_kg"] - r["payload_true_kg"] for r in weighed])
            u = np.array([r["uncertainty_kg"] for r in weighed])
            ae = np.abs(err)
            z = ae / u if u.size else np.array([])
            mu_errs = {r["conveyor"]: abs(r["mu_rel_error"]) for r in mine if "mu_rel_error" in r}
            out.append(
                {
                    "protocol": protocol,
                    "drift": drift,
                    "mode": mode,
                    "n": len(mine),
                    "unweighable_share": 1.0 - len(weighed) / len(mine) if mine else math.nan,
                    "max_kg": float(ae.max()) if ae.size else math.nan,
                    "p99_kg": float(np.percentile(ae, 99)) if ae.size else math.nan,
                    "median_kg": float(np.median(ae)) if ae.size else math.nan,
                    "within_1u": float(np.mean(z <= 1)) if z.size else math.nan,
                    "within_2u": float(np.mean(z <= 2)) if z.size else math.nan,
                    "within_3u": float(np.mean(z <= 3)) if z.size else math.nan,
                    "beyond_5u": float(np.mean(z > 5)) if z.size else math.nan,
                    "u_over_error": float(np.median(u) / np.median(ae)) if ae.size else math.nan,
                    "mu_median_rel_error": float(np.median(list(mu_errs.values())))
                    if mu_errs
                    else math.nan,
                    "calibration_failures": sum(1 for r in mine if "error" in r),
                    "channels": _channel_counts(mine),
                    "belt_mass_3pct_median_kg": _median_abs(
                        [r.get("belt_mass_3pct_shift_kg") for r in mine]
                    ),
                }
            )
    return out


def _channel_counts(rows: list[dict[str, Any]]) -> dict[str, int]:
    """How many calibrations (seed and conveyor) chose each torque channel."""
    chosen = {(r.get("seed"), r["conveyor"]): r.get("torque_channel") for r in rows}
    out: dict[str, int] = {}
    for channel in chosen.values():
        key = str(channel) if channel is not None else "failed"
        out[key] = out.get(key, 0) + 1
    return out


def _median_abs(values: list[float | None]) -> float:
    """Median of the magnitudes of the known values (NaN when none)."""
    known = [abs(v) for v in values if v is not None and math.isfinite(v)]
    return float(np.median(known)) if known else math.nan


def per_conveyor(rows: list[dict[str, Any]], convs: list[Conveyor]) -> list[dict[str, Any]]:
    """Per conveyor and protocol: the largest error with and without drift, and its sensitivity."""
    out = []
    for conv in convs:
        p = conv.profile
        sens = payload_sensitivity_nm_kg(
            mu=p.model.friction if p.model else 0.23,
            incline_rad=math.radians(conv.design["incline_deg"]),
            radius_m=p.sprocket.pitch_diameter_m / 2,
            ratio=p.gear.ratio,
            efficiency=p.gear.efficiency,
        )
        model = p.model
        w = 1400.0 * RPM_TO_RAD_S
        loss = (
            loss_torque_nm(
                w,
                model.loss_constant_nm,
                model.loss_viscous_nm_s_rad,
                model.loss_quadratic_nm_s2_rad2,
            )
            if model is not None
            else math.nan
        )
        drift_kg = DRIFT_AMPLITUDE * abs(loss) / max(abs(float(sens)), 1e-9)
        limit = None
        if abs(float(sens)) < LOW_SENSITIVITY_NM_KG:
            limit = "sensitivity"
        elif drift_kg > TARGETS["several_loads"][1]:
            limit = "drift"
        entry: dict[str, Any] = {
            "conveyor": p.id,
            **conv.design,
            "sensitivity_mnm_per_kg": 1e3 * float(sens),
            "drift_equivalent_kg": drift_kg,
            "limit": limit,
        }
        for protocol in PROTOCOLS:
            for drift, mode in CONDITIONS:
                mine = [
                    r
                    for r in rows
                    if r["conveyor"] == p.id
                    and r["protocol"] == protocol
                    and r.get("drift") == drift
                    and r.get("mode") == mode
                    and r.get("payload_kg") is not None
                ]
                errs = [abs(r["payload_kg"] - r["payload_true_kg"]) for r in mine]
                entry[f"{protocol}/{drift}/{mode}/max_kg"] = max(errs) if errs else None
        checked = [
            math.inf if r.get("friction_checked_rel") is None else r["friction_checked_rel"]
            for r in rows
            if r["conveyor"] == p.id
            and r["protocol"] == "one_load_several_speeds"
            and r.get("mode") == "unknown"
            and "friction_unchecked" in r
        ]
        entry["friction_checked_rel"] = float(np.median(checked)) if checked else None
        for protocol in PROTOCOLS:
            entry[f"{protocol}/friction_unchecked"] = any(
                r.get("friction_unchecked")
                for r in rows
                if r["conveyor"] == p.id and r["protocol"] == protocol
            )
        entry["friction_unchecked"] = entry["one_load_several_speeds/friction_unchecked"]
        out.append(entry)
    return out


def judge_targets(convs: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per protocol, mode and drift condition: how many conveyors meet their accuracy target.

    Conveyors in a physical limit class (``limit``: near-zero sensitivity, or
    a drift equivalent beyond the with-drift target) are counted apart.
    """
    out = []
    for protocol, (without, with_drift) in TARGETS.items():
        for mode in MODES:
            for drift, target in (("none", without), ("drift10", with_drift)):
                key = f"{protocol}/{drift}/{mode}/max_kg"
                judged = [c for c in convs if c["limit"] is None and c.get(key) is not None]
                if drift == "none":
                    # without drift the drift class is judged too: only the sensitivity limits
                    judged = [
                        c for c in convs if c["limit"] != "sensitivity" and c.get(key) is not None
                    ]
                met = [c for c in judged if c[key] <= target]
                out.append(
                    {
                        "protocol": protocol,
                        "mode": mode,
                        "drift": drift,
                        "target_kg": target,
                        "judged": len(judged),
                        "met": len(met),
                        "worst_kg": max((c[key] for c in judged), default=None),
                    }
                )
    return out


def _print(summary: list[dict[str, Any]], convs: list[dict[str, Any]], seconds: float) -> None:
    head = (
        f"{'protocol':24} {'drift':11} {'mode':8} {'n':>4} {'unweigh':>7} {'max':>7} {'p99':>7} "
        f"{'median':>7} {'<=1u':>5} {'<=2u':>5} {'<=3u':>5} {'>5u':>5} {'u/|e|':>6} {'mu err':>7} "
        f"{'belt+3%':>7}"
    )
    print(head)
    print("-" * len(head))
    for s in summary:
        print(
            f"{s['protocol']:24} {s['drift']:11} {s['mode']:8} {s['n']:4d} "
            f"{s['unweighable_share']:7.1%} "
            f"{s['max_kg']:7.2f} {s['p99_kg']:7.2f} {s['median_kg']:7.2f} "
            f"{s['within_1u']:5.0%} {s['within_2u']:5.0%} {s['within_3u']:5.0%} "
            f"{s['beyond_5u']:5.0%} {s['u_over_error']:6.2f} {s['mu_median_rel_error']:7.1%} "
            f"{_fmt(s['belt_mass_3pct_median_kg']):>7}"
        )
    print()
    print(
        "errors in kg; u: the reported standard uncertainty; mu err: median |relative error|; "
        "belt+3%: median payload shift (kg) when the profile's belt mass is 3 % high"
    )
    print(
        "modes: unknown = ±10 % drift allowed for (the default), trusted = the calibration's "
        "losses (weigh --loss-drift 0); drift both = the two conditions pooled"
    )
    print(
        "largest error per conveyor (kg), several_loads: no drift trusted, unknown / drift "
        "unknown; drift eq.: what a 10 % loss drift reads as, kg"
    )
    for c in convs:
        print(
            f"  {c['conveyor']}: {c['length_m']:5.1f} m, incline {c['incline_deg']:+5.1f} deg, "
            f"mu {c['mu']:.2f}, dir {c['direction']:+d}, {c['sample_time_ms']:.0f} ms, "
            f"sensitivity {c['sensitivity_mnm_per_kg']:6.2f} mNm/kg, drift eq. "
            f"{c['drift_equivalent_kg']:6.1f} kg: "
            f"{_fmt(c['several_loads/none/trusted/max_kg'])}, "
            f"{_fmt(c['several_loads/none/unknown/max_kg'])} / "
            f"{_fmt(c['several_loads/drift10/unknown/max_kg'])}"
            + (f"  [limit: {c['limit']}]" if c["limit"] else "")
            + (
                f"  [friction checked to {_fmt(c['friction_checked_rel'])}"
                + (", friction_unchecked]" if c["friction_unchecked"] else "]")
            )
        )
    counts = ", ".join(
        f"{protocol} {sum(bool(c[f'{protocol}/friction_unchecked']) for c in convs)}"
        for protocol in PROTOCOLS
    )
    print(
        "calibrations warning friction_unchecked (the ramps cannot catch a 50 % rail friction "
        f"change; the weights rest on the calibration's friction), of {len(convs)}: {counts} "
        "(the per-conveyor lines: one_load_several_speeds)"
    )
    print("targets (largest error per conveyor; conveyors in a limit class judged apart):")
    for t in judge_targets(convs):
        print(
            f"  {t['protocol']:24} {t['mode']:8} {t['drift']:8} <= {t['target_kg']:.1f} kg: "
            f"{t['met']} of {t['judged']} (worst {_fmt(t['worst_kg'])} kg)"
        )
    print(f"\ntotal run time {seconds:.0f} s")


def markdown(summary: list[dict[str, Any]], title: str) -> str:
    """The summary as a markdown table (per protocol, drift condition and mode)."""
    lines = [
        f"{title}",
        "",
        "| protocol | drift | mode | n | unweighable | median kg | max kg | <=1u | <=2u | >5u "
        "| u/\\|e\\| | channels |",
        "|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---|",
    ]
    for r in summary:
        if r["drift"] == "both":
            continue  # per condition, not pooled
        channels = ", ".join(f"{k} {v}" for k, v in sorted(r.get("channels", {}).items()))
        lines.append(
            f"| {r['protocol']} | {r['drift']} | {r['mode']} | {r['n']} | "
            f"{r['unweighable_share']:.1%} | {_fmt(r['median_kg'])} | {_fmt(r['max_kg'])} | "
            f"{r['within_1u']:.0%} | {r['within_2u']:.0%} | {r['beyond_5u']:.1%} | "
            f"{_fmt(r['u_over_error'])} | {channels} |"
        )
    return "\n".join(lines) + "\n"


def _header(args: argparse.Namespace) -> None:
    print(
        f"weighing over {args.conveyors} random conveyors (seed {args.seed}), every realism "
        "effect on"
    )


def _fmt(x: float | None) -> str:
    return "-" if x is None or not math.isfinite(x) else f"{x:.2f}"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("what", choices=["weighing", "monitoring"])
    parser.add_argument("--conveyors", type=int, default=30)
    parser.add_argument("--seed", type=int, default=20261125)
    parser.add_argument(
        "--seeds",
        type=int,
        default=1,
        help="weighing: draw the conveyors this many times (seeds SEED, SEED+1, ...), pooled",
    )
    parser.add_argument(
        "--markdown", type=Path, default=None, help="also write the summary (table) as markdown"
    )
    parser.add_argument(
        "--without",
        action="append",
        default=[],
        choices=[*RICHER, "export"],
        help="leave one effect of the richer plant out (repeatable), to see what it costs",
    )
    parser.add_argument(
        "--json", type=Path, default=None, help="docs/evaluation/fidelity-WHAT.json by default"
    )
    parser.add_argument("--per-fault", type=int, default=8, help="monitoring: conveyors per fault")
    parser.add_argument("--healthy", type=int, default=12, help="monitoring: healthy sequences")
    parser.add_argument(
        "--declined",
        type=int,
        default=6,
        help="monitoring: healthy sequences on conveyors conveying downhill (-15 to -5 degrees)",
    )
    parser.add_argument(
        "--seed-list",
        type=int,
        nargs="+",
        default=None,
        help="monitoring, weighing --sequences: run each of these seeds (default: --seed) "
        "and pool the tables",
    )
    parser.add_argument("--recordings", type=int, default=200, help="monitoring: per sequence")
    parser.add_argument("--workers", type=int, default=2, help="monitoring: processes")
    parser.add_argument(
        "--only", nargs="*", default=None, help="monitoring: fault types (or healthy) to run"
    )
    parser.add_argument(
        "--life-cache",
        type=Path,
        default=None,
        help="monitoring: write each alarmed sequence's remaining-life forecast inputs "
        "(per lambda) to this JSON, for scripts/life_replay.py",
    )
    parser.add_argument(
        "--sequences",
        action="store_true",
        help="weighing: zero-tracking sequences (scripts/weighing_sequences.py) instead",
    )
    parser.add_argument(
        "--cache",
        type=Path,
        default=None,
        help="weighing --sequences: keep the weighings in this folder and reuse them "
        "(for runs that change only the zero tracking)",
    )
    args = parser.parse_args(argv)
    args.json = args.json or EVALUATION / f"fidelity-{args.what}.json"
    args.json.parent.mkdir(parents=True, exist_ok=True)
    if args.sequences:
        sys.path.insert(0, str(Path(__file__).resolve().parent))
        from weighing_sequences import run_sequences

        found = run_sequences(args, draw_conveyor, calibration_runs, _run)
        args.json.write_text(json.dumps(json_ready(found), indent=1, allow_nan=False))
        if args.markdown is not None:
            args.markdown.write_text(found["markdown"])
        return 0
    if args.what == "monitoring":
        sys.path.insert(0, str(Path(__file__).resolve().parent))
        from fidelity_monitoring import run_seeds

        result = run_seeds(args, draw_conveyor, calibration_runs)
        args.json.write_text(json.dumps(json_ready(result), indent=1, allow_nan=False))
        if args.markdown is not None:
            args.markdown.write_text(result["markdown"])
        return 0
    started = time.perf_counter()
    _header(args)
    without = tuple(args.without)
    rows: list[dict[str, Any]] = []
    convs: list[Conveyor] = []
    for s in range(args.seeds):
        seed = args.seed + s
        rng = np.random.default_rng(seed)
        drawn = [draw_conveyor(rng, k, without) for k in range(args.conveyors)]
        for k, conv in enumerate(drawn):
            try:
                found = evaluate_conveyor(conv, seed + 1000 * (k + 1))
            except ChaintwinError as exc:  # a conveyor the simulator cannot run is listed
                print(f"{conv.profile.id}: not evaluated ({exc})", file=sys.stderr)
                continue
            rows += [r | {"seed": seed} for r in found]
            print(f"seed {seed} {conv.profile.id} done", file=sys.stderr, flush=True)
        convs += drawn if args.seeds == 1 else []
    summary = summarise(rows)
    table = per_conveyor(rows, convs)
    if args.markdown is not None:
        title = (
            f"Weighing over {args.conveyors} drawn conveyors x {args.seeds} seed(s) "
            f"(from {args.seed}), every realism effect on, the set point's noise included"
        )
        args.markdown.write_text(markdown(summary, title))
    seconds = time.perf_counter() - started
    _print(summary, table, seconds)
    args.json.write_text(
        json.dumps(
            json_ready(
                {
                    "summary": summary,
                    "targets": judge_targets(table),
                    "conveyors": table,
                    "rows": rows,
                }
            ),
            indent=1,
            allow_nan=False,
        )
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
