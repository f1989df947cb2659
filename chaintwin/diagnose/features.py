"""Condition features of one recording: what the health model tracks.

Each feature is a number per recording whose rise means a particular kind
of degradation (:data:`FEATURES` names the probable cause of each). They
come from the calibrated model of the conveyor (a calibration file, or one
learned from the conveyor's first recordings, :mod:`chaintwin.diagnose.learned`):

``friction``
    Rail friction against the calibration, μ_now/μ_cal, from one fit of the
    friction payload p_f, the inertia payload p_i and a speed-loss change
    together (:func:`~chaintwin.identify.signatures.fit_condition`):
    ``(m0 + p_f)/(m0 + p_i)`` with m0 the belt and tray mass. The inertia
    signature does not see friction, so this is 1 for any load on a healthy
    conveyor and rises with the rails' friction.
``speed_loss``
    The gear unit's speed-dependent loss at the plateau speed against the
    calibration's: ``1 + ΔBmB·ω/(BmA + BmB·ω + BmC·ω²)``. Lubrication
    trouble raises it; temperature moves it by several percent.
``residual_std``
    Of the constant-speed residual (measured − model torque,
    :mod:`chaintwin.diagnose.residuals`): broadband noise (bearing).
``residual_kurtosis``, ``crest_factor``
    Of the same residual: impulses. Alarmed when they leave their baseline
    band, with the probable cause of what made them impulsive (an obstacle,
    a tooth, a worn sprocket; a bearing when no impact stands out; a
    payload event, reported and not alarmed, when the impacts drag):
    :func:`~chaintwin.diagnose.causes.resolve_causes`.
``residual_step``
    How far the constant-speed residual's level moves within a plateau,
    averaged over 0.2 s (Nm, :func:`~chaintwin.diagnose.impacts.residual_step`):
    an item caught for part of the plateau steps it up and down. Not
    alarmed: on a recording the impact search could not look at (a 1 ms
    scope), beyond its baseline (:data:`CAUGHT_Z`) it marks the recording
    as one whose exceedances an event may have made (see
    :func:`~chaintwin.diagnose.alarms.judge`).
``impact_count``, ``impact_rate_per_m``, ``impact_energy_max``
    The recording's impacts (:mod:`chaintwin.diagnose.impacts`): how many,
    per metre of belt travel, the largest work, J. Alarmed like kurtosis.
``tooth_pass``
    Sum of the residual spectrum's amplitudes (Nm) at the sprocket
    tooth-pass order and its 2nd and 3rd harmonic: the chain's engagement
    with the sprocket (elongation).
``sprocket_comb``
    Sum of the residual spectrum's amplitudes (Nm) at the 4th to 8th
    harmonic of the tooth-pass order, away from the shaft combs: a worn
    sprocket's teeth knock at every engagement, a short impulse whose
    spectrum spreads to many harmonics, where an elongated chain's smoother
    engagement ripple stays in the first three (``tooth_pass``).
``comb_<shaft>``
    Sum of the amplitudes (Nm) at the first :data:`COMB_HARMONICS`
    harmonics of a gear shaft's order, less the largest of them: one damaged
    tooth on that shaft hits once per revolution, a comb of its harmonics
    that raises them all, while one harmonic alone can be something else
    (:func:`_line_sums`).
``unexplained_peak``
    The largest ratio of the residual spectrum to the conveyor's baseline
    spectrum away from every characteristic line and its harmonics (a
    line at a non-integer order: a bearing); set by the health model, which
    holds the baseline spectrum.
``belt_bump``
    Retired, always NaN: it mapped the residual by belt position across
    recordings, but scope positions start at an offset of their own in
    every recording. ``impact_hits_per_rev`` (set by the health model from
    :mod:`chaintwin.diagnose.impacts`) finds an obstruction instead.

The spectral features come from a Welch spectrum of the plateau's residual
averaged with the median over segments, so that a transient seen in one
segment only (an obstruction passed once) does not read as a line. Lines
above the Nyquist frequency of the scope are looked for where they fold
(:func:`~chaintwin.model.frequencies.apparent_order`).
"""

from __future__ import annotations

