"""Known answers for the closed-form physics and the simulator's plant.

Hand calculations use the reference conveyor white-belt-01's numbers read
from the profile, computed here independently of the code under test.
Run with ``-s`` to see the measured numbers.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

import chaintwin.examples
from chaintwin import physics
from chaintwin.read.profile import ConveyorProfile, load_profile
from chaintwin.simulate import PlantParameters, Setpoints, integrate_speed, simulate, trapezoid

PROFILES = Path(chaintwin.examples.__file__).parent / "profiles"
G = 9.81
NOMINAL = 1415.0 * 2.0 * math.pi / 60.0  # rad/s


@pytest.fixture(scope="module")
def profile() -> ConveyorProfile:
    return load_profile(PROFILES / "white-belt-01.yaml")


@pytest.fixture(scope="module")
def plant(profile: ConveyorProfile) -> PlantParameters:
    return PlantParameters.from_profile(profile, payload_kg=40.0)


def hand(profile: ConveyorProfile, payload_kg: float = 40.0) -> dict[str, float]:
    """The reference conveyor by hand, from the profile's raw numbers."""
    assert profile.model is not None
    big_r = profile.sprocket.pitch_diameter_m / 2.0
    z = profile.sprocket.teeth
    assert z is not None
    r = big_r * math.sin(math.pi / z) / (math.pi / z)
    loop = 2.0 * profile.belt.length_m + math.pi * profile.sprocket.pitch_diameter_m
    m_b = profile.belt.mass_per_m_kg * loop
    m = m_b + profile.tray_mass_kg + payload_kg
    return {
        "R": big_r,
        "r": r,
        "m_b": m_b,
        "m": m,
        "i": profile.kinematic_ratio,
        "eta": profile.gear.efficiency,
        "mu": profile.model.friction,
        "A": profile.model.loss_constant_nm,
        "B": profile.model.loss_viscous_nm_s_rad,
        "C": profile.model.loss_quadratic_nm_s2_rad2,
        "Jd": profile.motor.inertia_kgm2 + profile.gear.inertia_kgm2,
    }


# ---------------------------------------------------------------- physics.py
def test_physics_functions_match_hand_calculation(profile: ConveyorProfile) -> None:
    h = hand(profile)
    # chordal radius: 1.6 % below R for z = 10
    r = physics.chordal_radius_m(h["R"], 10)
    assert r == pytest.approx(h["r"], rel=1e-15)
    assert 1.0 - r / h["R"] == pytest.approx(0.01637, abs=1e-4)
    assert physics.chordal_radius_m(h["R"], None) == h["R"]
    assert physics.chordal_radius_m(h["R"], 0) == h["R"]
    # belt force, flat: μ g m sign(v)
    f = physics.belt_force_n(mu=h["mu"], moving_mass_kg=h["m"], carried_mass_kg=50.0)
    assert f == pytest.approx(h["mu"] * G * h["m"], rel=1e-14)
    assert f == pytest.approx(195.89, abs=0.01)
    backward = physics.belt_force_n(
        mu=h["mu"], moving_mass_kg=h["m"], carried_mass_kg=50.0, direction=-1.0
    )
    assert backward == -f
    # incline: only the carried mass climbs
    beta = math.radians(6.0)
    f_inc = physics.belt_force_n(
        mu=0.2, moving_mass_kg=100.0, carried_mass_kg=30.0, incline_rad=beta
    )
    assert f_inc == pytest.approx(0.2 * G * math.cos(beta) * 100.0 + G * math.sin(beta) * 30.0)
    # load torque: F r/(i η) motoring, F r η/i generating
    t_load = physics.load_torque_nm(f, h["r"], h["i"], h["eta"])
    assert t_load == pytest.approx(f * h["r"] / (h["i"] * h["eta"]), rel=1e-14)
    assert t_load == pytest.approx(0.40448, abs=2e-5)
    gen = physics.load_torque_nm(f, h["r"], h["i"], h["eta"], motoring=False)
    assert gen == pytest.approx(f * h["r"] * h["eta"] / h["i"], rel=1e-14)
    # losses
    w = NOMINAL
    loss = physics.loss_torque_nm(w, h["A"], h["B"], h["C"])
    assert loss == pytest.approx(h["A"] + h["B"] * w + h["C"] * w * w, rel=1e-14)
    arr = physics.loss_torque_nm(np.array([-w, 0.0, w]), h["A"], h["B"], h["C"])
    np.testing.assert_allclose(arr, [-loss, 0.0, loss], rtol=1e-14)
    # steady torque
    steady = physics.steady_torque_nm(
        speed_rad_s=w,
        mu=h["mu"],
        moving_mass_kg=h["m"],
        carried_mass_kg=50.0,
        incline_rad=0.0,
        radius_m=h["r"],
        ratio=h["i"],
        efficiency=h["eta"],
        loss_constant_nm=h["A"],
        loss_viscous_nm_s_rad=h["B"],
        loss_quadratic_nm_s2_rad2=h["C"],
    )
    assert steady == pytest.approx(t_load + loss, rel=1e-14)
    # payload sensitivity, flat: g μ r/(i η) per kg
    sens = physics.payload_sensitivity_nm_kg(
        mu=h["mu"], incline_rad=0.0, radius_m=h["r"], ratio=h["i"], efficiency=h["eta"]
    )
    assert sens == pytest.approx(G * h["mu"] * h["r"] / (h["i"] * h["eta"]), rel=1e-14)
    # power-flow side
    assert physics.motoring(f, h["m"], 0.0, 0.3)
    assert not physics.motoring(f, h["m"], -5.0, 0.3)  # hard stop: the belt drives
    assert physics.gear_factor(0.9) == pytest.approx(1.0 / 0.9)
    assert physics.gear_factor(0.9, motoring=False) == 0.9


