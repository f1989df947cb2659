"""Dynamic weighing: the payload from torque alone, with an uncertainty.

The payload shows up twice in a recording (docs/design.md, identifiability):

* **friction**: ``p·g·(μ·cosβ + sinβ)·r/(i·η)`` more torque at any speed,
  strong at constant speed. It confuses "heavier" with "rails got stickier".
* **inertia**: ``p·r²/(i²·η)`` more inertia, visible only in the ramps.
  It does not depend on μ or the losses.

:func:`weigh` subtracts the calibrated empty-conveyor model from the
measured torque (window integrals, see :mod:`chaintwin.model.windows`)
and fits what is left with the two signatures as separate unknowns, plus
the polygon effect's tooth-pass ripple as nuisance terms. The two estimates
are reported separately; when they disagree beyond their combined
uncertainty (3 sigma) the recording is **unweighable**: something other
than the load has changed (rail friction, losses beyond the allowed drift)
and no number can be stood behind, so ``payload_kg`` is None with the
warning ``unweighable`` and its reason. Otherwise the payload is their
covariance-weighted combination.

A recording is unweighable too when it does not move, holds no usable
window, or runs in a direction the calibration never saw (the incline and
the gear's efficiency act differently there).

Uncertainties are standard (1 sigma) and include every known source: the
fit's, inflated for serial correlation of the residuals; the calibration's
parameter covariance propagated through the estimate (numerical Jacobian);
the inertia signature's model error; and the drift of the gear losses since
the calibration (:mod:`chaintwin.weigh.drift`; by default ±10 % allowed
for, :meth:`LossDrift.unknown`). Incomplete cycles are weighed from what
they hold and their uncertainty doubled.

A load that changes during the movement (a tray placed on the moving belt)
is found as a step in the friction payload of successive constant-speed
windows; each segment is weighed on its own and the payload reported is the
last segment's (what the belt carries at the end of the movement).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from chaintwin._stats import median
from chaintwin.errors import EstimationError
from chaintwin.identify.calibration import INERTIA_MODEL_REL, Calibration
from chaintwin.identify.channels import on_channel
from chaintwin.identify.signatures import SignatureFit, fit_signatures
from chaintwin.model.rigid import incline_terms, motoring_mask
from chaintwin.model.windows import WindowIntegrals, window_integrals
from chaintwin.read.profile import ConveyorProfile
from chaintwin.read.recording import Recording, RecordingWarning
from chaintwin.units import RPM_TO_RAD_S
from chaintwin.validate.checks import Inspection
from chaintwin.validate.phases import Phase
from chaintwin.weigh.drift import LossDrift
from chaintwin.weigh.tlf import motor_shaft_transport_loss_factor, transport_loss_factor

__all__ = [
    "CONSISTENCY_SIGMA",
    "FRICTION_CHANGED",
    "SETPOINT_MISSING",
    "UNWEIGHABLE",
    "Segment",
    "Signatures",
    "WeighResult",
    "reweigh",
    "weigh",
]

UNWEIGHABLE = "unweighable"
"""Warning code of a recording whose payload is None."""

SETPOINT_MISSING = "torque_setpoint_missing"
"""Warning code of a recording without the set point weighed with a calibration
on the set point (or the combination): the actual torque's terms were used."""

FRICTION_CHANGED = "friction_changed"
"""Warning code of a weight taken while the conveyor's monitoring sees its
rail friction move (:func:`reweigh` with ``friction=False``)."""

CONSISTENCY_SIGMA = 3.0
"""Friction and inertia estimates disagree beyond this many combined sigmas."""

STEP_MIN_KG = 2.0
"""Smallest load change reported as a segment, kg."""

STEP_SIGMA = 6.0
"""A load change must stand this many sigmas above the windows' scatter."""