import math
from collections.abc import Collection, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from chaintwin._stats import median
from chaintwin._types import FloatArray
from chaintwin.diagnose.impacts import Impact, impact_features, residual_step, scan_impacts
from chaintwin.errors import EstimationError, ModelError
from chaintwin.identify.calibration import Calibration
from chaintwin.identify.signatures import SignatureFit, fit_condition
from chaintwin.identify.verification import closed_loop_torque, twin_parameters
from chaintwin.model.frequencies import (
    SHAFT_HARMONICS,
    apparent_orders,
    characteristic_lines,
    characteristic_orders,
    fold_frequency,
    known_line_orders,
    shaft_orders,
)
from chaintwin.model.rigid import RigidParameters, acceleration, model_torque, motoring_mask
from chaintwin.model.windows import WindowIntegrals, window_integrals
from chaintwin.physics import loss_torque_nm
from chaintwin.read.profile import ConveyorProfile
from chaintwin.read.recording import Recording, RecordingWarning
from chaintwin.validate.checks import Inspection
from chaintwin.validate.phases import Phase
from chaintwin.weigh.drift import LOSS_DRIFT_HALF_RANGE, LossDrift
from chaintwin.weigh.weigh import WeighResult, reweigh, weigh

from .lines import band_amplitude, band_amplitudes
from .residuals import residual_analysis, residual_stats
from .spectra import Spectrum, welch_spectrum

__all__ = [
    "CAUGHT_Z",
    "COMB_HARMONICS",
    "DRIFT_OF",
    "FEATURES",
    "IMPULSIVE",
    "FeatureSpec",
    "RecordingFeatures",
    "feature_spec",
    "is_tracked",
    "recording_features",
    "structural_modes",
]

COMB_HARMONICS = SHAFT_HARMONICS
"""Harmonics of a shaft order summed into its ``comb_<shaft>`` feature."""

TOOTH_PASS_HARMONICS = 3
"""Harmonics of the tooth-pass order summed into ``tooth_pass``."""

SPROCKET_HARMONICS = (4, 5, 6, 7, 8)
"""Harmonics of the tooth-pass order summed into ``sprocket_comb``: beyond the
smooth engagement ripple an elongated chain makes (``tooth_pass``), the comb a
short knock at every tooth engagement (a worn sprocket) spreads to."""

GUARD_BINS = 4
"""Bins (of the zero-padded spectrum) either side of a line that belong to it."""

COMB_MIN_LINES = 3
"""Fewest lines of a comb whose largest is left out of its sum (:func:`_line_sums`)."""

LOW_FREQUENCY_HZ = 3.0
"""Lines whose apparent frequency is below this are left out of the line sums, Hz."""

SPECTRUM_SEGMENT = 512
"""Welch segment length, samples (fewer when the plateau is shorter)."""


@dataclass(frozen=True, slots=True)
class FeatureSpec:
    """How the health model treats a feature.

    Attributes
    ----------
    cause : str or None
        Probable cause when it rises (None: tracked, never alarmed).
    min_rel : float
        Smallest relative rise against the baseline that counts as an
        exceedance, whatever the statistics say (the allowance for slow
        temperature drift and the like).
    unit : str
        Unit of the value, for display.
    payload_dependent : bool
        The baseline regresses the value on the estimated payload.
    min_scale : float
        Floor of the baseline's robust scale (feature units), for features
        whose baseline can hold few distinct values.
    regressor : str
        The payload estimate the baseline regresses on: ``payload_inertia_kg``
        (the inertia signature: neither a loss drift nor a friction change
        moves it), or ``load_kg`` (the signatures combined trusting the
        calibration's losses: more precise, but a +-10 % loss drift moves it
        by up to 10 kg on a conveyor with high losses, over random conveyors,
        which reads as a change of every payload-dependent feature), or
        ``payload_kg`` (the weighing's own estimate: the torque amplitudes'
        alternative, since they follow the real load and on a 1 ms scope the
        inertia signature alone is too noisy for them: on one drawn conveyor
        the residual's spread correlated 0.85 with the weighed payload and
        0.39 with the inertia payload, and the baseline's line through the
        latter raised alarms on a healthy drive; used alone, the weighed
        payload's drift with the losses raised alarms on 12 ms conveyors).
    two_sided : bool
        A fall counts as much as a rise: a line the fault adds to one the
        healthy conveyor already has (the chain's polygon ripple at the
        tooth pass) can cancel part of it before it grows.
    alternative : str or None
        A second payload estimate the baseline may regress on instead, when
        the usual one's line explains little of the baseline
        (:data:`~chaintwin.diagnose.baseline.ALTERNATIVE_SHARE`).
    drift : str or None
        The feature that holds how far a drift of the gear losses across its
        whole range (±:data:`~chaintwin.weigh.drift.LOSS_DRIFT_HALF_RANGE`)
        moves this one on this recording (feature units): a rise must exceed
        it to count (:meth:`~chaintwin.diagnose.health.FeatureBaseline.check`).
    payload_curve : bool
        The baseline may follow the payload along a curve where a line does
        not hold (:func:`~chaintwin.diagnose.health.fit_baseline`): a
        spectral line's amplitude, which a belt mode tuned by the payload
        through the line raises over a band of payloads. Not for a two-sided
        feature (falls are judged on a flat baseline only).
    """

    cause: str | None
    min_rel: float
    unit: str
    payload_dependent: bool = False
    min_scale: float = 0.0
    regressor: str = "payload_inertia_kg"
    alternative: str | None = None
    two_sided: bool = False
    payload_curve: bool = False
    drift: str | None = None