def test_reflected_inertia_and_two_mass_frequency(
    profile: ConveyorProfile, plant: PlantParameters
) -> None:
    h = hand(profile)
    k2 = (h["r"] / h["i"]) ** 2
    j_mot = h["Jd"] + h["m"] * k2 / h["eta"]
    j_gen = h["Jd"] + h["m"] * k2 * h["eta"]
    assert j_mot == pytest.approx(0.0026642, abs=2e-7)
    assert plant.reflected_inertia_kgm2() == pytest.approx(j_mot, rel=1e-14)
    assert plant.reflected_inertia_kgm2(motoring=False) == pytest.approx(j_gen, rel=1e-14)
    assert profile.reflected_inertia_kgm2(40.0) == pytest.approx(j_mot, rel=1e-14)
    m1 = h["Jd"] * h["i"] ** 2 / h["r"] ** 2
    f_hand = math.sqrt(1e6 * (1.0 / m1 + 1.0 / h["m"])) / (2.0 * math.pi)
    assert m1 == pytest.approx(629.2, abs=0.2)
    assert plant.two_mass_frequency_hz() == pytest.approx(f_hand, rel=1e-14)
    assert f_hand == pytest.approx(18.22, abs=0.01)
    print(f"\nJ motoring {j_mot:.7f} kg m², generating {j_gen:.7f}; two-mass mode {f_hand:.3f} Hz")


# --------------------------------------------------------- simulated physics
def test_steady_torque_equals_hand_calculation(
    profile: ConveyorProfile, plant: PlantParameters
) -> None:
    h = hand(profile)
    sp = trapezoid(speed_rad_s=NOMINAL, accel_rad_s2=NOMINAL / 0.5, hold_s=4.0)
    res = simulate(plant, sp)
    assert res.success
    hold = (res.time > 2.5) & (res.time < 4.5)  # after the integrator has settled
    f = h["mu"] * G * h["m"]
    w = NOMINAL
    t_hand = f * h["r"] / (h["i"] * h["eta"]) + h["A"] + h["B"] * w + h["C"] * w * w
    measured = float(np.mean(res.torque[hold]))
    print(f"\nsteady torque: simulated {measured:.9f} Nm, hand {t_hand:.9f} Nm")
    assert measured == pytest.approx(t_hand, rel=1e-9)
    assert np.ptp(res.torque[hold]) < 1e-8
    np.testing.assert_allclose(res.sprocket_force_n[hold], f, rtol=1e-7)
    np.testing.assert_allclose(res.load_torque_nm[hold], f * h["r"] / (h["i"] * h["eta"]))
    assert plant.steady_torque_nm(w) == pytest.approx(t_hand, rel=1e-13)


