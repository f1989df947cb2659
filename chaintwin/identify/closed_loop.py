"""The closed loop of the output-error fit: its parameters, the plant they make, the
recordings' preparation and the checks of a fit (:mod:`chaintwin.identify.output_error`)."""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from chaintwin._types import FloatArray
from chaintwin.errors import ChaintwinError, ConvergenceWarning, EstimationError
from chaintwin.read.profile import ConveyorProfile, ModelSpec
from chaintwin.read.recording import Recording
from chaintwin.simulate.plant import PlantParameters
from chaintwin.simulate.setpoints import Setpoints, from_arrays

__all__ = [
    "FAILED_RESIDUAL",
    "NEUTRAL",
    "PARAMETER_NAMES",
    "Fitted",
    "Prepared",
    "StartResult",
    "base_plant",
    "finite_channel",
    "fit_bounds",
    "fixed_values",
    "plant_of",
    "plant_values",
    "prepare",
    "sample_like",
    "warn_poor_fit",
]

PARAMETER_NAMES: tuple[str, ...] = (
    "mu",
    "loss_constant_nm",
    "loss_viscous_nm_s_rad",
    "loss_quadratic_nm_s2_rad2",
    "drive_inertia_scale",
)
"""Parameters the output-error fit can fit (see the module docstring)."""

NEUTRAL: Mapping[str, float] = {
    "mu": 0.23,
    "loss_constant_nm": 0.0,
    "loss_viscous_nm_s_rad": 0.0,
    "loss_quadratic_nm_s2_rad2": 0.0,
    "drive_inertia_scale": 1.0,
}
"""Values of the parameters that are neither fitted nor given in ``fixed``."""

FAILED_RESIDUAL = 10.0
"""Residual (scaled units) given to every sample of a diverged simulation."""


@dataclass(frozen=True, slots=True)
class StartResult:
    """Where one starting point of the fit ended.

    Parameters
    ----------
    start : dict of str to float
        The starting point, SI.
    theta : dict of str to float
        The solution, SI.
    cost : float
        Half the sum of squared scaled residuals at the solution.
    nfev : int
        Simulations run for this start (residual evaluations, finite
        differences included; one per recording each).
    status : int
        :func:`scipy.optimize.least_squares` status (> 0: converged).
    message : str
        Its message.
    """

    start: dict[str, float]
    theta: dict[str, float]
    cost: float
    nfev: int
    status: int
    message: str

    @property
    def converged(self) -> bool:
        """Whether the optimiser met a tolerance (status > 0)."""
        return self.status > 0


@dataclass(frozen=True, slots=True)
class Prepared:
    """A recording made ready for repeated simulation."""

    setpoints: Setpoints
    theta0: float
    base: PlantParameters
    index: npt.NDArray[np.int64] | None  # sample → cycle, when on the grid
    sim_time: FloatArray  # recording times relative to the first sample
    mask: npt.NDArray[np.bool_]
    torque: FloatArray  # measured, at the compared samples
    speed: FloatArray


@dataclass(frozen=True, slots=True)
class Fitted:
    names: tuple[str, ...]
    theta: dict[str, float]
    values: dict[str, float]  # fitted and fixed, every name in PARAMETER_NAMES
    covariance: FloatArray
    stderr: dict[str, float]
    cost: float
    starts: list[StartResult]
    nfev: int
    agree: bool
    rms_torque_nm: float
    rms_speed_rad_s: float
    n_samples: int


def finite_channel(recording: Recording, name: str) -> FloatArray:
    values = recording.channels.get(name)
    if values is None:
        if name == "speed_setpoint":
            raise EstimationError(
                f"{recording.source}: has no speed_setpoint channel; the output-error fit "
                "drives the simulated closed loop with the recorded set points: record the "
                "speed set point (and the position set point) with the scope"
            )
        raise EstimationError(f"{recording.source}: has no {name} channel")
    arr = np.asarray(values, dtype=np.float64)
    if not np.all(np.isfinite(arr)):
        raise EstimationError(
            f"{recording.source}: the {name} channel holds NaN or infinite values; cut the "
            "recording to its valid part"
        )
    return arr


def plant_values(
    names: Sequence[str], x: FloatArray, fixed: Mapping[str, float]
) -> dict[str, float]:
    values = dict(fixed)
    for name, value in zip(names, x, strict=True):
        values[name] = float(value)
    return values