AMPLITUDE = "payload_kg"
"""The torque amplitudes' alternative regressor (see :class:`FeatureSpec`)."""

CAUGHT_Z = 3.0
"""Baseline scales beyond which ``residual_step`` marks a recording the impact
search could not look at (a 1 ms scope's plateau) as caught: an item held
for part of its plateau. Not an alarm but a doubt: a caught recording's
exceedances count only when a neighbour that is not caught exceeds too, so
a false mark costs a growing fault one recording at most, while a missed
one lets an event's exceedances count. Hence a looser limit than the
alarms' (one-sided 0.13 % of a normal noise). On a declined 1 ms conveyor
(4.7 Nm drive) the 10 recordings with an item caught stood 25-211 scales
out; 7 of its 170 other recordings were marked too (up to 3.6 scales).
Where the search looked its verdict stands:
an obstacle's hit rings the belt, which steps the level averaged too (6-39
scales on a 12 ms conveyor whose hits the search found as knocks)."""

SPEED_LOSS_MIN_REL = 0.3
"""Smallest rise of ``speed_loss`` that counts, beside its drift allowance. The
condition fit puts a change of every gear loss into the speed-dependent one,
so a +-10 % drift of the losses (oil temperature) moves ``speed_loss`` too:
by 0.2 over the drift's range on the reference conveyor, by 0.66 on a drawn
one whose losses dwarf its payload's friction. That movement is allowed for
per recording (``speed_loss_drift``, :func:`_condition_values`); this floor
is for the rest. At 0.5 with the allowance, lubrication faults were found
44, 52 and 71 recordings after their onset (median over the alarmed
sequences, three seeds of the monitoring evaluation); at 0.3, 31.5, 42 and
56, one more of them named right, no false alarm more."""

IMPULSIVE = "impulsive"
"""Stand-in cause of the features any impulsive torque raises (kurtosis, crest
factor, the impact features): :func:`~chaintwin.diagnose.causes.resolve_causes`
names the specific one from what else rose and from the recording's impacts."""

FEATURES: dict[str, FeatureSpec] = {
    "friction": FeatureSpec(
        "friction",
        0.05,
        "-",
        payload_dependent=True,
        regressor="payload_inertia_kg",
        drift="friction_drift",
    ),
    "speed_loss": FeatureSpec(
        "lubrication", SPEED_LOSS_MIN_REL, "-", payload_dependent=True, drift="speed_loss_drift"
    ),
    "friction_drift": FeatureSpec(None, 0.0, "-"),
    "speed_loss_drift": FeatureSpec(None, 0.0, "-"),
    "residual_std": FeatureSpec(
        "bearing", 0.3, "Nm", payload_dependent=True, alternative=AMPLITUDE
    ),
    "residual_kurtosis": FeatureSpec(IMPULSIVE, 0.5, "-", min_scale=0.1),
    "crest_factor": FeatureSpec(IMPULSIVE, 0.3, "-", min_scale=0.1),
    "tooth_pass": FeatureSpec(
        "elongation", 0.08, "Nm", payload_dependent=True, alternative=AMPLITUDE, two_sided=True
    ),
    "sprocket_comb": FeatureSpec(
        "sprocket", 0.5, "Nm", payload_dependent=True, alternative=AMPLITUDE, payload_curve=True
    ),
    "unexplained_peak": FeatureSpec("bearing", 1.0, "-"),
    "belt_bump": FeatureSpec("obstruction", 1.5, "-", min_scale=0.5),  # retired: always NaN
    "payload_kg": FeatureSpec(None, 0.0, "kg"),
    "load_kg": FeatureSpec(None, 0.0, "kg"),
    "payload_drift_kg": FeatureSpec(None, 0.0, "kg"),
    "payload_inertia_drift_kg": FeatureSpec(None, 0.0, "kg"),
    "payload_inertia_kg": FeatureSpec(None, 0.0, "kg"),
    "tlf": FeatureSpec(None, 0.0, "-"),
    "impact_count": FeatureSpec(IMPULSIVE, 0.0, "-", min_scale=0.15),
    "impact_rate_per_m": FeatureSpec(IMPULSIVE, 0.0, "1/m", min_scale=0.01),
    "impact_energy_max": FeatureSpec(IMPULSIVE, 0.0, "J", min_scale=0.01),
    "impact_isolated": FeatureSpec(None, 0.0, "-"),
    "impact_rail_hits": FeatureSpec(None, 0.0, "-"),  # knocks one rail obstacle could have made
    "impact_drags": FeatureSpec(None, 0.0, "-"),
    "residual_step": FeatureSpec(None, 0.2, "Nm"),  # an item caught: see CAUGHT_Z
    "belt_travel_m": FeatureSpec(None, 0.0, "m"),
    "usage_kg_m": FeatureSpec(None, 0.0, "kg·m"),  # payload × travel (wear.py), set by the monitor
    "usage_since_baseline_t_km": FeatureSpec(None, 0.0, "t·km"),  # what expected_wear is taken for
    "impact_hits_per_rev": FeatureSpec("obstruction", 0.0, "1/rev", min_scale=0.1),
    "impact_pooled_hits": FeatureSpec(None, 0.0, "-"),  # isolated knocks behind the rate above
    "impact_pooled_revs": FeatureSpec(None, 0.0, "rev"),  # belt revolutions the pool covers
}
"""Every tracked feature (``comb_<shaft>`` features are added per profile, cause gear)."""