@pytest.mark.parametrize(
    ("name", "payload", "options"),
    [
        ("white-belt-01", 40.0, {}),
        ("incline-line-02", 60.0, {}),
        ("white-belt-01", 40.0, {"elastic": True}),
    ],
)
def test_energy_balance_over_a_cycle(name: str, payload: float, options: dict[str, bool]) -> None:
    """Motor work = friction + losses + gear efficiency losses + ΔKE (standstill to standstill)."""
    p = PlantParameters.from_profile(load_profile(PROFILES / f"{name}.yaml"), payload_kg=payload)
    p = p.replace(**options)
    sp = trapezoid(speed_rad_s=NOMINAL, accel_rad_s2=NOMINAL / 0.5, hold_s=3.0)
    res = simulate(p, sp)
    assert res.success
    dt = p.cycle_s
    w = res.speed
    w_motor = float(np.trapezoid(res.torque * w, dx=dt))
    travel = np.abs(np.diff(res.belt_position_m)).sum()
    lift = res.belt_position_m[-1] - res.belt_position_m[0]
    w_friction = (
        p.mu * G * math.cos(p.incline_rad) * p.moving_mass_kg * travel
        + G * math.sin(p.incline_rad) * p.carried_mass_kg * lift
    )
    w_losses = float(
        np.trapezoid(
            p.loss_constant_nm * np.abs(w)
            + p.loss_viscous_nm_s_rad * w * w
            + p.loss_quadratic_nm_s2_rad2 * np.abs(w) ** 3,
            dx=dt,
        )
    )
    power = res.sprocket_force_n * res.belt_speed_m_s  # delivered to the belt
    eta = p.efficiency
    w_gear = float(
        np.trapezoid(np.where(power > 0.0, power * (1 / eta - 1), -power * (1 - eta)), dx=dt)
    )
    d_ke = 0.5 * p.drive_inertia_kgm2 * (w[-1] ** 2 - w[0] ** 2) + 0.5 * p.moving_mass_kg * (
        res.belt_speed_m_s[-1] ** 2 - res.belt_speed_m_s[0] ** 2
    )
    residual = w_motor - (w_friction + w_losses + w_gear + d_ke)
    print(
        f"\n{name} {options}: motor {w_motor:.3f} J = friction {w_friction:.3f} + losses "
        f"{w_losses:.3f} + gear {w_gear:.3f} + ΔKE {d_ke:.2e}; residual {residual:.4f} J "
        f"({residual / w_motor:.2e})"
    )
    assert abs(residual) < 1e-3 * w_motor
    # net work at the sprocket = friction work (+ ΔKE of the belt, ~0 here)
    w_belt = float(np.trapezoid(power, dx=dt))
    assert w_belt == pytest.approx(w_friction, rel=1e-3)


def test_two_mass_model_rings_at_its_mode(profile: ConveyorProfile) -> None:
    """Free belt (no friction, losses or damping), torque at the limit: spring force rings."""
    p = PlantParameters.from_profile(
        profile,
        payload_kg=40.0,
        elastic=True,
        mu=0.0,
        loss_constant_nm=0.0,
        loss_viscous_nm_s_rad=0.0,
        loss_quadratic_nm_s2_rad2=0.0,
        belt_damping_n_s_m=0.0,
        efficiency=1.0,  # the textbook formula has no gear losses
    )
    n = 801
    speed = np.full(n, 2000.0)  # far above reach: the torque set point sits at the limit
    res = simulate(p, Setpoints(p.cycle_s, speed, integrate_speed(speed, p.cycle_s)))
    assert res.success
    assert res.saturated_cycles == n
    t, force = res.time, res.sprocket_force_n
    window = t > 0.05
    centred = force[window] - force[window].mean()
    tw = t[window]
    idx = np.flatnonzero(np.signbit(centred[:-1]) != np.signbit(centred[1:]))
    crossings = tw[idx] - centred[idx] * (tw[idx + 1] - tw[idx]) / (centred[idx + 1] - centred[idx])
    f_measured = (len(crossings) - 1) / (2.0 * (crossings[-1] - crossings[0]))
    f_expected = p.two_mass_frequency_hz()
    f_locked = math.sqrt(p.belt_stiffness_n_m / p.moving_mass_kg) / (2.0 * math.pi)
    print(
        f"\ntwo-mass mode: measured {f_measured:.3f} Hz, expected {f_expected:.3f} Hz "
        f"(drive locked would be {f_locked:.3f} Hz)"
    )
    assert f_measured == pytest.approx(f_expected, rel=0.01)
    assert abs(f_measured / f_locked - 1.0) > 0.03