def plant_of(
    base: PlantParameters, values: Mapping[str, float], inertia: tuple[float, float]
) -> PlantParameters:
    scale = values["drive_inertia_scale"]
    return base.replace(
        mu=values["mu"],
        loss_constant_nm=values["loss_constant_nm"],
        loss_viscous_nm_s_rad=values["loss_viscous_nm_s_rad"],
        loss_quadratic_nm_s2_rad2=values["loss_quadratic_nm_s2_rad2"],
        motor_inertia_kgm2=inertia[0] * scale,
        gear_inertia_kgm2=inertia[1] * scale,
    )


def base_plant(profile: ConveyorProfile, payload_kg: float) -> PlantParameters:
    """The rigid plant of the profile's known data with neutral model values."""
    spec = ModelSpec(
        friction=NEUTRAL["mu"],
        static_friction_ratio=1.0,
        loss_constant_nm=0.0,
        loss_viscous_nm_s_rad=0.0,
        loss_quadratic_nm_s2_rad2=0.0,
    )
    try:
        return PlantParameters.from_profile(profile, payload_kg=payload_kg, model=spec)
    except ChaintwinError as exc:
        raise EstimationError(f"profile '{profile.id}': {exc}") from None


def sample_like(sim_values: FloatArray, prep: Prepared, cycle_s: float) -> FloatArray:
    """A simulated channel at the recording's sample times."""
    if prep.index is not None:
        out: FloatArray = sim_values[prep.index]
        return out
    grid = np.arange(sim_values.shape[0], dtype=np.float64) * cycle_s
    return np.asarray(np.interp(prep.sim_time, grid, sim_values), dtype=np.float64)


def prepare(
    recording: Recording,
    profile: ConveyorProfile,
    payload_kg: float,
    *,
    min_speed_share: float,
    skip_start_s: float,
    n_parameters: int,
) -> Prepared:
    """What a fit needs of one recording: set points, start, sample grid and kept samples.

    Raises
    ------
    EstimationError
        When the recording cannot be simulated and compared (too short, no
        motion, starting in motion, too few moving samples).
    """
    if not (math.isfinite(payload_kg) and payload_kg >= 0.0):
        raise EstimationError(f"payload_kg={payload_kg!r} must be a mass ≥ 0 kg")
    cycle = profile.controller.cycle_s
    t = finite_channel(recording, "time")
    w_sp = finite_channel(recording, "speed_setpoint")
    w = finite_channel(recording, "speed")
    tq = finite_channel(recording, "torque")
    psp = recording.channels.get("position_setpoint")
    if psp is not None:
        psp = finite_channel(recording, "position_setpoint")
    if t.size < 8 or np.any(np.diff(t) <= 0.0):
        raise EstimationError(
            f"{recording.source}: needs at least 8 samples with strictly increasing time"
        )
    peak = float(np.max(np.abs(w_sp)))
    if peak <= 0.0:
        raise EstimationError(
            f"{recording.source}: the speed set point never leaves zero; the conveyor "
            "does not move, so there is nothing to fit"
        )
    rest = min_speed_share * peak
    if abs(w_sp[0]) > rest or abs(w[0]) > rest:
        raise EstimationError(
            f"{recording.source}: starts in motion; the simulation starts at rest: give a "
            "recording triggered before the move"
        )
    setpoints = from_arrays(t, w_sp, psp, cycle_s=cycle)
    theta0 = float(psp[0]) if psp is not None else 0.0

    rel = (t - t[0]) / cycle
    nearest = np.rint(rel)
    on_grid = bool(np.max(np.abs(rel - nearest)) <= 1e-6)
    index = np.minimum(nearest.astype(np.int64), len(setpoints) - 1) if on_grid else None

    moving = np.abs(w_sp) > rest
    mask = moving.copy()
    skip = skip_start_s
    if skip > 0.0:
        rises = np.flatnonzero(moving[1:] & ~moving[:-1]) + 1
        if moving[0]:
            rises = np.concatenate(([0], rises))
        for a in rises.tolist():
            mask &= ~((t >= t[a]) & (t < t[a] + skip))
    if int(np.count_nonzero(mask)) < 2 * n_parameters + 2:
        raise EstimationError(
            f"{recording.source}: only {int(np.count_nonzero(mask))} samples with the "
            "set point moving after the start transients; give a longer movement"
        )
    return Prepared(
        setpoints=setpoints,
        theta0=theta0,
        base=base_plant(profile, payload_kg),
        index=index,
        sim_time=t - t[0],
        mask=mask,
        torque=tq[mask],
        speed=w[mask],
    )


