"""Output-error fit: simulate the closed loop from the recorded set points.

The rigid model's parameters are fitted by simulating the drive's controller
replica and the rigid plant (:func:`chaintwin.simulate.simulate`) from the
recording's own speed and position set points and comparing the simulated
torque and speed with the measured ones (docs/design.md, section 3). It needs no
measured acceleration and checks the controller replica on the way; it is
also what the reference did.

What is fitted
--------------
Any of

* ``mu``: belt-on-rail friction coefficient μ;
* ``loss_constant_nm``: BmA, Nm;
* ``loss_viscous_nm_s_rad``: BmB, Nm·s/rad;
* ``loss_quadratic_nm_s2_rad2``: BmC, Nm·s²/rad²;
* ``drive_inertia_scale``: factor on the profile's motor + gear inertia.

The profile's ``model:`` section is **not** read (it would hold the answer):
the plant is built with :meth:`PlantParameters.from_profile` from the
profile's known data and an explicit :class:`~chaintwin.read.profile.ModelSpec`
of neutral values, and the fitted fields are replaced per evaluation.
Parameters that are not fitted take the value given in ``fixed``, else the
documented neutral default :data:`NEUTRAL`: no gear losses (BmA = BmB =
BmC = 0), inertia scale 1, and μ 0.23 (ModelSpec's typical value;
fit mu or fix it). The plant is the rigid model with every realism
switch off (no elastic belt, so its stiffness is irrelevant; no stick-slip,
no polygon effect), the torque lag τ from ``motor.torque_time_constant_s``.

With one known load, μ and BmA both multiply ``sign(ω)`` and cannot be told
apart (docs/design.md, identifiability): fit them together only from recordings
at two or more loads (``fit`` takes several recordings). With one speed,
μ, BmB and BmC are separated only by the ramps; recordings at two or three
speeds separate them much better.

Alignment
---------
Set points: the recorded speed set point is resampled to the controller
cycle by :func:`~chaintwin.simulate.from_arrays`, cycle ``k`` at
``time[0] + k·cycle``, so sample ``j`` of a recording at ``Ts = m·cycle``
is controller cycle ``j·m``; between samples the set point is linear (a
ramp corner that falls between two scope samples is rounded off by up to
one sample). The position set point is taken as recorded (interpolated) and
the simulation starts at ``initial_motor_angle = position_setpoint[0]``, so
the simulated position set point equals the recorded one at every sample
and the simulation starts with no position error (the true error at rest is
below the encoder's increment, which the recorded actual position cannot
resolve). Without a position set point channel the speed set point is
integrated. The simulation starts at rest, so the recording must too.

Scope phase: a scope keeps every m-th controller cycle from an unknown
phase (the virtual conveyor draws it at random when noise is on). That needs
no handling here: simulation and measurement share the recording's own time
grid (the simulation is sampled at the recording's times, exactly when they
fall on controller cycles, else by linear interpolation).

Which samples are compared
--------------------------
Samples where the speed set point exceeds ``min_speed_share`` of its peak,
less the first ``skip_start_s`` after each start of motion. Standstill is
left out: there the torque is the position controller integrating
sub-increment errors against static friction, which says nothing about the
parameters. The end of each move is left out after the set point reaches
zero: a real belt stops with a rebound (spring and stick-slip) that the
rigid model does not have. The start of motion is left out for the same
reason (breakaway above kinetic friction, belt wind-up); docs/design.md section 2.

Residuals and cost
------------------
``(T_sim − T_meas)/T_scale`` and ``(ω_sim − ω_meas)/ω_scale`` over the
compared samples of every recording, with ``T_scale`` the peak measured
|torque| and ``ω_scale`` the peak |speed set point| over those samples
(dimensionless, so one cost adds torque and speed).
:func:`scipy.optimize.least_squares` (trust region reflective, bounded)
works on each parameter mapped linearly to [0, 1] over its bounds, from
``starts`` Latin hypercube points in the inner 80 % of the box.

Standard errors come from the Jacobian at the best solution,
``cov = s²·(JᵀJ)⁻¹`` with ``s² = Σr²/(m − p)``. They assume white
residuals; what the rigid model leaves in them (polygon ripple, belt
ringing) is not white, so treat them as indicative.

Speed
-----
One simulation per recording and residual evaluation, through
:func:`~chaintwin.simulate.simulate` (about 0.4 ms for a 12 s recording at
a 1 ms cycle); a fit of three parameters from four starts runs some 150
simulations. Batching the finite-difference Jacobian through
a batch simulator was not worth its overhead at three or four members.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import replace
from typing import Any, Self

import numpy as np
from scipy.optimize import least_squares
from scipy.stats import qmc

from chaintwin._types import FloatArray
from chaintwin.errors import ConvergenceWarning, EstimationError, NotFittedError
from chaintwin.identify.closed_loop import (
    FAILED_RESIDUAL,
    NEUTRAL,
    PARAMETER_NAMES,
    Fitted,
    Prepared,
    StartResult,
    base_plant,
    fit_bounds,
    fixed_values,
    plant_of,
    plant_values,
    prepare,
    sample_like,
    warn_poor_fit,
)
from chaintwin.read.profile import ConveyorProfile
from chaintwin.read.recording import Recording
from chaintwin.simulate.engine import SimulationResult, simulate
from chaintwin.simulate.plant import PlantParameters

__all__ = [
    "NEUTRAL",
    "PARAMETER_NAMES",
    "ConvergenceWarning",
    "OutputErrorFit",
    "StartResult",
]


class OutputErrorFit:
    """Fit rigid-model parameters by simulating the closed loop (output error).

    See the module docstring for the model, the alignment of set points and
    samples, which samples are compared, and the cost.

    Parameters
    ----------
    parameters : sequence of str
        Names to fit, from :data:`PARAMETER_NAMES`.
    starts : int
        Number of starting points (Latin hypercube in the bounds).
    bounds : mapping of str to (float, float), optional
        Bounds per fitted parameter, SI; missing names get the defaults:
        mu (0, 1); BmA (0, T/2); BmB (0, T/(2·ω)); BmC (0, T/(2·ω²));
        drive_inertia_scale (0.25, 4), with T the motor's nominal torque (else
        the torque limit / 3, else the peak measured torque) and ω the peak
        speed set point.
    seed : int
        Seed of the starting points.
    max_nfev : int
        Most residual evaluations per start (finite differences excluded, as
        :func:`scipy.optimize.least_squares` counts).
    fixed : mapping of str to float, optional
        Values of parameters that are not fitted (default :data:`NEUTRAL`).
    skip_start_s : float
        Time after each start of motion left out of the comparison, s.
    min_speed_share : float
        Samples with a speed set point below this share of its peak are left
        out of the comparison.

    Attributes
    ----------
    theta_ : dict of str to float
        The fitted values, SI.
    stderr_ : dict of str to float
        Their standard errors, SI.
    covariance_ : ndarray of float, shape (p, p)
        Parameter covariance in the order of ``parameters``.
    cost_ : float
        Half the sum of squared scaled residuals at the best solution.
    starts_ : list of StartResult
        Every start and where it ended.
    agree_ : bool
        True when every start ended within ``max(3·stderr, 1 %)`` of the best
        solution in every parameter.
    nfev_ : int
        Simulations run in all (all starts, finite differences included).
    rms_torque_nm_, rms_speed_rad_s_ : float
        RMS of simulated minus measured torque (Nm) and speed (rad/s) over the
        compared samples at the best solution.
    n_samples_ : int
        Compared samples (per channel, all recordings).

    Warns
    -----
    ConvergenceWarning
        When the best start did not converge, a fitted value sits on its
        bound, or the starts disagree.
    """

    # set by fit(); __init__ only stores settings
    _fit: Fitted | None = None

    def __init__(
        self,
        *,
        parameters: Sequence[str] = ("mu", "loss_viscous_nm_s_rad", "drive_inertia_scale"),
        starts: int = 4,
        bounds: Mapping[str, tuple[float, float]] | None = None,
        seed: int = 0,
        max_nfev: int = 200,
        fixed: Mapping[str, float] | None = None,
        skip_start_s: float = 0.1,
        min_speed_share: float = 0.02,
    ) -> None:
        self.parameters = parameters
        self.starts = starts
        self.bounds = bounds
        self.seed = seed
        self.max_nfev = max_nfev
        self.fixed = fixed
        self.skip_start_s = skip_start_s
        self.min_speed_share = min_speed_share

    def __repr__(self) -> str:
        return (
            f"OutputErrorFit(parameters={tuple(self.parameters)!r}, starts={self.starts!r}, "
            f"bounds={self.bounds!r}, seed={self.seed!r}, max_nfev={self.max_nfev!r}, "
            f"fixed={self.fixed!r}, skip_start_s={self.skip_start_s!r}, "
            f"min_speed_share={self.min_speed_share!r})"
        )

    # ------------------------------------------------------------ checks
    def _names(self) -> tuple[str, ...]:
        given = self.parameters
        names = (given,) if isinstance(given, str) else tuple(given)
        if not names:
            raise EstimationError("give at least one parameter to fit")
        unknown = [n for n in names if n not in PARAMETER_NAMES]
        if unknown:
            raise EstimationError(
                f"unknown parameter(s) {', '.join(unknown)}; choose from "
                f"{', '.join(PARAMETER_NAMES)}"
            )
        if len(set(names)) != len(names):
            raise EstimationError(f"parameters {names} name one parameter twice")
        return names

    def _check_settings(self) -> None:
        if not (isinstance(self.starts, int) and self.starts >= 1):
            raise EstimationError(f"starts={self.starts!r} must be a whole number ≥ 1")
        if not (isinstance(self.max_nfev, int) and self.max_nfev >= 1):
            raise EstimationError(f"max_nfev={self.max_nfev!r} must be a whole number ≥ 1")
        if not (math.isfinite(self.skip_start_s) and self.skip_start_s >= 0.0):
            raise EstimationError(f"skip_start_s={self.skip_start_s!r} must be a time ≥ 0 s")
        if not (math.isfinite(self.min_speed_share) and 0.0 < self.min_speed_share < 1.0):
            raise EstimationError(f"min_speed_share={self.min_speed_share!r} must lie in (0, 1)")

    def _fixed_values(self, names: tuple[str, ...]) -> dict[str, float]:
        return fixed_values(names, self.fixed)

    def _bounds(
        self, names: tuple[str, ...], torque_ref: float, speed_ref: float
    ) -> tuple[FloatArray, FloatArray]:
        return fit_bounds(names, self.bounds, torque_ref, speed_ref)

    def _prepare(
        self, recording: Recording, profile: ConveyorProfile, payload_kg: float
    ) -> Prepared:
        return prepare(
            recording,
            profile,
            payload_kg,
            min_speed_share=self.min_speed_share,
            skip_start_s=self.skip_start_s,
            n_parameters=len(self.parameters),
        )

    # ----------------------------------------------------------- fitting
    def fit(
        self,
        recording: Recording | Sequence[Recording],
        profile: ConveyorProfile,
        *,
        payload_kg: float | Sequence[float],
    ) -> Self:
        """Fit the parameters to one recording or several of the same conveyor.

        Parameters
        ----------
        recording : Recording or sequence of Recording
            Recordings with speed set point, speed and torque (position set
            point recommended), each starting at rest. Several recordings
            (other speeds, other loads) are fitted jointly.
        profile : ConveyorProfile
            The conveyor's known data; its ``model:`` section is not read.
        payload_kg : float or sequence of float
            The known payload of each recording, kg (one value for all).

        Returns
        -------
        OutputErrorFit
            ``self``, fitted.

        Raises
        ------
        EstimationError
            For invalid settings, a recording without speed set point, one
            that does not move or starts in motion, or when no start gives a
            finite cost.
        """
        names = self._names()
        self._check_settings()
        fixed = self._fixed_values(names)
        recs = [recording] if isinstance(recording, Recording) else list(recording)
        if not recs:
            raise EstimationError("give at least one recording")
        if isinstance(payload_kg, int | float):
            payloads = [float(payload_kg)] * len(recs)
        else:
            payloads = [float(p) for p in payload_kg]
            if len(payloads) != len(recs):
                raise EstimationError(
                    f"{len(payloads)} payloads for {len(recs)} recordings; give one per recording"
                )
        preps = [self._prepare(r, profile, p) for r, p in zip(recs, payloads, strict=True)]

        torque_scale = max(float(np.max(np.abs(p.torque))) for p in preps)
        speed_scale = max(float(np.max(np.abs(p.setpoints.speed))) for p in preps)
        if torque_scale <= 0.0:
            raise EstimationError("the measured torque is zero while moving; check the channels")
        nominal = profile.nominal_torque_nm
        limit = profile.torque_limit_nm
        torque_ref = nominal if nominal else (limit / 3.0 if limit else torque_scale)
        lo, hi = self._bounds(names, torque_ref, speed_scale)
        span = hi - lo
        inertia = (preps[0].base.motor_inertia_kgm2, preps[0].base.gear_inertia_kgm2)
        cycle = profile.controller.cycle_s
        counter = [0]

        def residuals(u: FloatArray) -> FloatArray:
            values = plant_values(names, lo + u * span, fixed)
            parts: list[FloatArray] = []
            for prep in preps:
                counter[0] += 1
                sim = simulate(
                    plant_of(prep.base, values, inertia),
                    prep.setpoints,
                    initial_motor_angle=prep.theta0,
                )
                n = int(np.count_nonzero(prep.mask))
                if not sim.success:
                    parts.append(np.full(2 * n, FAILED_RESIDUAL))
                    continue
                tq = sample_like(sim.torque, prep, cycle)[prep.mask]
                w = sample_like(sim.speed, prep, cycle)[prep.mask]
                parts.append((tq - prep.torque) / torque_scale)
                parts.append((w - prep.speed) / speed_scale)
            r = np.concatenate(parts)
            return np.where(np.isfinite(r), r, FAILED_RESIDUAL)

        sampler = qmc.LatinHypercube(d=len(names), rng=np.random.default_rng(self.seed))
        unit_starts = 0.1 + 0.8 * sampler.random(self.starts)
        results: list[StartResult] = []
        best: tuple[float, Any] | None = None
        for u0 in unit_starts:
            before = counter[0]
            sol: Any = least_squares(
                residuals,
                u0,
                bounds=(0.0, 1.0),
                method="trf",
                x_scale=1.0,
                diff_step=1e-6,
                ftol=1e-10,
                xtol=1e-10,
                gtol=1e-10,
                max_nfev=self.max_nfev,
            )
            cost = float(sol.cost)
            results.append(
                StartResult(
                    start=dict(zip(names, (lo + u0 * span).tolist(), strict=True)),
                    theta=dict(zip(names, (lo + sol.x * span).tolist(), strict=True)),
                    cost=cost,
                    nfev=counter[0] - before,
                    status=int(sol.status),
                    message=str(sol.message),
                )
            )
            if math.isfinite(cost) and (best is None or cost < best[0]):
                best = (cost, sol)
        if best is None:
            raise EstimationError(
                "no start gave a finite cost; check that the recording and the profile belong "
                "to the same conveyor"
            )
        sol = best[1]
        x_best = lo + sol.x * span
        r = residuals(sol.x)
        jac = np.asarray(sol.jac, dtype=np.float64)
        m, p = jac.shape
        s2 = float(r @ r) / max(m - p, 1)
        try:
            cov_unit = s2 * np.linalg.inv(jac.T @ jac)
            cov = cov_unit * np.outer(span, span)
        except np.linalg.LinAlgError:
            cov = np.full((p, p), math.inf)
        stderr = np.sqrt(np.where(np.diag(cov) >= 0.0, np.diag(cov), math.inf))

        tol = np.maximum(np.maximum(3.0 * stderr, 0.01 * np.abs(x_best)), 1e-9 * span)
        agree = all(
            bool(np.all(np.abs(np.array([s.theta[n] for n in names]) - x_best) <= tol))
            for s in results
        )
        # residual RMS in physical units, split by channel
        torque_sq = 0.0
        speed_sq = 0.0
        n_samples = 0
        offset = 0
        for prep in preps:
            n = int(np.count_nonzero(prep.mask))
            torque_sq += float(np.sum(r[offset : offset + n] ** 2)) * torque_scale**2
            speed_sq += float(np.sum(r[offset + n : offset + 2 * n] ** 2)) * speed_scale**2
            offset += 2 * n
            n_samples += n
        theta = dict(zip(names, x_best.tolist(), strict=True))
        self._fit = Fitted(
            names=names,
            theta=theta,
            values=plant_values(names, x_best, fixed),
            covariance=cov,
            stderr=dict(zip(names, stderr.tolist(), strict=True)),
            cost=float(sol.cost),
            starts=results,
            nfev=counter[0],
            agree=agree,
            rms_torque_nm=math.sqrt(torque_sq / n_samples),
            rms_speed_rad_s=math.sqrt(speed_sq / n_samples),
            n_samples=n_samples,
        )
        warn_poor_fit(names, sol, lo, hi, x_best, agree)
        return self

    # ----------------------------------------------------------- results
    def _fitted(self) -> Fitted:
        if self._fit is None:
            raise NotFittedError(
                "this OutputErrorFit is not fitted yet; call fit(recording, profile, "
                "payload_kg=...) first"
            )
        return self._fit

    @property
    def theta_(self) -> dict[str, float]:
        """The fitted values by name, SI."""
        return dict(self._fitted().theta)

    @property
    def stderr_(self) -> dict[str, float]:
        """Standard errors by name, SI (from the Jacobian at the best solution)."""
        return dict(self._fitted().stderr)

    @property
    def covariance_(self) -> FloatArray:
        """Parameter covariance, shape (p, p), in the order of ``parameters``."""
        return self._fitted().covariance.copy()

    @property
    def cost_(self) -> float:
        """Half the sum of squared scaled residuals at the best solution."""
        return self._fitted().cost

    @property
    def starts_(self) -> list[StartResult]:
        """Every start and where it ended."""
        return list(self._fitted().starts)

    @property
    def agree_(self) -> bool:
        """Whether every start ended within ``max(3·stderr, 1 %)`` of the best solution."""
        return self._fitted().agree

    @property
    def nfev_(self) -> int:
        """Simulations run in all (every start, finite differences included)."""
        return self._fitted().nfev

    @property
    def rms_torque_nm_(self) -> float:
        """RMS of simulated minus measured torque over the compared samples, Nm."""
        return self._fitted().rms_torque_nm

    @property
    def rms_speed_rad_s_(self) -> float:
        """RMS of simulated minus measured speed over the compared samples, rad/s."""
        return self._fitted().rms_speed_rad_s

    @property
    def n_samples_(self) -> int:
        """Compared samples per channel, all recordings."""
        return self._fitted().n_samples

    def plant_parameters(self, profile: ConveyorProfile, *, payload_kg: float) -> PlantParameters:
        """The fitted rigid plant of a conveyor at a payload.

        Parameters
        ----------
        profile : ConveyorProfile
            The conveyor (its ``model:`` section is not read).
        payload_kg : float
            Payload, kg.

        Returns
        -------
        PlantParameters
            Rigid, realism off, fitted and fixed values applied.

        Raises
        ------
        NotFittedError
            Before ``fit``.
        """
        fitted = self._fitted()
        if not (math.isfinite(payload_kg) and payload_kg >= 0.0):
            raise EstimationError(f"payload_kg={payload_kg!r} must be a mass ≥ 0 kg")
        base = base_plant(profile, payload_kg)
        return plant_of(base, fitted.values, (base.motor_inertia_kgm2, base.gear_inertia_kgm2))

    def predict(
        self, recording: Recording, profile: ConveyorProfile, payload_kg: float
    ) -> SimulationResult:
        """Simulate a recording's set points with the fitted parameters.

        Parameters
        ----------
        recording : Recording
            Supplies the set points and the sample times (it must start at rest).
        profile : ConveyorProfile
            The conveyor.
        payload_kg : float
            Payload, kg.

        Returns
        -------
        SimulationResult
            Every channel sampled at the recording's times (``time`` is the
            recording's time column); ``setpoints`` holds the set points at
            the controller cycle that were simulated.

        Raises
        ------
        NotFittedError
            Before ``fit``.
        EstimationError
            For a recording the fit could not use either.
        """
        fitted = self._fitted()
        prep = self._prepare(recording, profile, payload_kg)
        plant = plant_of(
            prep.base, fitted.values, (prep.base.motor_inertia_kgm2, prep.base.gear_inertia_kgm2)
        )
        sim = simulate(plant, prep.setpoints, initial_motor_angle=prep.theta0)
        cycle = profile.controller.cycle_s

        def at(values: FloatArray) -> FloatArray:
            return sample_like(values, prep, cycle)

        return replace(
            sim,
            time=np.array(recording.time, dtype=np.float64),
            speed_setpoint=at(sim.speed_setpoint),
            position_setpoint=at(sim.position_setpoint),
            torque_setpoint=at(sim.torque_setpoint),
            torque=at(sim.torque),
            speed=at(sim.speed),
            position=at(sim.position),
            belt_position_m=at(sim.belt_position_m),
            belt_speed_m_s=at(sim.belt_speed_m_s),
            sprocket_force_n=at(sim.sprocket_force_n),
            load_torque_nm=at(sim.load_torque_nm),
            loss_torque_nm=at(sim.loss_torque_nm),
        )
