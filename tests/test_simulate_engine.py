"""The simulator as a tool: set points, control, symmetry, errors.

Run with ``-s`` to see the measured numbers.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
import pytest

import chaintwin.examples
from chaintwin.errors import ModelError
from chaintwin.read.profile import ConveyorProfile, ModelSpec, load_profile
from chaintwin.simulate import (
    PlantParameters,
    Setpoints,
    _kernel,
    elastic_substeps,
    from_arrays,
    ramp,
    simulate,
    stairs,
    trapezoid,
    trapezoid2,
)
from chaintwin.simulate.plant import calibrated_model

PROFILES = Path(chaintwin.examples.__file__).parent / "profiles"
NOMINAL = 1415.0 * 2.0 * math.pi / 60.0


@pytest.fixture(scope="module")
def profile() -> ConveyorProfile:
    return load_profile(PROFILES / "white-belt-01.yaml")


@pytest.fixture(scope="module")
def plant(profile: ConveyorProfile) -> PlantParameters:
    return PlantParameters.from_profile(profile, payload_kg=40.0)


# ---------------------------------------------------------------- set points
def test_trapezoid_shape_and_position() -> None:
    sp = trapezoid(speed_rad_s=100.0, accel_rad_s2=200.0, hold_s=1.0, decel_rad_s2=100.0)
    dt = sp.cycle_s
    # 0.1 lead + 0.5 up + 1.0 hold + 1.0 down + 0.4 tail
    assert sp.duration_s == pytest.approx(3.0)
    assert len(sp) == 3001
    np.testing.assert_allclose(sp.time[:3], [0.0, dt, 2 * dt])
    assert sp.speed.max() == pytest.approx(100.0)
    assert sp.speed[0] == 0.0
    assert sp.speed[-1] == 0.0
    k = round(0.35 / dt)
    assert sp.speed[k] == pytest.approx(50.0)
    # exact area: 0.5·100·0.5 + 100·1 + 0.5·100·1 = 175 rad
    assert sp.position[-1] == pytest.approx(175.0, rel=1e-9)
    assert sp.position[0] == 0.0
    back = trapezoid(
        speed_rad_s=100.0, accel_rad_s2=200.0, hold_s=1.0, decel_rad_s2=100.0, direction=-1
    )
    np.testing.assert_array_equal(back.speed, -sp.speed)
    np.testing.assert_array_equal(back.position, -sp.position)
    assert not sp.speed.flags.writeable


def test_trapezoid2_ramp_stairs_shapes() -> None:
    two = trapezoid2(
        speed_rad_s=100.0, accel1_rad_s2=100.0, accel2_rad_s2=400.0, switch_fraction=0.4, hold_s=0.5
    )
    # up: 0.4 s to 40 rad/s, 0.15 s to 100; mirrored on the way down
    dt = two.cycle_s
    acc = np.diff(two.speed) / dt
    assert acc.max() == pytest.approx(400.0, rel=1e-6)
    assert acc[round(0.3 / dt)] == pytest.approx(100.0, rel=1e-6)
    assert two.speed[round((0.1 + 0.2) / dt)] == pytest.approx(20.0)
    assert two.duration_s == pytest.approx(0.1 + 0.55 + 0.5 + 0.55 + 0.4)
    r = ramp(speed_rad_s=50.0, ramp_s=0.25, hold_s=1.0)
    assert np.abs(np.diff(r.speed)).max() / r.cycle_s == pytest.approx(200.0, rel=1e-6)
    assert r.duration_s == pytest.approx(0.1 + 0.25 + 1.0 + 0.25 + 0.4)
    s = stairs(speeds_rad_s=[50.0, 100.0, -20.0], step_s=0.5, accel_rad_s2=500.0)
    levels = [50.0, 100.0, -20.0]
    for level in levels:
        assert np.sum(np.isclose(s.speed, level)) >= 0.5 / s.cycle_s
    # 0.1 + 0.1 + 0.5 + 0.1 + 0.5 + 0.24 + 0.5 + 0.04 + 0.4
    assert s.duration_s == pytest.approx(2.48)
    assert s.speed[-1] == 0.0


def test_from_arrays_resamples_to_the_cycle() -> None:
    t = np.arange(0.0, 2.0 + 1e-9, 0.006) + 17.3  # a 6 ms scope with an offset clock
    w = np.interp(t, [17.3, 17.5, 18.5, 19.0, 19.3], [0.0, 0.0, 100.0, 100.0, 0.0])
    sp = from_arrays(t, w, cycle_s=0.001)
    assert sp.cycle_s == 0.001
    assert sp.duration_s == pytest.approx(t[-1] - t[0], abs=1e-3)
    np.testing.assert_allclose(np.interp(sp.time + t[0], t, w), sp.speed, atol=1e-12)
    # position integrated from the speed
    assert sp.position[-1] == pytest.approx(np.trapezoid(sp.speed, dx=0.001))
    pos = 5000.0 + np.concatenate(([0.0], np.cumsum(0.5 * (w[1:] + w[:-1]) * 0.006)))
    given = from_arrays(t, w, pos)
    assert given.position[0] == 0.0
    assert given.position[-1] == pytest.approx(pos[-1] - pos[0])
    with pytest.raises(ModelError, match="strictly increasing"):
        from_arrays(t[::-1], w)
    with pytest.raises(ModelError, match="same length"):
        from_arrays(t, w[:-1])
    with pytest.raises(ModelError, match="NaN"):
        from_arrays(t, np.where(t > 18.0, np.nan, w))


def test_setpoint_errors() -> None:
    with pytest.raises(ModelError, match="accel_rad_s2"):
        trapezoid(speed_rad_s=10.0, accel_rad_s2=0.0, hold_s=1.0)
    with pytest.raises(ModelError, match="direction"):
        ramp(speed_rad_s=10.0, ramp_s=1.0, hold_s=1.0, direction=2)
    with pytest.raises(ModelError, match="switch_fraction"):
        trapezoid2(
            speed_rad_s=1.0, accel1_rad_s2=1.0, accel2_rad_s2=1.0, switch_fraction=2.0, hold_s=1.0
        )
    with pytest.raises(ModelError, match="speeds_rad_s"):
        stairs(speeds_rad_s=[], step_s=1.0, accel_rad_s2=1.0)
    with pytest.raises(ModelError, match="5 values but position 4"):
        Setpoints(0.001, np.zeros(5), np.zeros(4))


# ------------------------------------------------------------------ control
@pytest.mark.parametrize(
    "kind",
    ["trapezoid", "trapezoid2", "ramp", "stairs"],
)
def test_controller_follows_setpoints(plant: PlantParameters, kind: str) -> None:
    sp = {
        "trapezoid": lambda: trapezoid(speed_rad_s=NOMINAL, accel_rad_s2=NOMINAL / 0.5, hold_s=3.0),
        "trapezoid2": lambda: trapezoid2(
            speed_rad_s=NOMINAL, accel1_rad_s2=150.0, accel2_rad_s2=400.0, hold_s=3.0
        ),
        "ramp": lambda: ramp(speed_rad_s=0.5 * NOMINAL, ramp_s=1.0, hold_s=2.0),
        "stairs": lambda: stairs(
            speeds_rad_s=[0.3 * NOMINAL, 0.7 * NOMINAL, NOMINAL, 0.5 * NOMINAL],
            step_s=1.0,
            accel_rad_s2=300.0,
        ),
    }[kind]()
    res = simulate(plant, sp)
    assert res.success
    assert res.saturated_cycles == 0
    peak = np.abs(sp.speed).max()
    err = res.speed - res.speed_setpoint
    constant = np.abs(np.gradient(sp.speed)) < 1e-9
    constant &= np.abs(sp.speed) > 0.0
    rms_const = float(np.sqrt(np.mean(err[constant] ** 2)) / peak)
    rms_all = float(np.sqrt(np.mean(err**2)) / peak)
    pos_err = float(np.abs(res.position - res.position_setpoint).max())
    print(
        f"\n{kind}: speed error RMS {rms_const:.2e} of peak at constant set point, "
        f"{rms_all:.2e} overall; max position error {pos_err:.3f} rad"
    )
    assert rms_const < 0.02
    assert rms_all < 0.02
    assert abs(res.position[-1] - res.position_setpoint[-1]) < 0.05


def test_forward_and_backward_runs_mirror(plant: PlantParameters) -> None:
    fwd_sp = trapezoid(speed_rad_s=NOMINAL, accel_rad_s2=NOMINAL / 0.5, hold_s=1.0)
    back_sp = trapezoid(speed_rad_s=NOMINAL, accel_rad_s2=NOMINAL / 0.5, hold_s=1.0, direction=-1)
    for p in (plant, plant.replace(stick_slip=True, elastic=True)):
        fwd = simulate(p, fwd_sp)
        back = simulate(p, back_sp)
        for name in ("torque", "torque_setpoint", "speed", "position", "belt_speed_m_s"):
            np.testing.assert_allclose(
                getattr(back, name), -getattr(fwd, name), rtol=0.0, atol=1e-12, err_msg=name
            )
        np.testing.assert_allclose(back.sprocket_force_n, -fwd.sprocket_force_n, atol=1e-9)


def test_initial_angle_and_belt_position(plant: PlantParameters) -> None:
    sp = trapezoid(speed_rad_s=NOMINAL, accel_rad_s2=NOMINAL / 0.5, hold_s=0.5)
    base = simulate(plant, sp)
    moved = simulate(plant, sp, initial_motor_angle=1234.5, initial_belt_position_m=3.0)
    np.testing.assert_allclose(moved.position - 1234.5, base.position, atol=1e-9)
    np.testing.assert_allclose(moved.position_setpoint - 1234.5, base.position_setpoint)
    np.testing.assert_allclose(moved.belt_position_m - 3.0, base.belt_position_m, atol=1e-9)
    np.testing.assert_allclose(moved.torque, base.torque, atol=1e-9)


def test_standstill_holds_without_chattering(plant: PlantParameters) -> None:
    sp = trapezoid(speed_rad_s=NOMINAL, accel_rad_s2=NOMINAL / 0.5, hold_s=0.5, tail_s=1.5)
    res = simulate(plant.replace(stick_slip=True), sp)
    tail = res.time > sp.duration_s - 0.5
    assert np.all(res.speed[tail] == 0.0)
    assert np.all(res.loss_torque_nm[tail] == 0.0)
    # stuck: the integrator moves the torque smoothly (no sign flipping cycle to cycle)
    slope = np.diff(res.torque[tail])
    assert np.count_nonzero(np.diff(np.sign(slope))) <= 1
    assert (
        np.abs(res.torque[tail]).max() < plant.steady_torque_nm(1e-9) * plant.static_friction_ratio
    )


# ------------------------------------------------------------------- errors
def test_cycle_mismatch_and_bad_parameters(plant: PlantParameters) -> None:
    sp = trapezoid(speed_rad_s=10.0, accel_rad_s2=100.0, hold_s=0.1, cycle_s=0.002)
    with pytest.raises(ModelError, match="cycle"):
        simulate(plant, sp)
    with pytest.raises(ModelError, match="efficiency"):
        plant.replace(efficiency=1.5)
    with pytest.raises(ModelError, match="unknown field"):
        plant.replace(frction=0.2)
    with pytest.raises(ModelError, match="ripple_amplitudes_nm"):
        plant.replace(ripple_orders=(1.0, 2.0), ripple_amplitudes_nm=(0.1,))
    with pytest.raises(ModelError, match="too stiff"):
        elastic_substeps(plant.replace(elastic=True, belt_stiffness_n_m=1e15))


def test_from_profile_defaults_and_overrides(profile: ConveyorProfile) -> None:
    p = PlantParameters.from_profile(profile, payload_kg=12.0, elastic=True)
    assert p.elastic
    assert p.payload_kg == 12.0
    assert p.belt_stiffness_n_m == 1e6  # the profile's model section
    assert p.torque_limit_nm == 7.5
    assert p.teeth == 10
    assert p.moving_mass_kg == pytest.approx(profile.moving_mass_kg(12.0))
    assert p.belt_speed_per_motor_speed == pytest.approx(profile.belt_speed_per_motor_speed)
    # stiffness from E·A/L when the model gives none
    q = PlantParameters.from_profile(profile, model=ModelSpec(friction=0.3))
    assert q.mu == 0.3
    b = profile.belt
    assert b.youngs_modulus_pa is not None
    assert b.cross_section_m2 is not None
    assert q.belt_stiffness_n_m == pytest.approx(
        b.youngs_modulus_pa * b.cross_section_m2 / b.length_m
    )
    # no torque limit known
    bare = profile.model_copy(
        update={
            "motor": profile.motor.model_copy(update={"nominal_torque_nm": None}),
            "controller": profile.controller.model_copy(update={"torque_limit_nm": None}),
            "model": None,
        }
    )
    with pytest.raises(ModelError, match="torque limit"):
        PlantParameters.from_profile(bare)
    default = PlantParameters.from_profile(bare, torque_limit_nm=5.0)
    assert default.mu == ModelSpec().friction
    assert default.torque_limit_nm == 5.0


def test_calibrated_model_maps_the_calibration_vocabulary() -> None:
    spec = ModelSpec(static_friction_ratio=1.4)
    got = calibrated_model(spec, {"mu": 0.31, "BmA": -0.01, "BmB": 0.002, "BmC": 1e-6, "J_d": 1.0})
    assert got.friction == 0.31
    assert got.loss_constant_nm == 0.0  # a fit's scatter below zero is simulated as zero
    assert got.loss_viscous_nm_s_rad == 0.002
    assert got.loss_quadratic_nm_s2_rad2 == 1e-6
    assert got.static_friction_ratio == 1.4  # what a calibration does not identify is kept


def test_kernel_cache_is_invalidated_when_a_dependency_changes(tmp_path: Path) -> None:
    # numba stamps a cache with the kernel file's own mtime; a newer
    # dependency (shared pieces, layout) must make the kernel file newer still
    kernel, piece = tmp_path / "rigid.py", tmp_path / "pieces.py"
    kernel.write_text("kernel")
    piece.write_text("piece")
    os.utime(kernel, ns=(1_000_000_000, 1_000_000_000))
    os.utime(piece, ns=(2_000_000_000, 2_000_000_000))
    _kernel.layout.keep_cache_fresh(str(kernel), str(piece))
    assert kernel.stat().st_mtime_ns > piece.stat().st_mtime_ns
    stamp = kernel.stat().st_mtime_ns
    _kernel.layout.keep_cache_fresh(str(kernel), str(piece))  # fresh: untouched
    assert kernel.stat().st_mtime_ns == stamp
    _kernel.layout.keep_cache_fresh(str(kernel), str(tmp_path / "missing.py"))  # no error


def test_coefficient_layout_is_one_table() -> None:
    names = [name for name, _ in _kernel.COEFFICIENTS]
    assert len(set(names)) == len(names) == _kernel.N_COEF
    assert _kernel.layout.C_DT == 0
    assert _kernel.layout.C_STRIBECK_V == _kernel.N_COEF - 1
    values = {name: float(i) for i, name in enumerate(names)}
    np.testing.assert_array_equal(_kernel.pack(values), np.arange(_kernel.N_COEF, dtype=float))
    with pytest.raises(ModelError, match="missing \\['dt'\\]"):
        _kernel.pack({name: 0.0 for name in names[1:]})
    with pytest.raises(ModelError, match="unknown \\['speed'\\]"):
        _kernel.pack({**values, "speed": 1.0})


@pytest.mark.slow
@pytest.mark.parametrize("elastic", [False, True])
def test_stribeck_friction_by_hand(plant: PlantParameters, elastic: bool) -> None:
    """At belt speed v the sliding friction is fc + (fs − fc)·exp(−(v/vs)²)."""
    vs = 0.05
    p = plant.replace(stick_slip=True, elastic=elastic, stribeck_speed_m_s=vs)
    krv = p.belt_speed_per_motor_speed
    w = vs / krv  # the plateau's belt speed is vs: the extra friction is (fs − fc)/e
    sp = trapezoid(speed_rad_s=w, accel_rad_s2=w / 0.2, hold_s=3.0)
    with_ = simulate(p, sp)
    without = simulate(p.replace(stribeck_speed_m_s=0.0), sp)
    plateau = (with_.time > 1.5) & (with_.time < 3.0)
    extra = float(np.mean(with_.torque[plateau] - without.torque[plateau]))
    fc = p.mu * 9.80665 * math.cos(p.incline_rad) * p.moving_mass_kg
    expected = (p.static_friction_ratio - 1.0) * fc * math.exp(-1.0) * krv / p.efficiency
    assert extra == pytest.approx(expected, rel=0.02)
    # far above the Stribeck speed it is Coulomb friction again
    fast = trapezoid(speed_rad_s=NOMINAL, accel_rad_s2=NOMINAL / 0.5, hold_s=1.0)
    a, b = simulate(p, fast), simulate(p.replace(stribeck_speed_m_s=0.0), fast)
    steady = (a.time > 1.0) & (a.time < 1.4)
    assert np.mean(a.torque[steady]) == pytest.approx(np.mean(b.torque[steady]), rel=1e-3)


def test_back_efficiency_where_the_belt_drives_the_motor(plant: PlantParameters) -> None:
    """Downhill at constant speed the gear passes f·η_back on to the motor (generating)."""
    down = plant.replace(incline_rad=-0.35, mu=0.1)
    sp = trapezoid(speed_rad_s=NOMINAL, accel_rad_s2=NOMINAL / 0.5, hold_s=1.5)
    krv = down.belt_speed_per_motor_speed
    g = 9.80665
    f = (
        krv
        * g
        * (
            down.mu * math.cos(down.incline_rad) * down.moving_mass_kg
            + math.sin(down.incline_rad) * down.carried_mass_kg
        )
    )
    assert f < 0.0  # the load drives the motor
    loss = (
        down.loss_constant_nm
        + down.loss_viscous_nm_s_rad * NOMINAL
        + down.loss_quadratic_nm_s2_rad2 * NOMINAL**2
    )
    for eta_back in (0.0, 0.6):
        res = simulate(down.replace(back_efficiency=eta_back), sp)
        steady = (res.time > 1.2) & (res.time < 1.9)
        eta = eta_back or down.efficiency
        assert np.mean(res.torque[steady]) == pytest.approx(f * eta + loss, rel=0.01)
    with pytest.raises(ModelError, match="back_efficiency"):
        plant.replace(back_efficiency=1.5)


def test_later_model_fields_reach_the_plant_and_keep_old_hashes(profile: ConveyorProfile) -> None:
    import hashlib
    import json

    plain = profile.model_copy(update={"model": ModelSpec()})
    # the hash of a profile written before these fields existed is unchanged
    data = plain.model_dump(mode="json")
    for name in ModelSpec.LATER_FIELDS:
        del data["model"][name]
    # nor had the profile's later keys (absent, they are not hashed)
    del data["limits"], data["expected_wear"], data["belt"]["tension_n"], data["zero_tracking"]
    old = hashlib.sha256(
        json.dumps(data, sort_keys=True, separators=(",", ":")).encode()
    ).hexdigest()
    assert plain.content_hash() == old
    richer = profile.model_copy(
        update={
            "model": ModelSpec(
                back_efficiency=0.7, stribeck_speed_m_s=0.03, unlisted_inertia_kgm2=2e-4
            )
        }
    )
    assert richer.content_hash() != old
    p = PlantParameters.from_profile(richer, payload_kg=0.0)
    assert p.back_efficiency == 0.7 and p.stribeck_speed_m_s == 0.03
    assert p.gear_inertia_kgm2 == pytest.approx(profile.gear.inertia_kgm2 + 2e-4)
