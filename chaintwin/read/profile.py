"""Conveyor profiles: what the engineer knows of a conveyor, validated.

A profile is a YAML file per conveyor (docs/data-contract.md, section 2), in SI
except where a field's name says otherwise (``_deg``, ``_rpm``). Unknown
fields are refused (a typo must not silently fall back to a default), and
every error names the field path.

Documented defaults for optional fields
---------------------------------------
=====================================  ==========  ==============================
field                                  default     note
=====================================  ==========  ==============================
belt.incline_deg                       0.0         flat conveyor
belt.youngs_modulus_pa, density,       none        only for belt natural
cross_section_m2                                   frequencies / stiffness
sprocket.teeth                         none        unknown: chordal radius = R
gear.efficiency                        0.95        typical helical gear unit
gear.inertia_kgm2                      0.0         referred to the motor shaft
gear.stages                            none        tooth counts per stage
motor.nominal_torque_nm                none        needed for ``%`` torque
motor.nominal_speed_rpm                none
motor.torque_time_constant_s           0.001       typical current loop
controller.cycle_s                     0.001
controller.position_gain_1_s           20.0
controller.speed_gain_nm_s_rad         0.2
controller.speed_integral_time_s       0.05
controller.torque_limit_nm             3 × nominal torque when known, else none
belt.tension_n                         none        lateral (string) modes of the
                                                   free strands left out
tray_mass_kg                           0.0         no carrier
model                                  none        simulation only
limits                                 none        statistical alarms only
expected_wear                          none        no wear expected with usage
=====================================  ==========  ==============================

``limits:`` sets engineer-chosen absolute limits per monitored feature, in
the feature's own units: ``limits: {friction: {warn: 1.15, alarm: 1.30, rule:
x_of_y}}`` (:class:`LimitSpec`). Profiles without ``limits`` or
``belt.tension_n`` keep the content hash they had before these fields existed.

``expected_wear:`` gives the change of a monitored feature that usage is
expected to cause, in the feature's units per t·km carried
(``expected_wear: {friction: 0.004}``): the monitor judges the feature after
taking off that rate times the usage since the baseline, so a heavily loaded
conveyor's faster, expected wear does not alarm
(:mod:`chaintwin.diagnose.wear` reports each feature's measured rate per
t·km, which is where a fleet's typical value comes from). Left out of the
content hash when absent, like ``limits``.

The optional ``model:`` section describes a plant for simulation; the
identification, calibration and weighing code never reads it.
"""

from __future__ import annotations

import hashlib
import json
import math
from pathlib import Path
from typing import Annotated, Any, ClassVar, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from chaintwin import physics
from chaintwin.errors import ProfileError
from chaintwin.read.files import read_limited, yaml_load
from chaintwin.read.integers import refuse_huge_integers

__all__ = [
    "MAX_ID_LENGTH",
    "BeltSpec",
    "ControllerSpec",
    "ConveyorProfile",
    "GearSpec",
    "LimitSpec",
    "ModelSpec",
    "MotorSpec",
    "SprocketSpec",
    "load_profile",
    "load_profiles",
    "parse_profile",
]

# numbers must be numbers: strict, so that YAML's true or "1.5" are refused, not read as 1.0
Positive = Annotated[float, Field(gt=0.0, allow_inf_nan=False, strict=True)]
NonNegative = Annotated[float, Field(ge=0.0, allow_inf_nan=False, strict=True)]