@dataclass(frozen=True, slots=True)
class Signatures:
    """The two signatures' payloads of a recording before they are combined.

    What :func:`reweigh` needs to combine them again with another loss drift.

    Attributes
    ----------
    friction_kg, friction_var : float
        Friction-signature payload (kg) and its variance without loss drift (kg²).
    inertia_kg, inertia_var : float or None
        Inertia-signature payload (kg) and variance (kg²); None without a ramp.
    covariance : float
        Their covariance, kg².
    drift_friction_kg, drift_inertia_kg : float
        How far each payload moves when the gear losses are (1 + δ) times the
        calibration's: d payload / dδ, kg (the friction one is the loss torque
        at speed over the payload sensitivity: tens of kg on most conveyors;
        the inertia one is small, from the ramps).
    widen : float
        Factor on every uncertainty (2 for an incomplete cycle).
    moving_mass_kg : float
        The belt's and the tray's own mass, kg: a payload whose standard
        uncertainty exceeds it cannot be told from the belt (unweighable;
        infinite: no such limit).
    friction_rel_kg : float
        How far the friction payload moves when the rail friction μ is
        (1 + ε) times the calibration's: d payload / dε, kg (NaN: not known).
        A heavier load and stickier rails give the same torque at constant
        speed; only the inertia signature tells them apart.
    friction_sigma : float
        Standard uncertainty ε of the rail friction relative to the
        calibration's that the friction signature's variance carries, 1
        (0: the calibration's rail friction is trusted, the default).
    """

    friction_kg: float
    friction_var: float
    inertia_kg: float | None
    inertia_var: float | None
    covariance: float
    drift_friction_kg: float
    drift_inertia_kg: float = 0.0
    widen: float = 1.0
    moving_mass_kg: float = float("inf")
    friction_rel_kg: float = float("nan")
    friction_sigma: float = 0.0

    def drifted_variances(self, drift: LossDrift) -> tuple[float, float | None, float]:
        """Variances of the friction and inertia payloads and their covariance with the
        loss drift carried (``drift.sigma²`` times the gradients' outer product), kg².

        The friction allowance (:attr:`friction_sigma`) is not in them; the
        inertia variance is None without an inertia signature.
        """
        k_f, k_i = self.drift_friction_kg, self.drift_inertia_kg
        var_f = self.friction_var + (drift.sigma * k_f) ** 2
        var_i = None if self.inertia_var is None else self.inertia_var + (drift.sigma * k_i) ** 2
        return var_f, var_i, self.covariance + drift.sigma**2 * k_f * k_i

    def friction_checked_rel(self, drift: LossDrift) -> float | None:
        """The smallest rail friction change this recording would catch, relative, or None.

        A change ε of μ moves the friction payload by ε·:attr:`friction_rel_kg`
        and leaves the inertia payload; the two then disagree beyond
        :data:`CONSISTENCY_SIGMA` combined sigmas (unweighable) when
        ``|ε|`` exceeds this. None without an inertia signature or a known
        sensitivity: nothing in the recording checks the friction.
        """
        k = self.friction_rel_kg
        var_f, var_i, cov = self.drifted_variances(drift)
        if var_i is None or not math.isfinite(k) or k == 0.0:
            return None
        diff_var = var_f + var_i - 2.0 * cov
        return CONSISTENCY_SIGMA * math.sqrt(max(diff_var, 0.0)) * self.widen / abs(k)


@dataclass(frozen=True, slots=True)
class _Combined:
    payload_kg: float | None
    uncertainty_kg: float | None
    friction_kg: float | None
    friction_uncertainty_kg: float | None
    inertia_uncertainty_kg: float | None
    consistent: bool
    warnings: tuple[RecordingWarning, ...]


def _unweighable(reason: str) -> RecordingWarning:
    return RecordingWarning(UNWEIGHABLE, f"no payload: {reason}")


def _combine(
    sig: Signatures,
    drift: LossDrift,
    friction: bool = True,
    friction_change: float | None = None,
) -> _Combined:
    """The payload from both signatures, or none when its uncertainty exceeds the belt's mass.

    See :func:`_combine_signatures`; a payload whose standard uncertainty is
    larger than the belt's and tray's own mass (:attr:`Signatures.moving_mass_kg`)
    is no number to stand behind (a 1 ms scope of a long, heavy belt can
    give 183 ± 1050 kg): unweighable, with the reason and what to record.
    """
    out = _combine_signatures(sig, drift, friction, friction_change)
    u = out.uncertainty_kg
    if out.payload_kg is None or u is None or u <= sig.moving_mass_kg:
        return out
    reason = (
        f"the payload's uncertainty (±{u:.0f} kg, 1 sigma) exceeds the belt's and tray's own "
        f"mass ({sig.moving_mass_kg:.0f} kg): the recording cannot tell the payload from the "
        "belt; record at 6-12 ms with a longer constant-speed run, or calibrate with a "
        "reference load"
    )
    return _Combined(None, None, None, None, None, False, (*out.warnings, _unweighable(reason)))


