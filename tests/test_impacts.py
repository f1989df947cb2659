"""Impacts on the torque residual: a hand calculation and the classification by regularity."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from chaintwin.diagnose.impacts import (
    MIN_SHARE,
    background_hits_per_m,
    detect_impacts,
    hits_per_revolution,
    impact_features,
    less_periodic,
    periodic,
    pooled_hits,
    residual_step,
    scan_impacts,
)
from chaintwin.read.profile import ConveyorProfile
from chaintwin.simulate.virtual import Realism, default_setpoints, run_virtual
from chaintwin.validate import inspect_recording


def _steady(reference_profile: ConveyorProfile) -> tuple[object, np.ndarray]:
    run = run_virtual(reference_profile, payload_kg=20.0, seed=3, realism=Realism.off())
    ins = inspect_recording(run.recording, reference_profile)
    return ins, run.recording.torque.copy()


def test_an_added_knock_is_found_with_its_time_duration_sign_and_energy(
    reference_profile: ConveyorProfile,
) -> None:
    ins, model = _steady(reference_profile)
    rec = ins.recording  # type: ignore[attr-defined]
    noise = np.random.default_rng(1).normal(0.0, 0.01, rec.samples)
    torque = model + noise
    k = int(np.searchsorted(rec.time, 5.0))
    n = 4  # samples: 24 ms at 6 ms, the shortest hit (MIN_IMPACT_S) and then some
    assert rec.sample_time_s == pytest.approx(0.006)
    torque[k : k + n] += 0.4  # 0.4 Nm more for four samples: something resisted
    knocked = dataclasses.replace(rec, channels={**rec.channels, "torque": torque})
    phases = list(ins.phases)  # type: ignore[attr-defined]
    (hit,) = detect_impacts(knocked, model, phases)
    assert hit.t_s == pytest.approx(rec.time[k])
    assert hit.duration_s == pytest.approx(n * rec.sample_time_s)
    assert hit.sign == 1
    # by hand: 0.4 Nm times the speed over four samples (the noise aside)
    expected = 0.4 * float(np.sum(rec.speed[k : k + n])) * rec.sample_time_s
    assert hit.energy_j == pytest.approx(expected, rel=0.1)
    # nothing in the same recording without the knock, nor with a one-sample glitch,
    # nor with two samples at 1.5 times the floor (less work than the floor in 20 ms)
    plain = dataclasses.replace(rec, channels={**rec.channels, "torque": model + noise})
    assert detect_impacts(plain, model, phases) == []
    floor = MIN_SHARE * rec.metadata.nominal_torque_nm
    for width, height in ((1, 0.4), (2, 1.5 * floor)):
        spiked = model + noise
        spiked[k : k + width] += height
        spike = dataclasses.replace(rec, channels={**rec.channels, "torque": spiked})
        assert detect_impacts(spike, model, phases) == [], (width, height)
    spiked[k : k + 2] += 1.5 * floor  # twice as high: the work of a hit
    (short,) = detect_impacts(
        dataclasses.replace(spike, channels={**rec.channels, "torque": spiked}), model, phases
    )
    assert short.duration_s == pytest.approx(2 * rec.sample_time_s)
    feats = impact_features([hit], knocked, phases, reference_profile.pitch_radius_m / 30.99)
    assert feats["impact_count"] == 1 and feats["impact_isolated"] == 1
    assert feats["belt_travel_m"] > 0 and feats["impact_energy_max"] == pytest.approx(
        abs(hit.energy_j)
    )


def test_regular_knocks_are_periodic_and_isolated_ones_pool_per_revolution(
    reference_profile: ConveyorProfile,
) -> None:
    ins, model = _steady(reference_profile)
    rec = ins.recording  # type: ignore[attr-defined]
    torque = model + np.random.default_rng(2).normal(0.0, 0.01, rec.samples)
    for t in (3.0, 4.0, 5.0, 6.0):  # a tooth once a second
        k = int(np.searchsorted(rec.time, t))
        torque[k : k + 4] += 0.4
    toothy = dataclasses.replace(rec, channels={**rec.channels, "torque": torque})
    hits = detect_impacts(toothy, model, list(ins.phases))  # type: ignore[attr-defined]
    assert len(hits) == 4 and periodic(hits)
    assert not periodic(hits[:2])
    # pooled: 2 isolated hits over 17.2 m of travel on an 8.6 m loop: 1 per revolution
    rows = [{"impact_isolated": 1.0, "belt_travel_m": 8.6}, {"belt_travel_m": 4.3}]
    rows.append({"impact_isolated": 1.0, "belt_travel_m": 4.3})
    assert hits_per_revolution(rows, 8.6) == pytest.approx(1.0)
    assert np.isnan(hits_per_revolution([{}], 8.6))
    # one knock says nothing of a rate: no obstacle read from it
    assert hits_per_revolution(rows[:2], 8.6) == 0.0
    baseline = [{"impact_rail_hits": 1.0, "belt_travel_m": 17.2}, {"belt_travel_m": 17.2}]
    assert background_hits_per_m(baseline) == pytest.approx(1.0 / 34.4)
    assert background_hits_per_m([{}]) == 0.0
    # beyond the healthy conveyor's own random knocks (its baseline: one in 34.4 m,
    # (1 + 1/2) / 34.4 m): 0.75 expected over 17.2 m, two hits are P = 0.17: background
    assert hits_per_revolution(rows, 8.6, baseline) == 0.0
    # a baseline that saw no knock over 68.8 m: (0 + 1/2) / 68.8 m, 0.125 expected in
    # 17.2 m; two hits are P = 1 - e^-0.125 (1 + 0.125) = 0.0072, beyond it:
    # (2 - 0.125) / 17.2 m x 8.6 m = 0.9375 per revolution, by hand
    quiet = [{"impact_rail_hits": 0.0, "belt_travel_m": 17.2}] * 4
    assert hits_per_revolution(rows, 8.6, quiet) == pytest.approx(0.9375)
    # the same two hits against a baseline of 34.4 m without a knock: 0.25 expected,
    # P = 1 - e^-0.25 (1.25) = 0.026, not beyond the background
    assert hits_per_revolution(rows, 8.6, quiet[:2]) == 0.0
    # an obstacle's hits over eight revolutions against that baseline: 8 hits, P ~ 1e-10
    many = [{"impact_rail_hits": 1.0, "belt_travel_m": 8.6}] * 8
    assert hits_per_revolution(many, 8.6, quiet[:2]) == pytest.approx((8 - 1.0) / 8)


def test_knocks_one_obstacle_cannot_have_made_are_not_pooled_as_its_hits(
    reference_profile: ConveyorProfile,
) -> None:
    ins, model = _steady(reference_profile)
    rec = ins.recording  # type: ignore[attr-defined]
    phases = list(ins.phases)  # type: ignore[attr-defined]
    belt_per_rad = reference_profile.pitch_radius_m / 30.99
    torque = model + np.random.default_rng(5).normal(0.0, 0.01, rec.samples)
    for t in (3.0, 4.5):  # two knocks 1.5 s apart
        k = int(np.searchsorted(rec.time, t))
        torque[k : k + 4] += 0.4
    hits = detect_impacts(_with(rec, torque), model, phases)  # type: ignore[arg-type]
    assert len(hits) == 2
    base = impact_features(hits, rec, phases, belt_per_rad)
    speed = base["belt_travel_m"] / sum(  # the mean belt speed over the searched spans
        (p.stop - p.start) * rec.sample_time_s for p in phases if p.kind == "constant"
    )
    # a loop ten times the knocks' spacing: one obstacle passes once in 15 s, not twice in 1.5 s
    long_loop = impact_features(hits, rec, phases, belt_per_rad, loop_length_m=15.0 * speed)
    assert long_loop["impact_isolated"] == 2 and long_loop["impact_rail_hits"] == 0
    # a loop the belt travels in 1.5 s: the same obstacle twice, both its hits
    one_rev = impact_features(hits, rec, phases, belt_per_rad, loop_length_m=1.5 * speed)
    assert one_rev["impact_rail_hits"] == 2
    # the pool counts the rail hits; rows stored before them count their knocks
    rows = [long_loop, {"impact_isolated": 1.0, "belt_travel_m": 1.0}]
    assert pooled_hits(rows) == 1.0


def _with(rec: object, torque: np.ndarray) -> object:
    return dataclasses.replace(rec, channels={**rec.channels, "torque": torque})  # type: ignore[type-var]


def test_a_knock_and_its_ringing_are_one_event_and_a_ringing_alone_is_none(
    reference_profile: ConveyorProfile,
) -> None:
    ins, model = _steady(reference_profile)
    rec = ins.recording  # type: ignore[attr-defined]
    phases = list(ins.phases)  # type: ignore[attr-defined]
    t = rec.time
    noise = np.random.default_rng(4).normal(0.0, 0.01, rec.samples)
    # a belt ringing at 3 Hz for a second, 0.3 Nm, no hit
    ring = np.where((t > 4.0) & (t < 5.0), 0.3 * np.sin(2 * np.pi * 3.0 * (t - 4.0)), 0.0)
    assert detect_impacts(_with(rec, model + noise + ring), model, phases) == []
    # a knock of 0.6 Nm followed by the drive's ringing 20-60 ms later
    k = int(np.searchsorted(t, 5.0))
    knock = np.zeros(rec.samples)
    knock[k : k + 2] = 0.6
    knock[k + 4 : k + 6] = -0.2
    knock[k + 8 : k + 10] = 0.1
    (hit,) = detect_impacts(_with(rec, model + noise + knock), model, phases)
    assert hit.sign == 1 and hit.peak_nm == pytest.approx(0.6, abs=0.05)
    assert hit.width_s <= 2 * rec.sample_time_s + 1e-9


def test_spikes_as_large_both_ways_are_no_hits(reference_profile: ConveyorProfile) -> None:
    ins, model = _steady(reference_profile)
    rec = ins.recording  # type: ignore[attr-defined]
    torque = model + np.random.default_rng(5).normal(0.0, 0.01, rec.samples)
    for t0, sign in ((2.5, 1.0), (4.5, -1.0), (7.0, 1.0)):  # aliased line content
        k = int(np.searchsorted(rec.time, t0))
        torque[k : k + 4] += sign * 0.3
    events = detect_impacts(_with(rec, torque), model, list(ins.phases))  # type: ignore[attr-defined]
    assert [e.sign for e in events] == [-1]  # the resisting ones do not stand out
    feats = impact_features(events, rec, list(ins.phases), 0.001)  # type: ignore[attr-defined]
    assert feats["impact_count"] == 0


def test_a_drag_is_told_from_a_knock(reference_profile: ConveyorProfile) -> None:
    ins, model = _steady(reference_profile)
    rec = ins.recording  # type: ignore[attr-defined]
    phases = list(ins.phases)  # type: ignore[attr-defined]
    torque = model + np.random.default_rng(6).normal(0.0, 0.01, rec.samples)
    drag = (rec.time > 4.0) & (rec.time < 4.5)  # an item caught for half a second
    torque[drag] += 0.2
    (event,) = detect_impacts(_with(rec, torque), model, phases)
    assert event.sign == 1 and event.width_s == pytest.approx(0.5, abs=0.05)
    feats = impact_features([event], rec, phases, 0.001)
    assert feats["impact_drags"] == 1 and feats["impact_isolated"] == 0


def test_what_repeats_at_a_given_order_is_taken_away_and_a_single_hit_stays(
    reference_profile: ConveyorProfile,
) -> None:
    ins, model = _steady(reference_profile)
    rec = ins.recording  # type: ignore[attr-defined]
    phases = list(ins.phases)  # type: ignore[attr-defined]
    order = 0.3  # per motor revolution: a sprocket's tooth pass, say
    comb = 0.25 * (np.mod(order * rec.position, 2 * np.pi) < 0.3)  # a short knock per tooth
    torque = model + np.random.default_rng(7).normal(0.0, 0.01, rec.samples) + comb
    k = int(np.searchsorted(rec.time, 5.5))
    torque[k : k + 4] += 0.5
    with_comb = _with(rec, torque)
    # without knowing the order the comb's knocks read as one long drag
    (blur,) = [e for e in detect_impacts(with_comb, model, phases) if e.sign > 0]
    assert blur.duration_s > 5.0
    # a knock narrower than a phase bin leaves some of it either way: what
    # resists the motion (what the features count) is the single hit alone
    resisting = [e for e in detect_impacts(with_comb, model, phases, [order]) if e.sign > 0]
    (hit,) = resisting
    assert hit.t_s <= rec.time[k] <= hit.t_s + hit.duration_s
    assert hit.peak_nm == pytest.approx(0.5, abs=0.1) and hit.duration_s < 1.0
    x = np.sin(np.linspace(0.0, 40.0 * np.pi, 4000))
    flat = less_periodic(x, np.linspace(0.0, 40.0 * np.pi, 4000), [1.0])
    assert float(np.max(np.abs(flat))) < 0.05  # a pure line at the order goes


def test_the_residual_step_is_a_drag_s_height_and_a_knock_s_share(
    reference_profile: ConveyorProfile,
) -> None:
    """By hand: the residual averaged over STEP_BOX_S = 0.2 s steps by a drag's whole
    height (0.3 Nm for 0.4 s), by a knock's share of the box (0.4 Nm for 4 of 33
    samples: 0.048 Nm), and white noise of 0.01 Nm averaged stays near 0.002 Nm."""
    ins, model = _steady(reference_profile)
    rec = ins.recording  # type: ignore[attr-defined]
    phases = list(ins.phases)  # type: ignore[attr-defined]
    noise = np.random.default_rng(2).normal(0.0, 0.01, rec.samples)
    plain = residual_step(_with(rec, model + noise), model, phases)
    assert plain < 0.015
    dragged = model + noise
    dragged[(rec.time > 4.0) & (rec.time < 4.4)] += 0.3
    assert residual_step(_with(rec, dragged), model, phases) == pytest.approx(0.3, abs=0.015)
    knocked = model + noise
    k = int(np.searchsorted(rec.time, 5.0))
    knocked[k : k + 4] += 0.4
    box = round(0.2 / rec.sample_time_s)
    assert residual_step(_with(rec, knocked), model, phases) == pytest.approx(
        0.4 * 4 / box, abs=0.015
    )


def test_a_1_ms_plateau_too_short_for_the_impact_search_has_a_residual_step(
    reference_profile: ConveyorProfile,
) -> None:
    """A 1 ms scope of a whole move (2048 samples: 0.94 s at constant speed) is not
    searched for impacts, but an item caught for 0.3 s of it steps its level."""
    setpoints = default_setpoints(
        reference_profile, duration_s=2.048, ramp_s=0.256, hold_s=0.936, direction=1
    )
    run = run_virtual(
        reference_profile,
        payload_kg=20.0,
        seed=3,
        realism=Realism.off(),
        sample_time_s=0.001,
        setpoints=setpoints,
    )
    ins = inspect_recording(run.recording, reference_profile)
    rec, phases = ins.recording, list(ins.phases)
    model = rec.torque.copy()
    noise = np.random.default_rng(4).normal(0.0, 0.01, rec.samples)
    (plateau,) = [p for p in phases if p.kind == "constant"]
    mid = rec.time[(plateau.start + plateau.stop) // 2]
    dragged = model + noise
    dragged[(rec.time > mid - 0.15) & (rec.time < mid + 0.15)] += 0.3
    impacts, spans = scan_impacts(_with(rec, dragged), model, phases)
    assert spans == [] and impacts == []  # too short to be searched
    assert residual_step(_with(rec, dragged), model, phases) == pytest.approx(0.3, abs=0.015)
    assert residual_step(_with(rec, model + noise), model, phases) < 0.015
