"""The torque channel a calibration weighs with, chosen by its recordings' residuals."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
from conftest import REFERENCE_PROFILE

from chaintwin.calibrating.procedure import calibrate
from chaintwin.identify.calibration import Calibration
from chaintwin.identify.channels import TORQUE_CHANNELS, ChannelSpreads, choose_channel
from chaintwin.read.profile import load_profile
from chaintwin.read.recording import Recording
from chaintwin.simulate.virtual import Realism, run_virtual
from chaintwin.validate import inspect_recording
from chaintwin.weigh import weigh
from chaintwin.weigh.weigh import SETPOINT_MISSING

PROFILE = load_profile(REFERENCE_PROFILE)


def _recordings(realism: Realism, seed: int) -> list[Recording]:
    return [
        run_virtual(
            PROFILE,
            payload_kg=load,
            sample_time_s=0.002,
            seed=seed + k,
            realism=realism,
            calibration=True,
            speed_rpm=rpm,
        ).recording
        for k, (load, rpm) in enumerate([(0.0, 700.0), (0.0, 1400.0), (40.0, 1400.0)])
    ]


@pytest.fixture(scope="module")
def noisy_actual() -> tuple[Realism, Calibration]:
    """A drive whose actual torque is noisy (3 % of nominal) and set point quiet."""
    realism = Realism(torque_noise=0.03)
    return realism, calibrate(_recordings(realism, 900), PROFILE)


def test_the_choice_rule_by_hand() -> None:
    spreads = ChannelSpreads(0.02, 0.01, 0.9, 0.0099, -0.1)
    assert choose_channel(spreads) == "torque_setpoint"  # the combination gains < 5 %
    assert choose_channel(dataclasses.replace(spreads, combined=0.008)) == "combined"
    assert choose_channel(ChannelSpreads(0.01, 0.02, 0.5, 0.0098, 0.8)) == "torque"


def test_a_noisy_actual_torque_is_not_chosen(noisy_actual: tuple[Realism, Calibration]) -> None:
    _realism, cal = noisy_actual
    spreads = cal.channel_spreads
    assert spreads is not None
    assert spreads.torque > spreads.torque_setpoint > 0.0
    assert cal.torque_channel in ("torque_setpoint", "combined")
    assert cal.torque_channel == choose_channel(spreads)
    assert cal.actual_torque is not None and cal.actual_torque.torque_channel == "torque"
    content = json.loads(json.dumps(cal.to_dict()))
    assert content["torque_channel"] == cal.torque_channel
    assert set(content["torque_channel_spreads_nm"]) >= {"torque", "torque_setpoint"}
    back = Calibration.from_dict(content)
    assert back.torque_channel == cal.torque_channel and back.channel_spreads == spreads
    assert back.actual_torque is not None
    content["torque_channel"] = "current"
    with pytest.raises(Exception, match="torque_channel"):
        Calibration.from_dict(content)


def test_without_the_set_point_the_actual_torque_terms_weigh(
    noisy_actual: tuple[Realism, Calibration],
) -> None:
    realism, cal = noisy_actual
    assert cal.actual_torque is not None
    rec = run_virtual(PROFILE, payload_kg=25.0, sample_time_s=0.002, seed=950, realism=realism)
    full = rec.recording
    bare = dataclasses.replace(
        full, channels={k: v for k, v in full.channels.items() if k != "torque_setpoint"}
    )
    on_channel = weigh(inspect_recording(full, PROFILE), cal)
    assert SETPOINT_MISSING not in [w.code for w in on_channel.warnings]
    fallback = weigh(inspect_recording(bare, PROFILE), cal)
    assert SETPOINT_MISSING in [w.code for w in fallback.warnings]
    # exactly what the actual-torque calibration weighs
    direct = weigh(inspect_recording(bare, PROFILE), cal.actual_torque)
    assert fallback.payload_kg == direct.payload_kg
    assert fallback.uncertainty_kg == direct.uncertainty_kg
    for res in (on_channel, fallback):
        assert res.payload_kg is not None and res.uncertainty_kg is not None
        assert abs(res.payload_kg - 25.0) < 3.0 * res.uncertainty_kg


def test_a_noisy_set_point_is_not_chosen() -> None:
    """The set point carrying 20 rpm of speed noise times the controller's gain."""
    realism = Realism(setpoint_noise=True, speed_noise_rpm=20.0)
    cal = calibrate(_recordings(realism, 960), PROFILE)
    assert cal.channel_spreads is not None
    assert cal.channel_spreads.torque_setpoint > cal.channel_spreads.torque
    assert cal.torque_channel == "torque" and cal.actual_torque is None
    assert cal.torque_channel in TORQUE_CHANNELS


def test_recordings_without_set_points_calibrate_on_the_actual_torque(tmp_path: Path) -> None:
    recs = _recordings(Realism(), 970)
    bare = [
        dataclasses.replace(
            r, channels={k: v for k, v in r.channels.items() if k != "torque_setpoint"}
        )
        for r in recs
    ]
    cal = calibrate(bare, PROFILE)
    assert cal.torque_channel == "torque" and cal.channel_spreads is None


def test_windows_chosen_on_the_actual_torque_are_kept_on_the_set_point(
    noisy_actual: tuple[Realism, Calibration],
) -> None:
    """Monitoring hands weighing the windows it kept (impacts left out), on the actual
    torque: a calibration on the set point integrates the same windows on its channel."""
    from chaintwin.model.rigid import motoring_mask
    from chaintwin.model.windows import window_integrals

    realism, cal = noisy_actual
    assert cal.actual_torque is not None
    run = run_virtual(PROFILE, payload_kg=25.0, sample_time_s=0.002, seed=951, realism=realism)
    ins = inspect_recording(run.recording, PROFILE)
    params = cal.actual_torque.parameters
    mot = motoring_mask(run.recording, drive_inertia_kgm2=params["J_d"], losses=params.losses)
    every = window_integrals(run.recording, cal.id_profile, motoring=mot, phases=list(ins.phases))
    plain = weigh(ins, cal)
    same = weigh(ins, cal, motoring=mot, windows=every)
    assert same.payload_kg == plain.payload_kg and same.uncertainty_kg == plain.uncertainty_kg
    keep = every.kind == 1
    keep |= (every.constant) & (np.arange(every.count) % 2 == 0)
    fewer = weigh(ins, cal, motoring=mot, windows=every.select(keep))
    assert fewer.payload_kg is not None and fewer.payload_kg != plain.payload_kg
