"""Calibration: a conveyor's parameters learned from known-load runs, and their file.

This module holds the :class:`Calibration` record, its file format and the
checks made when one is read; :func:`chaintwin.calibrating.procedure.calibrate`
makes one. It fits :class:`~chaintwin.identify.regression.RigidModelRegression`
to recordings whose metadata holds ``payload_kg`` (an empty tray at least),
identifies the torque lag where a recording at the controller cycle allows,
and judges its own data: how well the payload sensitivity (torque per kg,
``g·(μ·cosβ + sinβ)·r/(i·η)``) is determined, and which run would improve it.

Which case the data is in
-------------------------
``several_loads``
    Known loads that differ: the slope of torque in load is μ itself. The
    sensitivity is measured, not inferred; this is the belt-scale protocol.
``one_load_several_speeds``
    One load at two or more plateau speeds: the speed-dependent gear losses
    are separated from friction by the plateaus. μ still includes BmA
    (fixed to 0), which is typically well under 1 % of the friction torque.
``one_load_one_speed``
    One load at one speed (the published method): μ is separated from the
    speed-dependent losses only by the ramps, the least clean part of the
    recording; the sensitivity's uncertainty says how much that costs.
``learned``
    Learned from the conveyor's operation, payloads unknown
    (:func:`chaintwin.diagnose.learned.learn_calibration`): each payload is
    read from its recording's inertia with the datasheet inertia, so every
    weight is offset by that inertia's error. Good for monitoring against
    the conveyor's own baseline, not for weighing.

The calibration file is JSON (``format: chaintwin.calibration``, versioned),
self-contained: it embeds the profile and its hash so that weighing needs
nothing else, the recordings used (with content hashes), the parameters with
their covariance, the method and the chaintwin version.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from chaintwin.errors import CalibrationError
from chaintwin.identify.channels import TORQUE_CHANNELS, ChannelSpreads
from chaintwin.identify.regression import speed_clusters
from chaintwin.identify.zero_reference import ZeroReference
from chaintwin.model.rigid import (
    PARAMETER_NAMES,
    RigidParameters,
    drive_inertia_at,
    incline_terms,
)
from chaintwin.physics import payload_sensitivity_nm_kg
from chaintwin.read.files import read_limited, write_atomic
from chaintwin.read.integers import json_loads, refuse_huge_integers
from chaintwin.read.profile import ConveyorProfile, parse_profile
from chaintwin.read.recording import RecordingWarning
from chaintwin.units import RPM_TO_RAD_S

__all__ = [
    "CALIBRATION_CASES",
    "CALIBRATION_FORMAT",
    "CALIBRATION_VERSION",
    "Calibration",
    "broken_invariant",
    "identification_profile",
    "load_calibration",
    "sensitivity_nm_per_kg",
]

CALIBRATION_CASES = ("one_load_one_speed", "one_load_several_speeds", "several_loads", "learned")
"""The protocols a calibration can come from (its ``case``)."""

CALIBRATION_FORMAT = "chaintwin.calibration"
CALIBRATION_VERSION = 1

INERTIA_GAIN_PRIOR_SIGMA = 0.08
"""Prior uncertainty of the inertia signature's gain (1 by physics). The rigid
model misreads an elastic belt's start and stop as less inertia: on the
virtual conveyor up to 6 % of the payload at 100 kg. Known loads that differ
measure the gain; the estimate is combined with this prior."""

INERTIA_MODEL_REL = 0.05
"""Relative model error of the inertia signature beyond its calibrated gain. An
elastic belt on a polygonal sprocket rings at tooth pass and dissipates
energy in a way that grows faster than linearly with the load; on the virtual
conveyor this reads up to 19 % low at 100 kg on a short fast belt with an
8-tooth sprocket, about 2-6 % on the other example conveyors."""


def identification_profile(profile: ConveyorProfile) -> ConveyorProfile:
    """The profile without its ``model:`` section: what identification may read."""
    return profile.model_copy(update={"model": None})


def sensitivity_nm_per_kg(profile: ConveyorProfile, mu: float) -> float:
    """Payload sensitivity while motoring: ``g·(μ·cosβ + sinβ)·r/(i·η)``, Nm/kg.

    :func:`~chaintwin.physics.payload_sensitivity_nm_kg` with the
    profile's incline, chordal radius, gear ratio and efficiency.
    """
    return payload_sensitivity_nm_kg(
        mu=mu,
        incline_rad=profile.incline_rad,
        radius_m=profile.chordal_radius_m,
        ratio=profile.kinematic_ratio,
        efficiency=profile.gear.efficiency,
    )


@dataclass(frozen=True)
class Calibration:
    """A conveyor's calibrated parameters, self-contained.

    Parameters
    ----------
    profile : ConveyorProfile
        The profile calibrated (as given; identification used it without
        its ``model:`` section).
    parameters : RigidParameters
        J_d (kg·m²), μ, BmA (Nm), BmB (Nm·s/rad), BmC (Nm·s²/rad²), covariance.
    case : str
        ``several_loads``, ``one_load_several_speeds``, ``one_load_one_speed``
        or ``learned`` (see the module docstring).
    recordings : list of dict
        ``file``, ``sha256``, ``payload_kg``, ``tray_kg``, ``sample_time_s``,
        ``recorded_at``, ``plateau_speed_rpm`` of each recording used.
    torque_lag_s, torque_lag_stderr_s : float or None
        Motor torque lag, when a recording at the controller cycle allowed it.
    residual_rms_nm : float
        Model residual, Nm.
    inertia_gain, inertia_gain_sigma : float
        How the raw inertia-signature payload reads a known payload p on this
        conveyor, ``raw = offset + gain·p``: the gain (physics says 1, with a
        prior uncertainty :data:`INERTIA_GAIN_PRIOR_SIGMA`; known loads that
        differ refine it) and its standard uncertainty.
    inertia_offset_kg, inertia_offset_sigma_kg : float
        The offset (raw reading of an empty tray) and its uncertainty, kg.
    friction_drift : float
        Standard uncertainty of the rail friction μ relative to this
        calibration's that weighing carries into the friction signature's
        variance, 1 (``calibrate --friction-drift``; 0: the calibration's
        rail friction is trusted, as in files written before this field).
    torque_channel : str
        The torque weighing reads (:data:`~chaintwin.identify.channels.TORQUE_CHANNELS`):
        ``torque`` (the actual torque), ``torque_setpoint`` or ``combined``;
        the parameters are those fitted on it.
    channel_spreads : ChannelSpreads or None
        The residual spread of each channel on the calibration's recordings
        that chose it (None: the recordings hold no set point).
    actual_torque : Calibration or None
        The calibration on the actual torque, when ``torque_channel`` is
        another: a recording without a set point is weighed with it.
    ramp_noise_rate : float
        How well whole-ramp windows fit on this conveyor: residual variance
        per second of window, (N·m·s)²/s; weighing weights them with it.
    zero_reference : ZeroReference or None
        What the calibration's own recordings read as loss drift at their
        known payloads (the reference zero of zero tracking,
        :mod:`chaintwin.identify.zero_reference`); None in files written
        before it (zero tracking from known runs then needs a recalibration).
    warnings : tuple of RecordingWarning
        What the calibration found questionable.
    method : str
        How the parameters were obtained.
    created_at : str
        ISO 8601 UTC.
    chaintwin_version : str
        Version that wrote it.
    """

    profile: ConveyorProfile
    parameters: RigidParameters
    case: str
    recordings: list[dict[str, Any]]
    torque_lag_s: float | None = None
    torque_lag_stderr_s: float | None = None
    residual_rms_nm: float = float("nan")
    inertia_gain: float = 1.0
    inertia_gain_sigma: float = INERTIA_GAIN_PRIOR_SIGMA
    inertia_offset_kg: float = 0.0
    inertia_offset_sigma_kg: float = 0.0
    friction_drift: float = 0.0
    torque_channel: str = "torque"
    channel_spreads: ChannelSpreads | None = None
    actual_torque: Calibration | None = None
    ramp_noise_rate: float = float("nan")
    zero_reference: ZeroReference | None = None
    warnings: tuple[RecordingWarning, ...] = ()
    method: str = "windowed least squares of the rigid model (integral form)"
    created_at: str = field(default_factory=lambda: datetime.now(UTC).isoformat())
    chaintwin_version: str = ""

    # ------------------------------------------------------------ derived
    @property
    def id_profile(self) -> ConveyorProfile:
        """The profile as identification and weighing read it (no ``model:``)."""
        return identification_profile(self.profile)

    @property
    def profile_hash(self) -> str:
        """SHA-256 of the embedded profile."""
        return self.profile.content_hash()

    @property
    def sensitivity_nm_per_kg(self) -> float:
        """Torque per kg of payload at constant speed while motoring, Nm/kg."""
        return sensitivity_nm_per_kg(self.profile, self.parameters["mu"])

    @property
    def sensitivity_rel_uncertainty(self) -> float:
        """Relative standard uncertainty of the sensitivity (from μ's)."""
        g_cos, g_sin = incline_terms(self.profile)
        mu = self.parameters["mu"]
        return float(g_cos * self.parameters.stderr("mu") / abs(g_cos * mu + g_sin))

    @property
    def inertia_kgm2(self) -> float:
        """Reflected inertia at zero payload, tray included (motoring), kg·m²."""
        p = self.profile
        return drive_inertia_at(p, self.parameters["J_d"], p.belt_mass_kg + p.tray_mass_kg)

    @property
    def plateau_speeds_rpm(self) -> list[float]:
        """Distinct plateau speeds of the calibration recordings, rpm."""
        speeds = [r["plateau_speed_rpm"] for r in self.recordings if r["plateau_speed_rpm"]]
        return speed_clusters(speeds)

    @property
    def directions(self) -> frozenset[int]:
        """Directions of travel the calibration ran in (+1, -1); empty if not known.

        From each recording's constant-speed windows (``directions``), or, in
        files written before that field, the sign of its plateau speed.
        """
        out: set[int] = set()
        for r in self.recordings:
            if not isinstance(r, dict):
                continue
            if "directions" in r:
                out.update(int(d) for d in r["directions"])
            elif r.get("plateau_speed_rpm"):
                out.add(1 if r["plateau_speed_rpm"] > 0 else -1)
        return frozenset(out)

    def recommendation(self) -> str | None:
        """The run that would improve this calibration, or None."""
        if self.case == "several_loads":
            return None
        if self.case == "learned":
            return (
                "learned from operation with unknown payloads: weights are offset by the "
                "datasheet inertia's error (several kg). Record empty runs at 30, 60 and "
                "100 % speed in both directions and calibrate with `chaintwin calibrate`"
            )
        rel = self.sensitivity_rel_uncertainty
        text = (
            f"the payload sensitivity is known to ±{rel:.1%} (1 sigma), i.e. about "
            f"±{rel * 100:.1f} kg at 100 kg from friction alone"
        )
        if self.case == "one_load_one_speed":
            return (
                text + "; empty-tray runs at one speed cannot separate rail friction from the "
                "speed-dependent gear losses except through the ramps. Record one run with "
                "a known reference load (50-100 % of the usual payload), or empty runs at "
                "two or three speeds (e.g. 50 % and 75 % of nominal)"
            )
        return (
            text + "; friction is separated from the speed-dependent losses, but with one "
            "load it still includes the constant gear loss BmA. One run with a known "
            "reference load measures the sensitivity directly"
        )

    # ------------------------------------------------------------ file
    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form (see the module docstring)."""
        p = self.parameters
        return {
            "format": CALIBRATION_FORMAT,
            "format_version": CALIBRATION_VERSION,
            "chaintwin_version": self.chaintwin_version,
            "created_at": self.created_at,
            "method": self.method,
            "conveyor": self.profile.id,
            "profile_sha256": self.profile_hash,
            "profile": self.profile.model_dump(mode="json"),
            "case": self.case,
            "recommendation": self.recommendation(),
            "recordings": self.recordings,
            "parameters": {
                "names": list(PARAMETER_NAMES),
                "values": [float(v) for v in p.values],
                "covariance": [[float(c) for c in row] for row in p.covariance],
                "fixed": list(p.fixed),
            },
            "inertia_kgm2": self.inertia_kgm2,
            "payload_sensitivity_nm_per_kg": self.sensitivity_nm_per_kg,
            "payload_sensitivity_rel_uncertainty": self.sensitivity_rel_uncertainty,
            "torque_lag_s": self.torque_lag_s,
            "torque_lag_stderr_s": self.torque_lag_stderr_s,
            "residual_rms_nm": self.residual_rms_nm,
            "friction_drift": self.friction_drift,
            "torque_channel": self.torque_channel,
            "torque_channel_spreads_nm": None
            if self.channel_spreads is None
            else self.channel_spreads.to_dict(),
            "actual_torque": None if self.actual_torque is None else self.actual_torque.to_dict(),
            "inertia_signature": {
                "gain": self.inertia_gain,
                "gain_sigma": self.inertia_gain_sigma,
                "offset_kg": self.inertia_offset_kg,
                "offset_sigma_kg": self.inertia_offset_sigma_kg,
                "ramp_noise_rate": self.ramp_noise_rate,
            },
            "zero_reference": None
            if self.zero_reference is None
            else self.zero_reference.to_dict(),
            "warnings": [w.to_dict() for w in self.warnings],
        }

    def save(self, path: str | Path) -> Path:
        """Write the calibration file atomically (:func:`~chaintwin.read.files.write_atomic`).

        Raises
        ------
        CalibrationError
            When it cannot be written (an older file there is left as it was).
        """
        return write_atomic(
            path,
            json.dumps(self.to_dict(), indent=2) + "\n",
            what="calibration",
            error=lambda t, m: CalibrationError(f"{t}: {m}"),
        )

    @classmethod
    def from_dict(cls, data: Any, source: str = "<calibration>") -> Calibration:
        """Rebuild from :meth:`to_dict` output, checking format and profile hash.

        Raises
        ------
        CalibrationError
            When the content is not a chaintwin calibration or was altered.
        """
        refuse_huge_integers(data, source, CalibrationError, "calibration")
        if not isinstance(data, dict) or data.get("format") != CALIBRATION_FORMAT:
            raise CalibrationError(
                f"{source}: not a chaintwin calibration file (no 'format: "
                f"{CALIBRATION_FORMAT}'); make one with `chaintwin calibrate`"
            )
        version = data.get("format_version")
        if version != CALIBRATION_VERSION:
            raise CalibrationError(
                f"{source}: calibration format version {version!r} is not supported "
                f"(this chaintwin reads version {CALIBRATION_VERSION}); calibrate again"
            )
        try:
            if not isinstance(data.get("recordings"), list):
                raise ValueError("'recordings' must be a list")
            profile = parse_profile(data["profile"], f"{source}: embedded profile")
            params = data["parameters"]
            if list(params["names"]) != list(PARAMETER_NAMES):
                raise ValueError("parameter names")
            values = np.asarray(params["values"], dtype=np.float64)
            cov = np.asarray(params["covariance"], dtype=np.float64)
            if values.shape != (5,) or cov.shape != (5, 5):
                raise ValueError("parameter shapes")
            if not (np.isfinite(values).all() and np.isfinite(cov).all()):
                raise ValueError("non-finite parameters")
            cal = cls(
                profile=profile,
                parameters=RigidParameters(values, cov, tuple(params.get("fixed", ()))),
                case=str(data["case"]),
                recordings=list(data["recordings"]),
                torque_lag_s=data.get("torque_lag_s"),
                torque_lag_stderr_s=data.get("torque_lag_stderr_s"),
                residual_rms_nm=_number(data.get("residual_rms_nm")),
                inertia_gain=float(data["inertia_signature"]["gain"]),
                inertia_gain_sigma=float(data["inertia_signature"]["gain_sigma"]),
                inertia_offset_kg=float(data["inertia_signature"]["offset_kg"]),
                inertia_offset_sigma_kg=float(data["inertia_signature"]["offset_sigma_kg"]),
                ramp_noise_rate=_number(data["inertia_signature"]["ramp_noise_rate"]),
                friction_drift=float(data.get("friction_drift", 0.0)),
                torque_channel=str(data.get("torque_channel", "torque")),
                channel_spreads=None
                if data.get("torque_channel_spreads_nm") is None
                else ChannelSpreads.from_dict(data["torque_channel_spreads_nm"]),
                actual_torque=None
                if data.get("actual_torque") is None
                else cls.from_dict(data["actual_torque"], f"{source}: actual_torque"),
                zero_reference=None
                if data.get("zero_reference") is None
                else ZeroReference.from_dict(data["zero_reference"]),
                warnings=tuple(
                    RecordingWarning(str(w["code"]), str(w["message"]))
                    for w in data.get("warnings", [])
                ),
                method=str(data.get("method", "")),
                created_at=str(data.get("created_at", "")),
                chaintwin_version=str(data.get("chaintwin_version", "")),
            )
            if cal.torque_channel not in TORQUE_CHANNELS:
                raise ValueError(
                    f"torque_channel {cal.torque_channel!r} is not one of "
                    + ", ".join(TORQUE_CHANNELS)
                )
            if cal.torque_channel != "torque" and (
                cal.actual_torque is None or cal.channel_spreads is None
            ):
                raise ValueError("a calibration on the set point needs its actual-torque terms")
            if cal.case not in CALIBRATION_CASES:
                raise ValueError(f"case {cal.case!r} is not one of {', '.join(CALIBRATION_CASES)}")
            if not cal.directions <= {1, -1}:
                raise ValueError("recording directions must be 1 or -1")
        except (KeyError, TypeError, ValueError) as exc:
            raise CalibrationError(
                f"{source}: calibration file is incomplete or damaged ({exc}); calibrate again"
            ) from None
        if data.get("profile_sha256") != cal.profile_hash:
            raise CalibrationError(
                f"{source}: the embedded profile does not match its hash; the file was "
                "edited by hand. Calibrate again from the recordings"
            )
        problem = broken_invariant(cal)
        if problem is not None:
            raise CalibrationError(f"{source}: {problem}; calibrate again from the recordings")
        return cal


MAX_MU = 2.0
"""Largest friction coefficient a calibration may hold (belt on rails: 0.05-0.5)."""


def broken_invariant(cal: Calibration) -> str | None:
    """What is physically impossible in a calibration's numbers, or None.

    Positive drive inertia and inertia-signature gain, μ in (0, 2], a loss
    torque at nominal speed below the torque limit, a covariance with a
    non-negative diagonal; the shapes are checked on reading.
    """
    p = cal.parameters
    profile = cal.profile
    cov = p.covariance
    if not p["J_d"] > 0.0:
        return f"the drive inertia J_d is {p['J_d']:g} kg·m², not positive"
    if not 0.0 < p["mu"] <= MAX_MU:
        return f"the friction coefficient mu is {p['mu']:g}, not in (0, {MAX_MU:g}]"
    speed = (profile.motor.nominal_speed_rpm or 1500.0) * RPM_TO_RAD_S
    limit = profile.torque_limit_nm
    loss = abs(p["BmA"]) + abs(p["BmB"]) * speed + abs(p["BmC"]) * speed * speed
    if limit is not None and loss > limit:
        return (
            f"the losses (BmA, BmB, BmC) make {loss:.4g} Nm at nominal speed, more than the "
            f"drive's torque limit {limit:.4g} Nm"
        )
    # symmetric to rounding: an inverse's entries near zero differ by ~1e-16 of the largest
    scale = float(np.abs(cov).max()) if cov.size else 0.0
    if (np.diag(cov) < 0.0).any() or not np.allclose(cov, cov.T, rtol=1e-9, atol=1e-9 * scale):
        return "the parameter covariance is not a covariance (negative variance or asymmetric)"
    if not (math.isfinite(cal.inertia_gain) and cal.inertia_gain > 0.0):
        return f"the inertia signature's gain is {cal.inertia_gain:g}, not positive"
    sigmas = (cal.inertia_gain_sigma, cal.inertia_offset_sigma_kg)
    if not all(math.isfinite(v) and v >= 0.0 for v in sigmas) or not math.isfinite(
        cal.inertia_offset_kg
    ):
        return "the inertia signature's offset or uncertainties are not finite and non-negative"
    if not (math.isfinite(cal.friction_drift) and 0.0 <= cal.friction_drift <= 1.0):
        return f"the friction drift {cal.friction_drift:g} is not a share in [0, 1]"
    return None


def _number(value: Any) -> float:
    """A float from JSON, where null (or a missing value) stands for NaN."""
    return float("nan") if value is None else float(value)


def load_calibration(path: str | Path) -> Calibration:
    """Read a calibration file.

    Raises
    ------
    CalibrationError
        When it cannot be read or is not a valid calibration.
    """
    source = str(path)
    raw = read_limited(path, what="calibration", error=lambda s, m: CalibrationError(f"{s}: {m}"))
    try:
        data = json_loads(raw.decode("utf-8"))
    except UnicodeDecodeError as exc:
        raise CalibrationError(f"{source}: cannot read the calibration ({exc})") from None
    except json.JSONDecodeError as exc:
        raise CalibrationError(f"{source}, line {exc.lineno}: not valid JSON") from None
    except RecursionError:
        raise CalibrationError(f"{source}: nested too deeply to be a calibration") from None
    return Calibration.from_dict(data, source)
