"""Batch least squares of the rigid model on windowed integrals.

:class:`RigidModelRegression` identifies the drive inertia J_d, the rail
friction coefficient μ and the losses BmA, BmB, BmC from recordings with a
known payload (see :mod:`chaintwin.model.rigid` for the model and
:mod:`chaintwin.model.windows` for the integral form). It follows the
scikit-learn estimator contract: settings in ``__init__``, ``fit`` returns
``self``, fitted values end in ``_``.

Identifiability (docs/design.md): with one known load, μ·M and BmA both multiply
``sign(ω)`` and cannot be told apart; the fit then fixes BmA to
``bma_prior`` (default 0: gear units' Coulomb loss is typically well under
1 % of the rail friction torque) and says so in a warning. Loads that differ
by more than ``min_load_spread_kg`` separate them (the slope in load is μ).
Speed-dependent losses are separated from friction by the speed variation
the data holds: the ramps always, plateaus at several speeds better.

Standard errors come from ``s²·(XᵀX)⁻¹`` inflated for the residuals' serial
correlation (lag-1 autocorrelation ρ: factor (1+ρ)/(1−ρ)), since polygon
ripple and belt ringing make neighbouring windows' errors alike.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from chaintwin._types import FloatArray
from chaintwin.errors import EstimationError, NotFittedError
from chaintwin.model.rigid import (
    PARAMETER_NAMES,
    RigidParameters,
    drive_inertia_at,
    incline_terms,
    model_torque,
    motoring_mask,
)
from chaintwin.model.windows import DEFAULT_WINDOW_S, WindowIntegrals, window_integrals
from chaintwin.read.profile import ConveyorProfile
from chaintwin.read.recording import Recording, RecordingWarning

__all__ = [
    "RigidModelRegression",
    "design_matrix",
    "serial_correlation_factor",
    "speed_clusters",
]


@dataclass(frozen=True, slots=True)
class _Solution:
    values: FloatArray
    covariance: FloatArray
    residual_rms_nm: float
    singular_values: FloatArray
    n_windows: int
    plateau_speeds: list[float]
    warnings: list[RecordingWarning]
    fixed: list[str]
    noise_rates: FloatArray


SPEED_CLUSTER = 0.05
"""Plateau speeds within 5 % count as one speed."""


def speed_clusters(speeds: Sequence[float]) -> list[float]:
    """Distinct plateau speeds (within :data:`SPEED_CLUSTER`), ascending."""
    clusters: list[float] = []
    for s in sorted(abs(v) for v in speeds):
        if not clusters or s > clusters[-1] * (1.0 + SPEED_CLUSTER):
            clusters.append(s)
    return clusters


def serial_correlation_factor(residuals: FloatArray) -> float:
    """Variance inflation (1+ρ)/(1−ρ) for lag-1 autocorrelation ρ (clipped to [0, 0.9])."""
    if residuals.shape[0] < 3:
        return 1.0
    r = residuals - residuals.mean()
    den = float(np.dot(r, r))
    if den <= 0.0:
        return 1.0
    rho = float(np.dot(r[1:], r[:-1])) / den
    rho = min(max(rho, 0.0), 0.9)
    return (1.0 + rho) / (1.0 - rho)


def design_matrix(
    wi: WindowIntegrals,
    profile: ConveyorProfile,
    *,
    payload_kg: float,
    tray_kg: float,
) -> tuple[FloatArray, FloatArray]:
    """Regressors X (n × 5, :data:`PARAMETER_NAMES`) and target y of one recording.

    ``y = ∫T dt − known terms`` (incline, belt inertia at the known masses).
    """
    g_cos, g_sin = incline_terms(profile)
    mass = profile.belt_mass_kg + tray_kg + payload_kg
    r_over_i = profile.chordal_radius_m / profile.kinematic_ratio
    known = g_sin * (tray_kg + payload_kg) * wi.gf + mass * r_over_i * wi.gf_accel
    x = np.column_stack((wi.d_speed, g_cos * mass * wi.gf_sign, wi.sign, wi.speed, wi.speed_sq))
    return x, wi.torque - known


class RigidModelRegression:
    """Windowed least squares of the rigid model on recordings with known payload.

    Parameters
    ----------
    window_s : float
        Integration window, s.
    torque_channel : {"torque", "torque_setpoint"}
        Torque to explain.
    bma_prior : float
        BmA used when one load cannot separate it from friction, Nm.
    min_load_spread_kg : float
        Loads must differ by this much to separate μ from BmA, kg.
    fit_bmc : bool
        Fit the speed-squared loss BmC; False fixes it to 0.
    fit_bma : bool
        Fit the constant loss BmA where the loads can tell it from friction;
        False fixes it to ``bma_prior`` (a check of a fit that found it
        negative).
    ramp_windows : bool or None
        Use the short windows inside ramps. They resolve the speed dependence
        of the losses when all plateaus are at one speed, but a lightly damped
        elastic belt rings against them. None (default): use them only when
        the plateaus are at one speed.
    variance_components : bool
        Weight short and whole-ramp windows by their own residual noise rates
        (estimated from a first fit). The rates are estimated either way
        (``noise_rates_``) and serve weighing.
    ramp_side : {"both", "accelerate", "decelerate"}
        Which ramps' windows to use (plateau windows always). One side alone
        serves as a check: with one load at one speed the ramps alone separate
        friction from the speed-dependent losses, and the two sides disagree
        by what the rigid model misses there (breakaway and wind-up at the
        start, the power-flow change when braking).
    """

    def __init__(
        self,
        *,
        window_s: float = DEFAULT_WINDOW_S,
        torque_channel: str = "torque",
        bma_prior: float = 0.0,
        min_load_spread_kg: float = 5.0,
        fit_bmc: bool = True,
        fit_bma: bool = True,
        ramp_windows: bool | None = None,
        variance_components: bool = False,
        ramp_side: str = "both",
    ) -> None:
        self.ramp_side = ramp_side
        self.variance_components = variance_components
        self.ramp_windows = ramp_windows
        self.window_s = window_s
        self.torque_channel = torque_channel
        self.bma_prior = bma_prior
        self.min_load_spread_kg = min_load_spread_kg
        self.fit_bmc = fit_bmc
        self.fit_bma = fit_bma

    # ------------------------------------------------------------------ fit
    def fit(
        self,
        recordings: Sequence[Recording],
        profile: ConveyorProfile,
        payloads_kg: Sequence[float] | None = None,
        trays_kg: Sequence[float] | None = None,
    ) -> RigidModelRegression:
        """Fit to recordings with known payloads.

        Parameters
        ----------
        recordings : sequence of Recording
            Recordings of one conveyor.
        profile : ConveyorProfile
            Its profile (the ``model:`` section is ignored).
        payloads_kg : sequence of float, optional
            Payload of each recording, kg (default: each one's ``payload_kg``
            metadata, which must then be present).
        trays_kg : sequence of float, optional
            Tray mass of each recording, kg (default: ``tray_kg`` metadata,
            else the profile's ``tray_mass_kg``).

        Returns
        -------
        RigidModelRegression
            ``self``, fitted.

        Raises
        ------
        EstimationError
            When a payload is missing or the data cannot determine the model.
        ValueError
            When ``ramp_side`` is not one of its values (a programming error).
        """
        if self.ramp_side not in ("both", "accelerate", "decelerate"):
            raise ValueError(f"ramp_side {self.ramp_side!r}: use both, accelerate or decelerate")
        if not recordings:
            raise EstimationError("no recordings to fit")
        loads: list[float] = []
        trays: list[float] = []
        for k, rec in enumerate(recordings):
            if payloads_kg is not None:
                loads.append(float(payloads_kg[k]))
            elif rec.metadata.payload_kg is not None:
                loads.append(rec.metadata.payload_kg)
            else:
                raise EstimationError(
                    f"{rec.source}: no payload_kg in its metadata; identification needs "
                    "recordings with a known load (add '# payload_kg: <kg>')"
                )
            if trays_kg is not None:
                trays.append(float(trays_kg[k]))
            else:
                tray = rec.metadata.tray_kg
                trays.append(tray if tray is not None else profile.tray_mass_kg)

        jd0 = profile.motor.inertia_kgm2 + profile.gear.inertia_kgm2
        first = self._solve(recordings, profile, loads, trays, jd0, (0.0, 0.0, 0.0), True)
        use_ramps = (
            self.ramp_windows
            if self.ramp_windows is not None
            else len(speed_clusters(first.plateau_speeds)) < 2
        )
        # second pass: the power-flow direction from the first pass's estimates
        v = first.values
        sol = self._solve(
            recordings, profile, loads, trays, float(v[0]), (v[2], v[3], v[4]), use_ramps
        )
        self.ramp_windows_used_ = use_ramps
        sv = sol.singular_values
        self.parameters_ = RigidParameters(sol.values, sol.covariance, tuple(sol.fixed))
        self.theta_ = sol.values
        self.covariance_ = sol.covariance
        self.names_ = PARAMETER_NAMES
        self.residual_rms_nm_ = sol.residual_rms_nm
        self.n_windows_ = sol.n_windows
        self.condition_ = float(sv[0] / sv[-1]) if sv[-1] > 0 else float("inf")
        self.loads_kg_ = tuple(loads)
        self.trays_kg_ = tuple(trays)
        self.plateau_speeds_ = tuple(sol.plateau_speeds)
        self.warnings_ = tuple(sol.warnings)
        self.noise_rates_ = sol.noise_rates
        self.profile_ = profile
        return self

    def _solve(
        self,
        recordings: Sequence[Recording],
        profile: ConveyorProfile,
        loads: list[float],
        trays: list[float],
        jd: float,
        losses: tuple[float, ...],
        use_ramps: bool,
    ) -> _Solution:
        xs: list[FloatArray] = []
        ys: list[FloatArray] = []
        groups: list[int] = []
        speeds: list[float] = []
        weights: list[FloatArray] = []
        ripples: list[FloatArray] = []
        kinds: list[np.ndarray] = []
        for k, rec in enumerate(recordings):
            mot = motoring_mask(
                rec,
                drive_inertia_kgm2=jd,
                losses=(losses[0], losses[1], losses[2]),
                torque_channel=self.torque_channel,
            )
            wi = window_integrals(
                rec,
                profile,
                motoring=mot,
                window_s=self.window_s,
                torque_channel=self.torque_channel,
            )
            if wi.constant.any():
                speeds.append(float(np.median(wi.mean_speed[wi.constant])))
            if not use_ramps:
                keep = (wi.kind == 1) | wi.constant
                wi = wi.select(keep) if keep.any() else wi
            if self.ramp_side != "both":
                speeding_up = wi.d_speed * wi.sign > 0
                other = speeding_up if self.ramp_side == "decelerate" else ~speeding_up
                keep = wi.constant | ~other
                wi = wi.select(keep) if keep.any() else wi
            x, y = design_matrix(wi, profile, payload_kg=loads[k], tray_kg=trays[k])
            xs.append(x)
            ys.append(y)
            ripples.append(wi.ripple)
            groups.extend([k] * wi.count)
            kinds.append(wi.kind)
            weights.append(1.0 / np.sqrt(wi.duration))
        # integral noise grows with the square root of the window's duration
        wt = np.concatenate(weights)
        x_main = np.vstack(xs) * wt[:, None]
        y_all = np.concatenate(ys) * wt
        # the polygon effect's tooth-pass ripple: nuisance columns, one block per recording
        n_rip = sum(r.shape[1] for r in ripples)
        x_rip = np.zeros((x_main.shape[0], n_rip))
        row = col = 0
        for rip in ripples:
            x_rip[row : row + rip.shape[0], col : col + rip.shape[1]] = rip
            row += rip.shape[0]
            col += rip.shape[1]
        x_rip *= wt[:, None]
        masses = np.array(trays) + np.array(loads)
        warnings: list[RecordingWarning] = []

        free = np.ones(5, dtype=bool)
        values = np.zeros(5)
        fixed: list[str] = []
        if float(np.ptp(masses)) < self.min_load_spread_kg:
            free[2] = False
            values[2] = self.bma_prior
            fixed.append("BmA")
            warnings.append(
                RecordingWarning(
                    "friction_not_separable",
                    "all recordings carry the same load "
                    f"({masses.min():.4g} kg tray + payload): rail friction and the constant "
                    f"gear loss BmA both scale with sign(speed) and cannot be told apart; "
                    f"BmA was fixed to {self.bma_prior:g} Nm and mu absorbs it. Add a "
                    "recording with a different known load to separate them",
                )
            )
        elif not self.fit_bma:
            free[2] = False
            values[2] = self.bma_prior
            fixed.append("BmA")
        if not self.fit_bmc:
            free[4] = False
            fixed.append("BmC")
        cols = np.flatnonzero(free)
        y_fit = y_all - x_main[:, ~free] @ values[~free]
        xf = np.hstack((x_main[:, cols], x_rip))
        scale = np.sqrt(np.mean(xf * xf, axis=0))
        scale[scale == 0.0] = 1.0
        xs_ = xf / scale
        sol, _res, rank, _sv = np.linalg.lstsq(xs_, y_fit, rcond=None)
        if rank < xf.shape[1]:
            raise EstimationError(
                "the recordings do not determine the model (rank "
                f"{rank} of {xf.shape[1]}); record complete moves with ramps"
            )
        coef = sol / scale
        resid = y_fit - xf @ coef
        # variance components: short and whole-ramp windows misfit differently
        # (ripple and ringing average out over a whole ramp), so each kind gets
        # its own noise rate and the fit is repeated with those weights
        kind = np.concatenate(kinds)
        rates = np.ones(2)
        for kk in (0, 1):
            sel = kind == kk
            if sel.sum() >= 3:
                rates[kk] = float(np.mean(resid[sel] ** 2))
        if (kind == 1).sum() < 3 or (kind == 0).sum() < 3:
            rates[:] = float(np.mean(resid**2))
        rw = 1.0 / np.sqrt(rates[kind]) if self.variance_components else np.ones_like(resid)
        xs_ = xs_ * rw[:, None]
        y_fit = y_fit * rw
        sol, _res, rank, _sv = np.linalg.lstsq(xs_, y_fit, rcond=None)
        coef = sol / scale
        values[cols] = coef[: cols.shape[0]]
        resid = y_fit - xs_ @ sol
        dof = max(resid.shape[0] - xf.shape[1], 1)
        s2 = float(resid @ resid) / dof
        inflate = float(
            np.mean(
                [
                    serial_correlation_factor(resid[np.array(groups) == g])
                    for g in range(len(recordings))
                ]
            )
        )
        xtx_inv = np.linalg.inv(xs_.T @ xs_)
        cov_s = s2 * inflate * xtx_inv / np.outer(scale, scale)
        cov = np.zeros((5, 5))
        m = cols.shape[0]
        cov[np.ix_(cols, cols)] = cov_s[:m, :m]
        # residual torque per window: the integral residual over the window's duration
        # (resid = integral residual / sqrt(duration), so resid·wt is the torque residual)
        rms = float(np.sqrt(np.mean((resid / rw * wt) ** 2)))
        sv_main = np.linalg.svd(xs_[:, :m], compute_uv=False)
        return _Solution(
            values, cov, rms, sv_main, int(y_all.shape[0]), speeds, warnings, fixed, rates
        )

    def _check(self) -> None:
        if not hasattr(self, "parameters_"):
            raise NotFittedError("RigidModelRegression is not fitted yet; call fit() first")

    @property
    def stderr_(self) -> FloatArray:
        """Standard errors in the order of :data:`PARAMETER_NAMES`."""
        self._check()
        return np.sqrt(np.clip(np.diag(self.covariance_), 0.0, None))

    def inertia_kgm2(self, payload_kg: float = 0.0, tray_kg: float | None = None) -> float:
        """Reflected inertia (motoring) at a payload, kg·m²: J_d + M·r²/(i²·η)."""
        self._check()
        p = self.profile_
        tray = p.tray_mass_kg if tray_kg is None else tray_kg
        return drive_inertia_at(p, self.parameters_["J_d"], p.belt_mass_kg + tray + payload_kg)

    def predict(
        self, recording: Recording, *, payload_kg: float, tray_kg: float | None = None
    ) -> FloatArray:
        """Model torque at every sample of a recording, Nm.

        Evaluates :func:`chaintwin.model.rigid.model_torque` with the fitted
        parameters.
        """
        self._check()
        return model_torque(
            recording,
            self.profile_,
            self.parameters_,
            payload_kg,
            tray_kg=self.profile_.tray_mass_kg if tray_kg is None else tray_kg,
        )