def _friction_changed(sig: Signatures, change: float | None, weighed_by: str) -> RecordingWarning:
    """The ``friction_changed`` warning: what the monitoring measured, what it is worth."""
    per_10 = 0.1 * sig.friction_rel_kg
    worth = f" ({abs(per_10):.1f} kg per 10 %)" if math.isfinite(per_10) else ""
    moved = (
        f"by {change:+.0%}"
        if change is not None and math.isfinite(change)
        else "by an unmeasured amount"
    )
    return RecordingWarning(
        FRICTION_CHANGED,
        f"the conveyor's monitoring sees its rail friction moved {moved} since the "
        f"calibration: the friction signature would read that as payload{worth}; {weighed_by}",
    )


def _combine_signatures(
    sig: Signatures,
    drift: LossDrift,
    friction: bool = True,
    friction_change: float | None = None,
) -> _Combined:
    """The payload from both signatures, corrected for the loss drift.

    Each signature is moved by ``drift.mean`` times its drift gradient and
    the drift's uncertainty is carried into their variances and covariance
    (``drift.sigma²`` times the gradients' outer product). When the
    two disagree beyond :data:`CONSISTENCY_SIGMA` combined sigmas there is
    no payload (unweighable); else it is their covariance-weighted mean.
    With ``friction`` False (the conveyor's monitoring sees the rail
    friction move by the relative ``friction_change``) the payload is the
    inertia estimate alone, and the friction signature's uncertainty carries
    the measured change (``friction_change`` times :attr:`Signatures.friction_rel_kg`);
    without a ramp the payload is the friction signature's with that
    uncertainty (unweighable when the change is not known). Either way the
    warning ``friction_changed`` says so.
    """
    k_f, k_i = sig.drift_friction_kg, sig.drift_inertia_kg
    p_f = sig.friction_kg - drift.mean * k_f
    var_f, var_i, cov = sig.drifted_variances(drift)
    if sig.friction_sigma > 0.0 and math.isfinite(sig.friction_rel_kg):
        # the rail friction allowed to differ from the calibration's
        var_f += (sig.friction_sigma * sig.friction_rel_kg) ** 2
    w = sig.widen
    if not friction:
        change = (
            abs(friction_change)
            if friction_change is not None and math.isfinite(friction_change)
            else None
        )
        if change is not None and math.isfinite(sig.friction_rel_kg):
            # the measured change of the rail friction, as payload
            var_f += (change * sig.friction_rel_kg) ** 2
        if sig.inertia_kg is None or var_i is None:
            if change is None or not math.isfinite(sig.friction_rel_kg):
                reason = "the rail friction is suspect and there is no ramp to weigh by inertia"
                changed = _friction_changed(sig, friction_change, "no payload")
                return _Combined(
                    None, None, None, None, None, False, (changed, _unweighable(reason))
                )
            s_f = float(np.sqrt(var_f)) * w
            changed = _friction_changed(
                sig,
                friction_change,
                "no ramp to weigh by inertia: the payload is the friction signature's, its "
                "uncertainty carrying the measured change",
            )
            return _Combined(p_f, s_f, p_f, s_f, None, True, (changed,))
        p_i_only = sig.inertia_kg - drift.mean * k_i
        s_i = float(np.sqrt(var_i)) * w
        note = RecordingWarning(
            "weighed_by_inertia",
            "a friction, lubrication or obstruction alarm is open or developing: the "
            "payload is the inertia signature's, which friction cannot move",
        )
        changed = _friction_changed(
            sig,
            friction_change,
            "the payload is the inertia signature's; the friction signature's uncertainty "
            "carries the measured change",
        )
        return _Combined(p_i_only, s_i, p_f, float(np.sqrt(var_f)) * w, s_i, True, (note, changed))
    if sig.inertia_kg is None or var_i is None:
        s_f = float(np.sqrt(var_f))
        return _Combined(p_f, s_f * w, p_f, s_f * w, None, True, ())
    p_i = sig.inertia_kg - drift.mean * k_i
    diff_var = var_f + var_i - 2.0 * cov
    warnings: tuple[RecordingWarning, ...] = ()
    consistent = abs(p_f - p_i) <= CONSISTENCY_SIGMA * float(np.sqrt(diff_var))
    if consistent:
        c = np.array([[var_f, cov], [cov, var_i]])
        inv = np.linalg.inv(c)
        ones = np.ones(2)
        var = 1.0 / float(ones @ inv @ ones)
        payload = float(var * (ones @ inv @ np.array([p_f, p_i])))
        unc = float(np.sqrt(var))
    else:
        warnings = (
            _unweighable(
                f"the friction signature says {p_f:.1f} kg, the inertia signature "
                f"{p_i:.1f} kg (±{np.sqrt(diff_var):.1f} kg on the difference): the rail "
                "friction or the gear losses have changed since the calibration, not only "
                "the load; check the conveyor (chaintwin monitor) or recalibrate"
            ),
        )
        return _Combined(None, None, None, None, None, False, warnings)
    return _Combined(
        payload,
        unc * w,
        p_f,
        float(np.sqrt(var_f)) * w,
        float(np.sqrt(var_i)) * w,
        consistent,
        warnings,
    )


