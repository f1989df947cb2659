"""Residuals of the rigid model: measured minus model motor torque (docs/design.md, section 3).

The rigid model's torque per sample comes from
:func:`chaintwin.model.rigid.model_torque` (the one rigid model).

The residual ``e = T_measured − T_model`` (Nm) is what the rigid model does
not explain: belt ringing after the ramp corners, the polygon effect, gear and
bearing orders, an obstruction at one place on the belt, a wrong payload or
drifting friction. :func:`residual_stats` condenses it into the statistics of
docs/design.md section 3; :func:`residual_analysis` does so for the whole recording
and per kind of movement phase.

A fault locked to one place on the belt (an obstruction, a damaged module)
repeats at the same belt position in every recording, even when one belt
revolution takes longer than a scope: :func:`belt_position_m` gives the
absolute belt position per sample and :func:`position_profile` accumulates
residuals (or anything else) over belt-position bins, recording by recording.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np
from numba import njit
from scipy.integrate import cumulative_trapezoid

from chaintwin._stats import median as lean_median
from chaintwin._types import FloatArray
from chaintwin.errors import EstimationError
from chaintwin.model.frequencies import _kinematic_ratio
from chaintwin.read.profile import ConveyorProfile
from chaintwin.read.recording import Recording
from chaintwin.validate.phases import Phase, segment

__all__ = [
    "CORNER_SAMPLES",
    "DEFAULT_BIN_WIDTH_M",
    "MIN_SAMPLES",
    "PHASE_KINDS",
    "ResidualReport",
    "ResidualStats",
    "belt_position_m",
    "position_profile",
    "residual_analysis",
    "residual_stats",
]

MIN_SAMPLES = 4
"""Fewest samples :func:`residual_stats` accepts."""

CORNER_SAMPLES = 3
"""Samples left out at each end of a phase in the per-phase statistics."""

PHASE_KINDS: tuple[str, ...] = ("accelerate", "constant", "decelerate")
"""The moving phase kinds :func:`residual_analysis` reports separately."""

DEFAULT_BIN_WIDTH_M = 0.025
"""Default belt-position bin width of :func:`position_profile`, m."""


# --------------------------------------------------------------------- statistics
@dataclass(frozen=True)
class ResidualStats:
    """Statistics of a residual ``e = measured − model`` (torques, Nm).

    Attributes
    ----------
    mean, median : float
        Of e, Nm.
    std : float
        Population standard deviation of e (``ddof=0``), Nm.
    variance : float
        Population variance of e (``ddof=0``), Nm².
    rms : float
        ``sqrt(mean(e²))``, Nm.
    max_abs : float
        ``max|e|``, Nm.
    kurtosis : float
        Pearson kurtosis ``scipy.stats.kurtosis(e, fisher=False)``
        (biased, 3 for a Gaussian, 1.5 for a sine); nan when e is constant.
    skewness : float
        ``scipy.stats.skew(e)`` (biased); nan when e is constant.
    crest_factor : float
        ``max|e| / rms(e)`` (√2 for a sine); nan when e is all zero.
    correlation : float
        Pearson correlation of measured and model torque (not of e); 0.0 when
        either is constant (the coefficient is undefined there, and a constant
        model explains none of the measured variation).
    rel_error_pct : float
        ``100·rms(e)/rms(measured)``, %; nan when the measured torque is all
        zero.
    samples : int
        Number of samples used (pairs where both torques are finite).

    Notes
    -----
    :meth:`to_dict` writes nan as None (JSON null).
    """

    mean: float
    median: float
    std: float
    variance: float
    rms: float
    max_abs: float
    kurtosis: float
    skewness: float
    crest_factor: float
    correlation: float
    rel_error_pct: float
    samples: int

    def to_dict(self) -> dict[str, float | int | None]:
        """Return the fields as a JSON-ready dict (non-finite floats as None)."""
        out: dict[str, float | int | None] = {}
        for name in _STATS_FIELDS:
            value = getattr(self, name)
            if isinstance(value, float) and not math.isfinite(value):
                out[name] = None
            else:
                out[name] = value
        return out


_STATS_FIELDS: tuple[str, ...] = tuple(f.name for f in fields(ResidualStats))
"""Field names of :class:`ResidualStats` in order (``to_dict`` without ``asdict``'s deep copy)."""


def residual_stats(measured: FloatArray, model: FloatArray) -> ResidualStats:
    """Statistics of the residual ``e = measured − model``.

    See :class:`ResidualStats` for the definitions. Sample pairs where either
    value is not finite are left out.

    Parameters
    ----------
    measured : FloatArray
        Measured torque, Nm.
    model : FloatArray
        Model torque, Nm, same shape.

    Returns
    -------
    ResidualStats

    Raises
    ------
    EstimationError
        When the shapes differ or fewer than 4 finite sample pairs remain.
    """
    y = np.asarray(measured, dtype=np.float64)
    m = np.asarray(model, dtype=np.float64)
    if y.shape != m.shape:
        raise EstimationError(
            f"residual statistics need measured and model torque of the same shape; "
            f"got {y.shape} and {m.shape}"
        )
    e, sums = _residual_sums(
        np.ascontiguousarray(y.ravel(), dtype=np.float64),
        np.ascontiguousarray(m.ravel(), dtype=np.float64),
    )
    n = int(e.shape[0])
    if n < MIN_SAMPLES:
        raise EstimationError(
            f"residual statistics need at least {MIN_SAMPLES} finite samples; got {n}"
        )
    mean, variance, ee, max_abs, d4, d3, yy, corr = (float(v) for v in sums)
    std = math.sqrt(variance)
    rms = math.sqrt(ee / n)
    # constant residual (within rounding): skewness and kurtosis are undefined,
    # and scipy would warn about catastrophic cancellation
    if std <= 1e-12 * max(max_abs, 1e-300):
        kurtosis = skewness = math.nan
    else:
        # the biased central-moment estimators of scipy.stats.kurtosis(fisher=False)
        # and scipy.stats.skew (the tests check they agree), without their
        # per-call overhead, which dominated the monitoring step
        kurtosis = (d4 / n) / (variance * variance)
        skewness = (d3 / n) / variance**1.5
    rms_measured = math.sqrt(yy / n)
    return ResidualStats(
        mean=mean,
        median=lean_median(e),
        std=std,
        variance=variance,
        rms=rms,
        max_abs=max_abs,
        kurtosis=kurtosis,
        skewness=skewness,
        crest_factor=max_abs / rms if rms > 0.0 else math.nan,
        correlation=corr,
        rel_error_pct=100.0 * rms / rms_measured if rms_measured > 0.0 else math.nan,
        samples=n,
    )


@njit(cache=True, nogil=True)
def _residual_sums(
    y: np.ndarray, m: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover - compiled; tested through residual_stats
    """The finite pairs' residual ``e`` and, in two compiled passes over them: its
    mean, variance, Σe², max |e|, Σd⁴ and Σd³ (d = e − mean), Σy² and the
    Pearson correlation of y and m (0 when either is constant)."""
    count = y.shape[0]
    e = np.empty(count, dtype=np.float64)
    ys = np.empty(count, dtype=np.float64)
    ms = np.empty(count, dtype=np.float64)
    n = 0
    se = 0.0
    sy = 0.0
    sm = 0.0
    ee = 0.0
    yy = 0.0
    top = 0.0
    for i in range(count):
        a = y[i]
        b = m[i]
        if np.isfinite(a) and np.isfinite(b):
            r = a - b
            e[n] = r
            ys[n] = a
            ms[n] = b
            se += r
            sy += a
            sm += b
            ee += r * r
            yy += a * a
            top = max(top, abs(r))
            n += 1
    out = np.zeros(8, dtype=np.float64)
    if n == 0:
        return e[:0], out
    mean = se / n
    my = sy / n
    mm = sm / n
    d2s = 0.0
    d3s = 0.0
    d4s = 0.0
    saa = 0.0
    sbb = 0.0
    sab = 0.0
    for i in range(n):
        d = e[i] - mean
        d2 = d * d
        d2s += d2
        d3s += d2 * d
        d4s += d2 * d2
        da = ys[i] - my
        db = ms[i] - mm
        saa += da * da
        sbb += db * db
        sab += da * db
    corr = 0.0
    if saa > 0.0 and sbb > 0.0:
        corr = min(max(sab / np.sqrt(saa * sbb), -1.0), 1.0)
    out[0] = mean
    out[1] = d2s / n
    out[2] = ee
    out[3] = top
    out[4] = d4s
    out[5] = d3s
    out[6] = yy
    out[7] = corr
    return e[:n], out


@dataclass(frozen=True)
class ResidualReport:
    """Residual statistics of one recording, whole and per phase kind.

    Attributes
    ----------
    whole : ResidualStats
        Over every sample of the moving phases (corners included), or over
        the whole recording when asked to include standstill.
    by_phase : dict of str to ResidualStats
        ``"accelerate"``, ``"constant"``, ``"decelerate"``: pooled over all
        phases of that kind, without the first and last
        :data:`CORNER_SAMPLES` samples of each phase; a kind that is absent or
        has fewer than 4 samples left is left out.
    residual : FloatArray
        ``measured − model`` per sample, Nm.
    """

    whole: ResidualStats
    by_phase: dict[str, ResidualStats]
    residual: FloatArray

    def to_dict(self) -> dict[str, object]:
        """Return ``{"whole": {...}, "by_phase": {kind: {...}}}`` (JSON-ready)."""
        return {
            "whole": self.whole.to_dict(),
            "by_phase": {kind: s.to_dict() for kind, s in self.by_phase.items()},
        }


def residual_analysis(
    recording: Recording,
    model: FloatArray,
    *,
    phases: list[Phase] | None = None,
    include_standstill: bool = False,
) -> ResidualReport:
    """Residual of the measured torque against a model torque, whole and per phase.

    Parameters
    ----------
    recording : Recording
        Measured torque (``recording.torque``, Nm).
    model : FloatArray
        Model torque per sample, Nm (e.g. from :func:`chaintwin.model.rigid.model_torque`).
    phases : list of Phase, optional
        Movement phases; default :func:`~chaintwin.validate.phases.segment`.
        Each moving phase contributes its samples ``[start + 3, stop − 3)``
        to its kind: the ramp corners (jerk, the belt's ringing, the motor's
        torque lag) belong to neither side.
    include_standstill : bool
        Whether ``whole`` includes the standstill phases. Default False: at
        standstill Coulomb friction holds whatever torque the drive applies
        (after a stop, typically the speed controller's leftover braking
        torque, held by stiction), which the model cannot know; those samples
        would dominate the whole-recording statistics with something that
        says nothing about the movement. The returned ``residual`` always
        covers every sample.

    Returns
    -------
    ResidualReport

    Raises
    ------
    EstimationError
        When ``model`` does not have one value per sample, or fewer than 4
        finite samples are left for ``whole`` (no movement).
    """
    measured = recording.torque
    model = np.asarray(model, dtype=np.float64)
    if model.shape != measured.shape:
        raise EstimationError(
            f"{recording.source}: model torque has shape {model.shape}, "
            f"the recording {measured.shape}"
        )
    if phases is None:
        phases = segment(recording)
    if include_standstill:
        whole_idx = np.arange(measured.shape[0])
    else:
        moving = [np.arange(ph.start, ph.stop) for ph in phases if ph.moving]
        whole_idx = np.concatenate(moving) if moving else np.empty(0, dtype=np.int64)
    try:
        whole = residual_stats(measured[whole_idx], model[whole_idx])
    except EstimationError as exc:
        raise EstimationError(f"{recording.source}: {exc}") from exc
    by_phase: dict[str, ResidualStats] = {}
    for kind in PHASE_KINDS:
        parts = [
            np.arange(ph.start + CORNER_SAMPLES, ph.stop - CORNER_SAMPLES)
            for ph in phases
            if ph.kind == kind and ph.moving
        ]
        idx = np.concatenate(parts) if parts else np.empty(0, dtype=np.int64)
        sel = measured[idx], model[idx]
        if int(np.count_nonzero(np.isfinite(sel[0]) & np.isfinite(sel[1]))) < MIN_SAMPLES:
            continue
        by_phase[kind] = residual_stats(*sel)
    return ResidualReport(whole=whole, by_phase=by_phase, residual=measured - model)


# --------------------------------------------------------------------- belt position
def belt_position_m(recording: Recording, profile: ConveyorProfile) -> FloatArray:
    """Belt position along its loop per sample, m, in ``[0, loop_length)``.

    ``x = θ·r/i mod (2L + π·d)`` with θ the motor angle (rad), r the chordal
    mean radius and i the kinematic gear ratio: the product of the stages'
    tooth ratios when ``gear.stages`` is given (exact), else ``gear.ratio``
    (as :mod:`chaintwin.model.frequencies` does).

    The position channel is absolute (multi-turn, with any fixed offset), so
    x is the same place on the belt in every recording of a conveyor, up to
    that one offset. Without a position channel θ is the cumulative
    trapezoid integral of the speed from 0 at the first sample: the result is
    then relative to where the belt stood at the trigger and cannot be
    compared across recordings.

    Parameters
    ----------
    recording : Recording
        ``position`` (rad), else ``speed`` (rad/s) and ``time`` (s).
    profile : ConveyorProfile
        Sprocket, gear and belt length.

    Returns
    -------
    FloatArray
        Belt position, m.
    """
    theta = recording.position
    if theta is None:
        theta = cumulative_trapezoid(recording.speed, recording.time, initial=0.0)
    x = np.asarray(theta, dtype=np.float64) * (profile.chordal_radius_m / _kinematic_ratio(profile))
    out: FloatArray = np.mod(x, profile.loop_length_m)
    return out


def position_profile(
    position_m: FloatArray,
    values: FloatArray,
    loop_length_m: float,
    *,
    bin_width_m: float = DEFAULT_BIN_WIDTH_M,
    bins: int | None = None,
) -> tuple[FloatArray, FloatArray]:
    """Sum and count of values per belt-position bin, for a belt-locked map.

    The loop ``[0, loop_length)`` is cut into ``bins`` equal bins (default
    ``ceil(loop_length / bin_width_m)``, so each is at most ``bin_width_m``
    wide); positions are taken modulo the loop length first. Adding the
    returned sums and counts of several recordings and dividing gives the
    mean per place on the belt; a fault at one place (an obstruction) stands
    out there. Only pairs where position and value are finite are counted.

    Parameters
    ----------
    position_m : FloatArray
        Belt position per sample, m (e.g. :func:`belt_position_m`).
    values : FloatArray
        A value per sample (e.g. the residual, Nm), same shape.
    loop_length_m : float
        Belt loop length, m (> 0).
    bin_width_m : float
        Largest bin width, m (default 25 mm).
    bins : int, optional
        Number of bins; overrides ``bin_width_m``.

    Returns
    -------
    sums : FloatArray
        Sum of the values per bin (units of the values).
    counts : FloatArray
        Number of values per bin.

    Raises
    ------
    EstimationError
        When the shapes differ, or the loop length, bin width or bin count is
        not positive.
    """
    x = np.asarray(position_m, dtype=np.float64).ravel()
    v = np.asarray(values, dtype=np.float64).ravel()
    if np.shape(position_m) != np.shape(values):
        raise EstimationError(
            f"position and values must have the same shape; got "
            f"{np.shape(position_m)} and {np.shape(values)}"
        )
    if not (loop_length_m > 0.0 and math.isfinite(loop_length_m)):
        raise EstimationError(f"loop length must be positive; got {loop_length_m}")
    if bins is None:
        if not bin_width_m > 0.0:
            raise EstimationError(f"bin width must be positive; got {bin_width_m}")
        # tolerance: 0.3/0.025 is 11.999999999999998 in floating point
        bins = max(1, math.ceil(loop_length_m / bin_width_m - 1e-9))
    if bins < 1:
        raise EstimationError(f"bin count must be at least 1; got {bins}")
    keep = np.isfinite(x) & np.isfinite(v)
    x = np.mod(x[keep], loop_length_m)
    idx = np.minimum((x * (bins / loop_length_m)).astype(np.int64), bins - 1)
    sums: FloatArray = np.bincount(idx, weights=v[keep], minlength=bins).astype(np.float64)
    counts: FloatArray = np.bincount(idx, minlength=bins).astype(np.float64)
    return sums, counts