COMB_SPEC = FeatureSpec(
    "gear", 0.5, "Nm", payload_dependent=True, alternative=AMPLITUDE, payload_curve=True
)
"""Spec of the ``comb_<shaft>`` features."""


MODE_SPEC = FeatureSpec(
    "structure", 1.0, "Nm", payload_dependent=True, alternative=AMPLITUDE, payload_curve=True
)
"""Spec of the ``mode_<line>`` features (a structural mode's amplitude doubled)."""

PER_PROFILE = ("comb_", "mode_")
"""Prefixes of the features a profile adds (one per shaft, one per structural mode)."""

STRUCTURAL_MODES = 2
"""Longitudinal and lateral belt modes looked at (each ``n`` up to this)."""


def is_tracked(name: str) -> bool:
    """Whether the health model tracks a feature of this name."""
    return name in FEATURES or name.startswith(PER_PROFILE)


def feature_spec(name: str) -> FeatureSpec:
    """The spec of a feature, ``comb_<shaft>`` and ``mode_<line>`` included."""
    if name.startswith("comb_"):
        return COMB_SPEC
    if name.startswith("mode_"):
        return MODE_SPEC
    return FEATURES[name]


def structural_modes(
    spectrum: Spectrum, profile: ConveyorProfile, payload_kg: float, sample_time_s: float
) -> dict[str, float]:
    """Amplitude (Nm) of the residual spectrum at each structural mode, by ``mode_<line>``.

    The modes of :func:`~chaintwin.model.frequencies.characteristic_lines`
    (longitudinal belt modes and the two-mass mode from the belt's stiffness,
    lateral modes from ``belt.tension_n``; none without those data) at the
    recording's payload, where the scope shows them (folded above the
    Nyquist frequency). A mode is resolvable when its place lies above
    :data:`LOW_FREQUENCY_HZ`, below the spectrum's top and more than
    :data:`GUARD_BINS` bins from every speed-locked line and harmonic and
    from the other modes; an unresolvable one is NaN (never alarmed).
    """
    load = payload_kg if math.isfinite(payload_kg) and payload_kg > 0.0 else 0.0
    lines = characteristic_lines(
        profile, spectrum.speed_rpm, payload_kg=load, belt_modes=STRUCTURAL_MODES
    )
    places = {
        f"mode_{ln.name}": fold_frequency(ln.frequency_hz, sample_time_s)
        for ln in lines
        if ln.kind == "structural"
    }
    if not places:
        return {}
    speed_hz = spectrum.speed_rpm / 60.0
    locked = apparent_orders(known_line_orders(profile), spectrum.speed_rpm, sample_time_s)
    locked_hz = np.asarray(locked) * speed_hz
    guard = GUARD_BINS * spectrum.resolution
    top = float(spectrum.x[-1])
    out: dict[str, float] = {}
    for name, x in places.items():
        near_line = bool(np.any(np.abs(locked_hz - x) <= guard))
        near_mode = any(abs(y - x) <= guard for n, y in places.items() if n != name)
        if LOW_FREQUENCY_HZ < x < top and not near_line and not near_mode:
            out[name] = band_amplitude(spectrum, x, half_width_bins=2)
        else:
            out[name] = math.nan
    return out


RINGING_AFTER_S = 0.1
"""Left out after an impact in the broadband residual: the drive rings after a hit, s."""

IMPACT_MARGIN_S = 0.02
"""Margin around an impact within which a window counts as touched by it, s."""


def _model_load(w: WeighResult) -> float:
    """The load the model torque is computed with: the payload, else the friction signature's."""
    if w.payload_kg is not None:
        return w.payload_kg
    assert w.signatures is not None
    return w.signatures.friction_kg


