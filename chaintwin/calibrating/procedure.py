"""Calibrating a conveyor: its rigid-model parameters from recordings with a known load.

:func:`calibrate` fits :class:`~chaintwin.identify.regression.RigidModelRegression`
to the recordings, checks the ramps where the protocol is weak, identifies
the torque lag and the inertia signature's gain, and returns a
:class:`~chaintwin.identify.calibration.Calibration` (the record and its
file format live in :mod:`chaintwin.identify.calibration`; the protocols
and their limits are described there and in docs/design.md, section 3).
"""

from __future__ import annotations

import copy
import hashlib
import math
from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from chaintwin.errors import CalibrationError, ChaintwinError, EstimationError
from chaintwin.identify.calibration import (
    INERTIA_GAIN_PRIOR_SIGMA,
    Calibration,
    broken_invariant,
    identification_profile,
)
from chaintwin.identify.channels import choose_channel, measure_spreads, on_channel
from chaintwin.identify.regression import RigidModelRegression, speed_clusters
from chaintwin.identify.torque_lag import identify_torque_lag
from chaintwin.identify.zero_reference import ZeroReference
from chaintwin.model.rigid import PARAMETER_NAMES, RigidParameters
from chaintwin.model.windows import window_integrals
from chaintwin.read.files import read_limited
from chaintwin.read.profile import ConveyorProfile
from chaintwin.read.recording import Recording, RecordingWarning
from chaintwin.units import RPM_TO_RAD_S
from chaintwin.validate.phases import segment

__all__ = ["calibrate"]


def _sha256(recording: Recording) -> str | None:
    try:
        raw = read_limited(recording.source, what="recording", error=CalibrationError)
    except ChaintwinError:
        return None
    return hashlib.sha256(raw).hexdigest()


def _torque_lag(
    recordings: Sequence[Recording], profile: ConveyorProfile
) -> tuple[float | None, float | None, list[RecordingWarning]]:
    """Torque lag from recordings sampled at the controller cycle, inverse-variance pooled."""
    taus: list[float] = []
    errs: list[float] = []
    cycle = profile.controller.cycle_s
    for rec in recordings:
        tsp = rec.torque_setpoint
        if tsp is None or abs(rec.sample_time_s - cycle) > 0.05 * cycle:
            continue
        try:
            res = identify_torque_lag(rec.time, tsp, rec.torque, cycle_s=cycle)
        except EstimationError:
            continue
        if res.tau_stderr_s > 0 and math.isfinite(res.tau_stderr_s):
            taus.append(res.tau_s)
            errs.append(res.tau_stderr_s)
    if not taus:
        return (
            None,
            None,
            [
                RecordingWarning(
                    "torque_lag_unknown",
                    "the torque lag needs a recording at the controller cycle "
                    f"({cycle * 1e3:g} ms) with the torque set point; none was given",
                )
            ],
        )
    w = 1.0 / np.square(errs)
    tau = float(np.sum(w * np.asarray(taus)) / np.sum(w))
    return tau, float(1.0 / np.sqrt(np.sum(w))), []