def warn_poor_fit(
    names: tuple[str, ...],
    sol: Any,
    lo: FloatArray,
    hi: FloatArray,
    x_best: FloatArray,
    agree: bool,
) -> None:
    """Warn (:class:`ConvergenceWarning`) about a fit that did not converge, hit a
    bound, or whose starting points disagree."""
    if int(sol.status) <= 0:
        warnings.warn(
            f"the output-error fit did not converge ({sol.message}); raise max_nfev",
            ConvergenceWarning,
            stacklevel=3,
        )
    edge = 1e-6 * (hi - lo)
    at_bound = [
        n
        for n, x, a, b, e in zip(names, x_best, lo, hi, edge, strict=True)
        if x - a <= e or b - x <= e
    ]
    if at_bound:
        warnings.warn(
            f"fitted value(s) at a bound: {', '.join(at_bound)}; the recording cannot tell "
            "them, or the bounds are too narrow (their standard errors are not meaningful)",
            ConvergenceWarning,
            stacklevel=3,
        )
    if not agree:
        warnings.warn(
            "the starting points ended at different solutions; the cost has several "
            "minima or is flat: see starts_",
            ConvergenceWarning,
            stacklevel=3,
        )


def fixed_values(names: tuple[str, ...], fixed: Mapping[str, float] | None) -> dict[str, float]:
    """The values of the parameters not fitted: ``fixed`` over :data:`NEUTRAL`, checked."""
    values = dict(NEUTRAL)
    for name, value in (fixed or {}).items():
        if name not in PARAMETER_NAMES:
            raise EstimationError(
                f"fixed: unknown parameter '{name}'; choose from {', '.join(PARAMETER_NAMES)}"
            )
        if name in names:
            raise EstimationError(f"fixed: '{name}' is also fitted; give it in one place")
        low = 1e-6 if name == "drive_inertia_scale" else 0.0
        if not (math.isfinite(value) and value >= low):
            raise EstimationError(f"fixed: '{name}' = {value!r} must be a finite number ≥ {low:g}")
        values[name] = float(value)
    return values


def fit_bounds(
    names: tuple[str, ...],
    bounds: Mapping[str, tuple[float, float]] | None,
    torque_ref: float,
    speed_ref: float,
) -> tuple[FloatArray, FloatArray]:
    """Lower and upper bounds of the fitted parameters: given, else scaled defaults.

    ``torque_ref`` (Nm) and ``speed_ref`` (rad/s) scale the loss bounds.
    """
    defaults = {
        "mu": (0.0, 1.0),
        "loss_constant_nm": (0.0, 0.5 * torque_ref),
        "loss_viscous_nm_s_rad": (0.0, 0.5 * torque_ref / speed_ref),
        "loss_quadratic_nm_s2_rad2": (0.0, 0.5 * torque_ref / speed_ref**2),
        "drive_inertia_scale": (0.25, 4.0),
    }
    given = dict(bounds or {})
    extra = sorted(set(given) - set(names))
    if extra:
        raise EstimationError(
            f"bounds given for {', '.join(extra)}, which are not fitted; fit them or "
            "drop their bounds"
        )
    lo = np.empty(len(names))
    hi = np.empty(len(names))
    for i, name in enumerate(names):
        a, b = given.get(name, defaults[name])
        a, b = float(a), float(b)
        low_limit = 0.0 if name != "drive_inertia_scale" else 1e-6
        if not (math.isfinite(a) and math.isfinite(b) and low_limit <= a < b):
            raise EstimationError(
                f"bounds of '{name}' ({a!r}, {b!r}) must be finite with "
                f"{low_limit:g} ≤ lower < upper"
            )
        if name == "mu" and b > 2.0:
            raise EstimationError("bounds of 'mu' must lie within [0, 2]")
        lo[i], hi[i] = a, b
    return lo, hi
