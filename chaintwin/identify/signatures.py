"""The payload's two signatures in a recording, fitted against a calibrated model.

Shared by calibration (which checks its own recordings with it and learns
how the inertia signature behaves on this conveyor) and weighing. See
:mod:`chaintwin.weigh.weigh` for what the signatures are.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from numba import njit

from chaintwin._types import FloatArray
from chaintwin.errors import EstimationError
from chaintwin.identify.regression import serial_correlation_factor
from chaintwin.model.rigid import RigidParameters, incline_terms, motoring_mask
from chaintwin.model.windows import WindowIntegrals, window_integrals
from chaintwin.read.profile import ConveyorProfile
from chaintwin.read.recording import Recording
from chaintwin.validate.phases import Phase

__all__ = ["SignatureFit", "drift_bases", "fit_condition", "fit_signatures"]


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
    loss_gradient: FloatArray | None = None
    """How the estimates move when the gear losses are (1 + δ) times the
    calibration's: d estimate / dδ, in the estimates' units (kg; N·m·s/rad for
    :func:`fit_condition`'s ΔBmB)."""


def _columns(
    wi: WindowIntegrals, profile: ConveyorProfile, values: FloatArray, tray_kg: float
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Residual z of the empty model, friction and inertia regressors per kg.

    The inertia regressor is zero in windows at constant set point speed
    (``wi.constant``): see the comment in the body.

    ``values`` is one parameter vector (J_d, μ, BmA, BmB, BmC), giving z and
    the friction regressor per window, or a stack of them (K × 5), giving
    K × n_windows arrays (the same arithmetic per element, so each row is
    bit for bit what one vector gives). The inertia regressor does not
    depend on the parameters.
    """
    vals = np.asarray(values, dtype=np.float64)
    jd, mu, bma, bmb, bmc = (vals[..., j, None] for j in range(5))
    g_cos, g_sin = incline_terms(profile)
    m0 = profile.belt_mass_kg + tray_kg
    r_over_i = profile.chordal_radius_m / profile.kinematic_ratio
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
    # where the set point holds the speed (a plateau window) the payload's
    # inertia is not read: the measured Δω there is the encoder's noise, and
    # the same noise, times the drive's inertia (J_d·(i/r)², hundreds of kg at
    # the belt) and the belt's mass, is in z too. Read as acceleration, it
    # biases the inertia payload by about -(J_d·(i/r)²·η + M)·Σσ²_Δω/ΣΔω²
    # (errors in variables), a bias growing as 1/ω² as the plateau speed, and
    # with it each ramp's Δω, falls (-8 kg at 500 rpm against +1 kg at 1400 rpm
    # on an 8 m belt). The set point's Δω there is zero; z keeps the noise,
    # now uncorrelated with every regressor.
    xi = np.where(wi.constant, 0.0, r_over_i * wi.gf_accel)
    return wi.torque - base, xf, xi


def _fit(
    wi: WindowIntegrals,
    profile: ConveyorProfile,
    values: FloatArray,
    tray_kg: float,
    ramp_rate: float | None = None,
    loss_term: bool = False,
    columns: tuple[FloatArray, FloatArray, FloatArray] | None = None,
) -> SignatureFit:
    """Weighted least squares of the residual on the signatures and ripple terms.

    With ``loss_term`` a third unknown, a change of the speed-proportional
    gear loss ΔBmB (N·m·s/rad), is fitted beside the two signatures (needs
    a ramp: only the ramps vary the speed within a recording).

    Short and whole-ramp windows get their own noise rates (variance per
    second of window): the short windows' from this recording's residuals,
    the ramp windows' from the calibration (``ramp_rate``; a recording holds
    too few of them to tell), since a whole ramp averages out ripple and
    ringing that a short window does not.

    ``columns`` are :func:`_columns` of these windows, when already computed.
    """
    z, xf, xi = _columns(wi, profile, values, tray_kg) if columns is None else columns
    has_inertia = bool(np.any(wi.kind == 1))
    cols = [xf, xi] if has_inertia else [xf]
    if loss_term:
        if not has_inertia:
            raise EstimationError("a loss change needs a ramp between steady speeds")
        cols.append(wi.speed)
    x0 = np.column_stack([*cols, wi.ripple])
    scale = np.sqrt(np.mean(x0 * x0, axis=0))
    scale[scale == 0.0] = 1.0

    def solve(weights: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray, int]:
        xw = x0 / scale * weights[:, None]
        sol, _r, rank, _sv = np.linalg.lstsq(xw, z * weights, rcond=None)
        return sol, xw, z * weights - xw @ sol, int(rank)

    if z.shape[0] <= x0.shape[1]:
        raise EstimationError(
            f"{z.shape[0]} usable windows for {x0.shape[1]} unknowns: too little steady "
            "motion to weigh; record a complete move"
        )
    wt = 1.0 / np.sqrt(wi.duration)
    short = wi.kind == 0
    k = len(cols)
    rate = ramp_rate if ramp_rate is not None and np.isfinite(ramp_rate) else np.nan
    ok, coef, cov, weights = _two_pass(np.ascontiguousarray(x0), z, wt, short, float(rate))
    if ok:
        # well conditioned: solved by the normal equations in one compiled pass
        fit = _signature_fit(wi, z, xf, xi, coef, cov, weights, has_inertia, k, loss_term)
        return _with_loss_gradient(fit, x0, values) if loss_term else fit
    _sol, _xw, resid, _rank = solve(wt)
    rate_short = float(np.mean(resid[short] ** 2)) if short.sum() >= 3 else float(np.mean(resid**2))
    rate_ramp = ramp_rate if ramp_rate is not None and np.isfinite(ramp_rate) else rate_short
    floor = 1e-12 * max(float(np.mean((z * wt) ** 2)), 1e-30)
    rate_short = max(rate_short, floor)
    rates = np.where(short, rate_short, max(rate_ramp, floor))
    weights = wt / np.sqrt(rates)
    sol, xw, resid, rank = solve(weights)
    if rank < x0.shape[1]:
        raise EstimationError("the recording does not determine the payload")
    coef = sol / scale
    dof = max(z.shape[0] - x0.shape[1], 1)
    s2 = max(1.0, float(resid @ resid) / dof) * serial_correlation_factor(resid[short])
    try:
        cov = s2 * np.linalg.inv(xw.T @ xw) / np.outer(scale, scale)
    except np.linalg.LinAlgError:
        raise EstimationError("the recording does not determine the payload") from None
    fit = _signature_fit(wi, z, xf, xi, coef, cov, weights, has_inertia, k, loss_term)
    return _with_loss_gradient(fit, x0, values) if loss_term else fit


def drift_bases(values: FloatArray) -> list[FloatArray]:
    """What may drift with the oil's temperature, of one parameter vector
    (J_d, μ, BmA, BmB, BmC): the loss terms (BmA N·m, BmB N·m·s/rad, BmC
    N·m·s²/rad²) a drift scales, in one or two readings.

    With a negative calibrated loss term the calibration does not say which:
    it may be no loss but the fit's stand-in for what the rigid model lacks
    (then only the positive terms drift), or a real part of the loss curve's
    shape (then every term scales). The drift's allowance takes whichever
    reading moves the estimate in question more. Both happen: on a drawn
    conveyor 12° downhill, its belt nearly overhauling the gear (BmA = -0.050
    N·m, BmC negative, beside a viscous loss of 0.11 N·m at speed), scaling
    every term more than halved the drift's effect (the payload weighed
    trusting the losses moved 100 kg between the plant's losses at 0.9 and
    1.1 of nominal, the allowance said ±19 kg, a 31 kg payload was weighed
    -35 ± 22 kg); on another (1 ms scopes), the positive terms alone gave
    the smaller allowance (±5.6 kg against ±9 kg, its payloads weighed
    about 25 kg low: 54 of 91 weighings beyond 5 uncertainties).
    """
    every = np.asarray(values, dtype=np.float64)[2:5]
    positive = np.maximum(every, 0.0)
    return [positive] if np.array_equal(positive, every) else [positive, every]


def _with_loss_gradient(fit: SignatureFit, x0: FloatArray, values: FloatArray) -> SignatureFit:
    """The fit with its ``loss_gradient``: how its estimates move when the
    plant's gear losses are (1 + δ) times the calibration's, d estimate / dδ.

    The fit is linear in the measured torque at its final weights; a loss
    drift adds ``δ·(BmA·sign + BmB·ω + BmC·ω²)`` integrated over each window
    (the calibrated loss model, :func:`_columns`), so the gradient is one more
    weighted least-squares solve of that column, exact to the weights' own
    (second-order) dependence on the residuals.

    What drifts is :func:`drift_bases`; of two readings, the one that moves
    the speed-loss change (the condition fit's drift-sensitive estimate) more.
    """
    wi = fit.windows
    columns = np.column_stack(
        [b[0] * wi.sign + b[1] * wi.speed + b[2] * wi.speed_sq for b in drift_bases(values)]
    )
    w = fit.weights
    sol, _r, _rank, _sv = np.linalg.lstsq(x0 * w[:, None], columns * w[:, None], rcond=None)
    k = fit.estimate.shape[0]
    pick = int(np.argmax(np.abs(sol[k - 1, :])))
    return replace(fit, loss_gradient=np.asarray(sol[:k, pick], dtype=np.float64))


def _signature_fit(
    wi: WindowIntegrals,
    z: FloatArray,
    xf: FloatArray,
    xi: FloatArray,
    coef: FloatArray,
    cov: FloatArray,
    weights: FloatArray,
    has_inertia: bool,
    k: int,
    loss_term: bool,
) -> SignatureFit:
    """The fit of :func:`_fit` from its coefficients (``k`` signatures and loss
    term, then the ripple terms) and their covariance."""
    # friction payload of each window, other terms removed, for step detection
    rest = z - (xi * coef[1] if has_inertia else 0.0) - wi.ripple @ coef[k:]
    if loss_term:
        rest = rest - wi.speed * coef[2]
    with np.errstate(divide="ignore", invalid="ignore"):
        per_kg = np.where(np.abs(xf) > 0, rest / xf, np.nan)
    return SignatureFit(coef[:k], cov[:k, :k], has_inertia, wi, per_kg, weights)


@njit(cache=True, nogil=True)
def _two_pass(
    x0: np.ndarray, z: np.ndarray, wt: np.ndarray, short: np.ndarray, ramp_rate: float
) -> tuple[bool, np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """:func:`_fit`'s two weighted least-squares passes by their normal equations.

    The same arithmetic as its lstsq path (to rounding: the normal equations
    agree with lstsq when the scaled regressors are well conditioned,
    :data:`WELL_CONDITIONED`); ``ok`` False when a normal matrix is not, and
    the caller solves with lstsq. ``ramp_rate`` NaN: none given.

    Returns (ok, coefficients, covariance, weights).
    """
    n, p = x0.shape
    scale = np.empty(p)
    for j in range(p):
        acc = 0.0
        for i in range(n):
            acc += x0[i, j] * x0[i, j]
        scale[j] = np.sqrt(acc / n)
        if scale[j] == 0.0:
            scale[j] = 1.0
    xs = np.empty((n, p))
    for i in range(n):
        for j in range(p):
            xs[i, j] = x0[i, j] / scale[j]
    nshort = 0
    for i in range(n):
        if short[i]:
            nshort += 1
    empty = np.zeros(0)
    weights = wt.copy()
    resid = np.empty(n)
    normal = np.empty((p, p))
    for stage in range(2):
        a = np.empty((n, p))
        zw = np.empty(n)
        for i in range(n):
            zw[i] = z[i] * weights[i]
            for j in range(p):
                a[i, j] = xs[i, j] * weights[i]
        normal = a.T @ a
        eig = np.linalg.eigvalsh(normal)
        if not eig[0] > 1e-8 * eig[p - 1]:  # WELL_CONDITIONED
            return False, empty, np.zeros((0, 0)), weights
        sol = np.linalg.solve(normal, a.T @ zw)
        fitted = a @ sol
        for i in range(n):
            resid[i] = zw[i] - fitted[i]
        if stage == 1:
            coef = sol / scale
            break
        # noise rates of the short and the ramp windows from the first pass
        acc = 0.0
        cnt = 0
        for i in range(n):
            if short[i] or nshort < 3:
                acc += resid[i] * resid[i]
                cnt += 1
        rate_short = acc / cnt
        rate_ramp = ramp_rate if np.isfinite(ramp_rate) else rate_short
        acc = 0.0
        for i in range(n):
            acc += zw[i] * zw[i]
        floor = 1e-12 * max(acc / n, 1e-30)
        rate_short = max(rate_short, floor)
        rate_ramp = max(rate_ramp, floor)
        for i in range(n):
            weights[i] = wt[i] / np.sqrt(rate_short if short[i] else rate_ramp)
    dof = max(n - p, 1)
    ss = 0.0
    for i in range(n):
        ss += resid[i] * resid[i]
    # serial correlation of the short windows' residuals (serial_correlation_factor)
    factor = 1.0
    if nshort >= 3:
        r = np.empty(nshort)
        m = 0
        for i in range(n):
            if short[i]:
                r[m] = resid[i]
                m += 1
        mean = r.sum() / nshort
        r -= mean
        den = 0.0
        lag = 0.0
        for i in range(nshort):
            den += r[i] * r[i]
            if i > 0:
                lag += r[i] * r[i - 1]
        if den > 0.0:
            rho = min(max(lag / den, 0.0), 0.9)
            factor = (1.0 + rho) / (1.0 - rho)
    s2 = max(1.0, ss / dof) * factor
    cov = s2 * np.linalg.inv(normal) / np.outer(scale, scale)
    return True, coef, cov, weights


LOSS_STEP = 0.05
"""Relative step of the losses for their gradient in :func:`fit_signatures`, 1."""

WELL_CONDITIONED = 1e-8
"""Smallest eigenvalue ratio of a normal matrix :func:`_estimates` solves directly.

A condition number of the scaled regressors below 1e4, far from lstsq's
rank cut-off; the weighing's are typically about 4.
"""


def _estimates(
    wi: WindowIntegrals,
    profile: ConveyorProfile,
    values: FloatArray,
    tray_kg: float,
    ramp_rate: float | None = None,
) -> FloatArray:
    """The signature estimates of :func:`_fit`, for a stack of parameter vectors.

    For the numerical Jacobian of :func:`fit_signatures`, which asked
    :func:`_fit` ten times for the estimates alone. The same two weighted
    least-squares passes, solved together by their normal equations:

    * the regressors depend on the parameters through μ only, so they are
      scaled and weighted once per distinct μ;
    * the second pass's weights take one value over the short windows and
      one over the ramp windows, so its normal matrix is
      ``N_short/rate_short + N_ramp/rate_ramp`` of two matrices per μ.

    The normal equations agree with lstsq to rounding when the scaled
    regressors are well conditioned (:data:`WELL_CONDITIONED`); any
    parameter vector whose problem is not is handed to :func:`_fit` itself.

    Parameters
    ----------
    wi, profile, tray_kg, ramp_rate
        As :func:`_fit`.
    values : FloatArray
        K × 5 parameter vectors (J_d, μ, BmA, BmB, BmC).

    Returns
    -------
    FloatArray
        K × 1 (p_f) or K × 2 (p_f, raw p_i) estimates, kg.

    Raises
    ------
    EstimationError
        As :func:`_fit`.
    """
    z, xf, xi = _columns(wi, profile, values, tray_kg)
    _count, n = z.shape
    has_inertia = bool(np.any(wi.kind == 1))
    _mus, first, group = np.unique(values[:, 1], return_index=True, return_inverse=True)
    cols = [xf[first], np.broadcast_to(xi, (first.shape[0], n))] if has_inertia else [xf[first]]
    ripple = np.broadcast_to(wi.ripple, (first.shape[0], *wi.ripple.shape))
    x0 = np.concatenate([np.stack(cols, axis=-1), ripple], axis=-1)  # per μ: n × p
    p = x0.shape[-1]
    if n <= p:
        raise EstimationError(
            f"{n} usable windows for {p} unknowns: too little steady "
            "motion to weigh; record a complete move"
        )
    wt = 1.0 / np.sqrt(wi.duration)
    short = wi.kind == 0
    rate = ramp_rate if ramp_rate is not None and np.isfinite(ramp_rate) else np.nan
    # both passes per parameter vector in one compiled kernel, the regressors
    # and their normal matrices once per distinct μ
    estimates, good = _stacked_two_pass(
        np.ascontiguousarray(x0), np.ascontiguousarray(z), wt, short, float(rate), group
    )
    estimates = estimates[:, : len(cols)]
    for k in np.flatnonzero(~good):
        estimates[k] = _fit(wi, profile, values[k], tray_kg, ramp_rate).estimate
    return estimates


@njit(cache=True, nogil=True)
def _stacked_two_pass(
    x0: np.ndarray,
    z: np.ndarray,
    wt: np.ndarray,
    short: np.ndarray,
    ramp_rate: float,
    group: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """The coefficients of :func:`_two_pass` for a stack of residuals ``z`` (K × n),
    the regressors ``x0[group[k]]`` (per distinct μ: n × p) shared.

    The second pass's weights take one value over the short windows and one
    over the ramp windows, so its normal matrix is ``N_short/rate_short +
    N_ramp/rate_ramp`` of two matrices per μ. Returns (K × p coefficients,
    whether each problem was well conditioned: where not, the caller fits
    with :func:`_fit`).
    """
    groups, n, p = x0.shape
    count = z.shape[0]
    nshort = 0
    for i in range(n):
        if short[i]:
            nshort += 1
    scale = np.empty((groups, p))
    a = np.empty((groups, n, p))
    n_first = np.empty((groups, p, p))
    n_short = np.zeros((groups, p, p))
    n_ramp = np.zeros((groups, p, p))
    good_first = np.empty(groups, dtype=np.bool_)
    for g in range(groups):
        for j in range(p):
            acc = 0.0
            for i in range(n):
                acc += x0[g, i, j] * x0[g, i, j]
            scale[g, j] = np.sqrt(acc / n)
            if scale[g, j] == 0.0:
                scale[g, j] = 1.0
        for i in range(n):
            for j in range(p):
                a[g, i, j] = x0[g, i, j] / scale[g, j] * wt[i]
        ag = a[g]
        n_first[g] = ag.T @ ag
        eig = np.linalg.eigvalsh(n_first[g])
        good_first[g] = eig[0] > 1e-8 * eig[p - 1]  # WELL_CONDITIONED
        for i in range(n):
            target = n_short[g] if short[i] else n_ramp[g]
            for j in range(p):
                for m in range(p):
                    target[j, m] += ag[i, j] * ag[i, m]
    out = np.zeros((count, p))
    good = np.zeros(count, dtype=np.bool_)
    zw = np.empty(n)
    for k in range(count):
        g = group[k]
        if not good_first[g]:
            continue
        ag = a[g]
        for i in range(n):
            zw[i] = z[k, i] * wt[i]
        sol = np.linalg.solve(n_first[g], ag.T @ zw)
        fitted = ag @ sol
        acc = 0.0
        cnt = 0
        total = 0.0
        for i in range(n):
            r = zw[i] - fitted[i]
            if short[i] or nshort < 3:
                acc += r * r
                cnt += 1
            total += zw[i] * zw[i]
        rate_short = acc / cnt
        rate_ramp = ramp_rate if np.isfinite(ramp_rate) else rate_short
        floor = 1e-12 * max(total / n, 1e-30)
        rate_short = max(rate_short, floor)
        rate_ramp = max(rate_ramp, floor)
        normal = n_short[g] / rate_short + n_ramp[g] / rate_ramp
        eig = np.linalg.eigvalsh(normal)
        if not eig[0] > 1e-8 * eig[p - 1]:
            continue
        rhs = np.zeros(p)
        for i in range(n):
            w = zw[i] / (rate_short if short[i] else rate_ramp)
            for j in range(p):
                rhs[j] += ag[i, j] * w
        sol = np.linalg.solve(normal, rhs)
        for j in range(p):
            out[k, j] = sol[j] / scale[g, j]
        good[k] = True
    return out, good


def fit_signatures(
    rec: Recording,
    prof: ConveyorProfile,
    params: RigidParameters,
    tray: float,
    span: tuple[float, float] | None = None,
    motoring: np.ndarray | None = None,
    ramp_rate: float | None = None,
    windows: WindowIntegrals | None = None,
    phases: Sequence[Phase] | None = None,
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
    ramp_rate : float, optional
        Noise rate of whole-ramp windows learned by the calibration,
        (N·m·s)²/s (default: that of the short windows).
    windows : WindowIntegrals, optional
        The recording's window integrals, when already computed with this
        ``motoring`` (ignored with a ``span``).
    phases : sequence of Phase, optional
        The recording's movement phases (validation's segmentation), passed
        to :func:`~chaintwin.model.windows.window_integrals`.

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
            losses=params.losses,
        )
    if windows is not None and span is None:
        every = windows
    else:
        every = window_integrals(
            rec, prof, motoring=motoring, span=span, phases=None if phases is None else list(phases)
        )
    # primary: plateau windows and whole-ramp windows; the short windows inside
    # ramps see the belt's ringing against the motor's acceleration and bias the
    # inertia signature of a lightly damped belt
    keep = (every.kind == 1) | every.constant
    wi = every.select(keep) if keep.any() else every
    # the columns per window (elementwise): those of every window, selected
    cols_every = _columns(every, prof, params.values, tray)
    cols = cols_every
    if keep.any():
        z_all, xf_all, xi_all = cols_every
        cols = (z_all[..., keep], xf_all[..., keep], xi_all[keep])
    base = _fit(wi, prof, params.values, tray, ramp_rate, columns=cols)
    alternative: float | None = None
    if base.has_inertia and not keep.all():
        try:
            fit_every = _fit(every, prof, params.values, tray, ramp_rate, columns=cols_every)
            alternative = float(fit_every.estimate[1])
        except EstimationError:
            alternative = None
    base = replace(base, inertia_alternative=alternative)
    k = base.estimate.shape[0]
    jac = np.zeros((k, 5))
    # central differences: each parameter half a standard deviation up and down
    moved: list[int] = []
    steps: list[float] = []
    shifted: list[FloatArray] = []
    for j in range(5):
        sd = float(np.sqrt(max(params.covariance[j, j], 0.0)))
        if sd == 0.0:
            continue
        step = 0.5 * sd
        up = params.values.copy()
        up[j] += step
        dn = params.values.copy()
        dn[j] -= step
        moved.append(j)
        steps.append(step)
        shifted += [up, dn]
    # and the losses moved by ± LOSS_STEP of what may drift, for the loss drift's effect
    bases = drift_bases(params.values)
    for basis in bases:
        for sign in (1.0, -1.0):
            scaled = params.values.copy()
            scaled[2:] += sign * LOSS_STEP * basis
            shifted.append(scaled)
    est = _estimates(wi, prof, np.stack(shifted), tray, ramp_rate)
    for m, (j, step) in enumerate(zip(moved, steps, strict=True)):
        jac[:, j] = (est[2 * m] - est[2 * m + 1]) / (2 * step)
    # the model subtracts the calibrated losses: when the plant's are (1 + δ)
    # times those, the estimates move as if the calibrated ones were (1 - δ);
    # of the two readings of what drifts, the one that moves the friction
    # payload (the drift-sensitive estimate) more
    tail = est[len(est) - 2 * len(bases) :]
    gradients = [-(tail[2 * b] - tail[2 * b + 1]) / (2.0 * LOSS_STEP) for b in range(len(bases))]
    base = replace(base, loss_gradient=max(gradients, key=lambda g: abs(float(g[0]))))
    return base, base.covariance + jac @ params.covariance @ jac.T


def fit_condition(
    rec: Recording,
    prof: ConveyorProfile,
    params: RigidParameters,
    tray: float,
    motoring: np.ndarray | None = None,
    ramp_rate: float | None = None,
    windows: WindowIntegrals | None = None,
) -> SignatureFit:
    """Friction payload, inertia payload and a speed-loss change, fitted together.

    For condition monitoring: a change of the rail friction moves the
    friction payload away from the inertia payload, a change of the gear
    unit's speed-dependent losses (lubrication, temperature) shows as ΔBmB,
    and fitting both keeps one from being read as the other (at a single
    plateau speed the two are told apart by the ramps only, so ΔBmB is less
    precise than either payload). Uses every window, ramp interiors included.

    Parameters
    ----------
    rec, prof, params, tray, motoring, ramp_rate, windows
        As :func:`fit_signatures`.

    Returns
    -------
    SignatureFit
        ``estimate`` = [p_f (kg), p_i (kg, raw: before the calibration's
        inertia gain), ΔBmB (N·m·s/rad)], statistical covariance only.

    Raises
    ------
    EstimationError
        Without a ramp between steady speeds, or too few windows.
    """
    if motoring is None:
        motoring = motoring_mask(
            rec,
            drive_inertia_kgm2=params["J_d"],
            losses=params.losses,
        )
    every = windows if windows is not None else window_integrals(rec, prof, motoring=motoring)
    return _fit(every, prof, params.values, tray, ramp_rate, loss_term=True)
