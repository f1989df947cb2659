"""Impacts on the torque residual: a hand calculation and the classification by regularity."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from chaintwin.diagnose.impacts import (
    detect_impacts,
    hits_per_revolution,
    impact_features,
    periodic,
)
from chaintwin.read.profile import ConveyorProfile
from chaintwin.simulate.virtual import Realism, run_virtual
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
    torque[k : k + 3] += 0.4  # 0.4 Nm more for three samples: something resisted
    knocked = dataclasses.replace(rec, channels={**rec.channels, "torque": torque})
    phases = list(ins.phases)  # type: ignore[attr-defined]
    (hit,) = detect_impacts(knocked, model, phases)
    assert hit.t_s == pytest.approx(rec.time[k])
    assert hit.duration_s == pytest.approx(3 * rec.sample_time_s)
    assert hit.sign == 1
    # by hand: 0.4 Nm times the speed over three samples (the noise aside)
    expected = 0.4 * float(np.sum(rec.speed[k : k + 3])) * rec.sample_time_s
    assert hit.energy_j == pytest.approx(expected, rel=0.1)
    # nothing in the same recording without the knock
    plain = dataclasses.replace(rec, channels={**rec.channels, "torque": model + noise})
    assert detect_impacts(plain, model, phases) == []
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
        torque[k : k + 2] += 0.4
    toothy = dataclasses.replace(rec, channels={**rec.channels, "torque": torque})
    hits = detect_impacts(toothy, model, list(ins.phases))  # type: ignore[attr-defined]
    assert len(hits) == 4 and periodic(hits)
    assert not periodic(hits[:2])
    # pooled: 2 isolated hits over 17.2 m of travel on an 8.6 m loop: 1 per revolution
    rows = [{"impact_isolated": 1.0, "belt_travel_m": 8.6}, {"belt_travel_m": 4.3}]
    rows.append({"impact_isolated": 1.0, "belt_travel_m": 4.3})
    assert hits_per_revolution(rows, 8.6) == pytest.approx(1.0)
    assert np.isnan(hits_per_revolution([{}], 8.6))