@dataclass(frozen=True, slots=True)
class Segment:
    """A part of the movement with one load."""

    start_s: float
    end_s: float
    payload_kg: float

    def to_dict(self) -> dict[str, float]:
        """``{start_s, end_s, payload_kg}``."""
        return {"start_s": self.start_s, "end_s": self.end_s, "payload_kg": self.payload_kg}


@dataclass(frozen=True)
class WeighResult:
    """The weight on the belt in one recording.

    Attributes
    ----------
    file : str
        The recording as given.
    payload_kg, uncertainty_kg : float or None
        Payload and its standard uncertainty (1 sigma), kg; None when the
        recording is unweighable (a warning ``unweighable`` says why).
    payload_friction_kg, friction_uncertainty_kg : float or None
        Friction-signature estimate (corrected for the loss drift), kg; None
        when unweighable.
    payload_inertia_kg, inertia_uncertainty_kg : float or None
        Inertia-signature estimate (None without a ramp or when unweighable), kg.
    consistent : bool
        False when the two signatures disagree beyond 3 sigma (then unweighable).
    segments : tuple of Segment
        Loads of the movement's parts when the load changed; else empty.
    tlf : float or None
        Transport loss factor from the work at the sprocket (None under 1 kg).
    tlf_motor_shaft : float or None
        Transport loss factor from the work at the motor shaft, the published
        definition (None under 1 kg); see :mod:`chaintwin.weigh.tlf`.
    warnings : tuple of RecordingWarning
        The recording's and the weighing's warnings.
    signatures : Signatures or None
        The two signatures before they were combined (for :func:`reweigh`).
    loss_drift : LossDrift
        The loss drift the friction signature was corrected for.
    since_known_run_s : float or None
        With zero tracking (:mod:`chaintwin.weigh.zero_tracking`): the time
        since the conveyor's last recording with a known payload, s (None
        without one, or when a recording time is unknown).
    known_run : bool
        True for a recording with a known payload that zero tracking learned from.
    """

    file: str
    payload_kg: float | None
    uncertainty_kg: float | None
    payload_friction_kg: float | None
    friction_uncertainty_kg: float | None
    payload_inertia_kg: float | None
    inertia_uncertainty_kg: float | None
    consistent: bool
    segments: tuple[Segment, ...] = ()
    tlf: float | None = None
    warnings: tuple[RecordingWarning, ...] = field(default_factory=tuple)
    tlf_motor_shaft: float | None = None
    signatures: Signatures | None = None
    loss_drift: LossDrift = field(default_factory=LossDrift.unknown)
    since_known_run_s: float | None = None
    known_run: bool = False

    @property
    def friction_checked_rel(self) -> float | None:
        """Smallest relative rail friction change the recording would catch, or None.

        :meth:`Signatures.friction_checked_rel` with this result's loss drift:
        a smaller change passes the signatures' consistency check and reads
        as payload (:attr:`friction_10pct_kg` per 10 %).
        """
        sig = self.signatures
        return None if sig is None else sig.friction_checked_rel(self.loss_drift)

    @property
    def friction_10pct_kg(self) -> float | None:
        """How many kg a 10 % rise of the rail friction reads as in the friction payload."""
        sig = self.signatures
        if sig is None or not math.isfinite(sig.friction_rel_kg):
            return None
        return 0.1 * sig.friction_rel_kg

    @property
    def unweighable(self) -> str | None:
        """Why there is no payload, or None when there is one."""
        for w in self.warnings:
            if w.code == UNWEIGHABLE:
                return w.message
        return None

    def to_dict(self) -> dict[str, Any]:
        """The ``weigh --json`` object."""
        return {
            "file": self.file,
            "payload_kg": self.payload_kg,
            "uncertainty_kg": self.uncertainty_kg,
            "payload_friction_kg": self.payload_friction_kg,
            "payload_inertia_kg": self.payload_inertia_kg,
            "consistent": self.consistent,
            "segments": [s.to_dict() for s in self.segments],
            "tlf": self.tlf,
            "tlf_motor_shaft": self.tlf_motor_shaft,
            "warnings": [w.to_dict() for w in self.warnings],
            "friction_uncertainty_kg": self.friction_uncertainty_kg,
            "inertia_uncertainty_kg": self.inertia_uncertainty_kg,
            "friction_checked_rel": self.friction_checked_rel,
            "friction_10pct_kg": self.friction_10pct_kg,
            "loss_drift": self.loss_drift.to_dict(),
            "since_known_run_s": self.since_known_run_s,
            "known_run": self.known_run,
        }