def _calibrate_inertia_signature(
    cal: Calibration,
    recordings: Sequence[Recording],
    loads: Sequence[float],
    trays: Sequence[float],
) -> Calibration:
    """Learn how the raw inertia signature reads the known loads (gain, offset, scatter)."""
    from chaintwin.identify.signatures import fit_signatures

    known: list[float] = []
    raw: list[float] = []
    var: list[float] = []
    for rec, load, tray in zip(recordings, loads, trays, strict=True):
        try:
            fit, cov = fit_signatures(
                rec, cal.id_profile, cal.parameters, tray, ramp_rate=cal.ramp_noise_rate
            )
        except EstimationError:
            continue
        if fit.has_inertia:
            known.append(load)
            raw.append(float(fit.estimate[1]))
            var.append(float(cov[1, 1]))
    if not raw:
        return cal
    p = np.asarray(known)
    y = np.asarray(raw)
    w = 1.0 / np.maximum(np.asarray(var), 1e-12)
    if float(np.ptp(p)) >= 5.0:
        x = np.column_stack((np.ones_like(p), p))
        xtw = x.T * w
        cov = np.linalg.inv(xtw @ x)
        offset, gain = cov @ (xtw @ y)
        res = y - (offset + gain * p)
        if len(p) > 2:  # scatter beyond the stated uncertainties widens the estimate
            cov = cov * max(1.0, float(np.sum(w * res * res)) / (len(p) - 2))
        # combine with the physics prior gain = 1 ± INERTIA_GAIN_PRIOR_SIGMA
        prior_w = 1.0 / INERTIA_GAIN_PRIOR_SIGMA**2
        data_w = 1.0 / cov[1, 1]
        gain_post = (prior_w * 1.0 + data_w * gain) / (prior_w + data_w)
        return replace(
            cal,
            inertia_gain=float(gain_post),
            inertia_gain_sigma=float(np.sqrt(1.0 / (prior_w + data_w))),
            inertia_offset_kg=float(offset),
            inertia_offset_sigma_kg=float(np.sqrt(cov[0, 0])),
        )
    offset = float(np.sum(w * (y - p)) / np.sum(w))
    return replace(
        cal,
        inertia_offset_kg=offset,
        inertia_offset_sigma_kg=float(np.sqrt(1.0 / np.sum(w))),
    )


FRICTION_CHECK_MAX = 0.5
"""Above this smallest detectable rail friction change (relative, on the
calibration's best-placed recording) the calibration warns ``friction_unchecked``."""


def _friction_check(cal: Calibration, recordings: Sequence[Recording]) -> RecordingWarning | None:
    """Warn when this conveyor's recordings cannot check the rail friction.

    Each calibration recording is weighed with the new calibration; its
    :attr:`~chaintwin.weigh.weigh.WeighResult.friction_checked_rel` is the
    smallest relative friction change its inertia signature would catch.
    The best of them stands for the conveyor's operation (the slow empty
    runs ramp more gently than production does). When even that exceeds
    :data:`FRICTION_CHECK_MAX` (a heavy drive
    against a light belt, slow ramps, a coarse scope), a rise of the rail
    friction reads as payload, unseen: the weights then rest on the rail
    friction staying as calibrated.
    """
    from chaintwin.validate.checks import inspect_recording
    from chaintwin.weigh.drift import LossDrift
    from chaintwin.weigh.weigh import weigh

    checked: list[float] = []
    per_10pct: list[float] = []
    for rec in recordings:
        try:
            res = weigh(inspect_recording(rec, cal.profile), cal, loss_drift=LossDrift.unknown())
        except ChaintwinError:
            continue
        rel = res.friction_checked_rel
        checked.append(math.inf if rel is None else rel)
        if res.friction_10pct_kg is not None:
            per_10pct.append(abs(res.friction_10pct_kg))
    if not checked:
        return None
    best = min(checked)
    if best <= FRICTION_CHECK_MAX:
        return None
    unseen = "any change" if not math.isfinite(best) else f"a change up to {best:.0%}"
    kg = f" ({float(np.median(per_10pct)):.1f} kg per 10 %)" if per_10pct else ""
    return RecordingWarning(
        "friction_unchecked",
        f"the ramps cannot check the rail friction: {unseen} of it would read as "
        f"payload{kg} without a warning; the weights rest on the "
        "rail friction of this calibration. Record steeper or longer ramps (the inertia "
        "signature grows with the acceleration and the scope's length), check the weights "
        "with a reference load now and then, or weigh with `--friction-drift 0.1` to "
        "carry a 10 % friction drift into the uncertainty",
    )


CLOSURE_QUANTILE = 0.99
"""Own recordings misread beyond this chi-square quantile widen μ's uncertainty
(:func:`_closure`)."""