def test_chordal_radius_and_polygon_effect(plant: PlantParameters) -> None:
    sp = trapezoid(speed_rad_s=NOMINAL, accel_rad_s2=NOMINAL / 0.5, hold_s=3.0)
    rigid = simulate(plant, sp)
    moved = rigid.position[-1] - rigid.position[0]
    travel = rigid.belt_position_m[-1] - rigid.belt_position_m[0]
    r = plant.chordal_radius_m
    assert travel / moved == pytest.approx(r / plant.ratio, rel=1e-12)
    assert r < plant.pitch_radius_m * 0.99
    # polygon on: belt speed ripples at tooth pass, between R cos(π/z) and R (× ω/i)
    poly = simulate(plant.replace(polygon=True), sp)
    hold = (poly.time > 1.5) & (poly.time < 3.5)
    ratio = poly.belt_speed_m_s[hold] / poly.speed[hold] * plant.ratio
    z = plant.teeth
    big_r = plant.pitch_radius_m
    assert ratio.max() == pytest.approx(big_r, rel=2e-3)
    assert ratio.min() == pytest.approx(big_r * math.cos(math.pi / z), rel=2e-3)
    v = poly.belt_speed_m_s[hold] - poly.belt_speed_m_s[hold].mean()
    spectrum = np.abs(np.fft.rfft(v * np.hanning(v.size)))
    freqs = np.fft.rfftfreq(v.size, plant.cycle_s)
    peak = freqs[np.argmax(spectrum)]
    tooth_pass = NOMINAL / plant.ratio / (2.0 * math.pi) * z
    print(f"\npolygon: belt speed ripple peak {peak:.2f} Hz, tooth pass {tooth_pass:.2f} Hz")
    assert peak == pytest.approx(tooth_pass, abs=1.0 / (v.size * plant.cycle_s))
    # mean travel per motor radian is still the chordal radius over whole teeth
    pitch_motor = 2.0 * math.pi / z * plant.ratio
    teeth_moved = math.floor((poly.position[-1] - poly.position[0]) / pitch_motor)
    assert teeth_moved > 10
    traveled = poly.belt_position_m[-1] - poly.belt_position_m[0]
    assert traveled / (poly.position[-1] - poly.position[0]) == pytest.approx(
        r / plant.ratio, rel=1.0 / teeth_moved
    )


def breakaway_torque(res_torque: np.ndarray, speed: np.ndarray) -> float:
    first = int(np.flatnonzero(speed != 0.0)[0])
    # the belt starts moving during the cycle before the first non-zero speed
    return float(0.5 * (res_torque[first - 1] + res_torque[first]))


def test_stick_slip_raises_the_breakaway_torque(
    profile: ConveyorProfile, plant: PlantParameters
) -> None:
    h = hand(profile)
    sp = trapezoid(speed_rad_s=2.0, accel_rad_s2=0.5, hold_s=1.0, lead_s=0.05)
    kinetic = simulate(plant, sp)
    static = simulate(plant.replace(stick_slip=True), sp)
    t_kin = breakaway_torque(kinetic.torque, kinetic.speed)
    t_stat = breakaway_torque(static.torque, static.speed)
    f = h["mu"] * G * h["m"] * h["r"] / (h["i"] * h["eta"])
    ratio = plant.static_friction_ratio
    print(
        f"\nbreakaway: kinetic {t_kin:.4f} Nm (hand {h['A'] + f:.4f}), stick-slip {t_stat:.4f} Nm "
        f"(hand {h['A'] + ratio * f:.4f})"
    )
    assert t_kin == pytest.approx(h["A"] + f, rel=0.01)
    assert t_stat == pytest.approx(h["A"] + ratio * f, rel=0.01)
    assert np.flatnonzero(static.speed)[0] > np.flatnonzero(kinetic.speed)[0]