def _step(fit: SignatureFit) -> tuple[float, float, float] | None:
    """Find one load step among constant-speed windows: (time, before, after) or None."""
    wi = fit.windows
    sel = np.flatnonzero(wi.constant & (wi.kind == 0) & np.isfinite(fit.residual_per_kg))
    n = sel.shape[0]
    if n < 8:
        return None
    q = fit.residual_per_kg[sel]
    d = np.diff(q)
    sigma = 1.4826 * median(np.abs(d - median(d))) / np.sqrt(2.0)
    if sigma <= 0.0:
        sigma = float(np.std(q)) or 1e-12
    csum = np.cumsum(q)
    total = csum[-1]
    # the two-sample z of every split point j (first j windows against the
    # rest), 3 <= j < n - 2; the first largest positive one is the step
    j = np.arange(3, n - 2)
    left = csum[j - 1] / j
    right = (total - csum[j - 1]) / (n - j)
    zval = np.abs(right - left) / (sigma * np.sqrt(1.0 / j + 1.0 / (n - j)))
    zval = np.where(zval > 0.0, zval, -np.inf)  # also drops NaN, as a comparison would
    if zval.shape[0] == 0 or not zval.max() > 0.0:
        return None
    k = int(np.argmax(zval))
    best_z, best_j = float(zval[k]), int(j[k])
    before = float(np.mean(q[:best_j]))
    after = float(np.mean(q[best_j:]))
    if best_z < STEP_SIGMA or abs(after - before) < STEP_MIN_KG:
        return None
    return float(wi.t0[sel[best_j]]), before, after


def _friction_rel_kg(
    wi: WindowIntegrals, prof: ConveyorProfile, mu: float, rails_kg: float
) -> float:
    """d friction payload / d(relative μ change), kg, as the fit would read it.

    A change ε of μ adds ``ε·g·cosβ·μ·m·gf_sign`` to every window's torque
    integral (``m`` the mass on the rails: belt, tray and payload); the
    friction regressor ``g·(μ·cosβ·gf_sign + sinβ·gf)`` takes it up by least
    squares over the constant-speed windows (all windows when there are
    none), weighted as the fit's first pass.
    """
    g_cos, g_sin = incline_terms(prof)
    sel = wi.constant if wi.constant.any() else np.ones(wi.count, dtype=bool)
    xf = g_cos * mu * wi.gf_sign[sel] + g_sin * wi.gf[sel]
    dz = g_cos * mu * wi.gf_sign[sel]
    w = 1.0 / wi.duration[sel]
    den = float(np.sum(w * xf * xf))
    return rails_kg * float(np.sum(w * xf * dz)) / den if den > 0.0 else float("nan")


def _same_windows(
    recording: Recording,
    prof: ConveyorProfile,
    motoring: np.ndarray,
    phases: list[Phase],
    given: WindowIntegrals,
) -> WindowIntegrals | None:
    """The windows of ``given`` (by their start and end, s) integrated on ``recording``.

    For windows a caller chose on the actual torque (impacts left out) when
    the calibration weighs another channel; None when none matches.
    """
    try:
        every = window_integrals(recording, prof, motoring=motoring, phases=phases)
    except EstimationError:
        return None
    spans = set(zip(np.round(given.t0, 9).tolist(), np.round(given.t1, 9).tolist(), strict=True))
    keep = np.array(
        [
            (a, b) in spans
            for a, b in zip(
                np.round(every.t0, 9).tolist(), np.round(every.t1, 9).tolist(), strict=True
            )
        ],
        dtype=bool,
    )
    return every.select(keep) if keep.any() else None