def _closure(
    cal: Calibration,
    recordings: Sequence[Recording],
    loads: Sequence[float],
) -> tuple[Calibration, RecordingWarning | None]:
    """Weigh the calibration's own recordings: do they read back their known loads?

    Each recording is weighed with the calibration's losses trusted; its
    friction-signature payload is compared with the load it was recorded
    with. The fit's statistics assume the rigid model holds; where it does
    not over these recordings (seen on a 21.7 m belt recorded by a 1 ms scope:
    seven 2 s recordings, μ fitted 34 % high, the own recordings read 32 kg
    light on average, 8.7 times what they stated),
    the misreads exceed what they state. When their mean squared ratio to
    the stated uncertainty lies beyond the chi-square's
    :data:`CLOSURE_QUANTILE`, the excess mean square (kg²) is carried into
    μ's variance, converted by how the friction payload moves with μ
    (``(m_b + m_t + m_p)/μ`` kg per unit of μ), as the ramp check carries
    its split-half error (:func:`_widen_mu`): every weight with this
    calibration then includes it.
    """
    from scipy.stats import chi2

    from chaintwin.validate.checks import inspect_recording
    from chaintwin.weigh.drift import LossDrift
    from chaintwin.weigh.weigh import weigh

    errors: list[float] = []
    variances: list[float] = []
    masses: list[float] = []
    for rec, load in zip(recordings, loads, strict=True):
        try:
            res = weigh(inspect_recording(rec, cal.profile), cal, loss_drift=LossDrift())
        except ChaintwinError:
            continue
        sig = res.signatures
        if sig is None or not math.isfinite(sig.friction_var) or sig.friction_var <= 0.0:
            continue
        errors.append(sig.friction_kg - load)
        variances.append(sig.friction_var)
        masses.append(sig.moving_mass_kg + load)
    n = len(errors)
    if n == 0:
        return cal, None
    e = np.asarray(errors)
    ratio = float(np.mean(e * e / np.asarray(variances)))
    if ratio <= float(chi2.ppf(CLOSURE_QUANTILE, n)) / n:
        return cal, None
    excess = float(np.mean(e * e) - np.mean(variances))
    if excess <= 0.0:
        return cal, None
    mu = abs(float(cal.parameters["mu"]))
    sigma_mu = math.sqrt(excess) * mu / float(np.mean(masses))
    note = RecordingWarning(
        "calibration_misreads_own",
        f"weighed with this calibration, its own {n} recordings read their known loads "
        f"{float(np.mean(e)):+.1f} kg off on average (RMS {math.sqrt(float(np.mean(e * e))):.1f} "
        f"kg, {math.sqrt(ratio):.1f} times what they state): the rigid model does not hold "
        f"over them; {sigma_mu / mu:.1%} of mu is added to mu's uncertainty. Record longer "
        "moves (a longer scope sample time) and a heavier reference load",
    )
    return replace(cal, parameters=_widen_mu(cal.parameters, sigma_mu)), note


def _widen_mu(parameters: RigidParameters, half: float) -> RigidParameters:
    """``parameters`` with ``half`` (the split-half estimate of a systematic
    error of μ) added in quadrature to μ's standard uncertainty."""
    k = PARAMETER_NAMES.index("mu")
    cov = np.array(parameters.covariance, dtype=np.float64)
    cov[k, k] += half * half
    return replace(parameters, covariance=cov)


def _ramp_check(
    settings: RigidModelRegression,
    recordings: Sequence[Recording],
    profile: ConveyorProfile,
    parameters: RigidParameters,
) -> tuple[RigidParameters, list[RecordingWarning]]:
    """One load at one speed: μ from each ramp side alone; their disagreement joins μ's uncertainty.

    With one load at one speed, friction is told from the speed-dependent
    gear losses only by how the torque follows the speed in the ramps, in
    effect by extrapolating the losses to standstill. What the rigid model
    misses there (breakaway and the belt winding up when starting, the
    power-flow change and the belt unwinding when braking) biases that
    extrapolation by several percent of μ on the virtual conveyor, far more
    than the fit's statistical error says. The accelerating and the
    decelerating ramps suffer differently, so fitting each side alone and
    taking half their difference as a further standard uncertainty of μ
    (added in quadrature) makes the reported sensitivity uncertainty cover
    that bias: the split-half estimate of a systematic error.
    """
    mus: dict[str, float] = {}
    for side in ("accelerate", "decelerate"):
        one = copy.copy(settings)
        one.ramp_side = side
        try:
            mus[side] = one.fit(recordings, profile).parameters_["mu"]
        except EstimationError:
            continue
    if len(mus) < 2:
        return parameters, [
            RecordingWarning(
                "ramp_check",
                "one load at one speed: the ramps could not be fitted side by side, so the "
                "friction's extrapolation to standstill is not checked; its uncertainty is "
                "the fit's statistical one only",
            )
        ]
    half = 0.5 * abs(mus["accelerate"] - mus["decelerate"])
    mu = parameters["mu"]
    note = RecordingWarning(
        "ramp_check",
        f"one load at one speed: the accelerating ramps alone give mu = "
        f"{mus['accelerate']:.4f}, the decelerating ones {mus['decelerate']:.4f}; half their "
        f"difference ({half / mu:.1%} of mu) is added to mu's uncertainty (what the rigid "
        "model misses in the ramps)",
    )
    return _widen_mu(parameters, half), [note]