class _Spec(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class BeltSpec(_Spec):
    """The chain belt and its conveying path."""

    length_m: Positive
    """Conveying length between sprocket centres, m."""
    mass_per_m_kg: Positive
    """Chain belt mass per metre of belt, kg/m."""
    incline_deg: Annotated[float, Field(ge=-90.0, le=90.0, strict=True)] = 0.0
    """Incline, degrees; positive when conveying uphill."""
    youngs_modulus_pa: Positive | None = None
    """Belt material Young's modulus, Pa (optional)."""
    density_kg_m3: Positive | None = None
    """Belt material density, kg/m³ (optional)."""
    cross_section_m2: Positive | None = None
    """Load-bearing cross-section of the belt, m² (optional)."""
    tension_n: Positive | None = None
    """Static pretension of the free strands, N (optional; for their lateral modes)."""


class SprocketSpec(_Spec):
    """The drive sprocket."""

    pitch_diameter_m: Positive
    """Pitch diameter d, m."""
    teeth: Annotated[int, Field(ge=3, le=200, strict=True)] | None = None
    """Number of teeth z (optional; unknown means no chordal correction)."""


class GearSpec(_Spec):
    """The gear unit between motor and sprocket."""

    ratio: Positive
    """Gear ratio i = motor speed / output speed."""
    efficiency: Annotated[float, Field(gt=0.0, le=1.0, strict=True)] = 0.95
    """Efficiency η while the motor drives the belt."""
    inertia_kgm2: NonNegative = 0.0
    """Gear unit inertia referred to the motor shaft, kg·m²."""
    stages: (
        list[
            tuple[
                Annotated[int, Field(ge=1, strict=True)], Annotated[int, Field(ge=1, strict=True)]
            ]
        ]
        | None
    ) = None
    """Pinion and gear tooth counts per stage, motor side first (optional)."""

    @model_validator(mode="after")
    def _stages_match_ratio(self) -> GearSpec:
        if self.stages:
            product = math.prod(g / p for p, g in self.stages)
            if abs(product / self.ratio - 1.0) > 0.02:
                raise ValueError(
                    f"the stages' tooth ratios multiply to {product:.4g}, not the ratio "
                    f"{self.ratio:.4g}; correct gear.stages or gear.ratio"
                )
        return self


class MotorSpec(_Spec):
    """The motor."""

    inertia_kgm2: Positive
    """Rotor inertia, kg·m²."""
    nominal_torque_nm: Positive | None = None
    """Nominal torque, Nm; needed to read torque in ``%``."""
    nominal_speed_rpm: Positive | None = None
    """Nominal speed, rpm."""
    torque_time_constant_s: NonNegative = 0.001
    """Time constant τ of the torque lag 1/(1 + sτ), s."""


class ControllerSpec(_Spec):
    """The drive's cascade controller as parametrised."""

    cycle_s: Annotated[float, Field(gt=0.0, le=0.1)] = 0.001
    """Controller cycle, s."""
    position_gain_1_s: NonNegative = 20.0
    """Position controller gain, 1/s."""
    speed_gain_nm_s_rad: Positive = 0.2
    """Speed controller proportional gain, Nm·s/rad."""
    speed_integral_time_s: Positive = 0.05
    """Speed controller integral time, s."""
    torque_limit_nm: Positive | None = None
    """Torque limit, Nm (default: 3 × the motor's nominal torque)."""


class ModelSpec(_Spec):
    """What identification normally finds: for simulation only.

    Defaults are the published reference conveyor's values.
    """

    friction: Annotated[float, Field(ge=0.0, le=2.0, strict=True)] = 0.23
    """Kinetic belt-on-rail friction coefficient μ."""
    static_friction_ratio: Annotated[float, Field(ge=1.0, le=5.0)] = 1.2
    """Static over kinetic friction coefficient."""
    loss_constant_nm: NonNegative = 1.1e-4
    """BmA: constant (Coulomb) gear/motor loss torque, Nm."""
    loss_viscous_nm_s_rad: NonNegative = 2.1e-3
    """BmB: speed-proportional loss, Nm/(rad/s)."""
    loss_quadratic_nm_s2_rad2: NonNegative = 2.0e-6
    """BmC: speed-squared loss, Nm/(rad/s)²."""
    belt_stiffness_n_m: Positive | None = None
    """Belt stiffness k, N/m (default: E·A/L from the belt data)."""
    belt_damping_n_s_m: NonNegative = 200.0
    """Belt damping, N·s/m."""
    back_efficiency: Annotated[float, Field(gt=0.0, le=1.0)] | None = None
    """Gear efficiency when the belt drives the motor (decline, braking), 1
    (default: the gear's ``efficiency``)."""
    stribeck_speed_m_s: NonNegative = 0.0
    """Belt speed over which the sliding friction falls from static to
    kinetic (Stribeck curve), m/s (0: none)."""
    unlisted_inertia_kgm2: NonNegative = 0.0
    """Inertia at the motor shaft the profile does not list (sprockets,
    shafts, couplings), kg·m²."""

    #: Fields added after calibration files embedding profiles existed: left
    #: out of :meth:`ConveyorProfile.content_hash` while at their defaults.
    LATER_FIELDS: ClassVar[dict[str, object]] = {
        "back_efficiency": None,
        "stribeck_speed_m_s": 0.0,
        "unlisted_inertia_kgm2": 0.0,
    }


MAX_ID_LENGTH = 100
"""Longest conveyor id, characters (it names files, store rows and pages)."""


class LimitSpec(_Spec):
    """An engineer-set absolute limit of one monitored feature, in its own units.

    A value above ``warn`` attaches a warning to the recording's result; above
    ``alarm`` it counts as an exceedance, alarmed by ``rule``: ``x_of_y`` as
    the statistical alarms (X exceedances in the last Y recordings), or
    ``immediate`` (the first recording above it). Limits are upper limits.
    """

    warn: Annotated[float, Field(allow_inf_nan=False, strict=True)] | None = None
    """Warning level, feature units (optional)."""
    alarm: Annotated[float, Field(allow_inf_nan=False, strict=True)] | None = None
    """Alarm level, feature units (optional)."""
    rule: Literal["x_of_y", "immediate"] = "x_of_y"
    """How exceedances of ``alarm`` raise an alarm."""

    @model_validator(mode="after")
    def _levels(self) -> LimitSpec:
        if self.warn is None and self.alarm is None:
            raise ValueError("give warn, alarm or both")
        if self.warn is not None and self.alarm is not None and self.warn > self.alarm:
            raise ValueError(f"warn {self.warn:g} lies above alarm {self.alarm:g}")
        return self


class ConveyorProfile(_Spec):
    """A conveyor's known data (docs/data-contract.md, section 2), validated.

    Derived quantities are properties in SI units.
    """

    id: Annotated[str, Field(min_length=1, max_length=MAX_ID_LENGTH)]
    """The conveyor's id: 1 to :data:`MAX_ID_LENGTH` characters."""
    belt: BeltSpec
    sprocket: SprocketSpec
    gear: GearSpec
    motor: MotorSpec
    controller: ControllerSpec = ControllerSpec()
    tray_mass_kg: NonNegative = 0.0
    """Carrier mass that is not payload, kg."""
    model: ModelSpec | None = None
    """Plant parameters for simulation only; never read by identification."""
    limits: dict[Annotated[str, Field(min_length=1, max_length=100)], LimitSpec] | None = None
    """Absolute limits per monitored feature name (optional)."""
    expected_wear: dict[Annotated[str, Field(min_length=1, max_length=100)], NonNegative] | None = (
        None
    )
    """Expected change per t·km of usage per monitored feature, its units per t·km (optional)."""
    zero_tracking: Annotated[bool, Field(strict=True)] = False
    """Experimental: ingest, monitor and the live service track the gear losses' drift from
    known runs (recordings with metadata ``payload_kg``, :mod:`chaintwin.weigh.zero_tracking`);
    off by default (the history alone then narrows the loss-drift allowance)."""

    # ---------------------------------------------------------------- derived
    @property
    def pitch_radius_m(self) -> float:
        """Sprocket pitch radius R = d/2, m."""
        return self.sprocket.pitch_diameter_m / 2.0

    @property
    def chordal_radius_m(self) -> float:
        """Chordal mean radius r = R·sin(π/z)/(π/z), m (R when z is unknown).

        A chain advances r per sprocket radian on average
        (:func:`chaintwin.physics.chordal_radius_m`).
        """
        return physics.chordal_radius_m(self.pitch_radius_m, self.sprocket.teeth)

    @property
    def kinematic_ratio(self) -> float:
        """Gear ratio i as the gear's teeth make it: motor over sprocket speed.

        The product of the stages' tooth ratios ``Π(gear/pinion)`` when
        ``gear.stages`` is given (exact integers), else the nameplate
        ``gear.ratio`` (rounded; the profile accepts up to 2 % between the
        two). Every computation uses this one, so that the simulator and the
        analysis turn motor angle into belt travel alike.
        """
        stages = self.gear.stages
        if stages:
            return math.prod(g / p for p, g in stages)
        return self.gear.ratio

    @property
    def loop_length_m(self) -> float:
        """Belt loop length 2L + π·d, m."""
        return 2.0 * self.belt.length_m + math.pi * self.sprocket.pitch_diameter_m

    @property
    def belt_mass_kg(self) -> float:
        """Belt mass m_b = q·(2L + π·d), kg."""
        return self.belt.mass_per_m_kg * self.loop_length_m

    @property
    def incline_rad(self) -> float:
        """Incline β, rad."""
        return math.radians(self.belt.incline_deg)

    @property
    def belt_speed_per_motor_speed(self) -> float:
        """Mean belt speed per motor speed, r/i, in (m/s)/(rad/s)."""
        return self.chordal_radius_m / self.kinematic_ratio

    @property
    def nominal_torque_nm(self) -> float | None:
        """Motor nominal torque, Nm, when known."""
        return self.motor.nominal_torque_nm

    @property
    def torque_limit_nm(self) -> float | None:
        """Drive torque limit, Nm: as parametrised, else 3 × nominal, else None."""
        if self.controller.torque_limit_nm is not None:
            return self.controller.torque_limit_nm
        if self.motor.nominal_torque_nm is not None:
            return 3.0 * self.motor.nominal_torque_nm
        return None

    def moving_mass_kg(self, payload_kg: float = 0.0) -> float:
        """Mass moved by the belt: belt + tray + payload, kg."""
        return self.belt_mass_kg + self.tray_mass_kg + payload_kg

    def reflected_inertia_kgm2(self, payload_kg: float = 0.0, *, motoring: bool = True) -> float:
        """Inertia at the motor shaft, kg·m².

        ``J = J_motor + J_gear + (m_b + m_t + m_p)·r²/(i²·η)`` while motoring;
        with ``·η`` instead of ``/η`` when the belt drives the motor.

        Parameters
        ----------
        payload_kg : float
            Payload on the belt, kg.
        motoring : bool
            True while power flows from the motor to the belt.
        """
        return physics.reflected_inertia_kgm2(
            motor_inertia_kgm2=self.motor.inertia_kgm2,
            gear_inertia_kgm2=self.gear.inertia_kgm2,
            moving_mass_kg=self.moving_mass_kg(payload_kg),
            radius_m=self.chordal_radius_m,
            ratio=self.kinematic_ratio,
            efficiency=self.gear.efficiency,
            motoring=motoring,
        )

    def belt_stiffness_n_m(self) -> float | None:
        """Belt stiffness k, N/m: ``model.belt_stiffness_n_m``, else E·A/L, else None."""
        if self.model is not None and self.model.belt_stiffness_n_m is not None:
            return self.model.belt_stiffness_n_m
        b = self.belt
        if b.youngs_modulus_pa is not None and b.cross_section_m2 is not None:
            return b.youngs_modulus_pa * b.cross_section_m2 / b.length_m
        return None

    def content_hash(self) -> str:
        """SHA-256 of the profile's canonical JSON form (defaults filled in).

        Model fields added later are hashed only when set, so that the
        hashes of profiles written before them stay what they were.
        """
        data = self.model_dump(mode="json")
        # fields added later: hashed only when set
        if data.get("limits") is None:
            data.pop("limits", None)
        if data.get("expected_wear") is None:
            data.pop("expected_wear", None)
        if data["belt"].get("tension_n") is None:
            data["belt"].pop("tension_n", None)
        if data.get("zero_tracking") is False:
            data.pop("zero_tracking", None)
        model = data.get("model")
        if isinstance(model, dict):
            for name, default in ModelSpec.LATER_FIELDS.items():
                if model.get(name) == default:
                    del model[name]
        text = json.dumps(data, sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(text.encode()).hexdigest()


def _format_validation_error(source: str, exc: ValidationError) -> str:
    parts = []
    for err in exc.errors()[:3]:
        path = ".".join(str(p) for p in err["loc"]) or "(top level)"
        # a key the file spells with a line break or other control character: shown
        # escaped, so that the error stays on one line
        path = "".join(c if c.isprintable() else repr(c)[1:-1] for c in path)
        kind = err["type"]
        msg = " ".join(str(err["msg"]).split())
        if kind == "missing":
            hint = "add it"
        elif kind == "extra_forbidden":
            msg = "unknown field"
            hint = "remove it or correct its spelling"
        else:
            hint = "correct it"
        parts.append(f"field '{path}': {msg}; {hint}")
    more = len(exc.errors()) - 3
    tail = f" (and {more} more)" if more > 0 else ""
    return f"{source}: " + "; ".join(parts) + tail


def parse_profile(data: Any, source: str = "<profile>") -> ConveyorProfile:
    """Validate a profile given as parsed YAML (a mapping).

    Parameters
    ----------
    data : Any
        The parsed YAML document.
    source : str
        Where it came from, for messages.

    Raises
    ------
    ProfileError
        With the field path and what to do.
    """
    refuse_huge_integers(data, source, ProfileError, "profile")
    if not isinstance(data, dict):
        raise ProfileError(
            f"{source}: a profile must be a YAML mapping with id, belt, sprocket, gear "
            "and motor sections"
        )
    try:
        return ConveyorProfile.model_validate(data)
    except ValidationError as exc:
        raise ProfileError(_format_validation_error(source, exc)) from None


def load_profile(path: str | Path) -> ConveyorProfile:
    """Read and validate a conveyor profile YAML file.

    Raises
    ------
    ProfileError
        When the file cannot be read, is not YAML, or fails validation.
    """
    source = str(path)
    raw = read_limited(path, what="profile", error=lambda s, m: ProfileError(f"{s}: {m}"))
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ProfileError(f"{source}: cannot read the profile ({exc}); save it as UTF-8") from None
    try:
        data = yaml_load(text)
    except RecursionError:
        raise ProfileError(f"{source}: nested too deeply to be a profile") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f", line {mark.line + 1}" if mark is not None else ""
        raise ProfileError(f"{source}{where}: not valid YAML; fix the syntax") from None
    return parse_profile(data, source)


def load_profiles(folder: str | Path) -> dict[str, ConveyorProfile]:
    """Read every ``*.yaml``/``*.yml`` profile in a folder, keyed by ``id``.

    Raises
    ------
    ProfileError
        When a file is invalid, two files share an id, or none is found.
    """
    root = Path(folder)
    if not root.is_dir():
        raise ProfileError(f"{root}: not a folder of profiles; give the folder that holds them")
    found: dict[str, ConveyorProfile] = {}
    where: dict[str, Path] = {}
    for path in sorted([*root.glob("*.yaml"), *root.glob("*.yml")]):
        profile = load_profile(path)
        if profile.id in found:
            raise ProfileError(
                f"{path}: id '{profile.id}' is also the id of {where[profile.id]}; "
                "give each conveyor its own id"
            )
        found[profile.id] = profile
        where[profile.id] = path
    if not found:
        raise ProfileError(f"{root}: no *.yaml profile found in this folder")
    return found
