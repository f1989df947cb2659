"""The payload's two signatures in a recording, fitted against a calibrated model.

Shared by calibration (which checks its own recordings with it and learns
how the inertia signature behaves on this conveyor) and weighing. See
:mod:`chaintwin.weigh.weigh` for what the signatures are.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from chaintwin.errors import EstimationError
from chaintwin.identify.regression import RigidParameters, serial_correlation_factor
from chaintwin.identify.windows import (
    WindowIntegrals,
    incline_terms,
    motoring_mask,
    window_integrals,
)
from chaintwin.read.profile import ConveyorProfile
from chaintwin.read.recording import FloatArray, Recording

__all__ = ["SignatureFit", "fit_signatures"]


@dataclass(frozen=True)
class SignatureFit:
    """Raw friction (and inertia) payload estimates of one recording, kg."""

    estimate: FloatArray  # [p_f] or [p_f, p_i]
    covariance: FloatArray
    has_inertia: bool
    windows: WindowIntegrals
    residual_per_kg: FloatArray  # per-window friction payload for step detection
    weights: FloatArray
    inertia_alternative: float | None = None
    """Raw inertia payload from every window (ramp interiors too), kg: a second
    estimator whose disagreement with the primary one measures the inertia
    signature's model error on this recording."""


def _columns(
    wi: WindowIntegrals, profile: ConveyorProfile, values: FloatArray, tray_kg: float
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Residual z of the empty model, friction and inertia regressors per kg."""
    jd, mu, bma, bmb, bmc = (float(v) for v in values)
    g_cos, g_sin = incline_terms(profile)
    m0 = profile.belt_mass_kg + tray_kg
    r_over_i = profile.chordal_radius_m / profile.gear.ratio
    base = (
        jd * wi.d_speed
        + g_cos * mu * m0 * wi.gf_sign
        + g_sin * tray_kg * wi.gf
        + m0 * r_over_i * wi.gf_accel
        + bma * wi.sign
        + bmb * wi.speed
        + bmc * wi.speed_sq
    )
    xf = g_cos * mu * wi.gf_sign + g_sin * wi.gf
    xi = r_over_i * wi.gf_accel
    return wi.torque - base, xf, xi


def _fit(
    wi: WindowIntegrals, profile: ConveyorProfile, values: FloatArray, tray_kg: float
) -> SignatureFit:
    z, xf, xi = _columns(wi, profile, values, tray_kg)
    wt = 1.0 / np.sqrt(wi.duration)
    has_inertia = bool(np.any(wi.kind == 1))
    cols = [xf, xi] if has_inertia else [xf]
    x = np.column_stack([*cols, wi.ripple]) * wt[:, None]
    y = z * wt
    scale = np.sqrt(np.mean(x * x, axis=0))
    scale[scale == 0.0] = 1.0
    sol, _r, rank, _sv = np.linalg.lstsq(x / scale, y, rcond=None)
    if rank < x.shape[1]:
        raise EstimationError("the recording does not determine the payload")
    coef = sol / scale
    resid = y - x @ coef
    dof = max(y.shape[0] - x.shape[1], 1)
    s2 = float(resid @ resid) / dof * serial_correlation_factor(resid)
    xs = x / scale
    cov = s2 * np.linalg.inv(xs.T @ xs) / np.outer(scale, scale)
    k = len(cols)
    # friction payload of each window, other terms removed, for step detection
    rest = z - (xi * coef[1] if has_inertia else 0.0) - wi.ripple @ coef[k:]
    with np.errstate(divide="ignore", invalid="ignore"):
        per_kg = np.where(np.abs(xf) > 0, rest / xf, np.nan)
    return SignatureFit(coef[:k], cov[:k, :k], has_inertia, wi, per_kg, wt)


def fit_signatures(
    rec: Recording,
    prof: ConveyorProfile,
    params: RigidParameters,
    tray: float,
    span: tuple[float, float] | None = None,
    motoring: np.ndarray | None = None,
) -> tuple[SignatureFit, FloatArray]:
    """Fit the payload signatures against a calibrated empty-conveyor model.

    Parameters
    ----------
    rec : Recording
        The recording.
    prof : ConveyorProfile
        The profile (without ``model:``).
    params : RigidParameters
        Calibrated J_d, μ, BmA, BmB, BmC with covariance.
    tray : float
        Tray mass of the recording, kg.
    span : (float, float), optional
        Only windows inside this time span, s.
    motoring : np.ndarray of bool, optional
        Power-flow direction per sample (default from ``params``).

    Returns
    -------
    (SignatureFit, FloatArray)
        The fit (its ``covariance`` statistical only) and the covariance
        with the calibration's uncertainty propagated in (numerical Jacobian).
    """
    if motoring is None:
        motoring = motoring_mask(
            rec,
            drive_inertia_kgm2=params["J_d"],
            losses=(params["BmA"], params["BmB"], params["BmC"]),
        )
    every = window_integrals(rec, prof, motoring=motoring, span=span)
    # primary: plateau windows and whole-ramp windows; the short windows inside
    # ramps see the belt's ringing against the motor's acceleration and bias the
    # inertia signature of a lightly damped belt
    keep = (every.kind == 1) | every.constant
    wi = every.select(keep) if keep.any() else every
    base = _fit(wi, prof, params.values, tray)
    alternative: float | None = None
    if base.has_inertia and not keep.all():
        try:
            alternative = float(_fit(every, prof, params.values, tray).estimate[1])
        except EstimationError:
            alternative = None
    base = replace(base, inertia_alternative=alternative)
    k = base.estimate.shape[0]
    jac = np.zeros((k, 5))
    for j in range(5):
        sd = float(np.sqrt(max(params.covariance[j, j], 0.0)))
        if sd == 0.0:
            continue
        step = 0.5 * sd
        up = params.values.copy()
        up[j] += step
        dn = params.values.copy()
        dn[j] -= step
        jac[:, j] = (_fit(wi, prof, up, tray).estimate - _fit(wi, prof, dn, tray).estimate) / (
            2 * step
        )
    return base, base.covariance + jac @ params.covariance @ jac.T