def _load_kg(w: WeighResult, trusted: WeighResult) -> float:
    """The load regressor of the baselines: the signatures combined trusting the losses.

    The reported payload allows for a loss drift (honest, but leaning on the
    noisier inertia signature); a baseline regression wants the precise
    reading. Where that is unweighable, the payload; else NaN.
    ``trusted`` is ``reweigh(w, LossDrift())``.
    """
    for p in (trusted.payload_kg, w.payload_kg):
        if p is not None:
            return p
    return float("nan")


DRIFT_OF = {"payload_kg": "payload_drift_kg", "payload_inertia_kg": "payload_inertia_drift_kg"}
"""The feature that says how far a loss drift may have moved a regressor (1 sigma)."""


def _condition_values(
    cond: SignatureFit, params: RigidParameters, calibration: Calibration, m0: float
) -> dict[str, float]:
    """``friction`` and ``speed_loss`` from the condition fit, with their drift allowances.

    ``friction_drift`` and ``speed_loss_drift`` are how far a drift of the
    gear losses across its whole range (2 × :data:`~chaintwin.weigh.drift.
    LOSS_DRIFT_HALF_RANGE`, from one end to the other between the baseline
    and now) moves each, from the fit's loss gradient. On the reference
    conveyor the speed loss moves 0.21 between losses at 0.9 and 1.1 of
    nominal (simulated) and the allowance says 0.212; the friction 0.009-0.013
    against 0.010. Where the losses dwarf the payload's friction and the
    ramps hardly tell a loss change from a payload (a drawn conveyor 12°
    downhill, its belt nearly overhauling the gear, unweighable), the speed
    loss moved 0.66 against an allowance of 0.47 (the calibration's loss
    terms, fitted beside a friction that is not the plant's, are not the
    plant's either): its healthy speed loss went from 0.69 to 1.54 of the
    calibration's with the drift and alarmed lubrication on 48 recordings
    before; with the allowance on none, and its lubrication fault was found
    42 recordings after the onset.
    """
    nan = float("nan")
    p_f = float(cond.estimate[0])
    gain = calibration.inertia_gain
    p_i = (float(cond.estimate[1]) - calibration.inertia_offset_kg) / gain
    out: dict[str, float] = {}
    # an inertia payload that would take away half the belt is no reading
    sound = m0 + p_i > 0.5 * m0
    out["friction"] = (m0 + p_f) / (m0 + p_i) if sound else nan
    wi = cond.windows
    omega = median(wi.mean_speed[wi.constant]) if wi.constant.any() else nan
    loss = loss_torque_nm(omega, *params.losses)
    moving = loss > 0 and omega > 0
    out["speed_loss"] = 1.0 + float(cond.estimate[2]) * omega / loss if moving else nan
    g = cond.loss_gradient
    span = 2.0 * LOSS_DRIFT_HALF_RANGE
    if g is None:
        out["friction_drift"] = out["speed_loss_drift"] = nan
        return out
    d_friction = float(g[0]) / (m0 + p_i) - (m0 + p_f) * float(g[1]) / gain / (m0 + p_i) ** 2
    out["friction_drift"] = span * abs(d_friction) if sound else nan
    out["speed_loss_drift"] = span * abs(float(g[2]) * omega / loss) if moving else nan
    return out


def _payload_drift_kg(w: WeighResult, trusted: WeighResult) -> float:
    """How far the gear-loss drift allowance may have moved the weighed payload, 1 sigma, kg.

    The part of the reported uncertainty that trusting the calibration's
    losses takes away: ``sqrt(u² - u_trusted²)``. A baseline's line through
    the weighed payload sees this as an error of its regressor, which the
    baseline's own scatter (learned over a few days) need not hold.
    """
    return _drift_part(w.uncertainty_kg, trusted.uncertainty_kg)


def _payload_inertia_drift_kg(w: WeighResult, trusted: WeighResult) -> float:
    """The same for the inertia payload, 1 sigma, kg.

    The inertia signature hardly depends on the losses, but not at all is
    too much: the ramps run at other speeds than the plateau, and on a drawn
    1 ms conveyor (held-out seed 13) its payload read 8 kg higher with the
    plant's losses at 1.1 of nominal than at 0.9, the load the same. The
    broadband residual's baseline, regressed on it with a slope of 0.29 mNm
    a kg against a scale of 0.46 mNm, took the drift for a change and
    alarmed `bearing` on 19 recordings before the fault's onset.
    """
    return _drift_part(w.inertia_uncertainty_kg, trusted.inertia_uncertainty_kg)