def _no_payload(name: str, warnings: tuple[RecordingWarning, ...], drift: LossDrift) -> WeighResult:
    """An unweighable result: every number None, the warnings kept."""
    return WeighResult(
        file=name,
        payload_kg=None,
        uncertainty_kg=None,
        payload_friction_kg=None,
        friction_uncertainty_kg=None,
        payload_inertia_kg=None,
        inertia_uncertainty_kg=None,
        consistent=False,
        warnings=warnings,
        loss_drift=drift,
    )


def _uncovered_direction(inspection: Inspection, calibration: Calibration) -> str | None:
    """Why the recording runs where the calibration never ran, or None.

    The direction of travel of each constant-speed phase against the
    directions of the calibration's plateaus: the incline's sign turns and
    a gear unit's efficiency differs in reverse, so a calibration in one
    direction says nothing sure of the other.
    """
    covered = calibration.directions
    if not covered:
        return None
    speed = inspection.recording.speed
    for phase in inspection.phases:
        if phase.kind != "constant" or phase.stop - phase.start < 2:
            continue
        sign = 1 if median(speed[phase.start : phase.stop]) >= 0.0 else -1
        if sign not in covered:
            word = {1: "positive", -1: "negative"}
            return (
                f"the conveyor runs in the motor's {word[sign]} direction, the calibration "
                f"only in the {word[-sign]} one; calibrate with runs in both directions"
            )
    return None