STICK_SLIP_RATIO = 3.0
"""A plateau stick-slips when its speed ripple exceeds this many times the fastest ones'."""
STICK_SLIP_MIN_CV = 0.01
"""... and this share of its mean speed (polygon ripple and noise stay below), 1."""
LOSS_SIGNIFICANCE = 2.0
"""A loss coefficient this many standard errors below zero is physically impossible."""


def plateau_ripple(recording: Recording) -> tuple[float, float] | None:
    """Speed ripple on a recording's longest constant-speed phase.

    Returns
    -------
    tuple of float or None
        ``(cv, speed)``: the standard deviation of the speed over the phase's
        middle half divided by its mean magnitude (1), and that mean (rad/s);
        None without a constant phase of 8 samples or more.
    """
    phases = [p for p in segment(recording) if p.kind == "constant" and p.stop - p.start >= 8]
    if not phases:
        return None
    ph = max(phases, key=lambda p: p.stop - p.start)
    quarter = (ph.stop - ph.start) // 4
    w = recording.speed[ph.start + quarter : ph.stop - quarter]
    mean = float(np.mean(np.abs(w)))
    if mean <= 0.0:
        return None
    return float(np.std(w)) / mean, mean


def _stick_slip(recordings: Sequence[Recording]) -> list[tuple[str, float, float, float]]:
    """Plateaus that stick-slip: ``(source, cv, reference cv, speed rad/s)`` each.

    Slow plateaus of a long, elastic belt whose friction falls with speed
    (Stribeck) stick and slip: the speed ripples and the mean torque no longer
    reads the sliding friction. The reference is the median ripple of the
    fastest speed's plateaus (polygon effect and noise).
    """
    ripples = [(rec.source, plateau_ripple(rec)) for rec in recordings]
    found = [(src, r) for src, r in ripples if r is not None]
    if len(found) < 2:
        return []
    speeds = speed_clusters([r[1] for _, r in found])
    fastest = [r[0] for _, r in found if r[1] >= speeds[-1] / (1.0 + 0.05)]
    ref = float(np.median(fastest))
    return [
        (src, cv, ref, speed)
        for src, (cv, speed) in found
        if cv > max(STICK_SLIP_MIN_CV, STICK_SLIP_RATIO * ref) and speed < speeds[-1] / 1.05
    ]