def test_payload_step_raises_steady_torque(
    profile: ConveyorProfile, plant: PlantParameters
) -> None:
    h = hand(profile)
    step_kg = 25.0
    p = plant.replace(payload_step_time_s=3.0, payload_step_kg=step_kg)
    sp = trapezoid(speed_rad_s=NOMINAL, accel_rad_s2=NOMINAL / 0.5, hold_s=5.0)
    res = simulate(p, sp)
    before = res.torque[(res.time > 1.5) & (res.time < 2.9)].mean()
    after = res.torque[(res.time > 4.0) & (res.time < 5.5)].mean()
    expected = h["mu"] * G * step_kg * h["r"] / (h["i"] * h["eta"])
    print(f"\npayload step {step_kg} kg: torque +{after - before:.6f} Nm, hand +{expected:.6f} Nm")
    assert after - before == pytest.approx(expected, rel=1e-6)
    # the tray is placed at rest: the belt speed dips (momentum kept)
    k = round(3.0 / p.cycle_s)
    assert res.speed[k + 1] < res.speed[k - 1] - 1.0


def test_torque_lag_after_one_cycle_delay(plant: PlantParameters) -> None:
    tau = plant.torque_time_constant_s
    dt = plant.cycle_s
    k0 = 10
    speed = np.zeros(60)
    speed[k0:] = 3000.0  # the speed controller jumps straight to the torque limit
    res = simulate(plant, Setpoints(dt, speed, integrate_speed(speed, dt)))
    limit = plant.torque_limit_nm
    assert res.torque_setpoint[k0 - 1] == 0.0
    assert res.torque_setpoint[k0] == limit
    # set point of cycle k0 acts from cycle k0 + 1 on: first response at k0 + 2
    assert res.torque[k0] == 0.0
    assert res.torque[k0 + 1] == 0.0
    n = np.arange(0, 8)
    expected = limit * (1.0 - np.exp(-n * dt / tau))
    print(f"\ntorque lag τ = {tau * 1e3} ms: {res.torque[k0 + 1 : k0 + 9] / limit}")
    np.testing.assert_allclose(res.torque[k0 + 1 : k0 + 9], expected, rtol=1e-12, atol=1e-15)
    no_lag = simulate(
        plant.replace(torque_time_constant_s=0.0), Setpoints(dt, speed, integrate_speed(speed, dt))
    )
    assert no_lag.torque[k0 + 1] == 0.0
    assert no_lag.torque[k0 + 2] == limit


def test_downhill_belt_drives_the_motor() -> None:
    """Downhill, little friction: gravity beats friction, the gear runs backwards (η)."""
    p = PlantParameters.from_profile(
        load_profile(PROFILES / "incline-line-02.yaml"),
        payload_kg=100.0,
        incline_rad=-0.3,
        mu=0.05,
    )
    f = physics.belt_force_n(
        mu=p.mu,
        moving_mass_kg=p.moving_mass_kg,
        carried_mass_kg=p.carried_mass_kg,
        incline_rad=p.incline_rad,
    )
    assert f < 0.0  # gravity pulls the belt forward harder than friction holds it
    sp = trapezoid(speed_rad_s=NOMINAL, accel_rad_s2=NOMINAL / 0.5, hold_s=4.0)
    res = simulate(p, sp)
    hold = (res.time > 2.5) & (res.time < 4.5)
    expected_load = f * p.chordal_radius_m * p.efficiency / p.ratio
    np.testing.assert_allclose(res.load_torque_nm[hold], expected_load, rtol=1e-6)
    assert res.torque[hold].mean() == pytest.approx(p.steady_torque_nm(NOMINAL), rel=1e-7)
