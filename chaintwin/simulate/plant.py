"""Parameters of the simulated plant: conveyor, drive controller, realism, faults.

:class:`PlantParameters` is flat, frozen and SI (motor side unless a name
says otherwise). With every realism switch off and no disturbance it is the
rigid identification model of docs/design.md section 2; the switches add what the
rigid model leaves out (elastic belt, polygon effect, stick-slip) and the
disturbances inject faults (bearing/gear ripple, tooth impulses, a local
obstruction, a tray placed on the moving belt).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any, Protocol

from chaintwin import physics
from chaintwin.errors import ModelError
from chaintwin.read.profile import ConveyorProfile, ModelSpec

__all__ = ["DEFAULT_BELT_STIFFNESS_N_M", "PlantParameters", "calibrated_model"]

DEFAULT_BELT_STIFFNESS_N_M = 1.0e6
"""Belt stiffness used when the profile gives neither k nor E·A, N/m."""


class _ByName(Protocol):
    """Identified values looked up by name (a calibration's parameters, a mapping)."""

    def __getitem__(self, name: str, /) -> float: ...


def calibrated_model(model: ModelSpec, parameters: _ByName) -> ModelSpec:
    """A plant model with a calibration's identified friction and losses.

    The one translation from the calibration's vocabulary
    (:attr:`chaintwin.identify.calibration.Calibration.parameters`: ``mu``,
    ``BmA``, ``BmB``, ``BmC``) to the simulation's. Identified losses below
    zero (a fit's scatter around a small value) are simulated as zero; the
    other fields of ``model`` (static friction ratio, stiffness, damping)
    are kept.

    Parameters
    ----------
    model : ModelSpec
        The model to start from (a profile's ``model:`` section).
    parameters : RigidParameters or mapping of str to float
        Looked up by name: ``mu`` (1), ``BmA`` (Nm), ``BmB`` (Nm·s/rad), ``BmC`` (Nm·s²/rad²).

    Returns
    -------
    ModelSpec
        Use with :meth:`PlantParameters.from_profile` (``model=``).
    """
    return model.model_copy(
        update={
            "friction": parameters["mu"],
            "loss_constant_nm": max(parameters["BmA"], 0.0),
            "loss_viscous_nm_s_rad": max(parameters["BmB"], 0.0),
            "loss_quadratic_nm_s2_rad2": max(parameters["BmC"], 0.0),
        }
    )


@dataclass(frozen=True, slots=True)
class PlantParameters:
    """Everything the simulator needs, SI, motor side unless named otherwise.

    Parameters
    ----------
    motor_inertia_kgm2 : float
        Rotor inertia, kg·m² (> 0).
    gear_inertia_kgm2 : float
        Gear unit inertia at the motor shaft, kg·m².
    ratio : float
        Gear ratio i (motor speed / sprocket speed).
    efficiency : float
        Gear efficiency η in (0, 1].
    pitch_radius_m : float
        Sprocket pitch radius R, m.
    teeth : int
        Sprocket teeth z; 0 = unknown (chordal radius = R, no polygon effect).
    belt_mass_kg, tray_mass_kg, payload_kg : float
        Belt loop, tray and payload mass, kg.
    incline_rad : float
        Incline β, rad (positive: conveying uphill).
    loop_length_m : float
        Belt loop length, m (the obstruction repeats every loop).
    mu : float
        Kinetic belt-on-rail friction coefficient μ (profile key ``model.friction``).
    static_friction_ratio : float
        Static over kinetic friction (used when ``stick_slip`` is on).
    loss_constant_nm, loss_viscous_nm_s_rad, loss_quadratic_nm_s2_rad2 : float
        BmA (Nm), BmB (Nm·s/rad), BmC (Nm·s²/rad²).
    torque_time_constant_s : float
        τ of the motor torque lag 1/(1 + sτ), s (0: no lag).
    cycle_s : float
        Controller cycle, s.
    position_gain_1_s : float
        Position controller gain, 1/s.
    speed_gain_nm_s_rad : float
        Speed PI proportional gain Kp, Nm·s/rad.
    speed_integral_time_s : float
        Speed PI integral time Ti, s.
    torque_limit_nm : float
        Torque set point limit, Nm.
    elastic : bool
        Two-mass model (belt as spring and damper) instead of the rigid one.
    belt_stiffness_n_m, belt_damping_n_s_m : float
        Spring k (N/m) and damper c (N·s/m) of the elastic model.
    polygon : bool
        Chordal action: instantaneous radius R·cos φ, φ ∈ [−π/z, π/z).
    stick_slip : bool
        Static friction ``static_friction_ratio·μ`` until breakaway.
    ripple_orders : tuple of float
        Torque ripple orders of the motor angle (cycles per motor revolution).
    ripple_amplitudes_nm : tuple of float
        Ripple amplitudes, Nm, one per order.
    impulse_period_rad : float
        Motor angle between two tooth-damage impulses, rad (0: none).
    impulse_width_rad : float
        Motor-angle width of an impulse, rad.
    impulse_amplitude_nm : float
        Extra resisting torque during an impulse, Nm.
    obstruction_position_m : float
        Belt position (modulo the loop length) where a local friction bump starts, m.
    obstruction_width_m : float
        Length of the bump along the belt, m (0: none).
    obstruction_force_n : float
        Extra resisting force while the bump passes, N.
    payload_step_time_s : float
        Time a tray of ``payload_step_kg`` is placed on the moving belt, s
        (< 0: never). The belt side keeps its momentum.
    payload_step_kg : float
        Mass added at ``payload_step_time_s``, kg (negative: removed).
    back_efficiency : float
        Gear efficiency when the belt drives the motor (power flowing back:
        a decline, a braking ramp), in (0, 1]; 0: the same as ``efficiency``.
        Often lower than the forward one (worm stages far lower).
    stribeck_speed_m_s : float
        With ``stick_slip``: belt speed over which the sliding friction falls
        from the static to the kinetic level (Stribeck curve), m/s; 0: none.

    Raises
    ------
    ModelError
        When a value is out of range; the message names the field.
    """

    motor_inertia_kgm2: float
    gear_inertia_kgm2: float
    ratio: float
    efficiency: float
    pitch_radius_m: float
    teeth: int
    belt_mass_kg: float
    tray_mass_kg: float
    payload_kg: float
    incline_rad: float
    loop_length_m: float
    mu: float
    static_friction_ratio: float
    loss_constant_nm: float
    loss_viscous_nm_s_rad: float
    loss_quadratic_nm_s2_rad2: float
    torque_time_constant_s: float
    cycle_s: float
    position_gain_1_s: float
    speed_gain_nm_s_rad: float
    speed_integral_time_s: float
    torque_limit_nm: float
    elastic: bool = False
    belt_stiffness_n_m: float = DEFAULT_BELT_STIFFNESS_N_M
    belt_damping_n_s_m: float = 200.0
    polygon: bool = False
    stick_slip: bool = False
    ripple_orders: tuple[float, ...] = ()
    ripple_amplitudes_nm: tuple[float, ...] = ()
    impulse_period_rad: float = 0.0
    impulse_width_rad: float = 0.0
    impulse_amplitude_nm: float = 0.0
    obstruction_position_m: float = 0.0
    obstruction_width_m: float = 0.0
    obstruction_force_n: float = 0.0
    payload_step_time_s: float = -1.0
    payload_step_kg: float = 0.0
    back_efficiency: float = 0.0
    stribeck_speed_m_s: float = 0.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "ripple_orders", tuple(float(v) for v in self.ripple_orders))
        object.__setattr__(
            self, "ripple_amplitudes_nm", tuple(float(v) for v in self.ripple_amplitudes_nm)
        )
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if isinstance(value, float) and not math.isfinite(value):
                raise ModelError(f"plant parameters: '{f.name}' is {value}; give a finite number")
        rules: list[tuple[bool, str, str]] = [
            (self.motor_inertia_kgm2 > 0.0, "motor_inertia_kgm2", "must be positive"),
            (self.gear_inertia_kgm2 >= 0.0, "gear_inertia_kgm2", "must not be negative"),
            (self.ratio > 0.0, "ratio", "must be positive"),
            (0.0 < self.efficiency <= 1.0, "efficiency", "must lie in (0, 1]"),
            (
                0.0 <= self.back_efficiency <= 1.0,
                "back_efficiency",
                "must lie in (0, 1] (0: as efficiency)",
            ),
            (self.stribeck_speed_m_s >= 0.0, "stribeck_speed_m_s", "must not be negative"),
            (self.pitch_radius_m > 0.0, "pitch_radius_m", "must be positive"),
            (self.teeth == 0 or self.teeth >= 3, "teeth", "must be 0 (unknown) or at least 3"),
            (self.belt_mass_kg >= 0.0, "belt_mass_kg", "must not be negative"),
            (self.tray_mass_kg >= 0.0, "tray_mass_kg", "must not be negative"),
            (self.payload_kg >= 0.0, "payload_kg", "must not be negative"),
            (abs(self.incline_rad) <= 0.5 * math.pi, "incline_rad", "must lie in [-π/2, π/2]"),
            (self.loop_length_m > 0.0, "loop_length_m", "must be positive"),
            (self.mu >= 0.0, "mu", "must not be negative"),
            (self.static_friction_ratio >= 1.0, "static_friction_ratio", "must be at least 1"),
            (self.loss_constant_nm >= 0.0, "loss_constant_nm", "must not be negative"),
            (self.loss_viscous_nm_s_rad >= 0.0, "loss_viscous_nm_s_rad", "must not be negative"),
            (
                self.loss_quadratic_nm_s2_rad2 >= 0.0,
                "loss_quadratic_nm_s2_rad2",
                "must not be negative",
            ),
            (self.torque_time_constant_s >= 0.0, "torque_time_constant_s", "must not be negative"),
            (self.cycle_s > 0.0, "cycle_s", "must be positive"),
            (self.position_gain_1_s >= 0.0, "position_gain_1_s", "must not be negative"),
            (self.speed_gain_nm_s_rad > 0.0, "speed_gain_nm_s_rad", "must be positive"),
            (self.speed_integral_time_s > 0.0, "speed_integral_time_s", "must be positive"),
            (self.torque_limit_nm > 0.0, "torque_limit_nm", "must be positive"),
            (self.belt_stiffness_n_m > 0.0, "belt_stiffness_n_m", "must be positive"),
            (self.belt_damping_n_s_m >= 0.0, "belt_damping_n_s_m", "must not be negative"),
            (
                len(self.ripple_orders) == len(self.ripple_amplitudes_nm),
                "ripple_amplitudes_nm",
                "must have one amplitude per ripple order",
            ),
            (
                all(math.isfinite(o) and o > 0.0 for o in self.ripple_orders),
                "ripple_orders",
                "must be positive and finite",
            ),
            (
                all(math.isfinite(a) for a in self.ripple_amplitudes_nm),
                "ripple_amplitudes_nm",
                "must be finite",
            ),
            (self.impulse_period_rad >= 0.0, "impulse_period_rad", "must not be negative"),
            (
                0.0 <= self.impulse_width_rad <= max(self.impulse_period_rad, 0.0),
                "impulse_width_rad",
                "must lie between 0 and impulse_period_rad",
            ),
            (
                self.impulse_amplitude_nm == 0.0
                or (self.impulse_period_rad > 0.0 and self.impulse_width_rad > 0.0),
                "impulse_amplitude_nm",
                "needs a positive impulse_period_rad and impulse_width_rad",
            ),
            (self.obstruction_width_m >= 0.0, "obstruction_width_m", "must not be negative"),
            (
                self.obstruction_width_m <= self.loop_length_m,
                "obstruction_width_m",
                "must not exceed the loop length",
            ),
            (self.obstruction_force_n >= 0.0, "obstruction_force_n", "must not be negative"),
            (
                self.payload_kg + self.payload_step_kg >= 0.0,
                "payload_step_kg",
                "cannot remove more than the payload",
            ),
            (
                not self.elastic or self.moving_mass_kg > 0.0,
                "belt_mass_kg",
                "the elastic model needs a positive belt-side mass",
            ),
        ]
        for ok, name, what in rules:
            if not ok:
                raise ModelError(f"plant parameters: '{name}' {what} (got {getattr(self, name)})")

    # ------------------------------------------------------------ builders
    @classmethod
    def from_profile(
        cls,
        profile: ConveyorProfile,
        *,
        payload_kg: float = 0.0,
        model: ModelSpec | None = None,
        **overrides: Any,
    ) -> PlantParameters:
        """Build the plant of a conveyor profile.

        Parameters
        ----------
        profile : ConveyorProfile
            The conveyor's known data.
        payload_kg : float
            Payload on the belt, kg.
        model : ModelSpec, optional
            Friction, losses, stiffness and damping; defaults to the
            profile's ``model`` section, else :class:`ModelSpec`'s documented
            typical values (the reference conveyor's).
        **overrides
            Any field of :class:`PlantParameters` (``elastic=True``,
            ``mu=0.3``, ...).

        Returns
        -------
        PlantParameters

        Raises
        ------
        ModelError
            When the torque limit cannot be known (give
            ``controller.torque_limit_nm`` or ``motor.nominal_torque_nm`` in
            the profile, or ``torque_limit_nm=`` here), for an unknown
            override or an invalid value.

        Notes
        -----
        Belt stiffness: ``model.belt_stiffness_n_m`` when given, else E·A/L
        from the belt data, else 1e6 N/m.
        """
        spec = model if model is not None else (profile.model or ModelSpec())
        if spec.belt_stiffness_n_m is not None:
            stiffness = spec.belt_stiffness_n_m
        else:
            b = profile.belt
            if b.youngs_modulus_pa is not None and b.cross_section_m2 is not None:
                stiffness = b.youngs_modulus_pa * b.cross_section_m2 / b.length_m
            else:
                stiffness = DEFAULT_BELT_STIFFNESS_N_M
        limit = profile.torque_limit_nm
        if limit is None and "torque_limit_nm" not in overrides:
            raise ModelError(
                f"profile '{profile.id}': the torque limit is unknown; give "
                "controller.torque_limit_nm or motor.nominal_torque_nm in the profile, "
                "or torque_limit_nm= to the plant"
            )
        c = profile.controller
        base = cls(
            motor_inertia_kgm2=profile.motor.inertia_kgm2,
            # what the profile does not list (sprockets, shafts) turns with the gear
            gear_inertia_kgm2=profile.gear.inertia_kgm2 + spec.unlisted_inertia_kgm2,
            ratio=profile.kinematic_ratio,
            efficiency=profile.gear.efficiency,
            pitch_radius_m=profile.pitch_radius_m,
            teeth=profile.sprocket.teeth or 0,
            belt_mass_kg=profile.belt_mass_kg,
            tray_mass_kg=profile.tray_mass_kg,
            payload_kg=payload_kg,
            incline_rad=profile.incline_rad,
            loop_length_m=profile.loop_length_m,
            mu=spec.friction,
            static_friction_ratio=spec.static_friction_ratio,
            loss_constant_nm=spec.loss_constant_nm,
            loss_viscous_nm_s_rad=spec.loss_viscous_nm_s_rad,
            loss_quadratic_nm_s2_rad2=spec.loss_quadratic_nm_s2_rad2,
            torque_time_constant_s=profile.motor.torque_time_constant_s,
            cycle_s=c.cycle_s,
            position_gain_1_s=c.position_gain_1_s,
            speed_gain_nm_s_rad=c.speed_gain_nm_s_rad,
            speed_integral_time_s=c.speed_integral_time_s,
            torque_limit_nm=limit if limit is not None else 1.0,
            belt_stiffness_n_m=stiffness,
            belt_damping_n_s_m=spec.belt_damping_n_s_m,
            back_efficiency=spec.back_efficiency or 0.0,
            stribeck_speed_m_s=spec.stribeck_speed_m_s,
        )
        return base.replace(**overrides) if overrides else base

    def replace(self, **changes: Any) -> PlantParameters:
        """A copy with some fields changed (validated again).

        Raises
        ------
        ModelError
            For an unknown field name or an invalid value.
        """
        names = {f.name for f in dataclasses.fields(self)}
        unknown = sorted(set(changes) - names)
        if unknown:
            raise ModelError(
                f"plant parameters: unknown field(s) {', '.join(unknown)}; "
                f"valid fields are {', '.join(sorted(names))}"
            )
        return dataclasses.replace(self, **changes)

    # ------------------------------------------------------------- derived
    @property
    def chordal_radius_m(self) -> float:
        """Chordal mean radius r = R·sin(π/z)/(π/z), m (R when z is unknown)."""
        return physics.chordal_radius_m(self.pitch_radius_m, self.teeth)

    @property
    def belt_speed_per_motor_speed(self) -> float:
        """Mean belt speed per motor speed, r/i, (m/s)/(rad/s)."""
        return self.chordal_radius_m / self.ratio

    @property
    def moving_mass_kg(self) -> float:
        """Belt + tray + payload, kg (before any payload step)."""
        return self.belt_mass_kg + self.tray_mass_kg + self.payload_kg

    @property
    def carried_mass_kg(self) -> float:
        """Tray + payload (the mass that climbs an incline), kg."""
        return self.tray_mass_kg + self.payload_kg

    @property
    def drive_inertia_kgm2(self) -> float:
        """Motor + gear inertia at the motor shaft, kg·m²."""
        return self.motor_inertia_kgm2 + self.gear_inertia_kgm2

    @property
    def polygon_active(self) -> bool:
        """Whether the polygon effect is simulated (switched on and z known)."""
        return self.polygon and self.teeth > 0

    @property
    def is_plain_rigid(self) -> bool:
        """True for the rigid identification model with no fault injected.

        Such plants run on the lean kernel (``_kernel.plain_kernel``).
        """
        return not (
            self.elastic
            or (self.stick_slip and self.stribeck_speed_m_s > 0.0)
            or self.polygon_active
            or self.ripple_orders
            or self.impulse_amplitude_nm != 0.0
            or (self.obstruction_width_m > 0.0 and self.obstruction_force_n > 0.0)
        )

    def reflected_inertia_kgm2(self, *, motoring: bool = True) -> float:
        """Rigid-model inertia at the motor, kg·m² (see :mod:`chaintwin.physics`)."""
        return physics.reflected_inertia_kgm2(
            motor_inertia_kgm2=self.motor_inertia_kgm2,
            gear_inertia_kgm2=self.gear_inertia_kgm2,
            moving_mass_kg=self.moving_mass_kg,
            radius_m=self.chordal_radius_m,
            ratio=self.ratio,
            efficiency=self.efficiency,
            motoring=motoring,
        )

    def steady_torque_nm(self, speed_rad_s: float) -> float:
        """Rigid-model motor torque at a constant speed, Nm."""
        return physics.steady_torque_nm(
            speed_rad_s=speed_rad_s,
            mu=self.mu,
            moving_mass_kg=self.moving_mass_kg,
            carried_mass_kg=self.carried_mass_kg,
            incline_rad=self.incline_rad,
            radius_m=self.chordal_radius_m,
            ratio=self.ratio,
            efficiency=self.efficiency,
            loss_constant_nm=self.loss_constant_nm,
            loss_viscous_nm_s_rad=self.loss_viscous_nm_s_rad,
            loss_quadratic_nm_s2_rad2=self.loss_quadratic_nm_s2_rad2,
        )

    def two_mass_frequency_hz(self) -> float:
        """Belt mode of the elastic model, Hz."""
        return physics.two_mass_frequency_hz(
            drive_inertia_kgm2=self.drive_inertia_kgm2,
            ratio=self.ratio,
            radius_m=self.chordal_radius_m,
            belt_mass_kg=self.moving_mass_kg,
            stiffness_n_m=self.belt_stiffness_n_m,
        )