def _loss_check(
    settings: RigidModelRegression,
    recordings: Sequence[Recording],
    profile: ConveyorProfile,
    parameters: RigidParameters,
) -> tuple[RigidParameters, list[RecordingWarning]]:
    """Empty runs at several speeds: fall back to linear losses where the fit is not physical.

    Three plateau speeds determine μ, BmB and BmC exactly, so the fit cannot
    show its own model error, and an error of the slowest plateau's torque
    reaches μ about three times amplified (the losses' extrapolation to
    standstill). Two signs that this happened: a loss coefficient
    significantly below zero (losses that fall with speed do not exist), or a
    plateau that stick-slips. Then the fit is repeated with BmC fixed to 0
    (losses linear in speed: fewer unknowns than speeds, so the plateaus
    check each other) and half the difference of the two μ joins μ's
    uncertainty (the split-half allowance of :func:`_ramp_check`).
    """
    notes: list[RecordingWarning] = []
    reasons: list[str] = []
    for name in ("BmB", "BmC"):
        sd = parameters.stderr(name)
        if name not in parameters.fixed and sd > 0 and parameters[name] < -LOSS_SIGNIFICANCE * sd:
            reasons.append(
                f"{name} = {parameters[name]:.3g} is below zero by "
                f"{-parameters[name] / sd:.1f} standard errors"
            )
    for src, cv, ref, speed in _stick_slip(recordings):
        reason = (
            f"{src}: the plateau at {speed / RPM_TO_RAD_S:.0f} rpm stick-slips (speed ripple "
            f"{cv:.1%} of its speed, {ref:.1%} on the fastest plateaus)"
        )
        reasons.append(reason)
        notes.append(
            RecordingWarning(
                "stick_slip",
                reason + "; its torque does not read the sliding friction. Record the slow "
                "runs faster (at least twice this speed) or add a run with a known reference "
                "load",
            )
        )
    if not reasons or not settings.fit_bmc:
        return parameters, notes
    linear = copy.copy(settings)
    linear.fit_bmc = False
    try:
        refit = linear.fit(recordings, profile).parameters_
    except EstimationError:
        return parameters, notes
    half = 0.5 * abs(parameters["mu"] - refit["mu"])
    notes.append(
        RecordingWarning(
            "losses_not_physical",
            "the plateaus do not fit losses that rise with speed as physics has them ("
            + "; ".join(reasons)
            + f"): refitted with losses linear in speed, mu = {refit['mu']:.4f} instead of "
            f"{parameters['mu']:.4f}; half the difference ({half / max(refit['mu'], 1e-12):.1%}"
            " of mu) is added to mu's uncertainty",
        )
    )
    return _widen_mu(refit, half), notes


def _constant_loss_check(
    settings: RigidModelRegression,
    recordings: Sequence[Recording],
    profile: ConveyorProfile,
    parameters: RigidParameters,
) -> tuple[RigidParameters, list[RecordingWarning]]:
    """Several loads: a constant loss found below zero is no loss; refit without it
    and let half the difference of the two μ join μ's uncertainty.

    The empty runs cannot tell the belt's friction μ·m0 from the constant
    gear loss BmA (both a torque of the travel's sign); only the loads do,
    and a small one on a heavy belt barely. On a drawn conveyor (251 kg belt,
    one 20 kg reference run, 1 ms scopes) the fit found μ = 0.348 ± 0.056 and
    BmA = -1.15 ± 0.32 N·m where the plant had μ = 0.128 and no constant
    loss, and its payloads were weighed about 30 kg low at 3-6
    uncertainties. A constant loss :data:`LOSS_SIGNIFICANCE` standard errors
    below zero is the sign (losses do not drive a conveyor); the refit with
    BmA fixed at 0 and half the difference of the two μ as a further
    uncertainty is the split-half allowance of :func:`_loss_check`.
    """
    sd = parameters.stderr("BmA")
    if "BmA" in parameters.fixed or not (sd > 0 and parameters["BmA"] < -LOSS_SIGNIFICANCE * sd):
        return parameters, []
    without = copy.copy(settings)
    without.fit_bma = False
    try:
        refit = without.fit(recordings, profile).parameters_
    except EstimationError:
        return parameters, []
    half = 0.5 * abs(parameters["mu"] - refit["mu"])
    note = RecordingWarning(
        "losses_not_physical",
        f"the constant loss BmA = {parameters['BmA']:.3g} N·m is below zero by "
        f"{-parameters['BmA'] / sd:.1f} standard errors: refitted with BmA = 0, mu = "
        f"{refit['mu']:.4f} instead of {parameters['mu']:.4f}; half the difference "
        f"({half / max(refit['mu'], 1e-12):.1%} of mu) is added to mu's uncertainty. A heavier "
        "reference load tells the belt's friction from the gear's constant loss better",
    )
    return _widen_mu(refit, half), [note]