def _drift_part(u: float | None, u_trusted: float | None) -> float:
    """``sqrt(u² - u_trusted²)``: the part of an uncertainty the loss drift adds; NaN without."""
    if u is None or u_trusted is None:
        return float("nan")
    return math.sqrt(max(u * u - u_trusted * u_trusted, 0.0))


@dataclass(frozen=True)
class RecordingFeatures:
    """What one recording says about the conveyor's condition.

    Attributes
    ----------
    weighing : WeighResult
        Payload, signatures, segments, TLF, warnings.
    values : dict of str to float
        Scalar features (NaN where the recording cannot tell).
    spectrum : Spectrum or None
        Plateau spectrum of the residual (for ``unexplained_peak``).
    residuals : dict
        :meth:`~chaintwin.diagnose.residuals.ResidualReport.to_dict`.
    warnings : tuple of RecordingWarning
        The weighing's and the feature extraction's warnings.
    """

    weighing: WeighResult
    values: dict[str, float]
    spectrum: Spectrum | None
    residuals: dict[str, Any] = field(default_factory=dict)
    warnings: tuple[RecordingWarning, ...] = ()
    impacts: tuple[Impact, ...] = ()


def _std_without(
    recording: Recording, model: FloatArray, phases: Sequence[Phase], impacts: Sequence[Impact]
) -> float:
    """Standard deviation of the constant-speed residual outside the impacts, Nm (NaN: too few).

    The samples of each event from :data:`IMPACT_MARGIN_S` before it to
    :data:`RINGING_AFTER_S` after it are left out, and the ramp corners as
    :func:`~chaintwin.diagnose.residuals.residual_analysis` leaves them.
    """
    spans = [np.arange(p.start + 3, p.stop - 3) for p in phases if p.kind == "constant"]
    idx = np.concatenate(spans) if spans else np.empty(0, dtype=np.intp)
    y = recording.torque[idx].copy()
    t = recording.time[idx]
    for hit in impacts:
        y[(t >= hit.t_s - IMPACT_MARGIN_S) & (t <= hit.t_s + hit.duration_s + RINGING_AFTER_S)] = (
            np.nan
        )
    try:
        return residual_stats(y, model[idx]).std
    except EstimationError:
        return float("nan")


def _line_centres(
    spec: Spectrum, orders: list[float], ts: float, avoid: Sequence[float] = ()
) -> list[float]:
    """Apparent places (Hz) of the given orders whose band amplitudes are summed.

    Orders whose apparent place lies within :data:`GUARD_BINS` bins of the
    apparent place of an order in ``avoid`` are skipped (another line's
    mainlobe would be read as this one's), and so are those that fold below
    :data:`LOW_FREQUENCY_HZ` (a harmonic close to a multiple of the sampling
    frequency), where the residual's slow content moves with the load and
    the losses.
    """
    return _many_line_centres(spec, [(orders, avoid)], ts)[0]


def _many_line_centres(
    spec: Spectrum, asked: Sequence[tuple[list[float], Sequence[float]]], ts: float
) -> list[list[float]]:
    """:func:`_line_centres` of several (orders, avoid) pairs, their apparent
    places folded in one call (elementwise: the same numbers as one call each)."""
    speed_hz = spec.speed_rpm / 60.0
    guard = GUARD_BINS * spec.resolution
    wanted = [(list(orders), list(avoid)) for orders, avoid in asked if orders]
    flat = [x for orders, avoid in wanted for x in (*avoid, *orders)]
    places = (apparent_orders(flat, spec.speed_rpm, ts) * speed_hz).tolist() if wanted else []
    top = float(spec.x[-1])
    found: list[list[float]] = []
    at = 0
    for orders, avoid in wanted:
        others = places[at : at + len(avoid)]
        at += len(avoid)
        out: list[float] = []
        for x in places[at : at + len(orders)]:
            if any(abs(x - y) <= guard for y in others):
                continue
            if LOW_FREQUENCY_HZ < x < top:
                out.append(x)
        at += len(orders)
        found.append(out)
    it = iter(found)
    return [next(it) if orders else [] for orders, _avoid in asked]


