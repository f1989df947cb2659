"""Zero tracking: the loss-drift allowance from known runs and the conveyor's own history.

A belt scale keeps its accuracy by zero setting on an empty belt. A chain
conveyor's friction signature drifts with the gear losses (:mod:`.drift`);
a recording with a known payload in operation (metadata ``payload_kg``:
an empty run at shift start, a check-weighed load, a calibration
recording) measures that drift directly: with the payload known, what is
left of each signature is the losses' share, ``δ = (p_sig − p_known)/k``
for the friction and the inertia signature (``k`` their drift gradients,
:attr:`~.weigh.Signatures.drift_friction_kg`), combined by generalised
least squares with their covariance.

Learning from known runs is experimental and opt-in (``known_runs`` of
:meth:`ZeroTracker.track`; the profile's ``zero_tracking``, ``weigh
--zero-tracking``): over simulated conveyors with every realism effect on,
a few tracked weights were still beyond five uncertainties. By default a
known run is one more recording of the history (below).

A known run carries the calibration model's error as its reference zero
(:mod:`chaintwin.identify.zero_reference`) measures it: the scatter of what
the calibration's own recordings read beyond their uncertainties. The
zero those recordings read is not subtracted: they are read in-sample, at
the calibration's speeds and ramps, while a known run in operation reads
the operating point's own offset, which the weighings at that point share
(a belt scale's zero setting takes it out the same way).

Between known runs the losses move on. :class:`ZeroTracker` allows for

* a drift with a trend: the sequence of known runs feeds a Kalman filter
  of the drift and its rate (a local linear trend: the rate wanders as an
  integrated random walk, the drift itself as a random walk), whose
  process noise is scaled by the normalised innovations of the recent
  known runs (the drift rate learned from the conveyor's own sequence,
  from the priors :data:`RATE_CHANGE_PRIOR` and :data:`WALK_PRIOR`). A
  known run that the filter did not expect beyond :data:`JUMP_SIGMA`
  (an oil change) restarts the drift at the measured value and widens the
  allowance through the learned scale;
* the warm-up after a start: known runs at shift start see the gear cold,
  the weighings later in the day see it warm, and a sequence of morning
  runs cannot show that difference. It is modelled as an offset
  ``a·(1 − exp(−Δt/τ))`` (τ = :data:`WARM_UP_S`) with the prior
  ``a = 0 ± WARM_UP_REL``, learned from the weighed recordings'
  friction-minus-inertia differences over the days, beside the inertia
  signature's offset in operation (its ramps are not the calibration's:
  hundreds of kg on some conveyors), which the known runs, at no warm-up,
  pin (without that term the offset read as a warm-up of tens of per cent) (each is noisy: the
  inertia signature is weak, on most conveyors one recording tells δ only
  to ±3-15 %; pooled over many days the repeating offset shows). The
  inertia signature's gain error (a share of the payload, prior
  :data:`GAIN_PRIOR`) is fitted beside it, since it reads as a drift in
  proportion to the payload;
* the history since the last known run: pooled, and its latest recording
  alone, a difference (the gain error taken out) that disagrees with the
  prediction beyond :data:`WIDEN_SIGMA` moves the allowance half-way to it
  and widens it to cover both (a history less precise than the default
  allowance is not used for this).

Without known runs the allowance is the default ±10 % (:meth:`LossDrift.unknown`)
and narrows only where the differences of the recent recordings, regressed
on the payload (the intercept is the drift, the slope the inertia
signature's gain error), show the losses where the calibration left them,
to no less than :data:`HISTORY_FLOOR_REL`; it widens again when they move.

What a conveyor's history can and cannot show: a δ that stays put is
averaged down by the number of recordings, so the history narrows a
stable conveyor's allowance; a drift faster than the pooling window, or
smaller than the pooled inertia noise (a few per cent on most conveyors),
it cannot see, and a systematic error of the inertia signature (its model
error, a share of the payload) does not average away. A Kalman filter on
the difference, tried before, followed that noise and bias rather than the
losses; known runs carry no inertia noise and are what narrows the
allowance to the losses' real movement.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from datetime import datetime
from typing import Any

import numpy as np

from chaintwin.identify.calibration import INERTIA_MODEL_REL
from chaintwin.identify.defaults import LOSS_DRIFT_REL
from chaintwin.identify.zero_reference import ZeroReference
from chaintwin.read.recording import RecordingWarning
from chaintwin.weigh.drift import LossDrift
from chaintwin.weigh.weigh import Signatures, WeighResult, reweigh

__all__ = [
    "GAIN_PRIOR",
    "HISTORY_FLOOR_REL",
    "JUMP_SIGMA",
    "RATE_CHANGE_PRIOR",
    "TRACKING_VERSION",
    "WALK_PRIOR",
    "WARM_UP_REL",
    "WARM_UP_S",
    "ZeroTracker",
    "known_run_drift",
]

TRACKING_VERSION = 2
"""Format version of :meth:`ZeroTracker.to_dict` (1: rows without the offset's regressor;
such a state loads with its warm-up rows and history dropped)."""

DAY_S = 86400.0

RATE_PRIOR = 0.05 / DAY_S
"""Standard uncertainty of the drift rate at the first known run, 1/s: 5 % a day."""

RATE_CHANGE_PRIOR = (0.05 / DAY_S) ** 2 / DAY_S
"""Prior diffusion of the drift rate, 1/s³: it changes by 5 % a day in a day."""

WALK_PRIOR = 0.005**2 / DAY_S
"""Prior random walk of the drift itself, 1/s: 0.5 % in a day."""

JUMP_SIGMA = 3.0
"""A known run this many sigmas off the prediction is a jump (an oil change)."""

SCALE_KEEP = 10
"""Known runs whose normalised innovations scale the process noise."""

WARM_KEEP = 300
"""Recordings the warm-up offset is learned from (the most recent)."""

GAIN_PRIOR = INERTIA_MODEL_REL
"""Prior standard uncertainty of the inertia signature's gain error beyond its
calibrated gain, 1: it reads as a drift in proportion to the payload."""

WARM_UP_REL = 0.03
"""How far the losses may move from a known run's within a few hours of it, 1
(a gear warming up after a cold start)."""

WARM_UP_LIMIT = 2.0 * WARM_UP_REL
"""A warm-up offset fitted beyond this, 1, is no warm-up: the differences of the
recordings with a payload disagree with the known runs (an inertia signature whose
error is a share of the payload, beyond its calibrated model error), so the known
runs' drift is not carried over to them and the allowance is the history's."""

WARM_UP_S = 3600.0
"""Time constant of that movement, s."""

HISTORY_FLOOR_REL = 0.02
"""The narrowest allowance the history alone gives (without known runs), 1."""

HISTORY_SCATTER = True
"""Without known runs, scale the history's variances to its own scatter (see
:meth:`ZeroTracker._history_fit`)."""

SCATTER_FLOOR = 1.0e-4
"""The smallest factor the history's own scatter puts on its recordings' variances, 1."""

HISTORY_MIN = 8
"""Recordings the history needs before it narrows the allowance."""

HISTORY_KEEP = 30
"""Recordings the history pools (the most recent)."""

HISTORY_RECENT = 1
"""The latest recordings the history also checks on their own (a step shows there first)."""

OFFSET_PRIOR_KG = 1.0e4
"""Prior standard uncertainty of the inertia signature's offset in operation, kg
(weak: the known runs measure it)."""

NO_REFERENCE = "zero_reference_missing"
"""Warning code of a known run read against a calibration without a reference zero."""

WIDEN_SIGMA = 2.0
"""The history widens the allowance when its mean is this many sigmas off."""


def _gls(ys: list[float], xs: list[float], c: np.ndarray) -> tuple[float, float] | None:
    """δ and its variance from ``y = x·δ + e``, ``cov(e) = c``; None when x carries nothing."""
    x = np.asarray(xs, dtype=float)
    y = np.asarray(ys, dtype=float)
    try:
        inv = np.linalg.inv(c)
    except np.linalg.LinAlgError:
        return None
    info = float(x @ inv @ x)
    if not (info > 0.0 and math.isfinite(info)):
        return None
    return float(x @ inv @ y) / info, 1.0 / info


def known_run_drift(sig: Signatures, payload_kg: float) -> tuple[float, float] | None:
    """The loss drift δ a recording with a known payload measures, and its variance.

    Parameters
    ----------
    sig : Signatures
        The recording's signatures (:attr:`WeighResult.signatures`).
    payload_kg : float
        The payload known to be on the belt, kg.

    Returns
    -------
    tuple of float or None
        ``(δ, var δ)``, 1 and 1; None when neither signature depends on the
        losses (no drift gradient).
    """
    w2 = sig.widen**2
    var_f = sig.friction_var
    if sig.friction_sigma > 0.0 and math.isfinite(sig.friction_rel_kg):
        var_f += (sig.friction_sigma * sig.friction_rel_kg) ** 2
    if sig.inertia_kg is None or sig.inertia_var is None or sig.drift_inertia_kg == 0.0:
        return _gls(
            [sig.friction_kg - payload_kg], [sig.drift_friction_kg], np.array([[var_f * w2]])
        )
    c = np.array([[var_f, sig.covariance], [sig.covariance, sig.inertia_var]]) * w2
    return _gls(
        [sig.friction_kg - payload_kg, sig.inertia_kg - payload_kg],
        [sig.drift_friction_kg, sig.drift_inertia_kg],
        c,
    )


def _difference_drift(sig: Signatures) -> tuple[float, float, float, float] | None:
    """δ from the friction-minus-inertia difference of a recording with an unknown payload.

    ``p_f − p_i = δ·(k_f − k_i) + e``. Returns ``(δ, var δ, p_i/(k_f − k_i),
    1/(k_f − k_i))``: the third is the regressor of the inertia signature's
    gain error (a share of the payload, which reads as δ in proportion to
    the payload), the last (1/kg) that of its offset in operation (kg: the
    ramps of operation are not the calibration's); None without an inertia
    signature.
    """
    if sig.inertia_kg is None or sig.inertia_var is None:
        return None
    k = sig.drift_friction_kg - sig.drift_inertia_kg
    var = (sig.friction_var + sig.inertia_var - 2.0 * sig.covariance) * sig.widen**2
    if k == 0.0 or not (var > 0.0 and math.isfinite(var)):
        return None
    return (sig.friction_kg - sig.inertia_kg) / k, var / k**2, sig.inertia_kg / k, 1.0 / k


def _iso(at: datetime | None) -> str | None:
    return None if at is None else at.isoformat()


def _seconds(a: str | None, b: datetime | None) -> float | None:
    """``b − a`` in s, or None when either time is unknown."""
    if a is None or b is None:
        return None
    start = datetime.fromisoformat(a)
    if (start.tzinfo is None) != (b.tzinfo is None):
        return None
    return (b - start).total_seconds()


def _warm(since: float) -> float:
    """The warm-up offset's regressor at ``since`` s after a known run, 1."""
    return 1.0 - math.exp(-max(since, 0.0) / WARM_UP_S)


def _fit(
    x: np.ndarray, y: np.ndarray, var: np.ndarray, prior_sd: tuple[float, ...]
) -> tuple[np.ndarray, np.ndarray]:
    """Weighted least squares of ``y = x·β`` with zero-mean priors on β: β and its
    covariance, inflated by the scatter beyond the rows' variances."""
    w = 1.0 / var
    info = (x.T * w) @ x + np.diag([1.0 / sd**2 for sd in prior_sd])
    cov = np.linalg.inv(info)
    beta = cov @ ((x.T * w) @ y)
    n = y.shape[0]
    if n > x.shape[1]:
        chi2 = float(np.sum(w * (y - x @ beta) ** 2))
        cov = cov * max(1.0, chi2 / (n - x.shape[1]))
    return beta, cov


def _corrected(rows: list[list[float]], beta: np.ndarray, cov: np.ndarray) -> list[list[float]]:
    """History rows ``[δ, var, p_i/k, 1/k]`` as ``[δ, var]`` with the inertia signature's
    gain error and offset (``beta``, covariance ``cov``) taken out."""
    out = []
    for d, v, pk, ik in rows:
        x = np.array([pk, ik])
        out.append([d - float(x @ beta), v + float(x @ cov @ x)])
    return out


def _weighted_mean(rows: list[list[float]]) -> tuple[float, float] | None:
    """Weighted mean of ``[value, variance]`` rows and its variance, inflated by the
    scatter beyond the rows' own variances."""
    n = len(rows)
    if n == 0:
        return None
    d = np.array([r[0] for r in rows])
    w = 1.0 / np.array([r[1] for r in rows])
    mean = float(np.sum(w * d) / np.sum(w))
    chi2 = float(np.sum(w * (d - mean) ** 2))
    excess = max(1.0, chi2 / (n - 1)) if n > 1 else 1.0
    return mean, excess / float(np.sum(w))


@dataclass
class ZeroTracker:
    """A conveyor's loss-drift allowance, kept from recording to recording.

    Feed every weighing in recorded order to :meth:`track`; it returns the
    weighing combined with the allowance (:func:`~.weigh.reweigh`).

    Attributes
    ----------
    at : str or None
        When the last known run was recorded, ISO 8601 (None: no known run yet).
    state : list of float
        The drift δ (1) and its rate (1/s) after the last known run.
    covariance : list of list of float
        Their covariance (2 × 2).
    innovations : list of float
        Normalised squared innovations of the recent known runs, 1.
    warm : list of list of float
        ``[x, p_i/k, 1/k, r, var r]`` of recent recordings: the warm-up
        regressor, the regressors of the inertia signature's gain error and
        offset, the difference's δ minus the prediction (for a known run:
        minus what it read), and its variance.
    history : list of list of float
        ``[δ, var δ, p_i/k, 1/k]`` of the recordings' signature differences
        since the last known run (all recent ones without known runs),
        oldest first.
    reference_var : float
        The calibration model's error variance that the last known run carries
        (:attr:`~chaintwin.identify.zero_reference.ZeroReference.model_sigma`), 1.
    """

    at: str | None = None
    state: list[float] = field(default_factory=lambda: [0.0, 0.0])
    covariance: list[list[float]] = field(default_factory=lambda: [[0.0, 0.0], [0.0, 0.0]])
    innovations: list[float] = field(default_factory=list)
    warm: list[list[float]] = field(default_factory=list)
    history: list[list[float]] = field(default_factory=list)
    reference_var: float = 0.0

    @property
    def noise_scale(self) -> float:
        """Factor on the process noise: the recent known runs' mean normalised innovation."""
        if not self.innovations:
            return 1.0
        return min(max(float(np.mean(self.innovations)), 0.25), 400.0)

    def _predict(self, since: float) -> tuple[np.ndarray, np.ndarray]:
        """Drift and rate ``since`` s after the last known run, and their covariance."""
        f = np.array([[1.0, since], [0.0, 1.0]])
        q = RATE_CHANGE_PRIOR * np.array(
            [[since**3 / 3.0, since**2 / 2.0], [since**2 / 2.0, since]]
        ) + WALK_PRIOR * np.array([[since, 0.0], [0.0, 0.0]])
        x = f @ np.array(self.state)
        p = f @ np.array(self.covariance) @ f.T + self.noise_scale * q
        return x, p

    def _warm_fit(self) -> tuple[float, float, np.ndarray, np.ndarray]:
        """The warm-up offset ``a`` with its variance, and the inertia signature's gain
        error and offset in operation with their covariance, from the priors and the
        recordings since known runs (the known runs, at no warm-up, pin the offset)."""
        if not self.warm:
            return 0.0, WARM_UP_REL**2, np.zeros(2), np.diag([GAIN_PRIOR**2, 0.0])
        rows = np.array(self.warm)
        beta, cov = _fit(
            rows[:, :3], rows[:, 3], rows[:, 4], (WARM_UP_REL, GAIN_PRIOR, OFFSET_PRIOR_KG)
        )
        return float(beta[0]), float(cov[0, 0]), beta[1:], cov[1:, 1:]

    def _history_fit(self) -> tuple[float, float, float, float, float] | None:
        """The drift and the gain error with their variances from the history alone, and
        the factor its own scatter puts on its recordings' variances.

        A recording's difference carries the calibration model's error in its
        variance; in operation that error is the same from recording to
        recording and shows in the intercept, not in the scatter. The scatter
        about the fit (χ²/dof, not below :data:`SCATTER_FLOOR`) is what
        averages down over the history.
        """
        if len(self.history) < HISTORY_MIN:
            return None
        rows = np.array(self.history)
        x = np.column_stack([np.ones(rows.shape[0]), rows[:, 2]])
        prior = (LOSS_DRIFT_REL, GAIN_PRIOR)
        var = rows[:, 1]
        scale = 1.0
        if HISTORY_SCATTER:
            beta, _ = _fit(x, rows[:, 0], var, prior)
            chi2 = float(np.sum((rows[:, 0] - x @ beta) ** 2 / var))
            scale = max(chi2 / (rows.shape[0] - x.shape[1]), SCATTER_FLOOR)
            var = var * scale
        beta, cov = _fit(x, rows[:, 0], var, prior)
        return float(beta[0]), float(cov[0, 0]), float(beta[1]), float(cov[1, 1]), scale

    def _without_known(self) -> LossDrift:
        """The allowance from the history alone: the default narrowed where the recent
        recordings show the losses where the calibration left them."""
        found = self._history_fit()
        if found is None:
            return LossDrift.unknown()
        c, c_var, gain, gain_var, scale = found
        # the whole history and its most recent part: a move shows in the latter first
        recent = _weighted_mean(
            _corrected(
                [[d, v * scale, pk, ik] for d, v, pk, ik in self.history[-HISTORY_MIN:]],
                np.array([gain, 0.0]),
                np.diag([gain_var, 0.0]),
            )
        )
        sigma = math.sqrt(c**2 + 4.0 * c_var)
        if recent is not None:
            sigma = max(sigma, math.sqrt(recent[0] ** 2 + 4.0 * recent[1]))
        return LossDrift(0.0, min(max(sigma, HISTORY_FLOOR_REL), LOSS_DRIFT_REL))

    def allowance(
        self, at: datetime | None, *, known_runs: bool = True
    ) -> tuple[LossDrift, float | None]:
        """The loss drift to weigh a recording made at ``at`` with, and the time since the
        last known run, s (None without one, when a time is unknown, or with
        ``known_runs`` False: the known runs learned are then not used)."""
        if self.at is None or not known_runs:
            return self._without_known(), None
        since = _seconds(self.at, at)
        if since is None or since < 0.0:
            return LossDrift.unknown(), since
        x, p = self._predict(since)
        a, a_var, beta, cov = self._warm_fit()
        if abs(a) > WARM_UP_LIMIT:
            # the loaded recordings' differences disagree with the known runs beyond any
            # warm-up: the known runs' drift does not carry over to them
            return self._without_known(), since
        xw = _warm(since)
        mean = float(x[0]) + a * xw
        var = float(p[0, 0]) + xw * xw * a_var + self.reference_var
        corrected = _corrected(self.history, beta, cov)
        worst: tuple[float, float, float] | None = None
        for pooled in (_weighted_mean(corrected), _weighted_mean(corrected[-HISTORY_RECENT:])):
            if pooled is None:
                continue
            h_mean, h_var = pooled
            if h_var >= LOSS_DRIFT_REL**2:
                continue  # a history that tells less than the default tells nothing here
            z = abs(h_mean - mean) / math.sqrt(h_var + var)
            if z > WIDEN_SIGMA and (worst is None or z > worst[0]):
                worst = (z, h_mean, h_var)
        if worst is not None:
            # the history since the known run says the losses moved: the losses are
            # where the known run left them or where the history says, either one
            _z, h_mean, h_var = worst
            half = 0.5 * (h_mean - mean)
            mean, var = mean + half, half**2 + max(var, h_var)
        return LossDrift(mean, math.sqrt(var)), since

    def _restart(self, delta: float, variance: float) -> None:
        """Start the filter at a measured drift, combined with the default allowance.

        The default (δ = 0 ± :data:`LOSS_DRIFT_REL`) is what is known of the
        losses without a known run: a known run that tells little (weak
        signatures, a 1 ms scope) moves the drift little.
        """
        info = 1.0 / variance + 1.0 / LOSS_DRIFT_REL**2
        self.state = [delta / variance / info, 0.0]
        self.covariance = [[1.0 / info, 0.0], [0.0, RATE_PRIOR**2]]

    def learn_known(
        self,
        sig: Signatures,
        payload_kg: float,
        at: datetime | None,
        reference: ZeroReference | None = None,
    ) -> bool:
        """Take a known run: the filter updates its drift and rate, and its scale learns.

        Parameters
        ----------
        sig : Signatures
            The known run's signatures.
        payload_kg : float
            Its known payload, kg.
        at : datetime or None
            When it was recorded.
        reference : ZeroReference or None
            The calibration's reference zero: the scatter of what its own
            recordings read beyond their uncertainties is the model error the
            known run carries (None: none carried).

        Returns
        -------
        bool
            False when the recording tells nothing of the losses.
        """
        found = known_run_drift(sig, payload_kg)
        if found is None:
            return False
        delta, r = found
        if reference is not None:
            # the calibration model's error where its own recordings read it: common
            # to every known run, so carried beside the filter into the allowance
            # rather than averaged down by it
            self.reference_var = reference.model_sigma**2
        since = _seconds(self.at, at)
        if self.at is None or since is None or since <= 0.0:
            # the first known run (or one whose time cannot be placed): start over
            self._restart(delta, r)
        else:
            x, p = self._predict(since)
            s = float(p[0, 0]) + r
            innovation = delta - float(x[0])
            nis = innovation**2 / s
            self.innovations = [*self.innovations, nis][-SCALE_KEEP:]
            if nis > JUMP_SIGMA**2:
                # a jump (an oil change): start again from the measured drift; the
                # recordings since the last known run were compared with the old losses
                self._restart(delta, r)
                if self.history:
                    self.warm = self.warm[: -len(self.history)]
            else:
                gain = p[:, 0] / s
                x = x + gain * innovation
                p = p - np.outer(gain, p[0, :])
                self.state = [float(x[0]), float(x[1])]
                self.covariance = [[float(v) for v in row] for row in 0.5 * (p + p.T)]
        diff = _difference_drift(sig)
        if diff is not None:
            # the difference at a known drift and no warm-up: the inertia signature's
            # offset and gain error in operation
            d_diff, var_diff, pk, ik = diff
            row = [0.0, pk, ik, d_diff - delta, var_diff + r]
            self.warm = [*self.warm, row][-WARM_KEEP:]
        self.at = _iso(at)
        self.history = []
        return True

    def observe(self, sig: Signatures, at: datetime | None) -> None:
        """Take a recording with an unknown payload into the history."""
        found = _difference_drift(sig)
        if found is None:
            return
        delta, var, pk, ik = found
        self.history = [*self.history, [delta, var, pk, ik]][-HISTORY_KEEP:]
        since = _seconds(self.at, at)
        if self.at is not None and since is not None and since >= 0.0:
            x, p = self._predict(since)
            row = [_warm(since), pk, ik, delta - float(x[0]), var + float(p[0, 0])]
            self.warm = [*self.warm, row][-WARM_KEEP:]

    def track(
        self,
        result: WeighResult,
        at: datetime | None,
        known_kg: float | None,
        reference: ZeroReference | None = None,
        *,
        known_runs: bool = False,
    ) -> WeighResult:
        """The weighing combined with the tracked allowance; the tracker learns from it.

        By default the allowance comes from the history alone (the recordings'
        signature differences narrow the default where the losses stay put)
        and a recording with a known payload is one more recording. With
        ``known_runs`` (experimental, opt-in) a known payload measures the
        drift and the others are weighed with what it can have moved since.

        Parameters
        ----------
        result : WeighResult
            The recording's weighing (any loss drift: it is combined again).
        at : datetime or None
            When the recording was made.
        known_kg : float or None
            The payload known to be on the belt (metadata ``payload_kg``), kg.
        reference : ZeroReference or None
            The calibration's reference zero (:attr:`Calibration.zero_reference`);
            None (a calibration written before it): a known run is read
            without its model error and its result warns that this needs a
            recalibration.
        known_runs : bool
            Learn from recordings with a known payload (default False).
        """
        sig = result.signatures
        if sig is None:
            drift, since = self.allowance(at, known_runs=known_runs)
            return dataclasses.replace(result, loss_drift=drift, since_known_run_s=since)
        known = known_runs and known_kg is not None and math.isfinite(known_kg)
        if known and known_kg is not None and self.learn_known(sig, known_kg, at, reference):
            drift, since = self.allowance(at)
            out = reweigh(result, drift)
            warnings = out.warnings
            if reference is None:
                warnings = (*warnings, _no_reference_warning())
            return dataclasses.replace(
                out, since_known_run_s=since, known_run=True, warnings=warnings
            )
        drift, since = self.allowance(at, known_runs=known_runs)
        out = reweigh(result, drift)
        self.observe(sig, at)
        return dataclasses.replace(out, since_known_run_s=since)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        return {
            "version": TRACKING_VERSION,
            "at": self.at,
            "state": list(self.state),
            "covariance": [list(r) for r in self.covariance],
            "innovations": list(self.innovations),
            "warm": [list(r) for r in self.warm],
            "history": [list(h) for h in self.history],
            "reference_var": self.reference_var,
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> ZeroTracker:
        """Inverse of :meth:`to_dict`; KeyError, TypeError or ValueError when damaged.

        A version 1 state keeps its filter; its warm-up rows and history
        (without the offset's regressor) are dropped and learned again.
        """
        version = int(data["version"])
        if version not in (1, TRACKING_VERSION):
            raise ValueError(f"zero tracking version {data['version']!r} is not supported")
        at = data["at"]
        old = version == 1
        out = cls(
            at=None if at is None else str(at),
            state=[float(v) for v in data["state"]],
            covariance=[[float(v) for v in row] for row in data["covariance"]],
            innovations=[float(v) for v in data["innovations"]],
            warm=[] if old else [[float(v) for v in row] for row in data["warm"]],
            history=[] if old else [[float(v) for v in row] for row in data["history"]],
            reference_var=0.0 if old else float(data["reference_var"]),
        )
        if out.at is not None:
            datetime.fromisoformat(out.at)
        shapes = [len(out.state) == 2, len(out.covariance) == 2]
        shapes += [len(row) == 2 for row in out.covariance]
        shapes += [len(row) == 5 for row in out.warm] + [len(row) == 4 for row in out.history]
        if not all(shapes):
            raise ValueError("zero tracking: a state, covariance or history row of the wrong size")
        values = [*out.state, *out.innovations, out.reference_var]
        values += [v for rows in (out.covariance, out.warm, out.history) for r in rows for v in r]
        if not all(math.isfinite(v) for v in values):
            raise ValueError("zero tracking holds a value that is not a number")
        return out


def _no_reference_warning() -> RecordingWarning:
    return RecordingWarning(
        NO_REFERENCE,
        "the calibration has no reference zero (written before it): this known run's loss "
        "drift carries no allowance for the calibration model's own error. Calibrate again "
        "to track the zero from known runs",
    )