def weigh(
    inspection: Inspection,
    calibration: Calibration,
    *,
    source: str | None = None,
    motoring: np.ndarray | None = None,
    windows: WindowIntegrals | None = None,
    loss_drift: LossDrift | None = None,
    friction_drift: float | None = None,
) -> WeighResult:
    """Weigh the payload of one recording.

    Parameters
    ----------
    inspection : Inspection
        A validated recording of the calibrated conveyor with its movement
        phases (:func:`~chaintwin.validate.checks.inspect_recording`); its
        warnings are carried into the result and its phases are used as
        they are, not segmented again.
    calibration : Calibration
        The conveyor's calibration.
    source : str, optional
        File name to report (default ``recording.source``).
    motoring : np.ndarray of bool, optional
        Power-flow direction per sample, when already computed with the
        calibration's parameters (:func:`~chaintwin.model.rigid.motoring_mask`).
    windows : WindowIntegrals, optional
        The recording's window integrals with that ``motoring``, when already
        computed (:func:`~chaintwin.model.windows.window_integrals`).
    loss_drift : LossDrift, optional
        How far the losses have drifted since the calibration
        (:mod:`chaintwin.weigh.drift`): the friction signature is corrected
        by it and its uncertainty carried. Default :meth:`LossDrift.unknown`:
        a drift of ±10 % allowed for, as nothing is known of it;
        ``LossDrift()`` trusts the calibration's losses.
    friction_drift : float, optional
        Standard uncertainty of the rail friction μ relative to the
        calibration's, carried into the friction signature's variance
        (default: the calibration's :attr:`~Calibration.friction_drift`,
        0 unless it was calibrated with one: the calibration's rail
        friction is trusted). Matters where the recording's inertia
        signature cannot check the friction
        (:attr:`WeighResult.friction_checked_rel` large or None).

    Returns
    -------
    WeighResult
        With ``payload_kg`` None and the warning ``unweighable`` when the
        recording does not move, holds no usable window, runs in a
        direction the calibration does not cover, or its two signatures
        disagree.
    """
    recording = inspection.recording
    phases = list(inspection.phases)
    name = source if source is not None else recording.source
    channel_note: RecordingWarning | None = None
    subset: WindowIntegrals | None = None
    if calibration.torque_channel != "torque":
        spreads = calibration.channel_spreads
        if recording.torque_setpoint is None or spreads is None:
            channel_note = RecordingWarning(
                SETPOINT_MISSING,
                f"the calibration weighs with the {calibration.torque_channel.replace('_', ' ')} "
                "(the smaller residual spread on its recordings), but this recording has no "
                "torque set point column: weighed with the actual torque and the "
                "calibration's actual-torque terms",
            )
            calibration = calibration.actual_torque or calibration
        else:
            recording = on_channel(recording, calibration.torque_channel, spreads.torque_weight)
            # motoring and windows handed in were computed on the actual torque:
            # the same windows (by their spans) are integrated again on the channel
            subset, motoring, windows = windows, None, None
    prof = calibration.id_profile
    params = calibration.parameters
    drifted = LossDrift.unknown() if loss_drift is None else loss_drift
    tray = recording.metadata.tray_kg
    tray = prof.tray_mass_kg if tray is None else tray
    warnings: list[RecordingWarning] = list(recording.warnings)
    if channel_note is not None:
        warnings.append(channel_note)

    def nothing(reason: str) -> WeighResult:
        return _no_payload(name, (*warnings, _unweighable(reason)), drifted)

    if recording.has_warning("no_motion"):
        return nothing("the conveyor does not move")
    uncovered = _uncovered_direction(inspection, calibration)
    if uncovered is not None:
        return nothing(uncovered)
    mot = (
        motoring
        if motoring is not None
        else motoring_mask(
            recording,
            drive_inertia_kgm2=params["J_d"],
            losses=params.losses,
        )
    )
    if subset is not None:
        windows = _same_windows(recording, prof, mot, phases, subset)
    rate = calibration.ramp_noise_rate
    try:
        fit, cov = fit_signatures(
            recording,
            prof,
            params,
            tray,
            motoring=mot,
            ramp_rate=rate,
            windows=windows,
            phases=phases,
        )
    except EstimationError as exc:
        return nothing(str(exc))

    segments: tuple[Segment, ...] = ()
    step = _step(fit)
    if step is not None:
        t_step, _before, _after = step
        t = recording.time
        try:
            first, _cov_first = fit_signatures(
                recording, prof, params, tray, (float(t[0]), t_step), mot, rate, phases=phases
            )
            last, cov_last = fit_signatures(
                recording, prof, params, tray, (t_step, float(t[-1])), mot, rate, phases=phases
            )
        except EstimationError:
            # too little on one side to weigh it: keep the whole-recording fit
            warnings.append(
                RecordingWarning(
                    "payload_changed",
                    f"the friction payload steps at t = {t_step:.3f} s, but one side is too "
                    "short to weigh on its own; the whole recording was weighed",
                )
            )
        else:
            segments = (
                Segment(float(fit.windows.t0[0]), t_step, float(first.estimate[0])),
                Segment(t_step, float(fit.windows.t1[-1]), float(last.estimate[0])),
            )
            warnings.append(
                RecordingWarning(
                    "payload_changed",
                    f"the load changed at t = {t_step:.3f} s from {first.estimate[0]:.1f} kg to "
                    f"{last.estimate[0]:.1f} kg (friction signature); each part is weighed on "
                    "its own and the payload is the last part's",
                )
            )
            fit, cov = last, cov_last

    widen = 1.0
    if recording.has_warning("incomplete_cycle"):
        widen = 2.0
        warnings.append(
            RecordingWarning(
                "weighed_incomplete_cycle",
                "weighed from an incomplete cycle; the uncertainty is doubled",
            )
        )
    p_i: float | None = None
    var_i: float | None = None
    cov_fi = 0.0
    if fit.has_inertia:
        # the inertia signature as this conveyor's calibration reads it
        g = calibration.inertia_gain
        p_i = (float(fit.estimate[1]) - calibration.inertia_offset_kg) / g
        cov_fi = float(cov[0, 1]) / g
        # the inertia signature's model error: a fixed share, or half the
        # disagreement of the two inertia estimators if that is larger
        model_err = INERTIA_MODEL_REL * abs(p_i)
        if fit.inertia_alternative is not None:
            model_err = max(model_err, 0.5 * abs(fit.inertia_alternative - fit.estimate[1]) / g)
        var_i = (
            float(cov[1, 1]) / g**2
            + (p_i * calibration.inertia_gain_sigma / g) ** 2
            + (calibration.inertia_offset_sigma_kg / g) ** 2
            + model_err**2
        )
    else:
        warnings.append(
            RecordingWarning(
                "no_inertia_signature",
                "no complete ramp in the recording: weighed from friction alone, which "
                "cannot tell a heavier load from higher friction",
            )
        )
    grad = fit.loss_gradient if fit.loss_gradient is not None else np.zeros(2)
    signatures = Signatures(
        friction_kg=float(fit.estimate[0]),
        friction_var=float(cov[0, 0]),
        inertia_kg=p_i,
        inertia_var=var_i,
        covariance=cov_fi,
        drift_friction_kg=float(grad[0]),
        drift_inertia_kg=float(grad[1]) / calibration.inertia_gain if fit.has_inertia else 0.0,
        widen=widen,
        moving_mass_kg=prof.belt_mass_kg + tray,
        friction_rel_kg=_friction_rel_kg(
            fit.windows,
            prof,
            float(params["mu"]),
            prof.belt_mass_kg + tray + max(float(fit.estimate[0]), 0.0),
        ),
        friction_sigma=calibration.friction_drift if friction_drift is None else friction_drift,
    )
    cal_speeds = calibration.plateau_speeds_rpm
    wi = fit.windows
    if cal_speeds and wi.constant.any():
        plateau = median(wi.mean_speed[wi.constant]) / RPM_TO_RAD_S
        if plateau < 0.95 * min(cal_speeds) or plateau > 1.05 * max(cal_speeds):
            warnings.append(
                RecordingWarning(
                    "speed_outside_calibration",
                    f"plateau speed {plateau:.0f} rpm is outside the calibrated "
                    f"{min(cal_speeds):.0f}-{max(cal_speeds):.0f} rpm; the losses are extrapolated",
                )
            )
    combined = _combine(signatures, drifted)
    if combined.payload_kg is None:
        out = _no_payload(name, (*warnings, *combined.warnings), drifted)
        return dataclasses.replace(out, segments=segments, signatures=signatures)
    tlf = transport_loss_factor(recording, prof, params, combined.payload_kg)
    tlf_shaft = motor_shaft_transport_loss_factor(recording, prof, combined.payload_kg)
    return WeighResult(
        file=name,
        payload_kg=combined.payload_kg,
        uncertainty_kg=combined.uncertainty_kg,
        payload_friction_kg=combined.friction_kg,
        friction_uncertainty_kg=combined.friction_uncertainty_kg,
        payload_inertia_kg=p_i,
        inertia_uncertainty_kg=combined.inertia_uncertainty_kg,
        consistent=combined.consistent,
        segments=segments,
        tlf=tlf,
        tlf_motor_shaft=tlf_shaft,
        warnings=(*warnings, *combined.warnings),
        signatures=signatures,
        loss_drift=drifted,
    )