def calibrate(
    recordings: Sequence[Recording],
    profile: ConveyorProfile,
    *,
    estimator: RigidModelRegression | None = None,
    version: str = "",
    friction_drift: float = 0.0,
) -> Calibration:
    """Calibrate a conveyor from recordings with a known ``payload_kg``.

    When every recording holds the torque set point, the torque channel is
    chosen by the data (:mod:`chaintwin.identify.channels`): the rigid
    model's residual spread on the actual torque, on the set point and on
    their inverse-variance combination; the calibration is then made on the
    channel with the smallest, keeping the actual torque's as
    :attr:`Calibration.actual_torque` for recordings without a set point.

    Parameters
    ----------
    recordings : sequence of Recording
        Calibration recordings of one conveyor; each needs ``payload_kg``.
    profile : ConveyorProfile
        The conveyor's profile (its ``model:`` section is not read).
    estimator : RigidModelRegression, optional
        Settings of the regression (default settings otherwise).
    version : str
        chaintwin version to record.
    friction_drift : float
        Standard uncertainty of the rail friction relative to the
        calibration's, 1, stored for weighing (default 0: trusted).

    Returns
    -------
    Calibration

    Raises
    ------
    EstimationError
        When a recording lacks ``payload_kg`` or the data cannot determine the model.
    CalibrationError
        When ``friction_drift`` is not a share in [0, 1], or the recordings give a
        physically impossible calibration (one its file could not hold: μ not
        in (0, 2], say, from empty runs at one speed that cannot separate the
        rail friction from the losses), which would weigh wrong numbers.
    """
    cal = _calibrate_channels(
        recordings, profile, estimator=estimator, version=version, friction_drift=friction_drift
    )
    problem = broken_invariant(cal)
    if problem is not None:
        advice = cal.recommendation() or "record a run with a reference load"
        raise CalibrationError(
            f"conveyor '{profile.id}': these recordings give an impossible calibration: "
            f"{problem}. What to do: {advice}"
        )
    return replace(cal, zero_reference=_zero_reference(cal, recordings))


def _zero_reference(cal: Calibration, recordings: Sequence[Recording]) -> ZeroReference:
    """The loss drift each calibration recording reads at its known payload with the
    calibration (:mod:`chaintwin.identify.zero_reference`)."""
    from chaintwin.validate.checks import inspect_recording
    from chaintwin.weigh.drift import LossDrift
    from chaintwin.weigh.weigh import weigh
    from chaintwin.weigh.zero_tracking import known_run_drift

    readings: list[tuple[float, float, float]] = []
    for rec in recordings:
        payload = rec.metadata.payload_kg
        if payload is None:
            continue
        try:
            res = weigh(inspect_recording(rec, cal.profile), cal, loss_drift=LossDrift.unknown())
        except ChaintwinError:
            continue
        found = None if res.signatures is None else known_run_drift(res.signatures, payload)
        if found is not None and math.isfinite(found[0]) and found[1] > 0.0:
            readings.append((float(payload), found[0], found[1]))
    return ZeroReference(tuple(readings))


def _calibrate_channels(
    recordings: Sequence[Recording],
    profile: ConveyorProfile,
    *,
    estimator: RigidModelRegression | None,
    version: str,
    friction_drift: float,
) -> Calibration:
    """:func:`calibrate` without the reference zero: on the torque channel the data chose."""
    cal, est = _calibrate_on(
        recordings, profile, estimator=estimator, version=version, friction_drift=friction_drift
    )
    if not recordings or any(r.torque_setpoint is None for r in recordings):
        return cal
    settings = estimator or RigidModelRegression()
    try:
        spreads = measure_spreads(recordings, cal.id_profile, settings, est)
    except EstimationError:
        return cal
    channel = choose_channel(spreads)
    if channel == "torque":
        return replace(cal, channel_spreads=spreads)
    derived = [on_channel(r, channel, spreads.torque_weight) for r in recordings]
    try:
        other, _est = _calibrate_on(
            derived, profile, estimator=estimator, version=version, friction_drift=friction_drift
        )
    except EstimationError:
        return replace(cal, channel_spreads=spreads)
    # the torque lag is the actual torque's behind the set point: the actual calibration's
    lag_codes = ("torque_lag_unknown",)
    warnings = [w for w in other.warnings if w.code not in lag_codes]
    warnings += [w for w in cal.warnings if w.code in lag_codes]
    return replace(
        other,
        torque_channel=channel,
        channel_spreads=spreads,
        actual_torque=cal,
        torque_lag_s=cal.torque_lag_s,
        torque_lag_stderr_s=cal.torque_lag_stderr_s,
        warnings=tuple(warnings),
    )