def _line_sums(
    spec: Spectrum, centres: dict[str, list[float]], combs: Collection[str] = ()
) -> dict[str, float]:
    """Sum of band amplitudes (±2 bins) at each group of apparent places, Nm.

    For the groups named in ``combs`` (of :data:`COMB_MIN_LINES` lines or more)
    the largest amplitude is left out of the sum: a comb is many lines, and a
    fault that makes one (a tooth that hits once per revolution) raises them
    all, while one harmonic that folds near where the residual's slow content
    lives can carry a comb alone. On a drawn 6 ms conveyor the rotor's 7th
    harmonic folded to 3.3 Hz held 10-15 of the comb's 23-26 mNm, and 40-46
    in one scope of ten (the slow content, not the rotor): its 20 baseline
    scopes showed none of those, and the healthy conveyor alarmed `gear` on
    7 recordings. Only the shaft combs: the sprocket comb (five harmonics of
    the tooth pass) trimmed so named 3 to 5 fewer sprocket faults right over
    three seeds of the monitoring evaluation.
    """
    flat = [x for group in centres.values() for x in group]
    amplitudes = iter(band_amplitudes(spec, flat, half_width_bins=2))
    sums: dict[str, float] = {}
    for name, group in centres.items():
        amps = [float(next(amplitudes)) for _ in group]
        if name in combs and len(amps) >= COMB_MIN_LINES:
            amps.remove(max(amps))
        sums[name] = float(sum(amps))
    return sums