def reweigh(
    result: WeighResult,
    loss_drift: LossDrift,
    *,
    friction: bool = True,
    friction_change: float | None = None,
) -> WeighResult:
    """The result combined again with another loss drift (see :func:`weigh`).

    Cheap (no fit): for what became known after the recording was weighed,
    e.g. on a worker: a drift estimate, or (``friction=False``) that the
    conveyor's monitoring sees the rail friction move, by the relative
    ``friction_change`` when it measured it, so that the payload is the
    inertia signature's (without a ramp, the friction signature's with the
    change in its uncertainty) and the result carries ``friction_changed``.
    The TLF is kept (it depends on the payload only weakly).
    """
    sig = result.signatures
    if sig is None:
        return result
    combined = _combine(sig, loss_drift, friction, friction_change)
    kept = tuple(
        w
        for w in result.warnings
        if w.code not in (UNWEIGHABLE, "weighed_by_inertia", FRICTION_CHANGED)
    )
    if combined.payload_kg is None:
        out = _no_payload(result.file, (*kept, *combined.warnings), loss_drift)
        return dataclasses.replace(out, segments=result.segments, signatures=sig)
    return dataclasses.replace(
        result,
        payload_kg=combined.payload_kg,
        uncertainty_kg=combined.uncertainty_kg,
        payload_friction_kg=combined.friction_kg,
        friction_uncertainty_kg=combined.friction_uncertainty_kg,
        payload_inertia_kg=sig.inertia_kg,
        inertia_uncertainty_kg=combined.inertia_uncertainty_kg,
        consistent=combined.consistent,
        warnings=(*kept, *combined.warnings),
        loss_drift=loss_drift,
    )