def _calibrate_on(
    recordings: Sequence[Recording],
    profile: ConveyorProfile,
    *,
    estimator: RigidModelRegression | None = None,
    version: str = "",
    friction_drift: float = 0.0,
) -> tuple[Calibration, RigidModelRegression]:
    """:func:`calibrate` on the recordings' ``torque`` as they are; with its main fit."""
    if not (math.isfinite(friction_drift) and 0.0 <= friction_drift <= 1.0):
        raise CalibrationError(
            f"friction drift {friction_drift!r}: give the rail friction's standard "
            "uncertainty as a share between 0 and 1 (e.g. 0.1)"
        )
    id_prof = identification_profile(profile)
    missing = [r.source for r in recordings if r.metadata.payload_kg is None]
    if missing:
        raise EstimationError(
            f"{missing[0]}: no payload_kg in its metadata; calibration needs recordings "
            "with a known load (an empty tray is '# payload_kg: 0')"
        )
    settings = estimator or RigidModelRegression()
    est = copy.copy(settings).fit(recordings, id_prof)
    loads = [t + p for t, p in zip(est.trays_kg_, est.loads_kg_, strict=True)]
    speeds = speed_clusters(est.plateau_speeds_)
    if max(loads) - min(loads) >= est.min_load_spread_kg:
        case = "several_loads"
    elif len(speeds) >= 2:
        case = "one_load_several_speeds"
    else:
        case = "one_load_one_speed"
    parameters = est.parameters_
    ramp_notes: list[RecordingWarning] = []
    if case == "one_load_one_speed":
        parameters, ramp_notes = _ramp_check(settings, recordings, id_prof, parameters)
    elif case == "one_load_several_speeds":
        parameters, ramp_notes = _loss_check(settings, recordings, id_prof, parameters)
    else:
        parameters, ramp_notes = _constant_loss_check(settings, recordings, id_prof, parameters)
    tau, tau_err, lag_warn = _torque_lag(recordings, id_prof)
    rec_info: list[dict[str, Any]] = []
    for k, rec in enumerate(recordings):
        wi = window_integrals(rec, id_prof)
        plateau = (
            float(np.median(wi.mean_speed[wi.constant])) / RPM_TO_RAD_S
            if wi.constant.any()
            else None
        )
        # directions of travel: where the motor turns at half its top speed or more
        speed = rec.speed
        fast = speed[np.abs(speed) >= 0.5 * float(np.max(np.abs(speed)))]
        signs = [s for s in (1, -1) if int(np.count_nonzero(np.sign(fast) == s)) >= 10]
        rec_info.append(
            {
                "file": rec.source,
                "sha256": _sha256(rec),
                "payload_kg": est.loads_kg_[k],
                "tray_kg": est.trays_kg_[k],
                "sample_time_s": rec.sample_time_s,
                "recorded_at": rec.metadata.recorded_at.isoformat()
                if rec.metadata.recorded_at
                else None,
                "plateau_speed_rpm": plateau,
                "directions": signs,
            }
        )
    warnings = list(est.warnings_) + lag_warn + ramp_notes
    for rec in recordings:
        for w in rec.warnings:
            warnings.append(RecordingWarning(w.code, f"{rec.source}: {w.message}"))
    cal = Calibration(
        profile=profile,
        parameters=parameters,
        case=case,
        recordings=rec_info,
        torque_lag_s=tau,
        torque_lag_stderr_s=tau_err,
        residual_rms_nm=est.residual_rms_nm_,
        ramp_noise_rate=float(est.noise_rates_[1]),
        warnings=tuple(warnings),
        chaintwin_version=version,
        friction_drift=friction_drift,
    )
    cal = _calibrate_inertia_signature(cal, recordings, est.loads_kg_, est.trays_kg_)
    cal, misread = _closure(cal, recordings, est.loads_kg_)
    if misread is not None:
        cal = replace(cal, warnings=(*cal.warnings, misread))
    unchecked = _friction_check(cal, recordings)
    if unchecked is not None:
        cal = replace(cal, warnings=(*cal.warnings, unchecked))
    note = cal.recommendation()
    if note is not None:
        cal = replace(cal, warnings=(*cal.warnings, RecordingWarning("calibration_weak", note)))
    return cal, est