def recording_features(
    inspection: Inspection, calibration: Calibration, *, residual: str = "inverse"
) -> RecordingFeatures:
    """Weigh a recording and extract its condition features.

    Parameters
    ----------
    inspection : Inspection
        A validated recording of the calibrated conveyor with its movement
        phases (validation's segmentation, used as it is).
    calibration : Calibration
        The conveyor's calibration (from a file or learned).
    residual : {"inverse", "closed-loop"}
        The model torque of the residual features: the rigid model driven by
        the measured speed, or the controller replica driven by the recorded
        set points (:func:`chaintwin.identify.verification.closed_loop_torque`;
        when the recording cannot be simulated, the inverse model with the
        warning ``closed_loop_unavailable``).

    Returns
    -------
    RecordingFeatures

    Raises
    ------
    EstimationError
        When the recording cannot be weighed (no motion, no usable window).
    """
    recording = inspection.recording
    phases = list(inspection.phases)
    # the features read the actual torque: the calibration's terms for it (a
    # calibration that weighs with the set point keeps them apart)
    actual = calibration.actual_torque or calibration
    prof = actual.id_profile
    params = actual.parameters
    warnings: list[RecordingWarning] = []
    # the acceleration (a Savitzky-Golay derivative) serves the power-flow mask
    # and both model torques: computed once
    alpha = acceleration(recording)
    mot = motoring_mask(
        recording,
        drive_inertia_kgm2=params["J_d"],
        losses=params.losses,
        alpha=alpha,
    )
    # the window integrals serve weighing and the condition fit alike; when
    # there are none, weighing refuses the recording in its own words
    every: WindowIntegrals | None
    try:
        every = window_integrals(recording, prof, motoring=mot, phases=phases)
    except EstimationError:
        every = None
    w = weigh(inspection, calibration, motoring=mot, windows=every)
    if w.signatures is None:
        # nothing to fit the model to (no motion, no usable window)
        raise EstimationError(f"{recording.source}: {w.unweighable}")
    tray = recording.metadata.tray_kg
    tray = prof.tray_mass_kg if tray is None else tray
    # impacts (an obstacle hit, a caught item) are no load and no friction: the
    # windows they touch are left out of the weighing and the condition fit
    first_load = _model_load(w)
    first = model_torque(
        recording, prof, params, first_load, tray_kg=tray, motoring=mot, alpha=alpha
    )
    # what repeats with the sprocket's teeth or a shaft is no impact
    orders = characteristic_orders(prof)
    shafts = shaft_orders(prof)
    periodic_orders = [
        o for name, o in orders.items() if name in ("sprocket_tooth_pass", "output_shaft")
    ]
    impacts, looked_at = scan_impacts(
        recording, first, phases, [*periodic_orders, *shafts.values()]
    )
    # an item caught for part of a plateau, also where the plateau is too short
    # to be searched for impacts (a 1 ms scope)
    step = residual_step(
        recording,
        first,
        phases,
        [*periodic_orders, *shafts.values()],
        impacts,
        (IMPACT_MARGIN_S, RINGING_AFTER_S),
    )
    if impacts and every is not None:
        touched = np.zeros(every.count, dtype=bool)
        for hit in impacts:
            lo, hi = hit.t_s - IMPACT_MARGIN_S, hit.t_s + hit.duration_s + IMPACT_MARGIN_S
            touched |= (every.t0 < hi) & (every.t1 > lo)
        if touched.any() and not touched.all():
            every = every.select(~touched)
            again = weigh(inspection, calibration, motoring=mot, windows=every)
            if again.signatures is not None:
                w = again
                warnings.append(
                    RecordingWarning(
                        "impacts_excluded",
                        f"{int(touched.sum())} window(s) with {len(impacts)} impact(s) left out "
                        "of the weighing and the condition fit",
                    )
                )
    # the load the model torque is computed with: the payload, or where
    # there is none (the signatures disagree) what the friction fits best
    load_kg = _model_load(w)
    m0 = prof.belt_mass_kg + tray
    nan = float("nan")
    trusted = reweigh(w, LossDrift())
    values: dict[str, float] = {
        "payload_kg": nan if w.payload_kg is None else w.payload_kg,
        # what the baselines regress on: precise rather than drift-proof
        "load_kg": _load_kg(w, trusted),
        "payload_drift_kg": _payload_drift_kg(w, trusted),
        "payload_inertia_drift_kg": _payload_inertia_drift_kg(w, trusted),
        "payload_inertia_kg": nan if w.payload_inertia_kg is None else w.payload_inertia_kg,
        "tlf": nan if w.tlf is None else w.tlf,
    }
    try:
        cond = fit_condition(
            recording, prof, params, tray, mot, actual.ramp_noise_rate, windows=every
        )
    except EstimationError:
        values["friction"] = values["speed_loss"] = nan
        values["friction_drift"] = values["speed_loss_drift"] = nan
    else:
        values.update(_condition_values(cond, params, actual, m0))

    if load_kg == first_load:
        model = first  # the same load: the same torque (nothing has changed it)
    else:
        model = model_torque(
            recording, prof, params, load_kg, tray_kg=tray, motoring=mot, alpha=alpha
        )
    if residual == "closed-loop":
        try:
            model = closed_loop_torque(recording, prof, twin_parameters(prof, actual), load_kg)
        except (EstimationError, ModelError) as exc:
            warnings.append(
                RecordingWarning(
                    "closed_loop_unavailable",
                    f"the closed loop cannot be simulated ({exc}); residual of the inverse model",
                )
            )
    report = residual_analysis(recording, model, phases=phases)
    steady = report.by_phase.get("constant")
    values["residual_std"] = steady.std if steady else nan
    if steady and impacts:
        # broadband noise (a bearing) is judged without the impacts: an item
        # caught for a while is no bearing
        clean = _std_without(recording, model, phases, impacts)
        values["residual_std"] = clean if math.isfinite(clean) else values["residual_std"]
    values["residual_kurtosis"] = steady.kurtosis if steady else nan
    values["crest_factor"] = steady.crest_factor if steady else nan
    values.update(
        impact_features(
            impacts,
            recording,
            phases,
            prof.chordal_radius_m / prof.kinematic_ratio,
            looked_at,
            prof.loop_length_m,
        )
    )
    values["residual_step"] = step

    plateaus = [p for p in phases if p.kind == "constant"]
    spectrum: Spectrum | None = None
    if plateaus:
        longest = max(plateaus, key=lambda p: p.stop - p.start)
        try:
            spectrum = welch_spectrum(
                recording,
                "torque",
                span=(longest.start, longest.stop),
                nperseg=min(SPECTRUM_SEGMENT, longest.stop - longest.start),
                average="median",
            )
        except EstimationError:
            spectrum = None
    ts = recording.sample_time_s
    if spectrum is not None:
        tp = orders.get("sprocket_tooth_pass")
        tp_orders = [h * tp for h in range(1, TOOTH_PASS_HARMONICS + 1)] if tp else []
        asked: dict[str, tuple[list[float], Sequence[float]]] = {}
        if tp:
            asked["tooth_pass"] = (tp_orders, ())
            # a shaft's comb would read as the sprocket's where they meet
            combs = [h * o for o in shafts.values() for h in range(1, COMB_HARMONICS + 1)]
            asked["sprocket_comb"] = (
                [h * tp for h in SPROCKET_HARMONICS],
                [*tp_orders, *combs],
            )
        for name, order in shafts.items():
            asked[f"comb_{name}"] = (
                [h * order for h in range(1, COMB_HARMONICS + 1)],
                tp_orders,
            )
        centres = dict(
            zip(asked, _many_line_centres(spectrum, list(asked.values()), ts), strict=True)
        )
        sums = _line_sums(spectrum, centres, [f"comb_{name}" for name in shafts])
        values["tooth_pass"] = sums["tooth_pass"] if tp else nan
        values["sprocket_comb"] = sums["sprocket_comb"] if tp else nan
        for name in shafts:
            values[f"comb_{name}"] = sums[f"comb_{name}"]
        values.update(structural_modes(spectrum, prof, values["payload_kg"], ts))
    else:
        values["tooth_pass"] = values["sprocket_comb"] = nan
        warnings.append(
            RecordingWarning(
                "no_plateau_spectrum",
                "no constant-speed phase long enough for a spectrum: the spectral "
                "features of this recording are unknown",
            )
        )
    return RecordingFeatures(
        weighing=w,
        values=values,
        spectrum=spectrum,
        residuals=report.to_dict(),
        warnings=tuple(warnings),
        impacts=tuple(impacts),
    )
