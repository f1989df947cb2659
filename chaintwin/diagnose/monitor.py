"""The health model of one conveyor, recording by recording, with its state.

:class:`ConveyorMonitor` takes a conveyor's recordings in recorded order and
for each one

1. weighs it and extracts its condition features
   (:mod:`chaintwin.diagnose.features`) against the conveyor's calibration,
   or, without one, against a calibration learned from its first
   ``baseline_n`` recordings (:mod:`chaintwin.diagnose.learned`);
2. while the baseline is being learned (the first ``baseline_n`` recordings
   after calibration and after each maintenance event), adds them to it;
3. afterwards checks every feature against its baseline
   (:mod:`chaintwin.diagnose.health`), applies the X-of-Y rule per feature,
   opens an alarm for a feature whose rule is met and names the probable
   cause (:func:`resolve_causes`);
4. closes an alarm once its feature has not exceeded in the last Y
   recordings, or at a maintenance event.

Everything it learns is in :meth:`ConveyorMonitor.to_state` (JSON-ready),
so monitoring continues with new recordings without recomputing old ones.
Maintenance events and acknowledgements are kept with who, when and why.
"""

from __future__ import annotations

import dataclasses
import math
import uuid
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from chaintwin.errors import ChaintwinError, EstimationError, MonitorError, StoreError
from chaintwin.identify.calibration import Calibration
from chaintwin.model.frequencies import apparent_orders, known_line_orders
from chaintwin.read.profile import ConveyorProfile
from chaintwin.read.recording import Recording, RecordingWarning
from chaintwin.validate.checks import Inspection
from chaintwin.validate.phases import segment

from .features import FEATURES, RecordingFeatures, feature_spec
from .features import recording_features as extract
from .health import FeatureBaseline, fit_baseline, forecast_crossing, x_of_y
from .learned import learn_calibration
from .peaks import median_spectrum
from .residuals import DEFAULT_BIN_WIDTH_M
from .spectra import Spectrum
from .state import close_alarms, new_event

__all__ = [
    "CAUSE_PRIORITY",
    "ConveyorMonitor",
    "MonitorSettings",
    "RecordingResult",
    "SettingsGiven",
    "resolve_causes",
]

CAUSE_PRIORITY: tuple[str, ...] = (
    "obstruction",
    "elongation",
    "gear",
    "bearing",
    "lubrication",
    "friction",
)
"""Causes from the most specific to the least: a specific fault also moves
the general features (an obstruction raises the mean friction, an elongated
chain's articulation raises friction, a broken tooth raises the broadband
residual), so those are read as the specific fault when it is present."""

EXPLAINED_BY: dict[str, tuple[str, ...]] = {
    "friction": ("obstruction", "elongation"),
    "residual_std": ("obstruction", "gear", "elongation"),
    "residual_kurtosis": ("obstruction",),
    "crest_factor": ("obstruction",),
    "unexplained_peak": ("obstruction", "gear"),
    "comb": ("obstruction",),
}
"""Which more specific causes explain a feature's rise (``comb`` stands for
every ``comb_<shaft>``): an obstruction's bump, passed once in a scope, is
an impulse whose spectrum spreads over the shaft lines too."""

NO_FORECAST: tuple[str, ...] = ("belt_bump",)
"""Features without a trend forecast: the belt map carries each place's value
from recording to recording, so its points are not independent (and an
obstruction does not grow steadily)."""

SPECTRUM_GUARD_BINS = 4
"""Bins either side of a known line left out of ``unexplained_peak``."""

MIN_MAP_SHARE = 0.9
"""Share of the belt loop the belt map must have seen twice before ``belt_bump`` is computed."""


@dataclass(frozen=True, slots=True)
class MonitorSettings:
    """How a conveyor is monitored.

    Attributes
    ----------
    baseline_n : int
        Recordings in a baseline (and in a learned calibration).
    x, y : int
        An alarm needs ``x`` exceedances of a feature in the last ``y`` recordings.
    z_limit : float
        A feature exceeds more than this many robust baseline scales above
        its baseline (and more than its smallest relative change).
    """

    baseline_n: int = 20
    x: int = 3
    y: int = 10
    z_limit: float = 5.0

    def __post_init__(self) -> None:
        if self.baseline_n < 5:
            raise MonitorError(
                f"baseline_n {self.baseline_n} must be at least 5 recordings", field="baseline_n"
            )
        if not 1 <= self.x <= self.y:
            raise MonitorError(
                f"alarm_rule {self.x}/{self.y} needs 1 <= X <= Y", field="alarm_rule"
            )
        if not (math.isfinite(self.z_limit) and self.z_limit > 0):
            raise MonitorError(f"z_limit {self.z_limit} must be a positive number", field="z_limit")


@dataclass(frozen=True, slots=True)
class SettingsGiven:
    """Settings as a user gave them (None: not given), merged with stored ones.

    A state keeps the settings it was monitored with; options given again
    replace them, options left out keep them (and defaults apply to a new
    conveyor).
    """

    baseline_n: int | None = None
    x: int | None = None
    y: int | None = None
    z_limit: float | None = None

    def merged(self, stored: MonitorSettings | None) -> MonitorSettings:
        """The settings to use: given, else stored, else the defaults.

        Raises
        ------
        MonitorError
            When the result is not a valid setting.
        """
        base = stored or MonitorSettings()
        return MonitorSettings(
            baseline_n=base.baseline_n if self.baseline_n is None else self.baseline_n,
            x=base.x if self.x is None else self.x,
            y=base.y if self.y is None else self.y,
            z_limit=base.z_limit if self.z_limit is None else self.z_limit,
        )


@dataclass
class RecordingResult:
    """What monitoring says about one recording (``monitor --json`` object)."""

    file: str
    conveyor: str
    recorded_at: str | None
    status: str
    """``learning`` (calibration being learned), ``baseline`` (part of the
    baseline), ``monitored``, ``duplicate`` or ``refused``."""
    alarm: bool = False
    causes: list[dict[str, Any]] = field(default_factory=list)
    payload_kg: float | None = None
    uncertainty_kg: float | None = None
    tlf: float | None = None
    features: dict[str, float | None] = field(default_factory=dict)
    exceeded: list[str] = field(default_factory=list)
    warnings: list[dict[str, str]] = field(default_factory=list)
    error: str | None = None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready; a refused recording gives ``file`` and ``error`` only."""
        if self.error is not None:
            return {"file": self.file, "error": self.error}
        return {
            "file": self.file,
            "recorded_at": self.recorded_at,
            "alarm": self.alarm,
            "causes": self.causes,
            "payload_kg": self.payload_kg,
            "tlf": self.tlf,
            "warnings": self.warnings,
            "conveyor": self.conveyor,
            "status": self.status,
            "uncertainty_kg": self.uncertainty_kg,
            "features": self.features,
            "exceeded": self.exceeded,
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> RecordingResult:
        """Inverse of :meth:`to_dict` (for results kept in a state)."""
        return cls(**{k: v for k, v in data.items() if k in cls.__dataclass_fields__})


def _spectrum(x: list[float], amplitude: list[float], speed_rpm: float) -> Spectrum:
    """A plateau torque spectrum as a state keeps it (grid, amplitudes, speed)."""
    grid = np.asarray(x)
    return Spectrum(
        x=grid,
        amplitude=np.asarray(amplitude),
        kind="frequency",
        resolution=float(grid[1] - grid[0]),
        channel="torque",
        speed_rpm=speed_rpm,
    )


def _number(x: float | None) -> float:
    """NaN for an unknown value (None, as a state file stores it)."""
    return float("nan") if x is None else float(x)


def _finite(x: float | None) -> float | None:
    return None if x is None or not math.isfinite(x) else float(x)


def resolve_causes(features: list[str]) -> dict[str, str]:
    """The probable cause of each feature that met the alarm rule together.

    Parameters
    ----------
    features : list of str
        Features whose X-of-Y rule is met at one recording.

    Returns
    -------
    dict of str to str
        Feature to cause: its own (:data:`~chaintwin.diagnose.features.FEATURES`),
        unless a more specific cause present among the others explains it
        (:data:`EXPLAINED_BY`).
    """
    own = {f: feature_spec(f).cause or "unknown" for f in features}
    present = set(own.values())
    out: dict[str, str] = {}
    for f, cause in own.items():
        for specific in EXPLAINED_BY.get("comb" if f.startswith("comb_") else f, ()):
            if specific in present:
                cause = specific
                break
        out[f] = cause
    return out


def _priority(cause: str) -> int:
    return CAUSE_PRIORITY.index(cause) if cause in CAUSE_PRIORITY else len(CAUSE_PRIORITY)


def _iso(t: datetime | None) -> str | None:
    """ISO 8601 in UTC, so that times from plants in other zones compare as strings."""
    return None if t is None else t.astimezone(UTC).isoformat()


def _parse_time(text: str | None) -> datetime | None:
    """A stored ISO time, None when absent or unreadable."""
    try:
        return None if text is None else datetime.fromisoformat(text)
    except (TypeError, ValueError):
        return None


class ConveyorMonitor:
    """Health model of one conveyor.

    Parameters
    ----------
    profile : ConveyorProfile
        The conveyor.
    settings : MonitorSettings
        Baseline size, X-of-Y rule, z limit.
    calibration : Calibration, optional
        Its calibration; without one a calibration is learned from the first
        ``baseline_n`` recordings. A sibling conveyor's calibration (another
        ``id``) serves as a starting point: its parameters with this
        conveyor's profile.
    loader : callable, optional
        Reads a recording again by file name, for recordings a state kept
        pending (calibration still being learned when the state was saved).
    """

    def __init__(
        self,
        profile: ConveyorProfile,
        settings: MonitorSettings | None = None,
        calibration: Calibration | None = None,
        *,
        loader: Callable[[str], Recording] | None = None,
    ) -> None:
        self.profile = profile
        self.settings = settings or MonitorSettings()
        self.loader = loader
        self.calibration_source = "none"
        self.notes: list[dict[str, str]] = []
        self.calibration: Calibration | None = None
        if calibration is not None:
            self.set_calibration(calibration)
        self.pending: list[Recording] = []
        self.pending_files: list[str] = []
        self._pending_meta: list[tuple[str | None, list[dict[str, str]]]] = []
        self.baseline_rows: list[dict[str, Any]] = []
        self.late_rows: list[dict[str, Any]] = []
        self.baseline_spectra: list[tuple[list[float], list[float], float] | None] = []
        self.baselines: dict[str, FeatureBaseline] | None = None
        self.baseline_spectrum: tuple[list[float], list[float], float] | None = None
        self.baseline_since: str | None = None
        self.belt_last: list[float | None] = []
        self.belt_prev: list[float | None] = []
        self.windows: dict[str, list[bool]] = {}
        self.window_times: dict[str, list[str | None]] = {}
        self.alarms: list[dict[str, Any]] = []
        self.events: list[dict[str, Any]] = []
        self.history: list[dict[str, Any]] = []
        self.processed: dict[str, int] = {}
        self.last_recorded_at: str | None = None
        # derived once, not state: (the object they were derived from, values)
        self._orders_cache: tuple[Calibration, npt.NDArray[np.float64]] | None = None
        self._baseline_cache: (
            tuple[
                tuple[list[float], list[float], float],
                npt.NDArray[np.float64],
                npt.NDArray[np.float64],
                float,
            ]
            | None
        ) = None

    # ---------------------------------------------------------- calibration
    def set_calibration(self, calibration: Calibration) -> None:
        """Use a calibration: this conveyor's, or a sibling's as a starting point."""
        if calibration.profile.id != self.profile.id:
            self.notes.append(
                RecordingWarning(
                    "sibling_calibration",
                    f"calibration of '{calibration.profile.id}' used as the starting point for "
                    f"'{self.profile.id}' (its parameters with this conveyor's profile); "
                    "payloads are approximate, features are compared with this conveyor's "
                    "own baseline",
                ).to_dict()
            )
            calibration = Calibration(
                **{
                    **{f: getattr(calibration, f) for f in calibration.__dataclass_fields__},
                    "profile": self.profile,
                }
            )
            self.calibration_source = "sibling"
        else:
            self.calibration_source = "file"
        self.calibration = calibration

    # ---------------------------------------------------------- events
    def add_event(self, kind: str, at: datetime, by: str, why: str) -> dict[str, Any]:
        """Record a maintenance event (:func:`~chaintwin.diagnose.state.new_event`).

        Recordings made after ``at`` form a new baseline; open alarms are
        closed by it.
        """
        event = new_event(kind, by, why, at)
        self.events.append(event)
        self.events.sort(key=lambda e: e["at"])
        close_alarms(self.alarms, event)
        return event

    def _apply_events(self, when: datetime | None) -> list[dict[str, str]]:
        """Apply maintenance events made before this recording: a new baseline."""
        notes: list[dict[str, str]] = []
        if when is None:
            return notes
        for event in self.events:
            if event["applied"] or _parse_time(event["at"]) is None:
                continue
            at = _parse_time(event["at"])
            assert at is not None
            if at <= when:
                event["applied"] = True
                self.restart_baseline()
                close_alarms(self.alarms, event)
                notes.append(
                    RecordingWarning(
                        "baseline_restarted",
                        f"maintenance '{event['kind']}' on {event['at']} by {event['by']} "
                        f"({event['why']}): the baseline restarts from this recording",
                    ).to_dict()
                )
        return notes

    def restart_baseline(self) -> None:
        """Forget the baseline: the next recordings form a new one."""
        self.baseline_rows = []
        self.late_rows = []
        self.baseline_spectra = []
        self.baselines = None
        self.baseline_spectrum = None
        self.baseline_since = None
        self.belt_last = []
        self.belt_prev = []
        self.windows = {}
        self.window_times = {}

    # ---------------------------------------------------------- processing
    def process(
        self,
        recording: Recording,
        sha256: str | None = None,
        *,
        features: RecordingFeatures | None = None,
    ) -> list[RecordingResult]:
        """Take the next recording (in recorded order).

        ``features``, when given, are the recording's features computed
        elsewhere (a worker process) against this monitor's calibration.

        Returns
        -------
        list of RecordingResult
            Usually one; none while a calibration is being learned (the
            recordings wait), all waiting ones when it has been learned.
        """
        when = recording.metadata.recorded_at
        if sha256 is not None and any(sha == sha256 for sha, _x in self._pending_meta):
            return [
                RecordingResult(
                    file=recording.source,
                    conveyor=self.profile.id,
                    recorded_at=_iso(when),
                    status="duplicate",
                    warnings=[
                        RecordingWarning(
                            "already_processed",
                            "this recording is already waiting for the learned calibration "
                            "(same content); it is not counted twice",
                        ).to_dict()
                    ],
                )
            ]
        if sha256 is not None and sha256 in self.processed:
            old = RecordingResult.from_dict(self.history[self.processed[sha256]])
            old.file = recording.source
            old.status = "duplicate"
            old.warnings = [
                *old.warnings,
                RecordingWarning(
                    "already_processed",
                    "this recording was processed before (same content); its earlier result "
                    "is shown and the health model is unchanged",
                ).to_dict(),
            ]
            return [old]
        extra: list[dict[str, str]] = []
        stamp = _iso(when)
        if (
            stamp is not None
            and self.last_recorded_at is not None
            and stamp < self.last_recorded_at
        ):
            extra.append(
                RecordingWarning(
                    "out_of_order",
                    f"recorded before the last recording already monitored "
                    f"({self.last_recorded_at}); processed now, after it",
                ).to_dict()
            )
        if stamp is not None:
            self.last_recorded_at = max(self.last_recorded_at or "", stamp)
        extra += self._apply_events(when)
        if "position" not in recording.channels and not self._noted("no_position"):
            self.notes.append(
                RecordingWarning(
                    "no_position",
                    "the recordings have no position channel: faults at one place of the belt "
                    "(obstruction) cannot be followed; add the position to the scope",
                ).to_dict()
            )
        if self.calibration is None:
            self.pending.append(recording)
            self.pending_files.append(str(Path(recording.source).resolve()))
            self._pending_meta.append((sha256, extra))
            if len(self.pending) < self.settings.baseline_n:
                return []
            return self._learn()
        return [self._monitor(recording, sha256, extra, features)]

    def waiting(self) -> list[tuple[Recording, str | None]]:
        """The recordings held back until a calibration is learned, with their content hashes."""
        return [(rec, sha) for rec, (sha, _x) in zip(self.pending, self._pending_meta, strict=True)]

    def _noted(self, code: str) -> bool:
        return any(n["code"] == code for n in self.notes)

    def flush_pending(self) -> list[RecordingResult]:
        """Monitor the recordings that waited for a calibration (after :meth:`set_calibration`)."""
        if self.calibration is None:
            return []
        recs, meta = self.pending, self._pending_meta
        self.pending, self.pending_files, self._pending_meta = [], [], []
        return [self._monitor(r, sha, extra) for r, (sha, extra) in zip(recs, meta, strict=True)]

    def _learn(self) -> list[RecordingResult]:
        try:
            cal = learn_calibration(self.pending, self.profile)
        except EstimationError as exc:
            # keep waiting for more recordings
            self.notes = [n for n in self.notes if n["code"] != "learning_failed"]
            self.notes.append(RecordingWarning("learning_failed", str(exc)).to_dict())
            return []
        self.notes = [n for n in self.notes if n["code"] != "learning_failed"]
        self.calibration = cal
        self.calibration_source = "learned"
        return self.flush_pending()

    def finish(self) -> list[RecordingResult]:
        """Results for recordings still waiting for a learned calibration."""
        out = []
        n = self.settings.baseline_n
        for rec in self.pending:
            out.append(
                RecordingResult(
                    file=rec.source,
                    conveyor=self.profile.id,
                    recorded_at=_iso(rec.metadata.recorded_at),
                    status="learning",
                    warnings=[
                        *(w.to_dict() for w in rec.warnings),
                        RecordingWarning(
                            "baseline_learning",
                            f"no calibration: waiting for {n} recordings to learn one "
                            f"({len(self.pending)} so far); no features yet",
                        ).to_dict(),
                    ],
                )
            )
        return out

    def _unexplained_peak(self, spectrum: Spectrum | None) -> tuple[float, float]:
        """Largest ratio to the baseline spectrum away from known lines, and its order."""
        if spectrum is None or self.baseline_spectrum is None or self.calibration is None:
            return float("nan"), float("nan")
        bx, ba, floor = self._baseline_arrays(self.baseline_spectrum)
        ref = np.interp(spectrum.x, bx, ba)
        ratio = spectrum.amplitude / np.maximum(ref, floor)
        speed_hz = spectrum.speed_rpm / 60.0
        if speed_hz <= 0:
            return float("nan"), float("nan")
        if not spectrum.x[-1] > 0:
            return float("nan"), float("nan")
        ts = 1.0 / (2.0 * float(spectrum.x[-1]))
        res = spectrum.resolution
        lines = apparent_orders(self._line_orders(self.calibration), spectrum.speed_rpm, ts)
        near = np.abs(spectrum.x[:, None] - lines[None, :] * speed_hz) <= SPECTRUM_GUARD_BINS * res
        guard = near.any(axis=1) | (spectrum.x < 2.0 * res)  # the trend left in the lowest bins
        ratio = np.where(guard, 0.0, ratio)
        k = int(np.argmax(ratio))
        return float(ratio[k]), float(spectrum.x[k] / speed_hz)

    def _line_orders(self, calibration: Calibration) -> npt.NDArray[np.float64]:
        """:func:`known_line_orders` of the calibration, computed once per calibration."""
        cached = self._orders_cache
        if cached is None or cached[0] is not calibration:
            cached = (
                calibration,
                np.asarray(known_line_orders(calibration.id_profile), dtype=np.float64),
            )
            self._orders_cache = cached
        return cached[1]

    def _baseline_arrays(
        self, spectrum: tuple[list[float], list[float], float]
    ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], float]:
        """The baseline spectrum as arrays and its median amplitude, once per baseline."""
        cached = self._baseline_cache
        if cached is None or cached[0] is not spectrum:
            bx, ba = np.asarray(spectrum[0]), np.asarray(spectrum[1])
            cached = (spectrum, bx, ba, float(np.median(ba)))
            self._baseline_cache = cached
        return cached[1], cached[2], cached[3]

    def _belt_bump(self, feats: RecordingFeatures) -> tuple[float, float | None]:
        """Update the belt map; its largest local rise and where, m.

        The map holds, per place of the loop, the residual's rise on the last
        two passes. A place counts with the smaller of the two: an obstruction
        is there on every pass, a one-off disturbance (stick-slip, a knock)
        on one only. The rise is in robust standard deviations of the map
        over the loop (median absolute deviation), a number that does not
        depend on the conveyor's noise level.
        """
        if self.calibration is None:
            return float("nan"), None
        prof = self.calibration.id_profile
        nbins = math.ceil(prof.loop_length_m / DEFAULT_BIN_WIDTH_M)
        if len(self.belt_last) != nbins or len(self.belt_prev) != nbins:
            self.belt_last = [None] * nbins
            self.belt_prev = [None] * nbins
        bins = np.asarray(feats.bump_bins).tolist()
        values = np.asarray(feats.bump_values, dtype=np.float64).tolist()
        for b, v in zip(bins, values, strict=True):
            if math.isfinite(v):
                self.belt_prev[int(b)] = self.belt_last[int(b)]
                self.belt_last[int(b)] = v
        last = np.array(self.belt_last, dtype=np.float64)  # None -> NaN
        prev = np.array(self.belt_prev, dtype=np.float64)
        both = np.where(np.isfinite(last) & np.isfinite(prev), np.minimum(last, prev), np.nan)
        if np.isfinite(both).sum() < MIN_MAP_SHARE * nbins:
            return float("nan"), None
        # a bump spans a few bins (its width plus a tooth pitch of averaging)
        padded = np.concatenate((both[-1:], both, both[:1]))
        smooth = np.convolve(np.nan_to_num(padded, nan=0.0), np.ones(3), mode="valid")
        counts = np.convolve(np.isfinite(padded).astype(float), np.ones(3), mode="valid")
        with np.errstate(invalid="ignore", divide="ignore"):
            local = np.where(counts > 0, smooth / counts, np.nan)
        idx = int(np.nanargmax(local))
        width = prof.loop_length_m / nbins
        centre = float(np.nanmedian(local))
        spread = 1.4826 * float(np.nanmedian(np.abs(local - centre)))
        if spread <= 0.0:
            return float("nan"), None
        return (float(local[idx]) - centre) / spread, (idx + 0.5) * width

    def _monitor(
        self,
        recording: Recording,
        sha256: str | None,
        extra: list[dict[str, str]],
        features: RecordingFeatures | None = None,
    ) -> RecordingResult:
        assert self.calibration is not None
        when = recording.metadata.recorded_at
        base = RecordingResult(
            file=recording.source,
            conveyor=self.profile.id,
            recorded_at=_iso(when),
            status="monitored",
        )
        try:
            feats = (
                features
                if features is not None
                else extract(
                    Inspection(
                        recording,
                        tuple(segment(recording)),
                        not recording.has_warning("incomplete_cycle"),
                    ),
                    self.calibration,
                )
            )
        except EstimationError as exc:
            base.status = "refused"
            text = str(exc)
            base.error = (
                text if text.startswith(recording.source) else f"{recording.source}: {text}"
            )
            return base
        w = feats.weighing
        values = dict(feats.values)
        bump, bump_at = self._belt_bump(feats)
        values["belt_bump"] = bump
        warnings = [x.to_dict() for x in w.warnings] + [x.to_dict() for x in feats.warnings] + extra
        if self.calibration_source != "file":
            warnings.append(
                RecordingWarning(
                    "payload_uncalibrated",
                    f"payload from a {self.calibration_source} calibration, not one made on "
                    "known loads: it may be offset by several kg (see chaintwin calibrate)",
                ).to_dict()
            )
        base.payload_kg = _finite(w.payload_kg)
        base.uncertainty_kg = _finite(w.uncertainty_kg)
        base.tlf = _finite(w.tlf)
        causes: list[dict[str, Any]] = []
        if w.segments:
            first, last = w.segments[0], w.segments[-1]
            causes.append(
                {
                    "cause": "payload_changed",
                    "feature": "payload_kg",
                    "change": (last.payload_kg - first.payload_kg)
                    / max(abs(first.payload_kg), 1.0),
                    "since": _iso(when),
                }
            )
        if w.segments:
            # the load changed during the movement: its features mix two loads
            base.status = "baseline" if self.baselines is None else "monitored"
            base.features = {k: _finite(v) for k, v in values.items()}
            warnings.append(
                RecordingWarning(
                    "not_judged",
                    "the load changed during the movement: this recording's features are "
                    "reported but neither learned nor compared with the baseline",
                ).to_dict()
            )
        elif self.baselines is None:
            base.status = "baseline"
            if self.baseline_since is None:
                self.baseline_since = _iso(when)
            self.baseline_rows.append(values)
            s = feats.spectrum
            self.baseline_spectra.append(
                None if s is None else (s.x.tolist(), s.amplitude.tolist(), s.speed_rpm)
            )
            n = len(self.baseline_rows)
            warnings.append(
                RecordingWarning(
                    "baseline_learning",
                    f"part of the baseline ({n} of {self.settings.baseline_n} recordings); "
                    "no alarms until it is complete",
                ).to_dict()
            )
            base.features = {k: _finite(v) for k, v in values.items()}
            if n >= self.settings.baseline_n:
                self._form_baseline()
        else:
            peak, peak_order = self._unexplained_peak(feats.spectrum)
            values["unexplained_peak"] = peak
            base.features = {k: _finite(v) for k, v in values.items()}
            met: list[str] = []
            change: dict[str, float] = {}
            for name, fb in self.baselines.items():
                spec = feature_spec(name)
                if spec.cause is None:
                    continue
                value = values.get(name, float("nan"))
                load = values.get(spec.regressor, float("nan"))
                ex = fb.check(value, load, self.settings.z_limit, spec.min_rel)
                win = self.windows.setdefault(name, [])
                times = self.window_times.setdefault(name, [])
                win.append(ex.exceeded)
                times.append(_iso(when))
                del win[: -self.settings.y]
                del times[: -self.settings.y]
                if ex.exceeded:
                    base.exceeded.append(name)
                if math.isfinite(ex.change):
                    change[name] = ex.change
                if x_of_y(win, self.settings.x, self.settings.y)[-1]:
                    met.append(name)
            self._late_baselines(values)
            resolved = resolve_causes(met)
            for name in met:
                alarm = self._open_alarm(name, resolved[name], change.get(name), when)
                detail = {
                    "cause": resolved[name],
                    "feature": name,
                    "change": alarm["change"],
                    "since": alarm["since"],
                }
                if name == "belt_bump" and bump_at is not None:
                    detail["belt_position_m"] = bump_at
                if name == "unexplained_peak" and math.isfinite(peak_order):
                    detail["order"] = peak_order
                causes.append(detail)
            self._close_alarms(when)
            base.alarm = bool(met)
        causes.sort(key=lambda c: (_priority(c["cause"]), -abs(c["change"] or 0.0)))
        base.causes = causes
        base.warnings = warnings
        self.history.append(base.to_dict() | {"sha256": sha256})
        if sha256 is not None:
            self.processed[sha256] = len(self.history) - 1
        return base

    def _form_baseline(self) -> None:
        rows = self.baseline_rows
        own = [None if sp is None else _spectrum(*sp) for sp in self.baseline_spectra]
        spectra = [sp for sp in own if sp is not None]
        if spectra:
            median = median_spectrum(spectra)
            self.baseline_spectrum = (
                median.x.tolist(),
                median.amplitude.tolist(),
                median.speed_rpm,
            )
            # the baseline's own unexplained peaks, for its limit
            for row, sp in zip(rows, own, strict=True):
                if sp is not None:
                    row["unexplained_peak"] = self._unexplained_peak(sp)[0]
        self.baseline_spectra = []  # the median is kept; the rows' spectra are not needed
        names = sorted({k for r in rows for k in r})
        out: dict[str, FeatureBaseline] = {}
        for name in names:
            if name not in FEATURES and not name.startswith("comb_"):
                continue
            spec = feature_spec(name)
            fb = fit_baseline(
                [_number(r.get(name)) for r in rows],
                [_number(r.get(spec.regressor)) for r in rows],
                payload_dependent=spec.payload_dependent,
                min_scale=spec.min_scale,
            )
            if fb is not None:
                out[name] = fb
        self.baselines = out

    def _late_baselines(self, values: dict[str, float]) -> None:
        """Baselines of features the first recordings could not tell (the belt map
        needs most of the loop seen), learned from the recordings that follow."""
        assert self.baselines is not None
        missing = [
            k
            for k in values
            if k not in self.baselines
            and (k in FEATURES or k.startswith("comb_"))
            and feature_spec(k).cause is not None
        ]
        if not missing:
            return
        self.late_rows.append(values)
        need = max(5, self.settings.baseline_n // 2)
        for name in missing:
            column = [_number(r.get(name)) for r in self.late_rows]
            if sum(np.isfinite(column)) < need:
                continue
            spec = feature_spec(name)
            fb = fit_baseline(
                column,
                [_number(r.get(spec.regressor)) for r in self.late_rows],
                payload_dependent=spec.payload_dependent,
                min_scale=spec.min_scale,
            )
            if fb is not None:
                self.baselines[name] = fb

    def _open_alarm(
        self, feature: str, cause: str, change: float | None, when: datetime | None
    ) -> dict[str, Any]:
        """The open alarm of a feature (opened now if there is none); its change is
        the latest known (a recording that cannot tell keeps the last one)."""
        for alarm in self.alarms:
            if alarm["status"] == "open" and alarm["feature"] == feature:
                alarm["cause"] = cause
                if change is not None:
                    alarm["change"] = change
                alarm["last_seen"] = _iso(when)
                return alarm
        times = self.window_times.get(feature, [])
        flags = self.windows.get(feature, [])
        since = next((t for t, f in zip(times, flags, strict=True) if f), _iso(when))
        alarm = {
            "id": uuid.uuid4().hex[:8],
            "conveyor": self.profile.id,
            "feature": feature,
            "cause": cause,
            "change": change,
            "since": since,
            "opened_at": _iso(when),
            "last_seen": _iso(when),
            "status": "open",
            "acknowledged": None,
        }
        self.alarms.append(alarm)
        return alarm

    def _close_alarms(self, when: datetime | None) -> None:
        for alarm in self.alarms:
            if alarm["status"] != "open":
                continue
            win = self.windows.get(alarm["feature"], [])
            if len(win) >= self.settings.y and not any(win):
                alarm["status"] = "closed"
                alarm["closed_at"] = _iso(when)
                alarm["closed_by"] = f"no exceedance in the last {self.settings.y} recordings"

    # ---------------------------------------------------------- summary
    def open_alarms(self) -> list[dict[str, Any]]:
        """Open alarms (acknowledged ones included)."""
        return [a for a in self.alarms if a["status"] == "open"]

    def forecasts(self) -> list[dict[str, Any]]:
        """When each tracked feature's trend crosses its limit (rising trends only)."""
        if not self.baselines:
            return []
        out = []
        since = self.baseline_since or ""
        rows = [
            h
            for h in self.history
            if h.get("status") == "monitored" and h.get("recorded_at") and h["recorded_at"] >= since
        ]
        if len(rows) < 8:
            return []
        times = [datetime.fromisoformat(h["recorded_at"]) for h in rows]
        for name, fb in self.baselines.items():
            spec = feature_spec(name)
            if spec.cause is None or name in NO_FORECAST:
                continue
            # at the baseline's mean payload: the load's part of the value taken out
            vals = [
                _number(h["features"].get(name))
                - fb.slope * (_number(h["features"].get(spec.regressor)) - fb.mean_payload_kg)
                for h in rows
            ]
            fc = forecast_crossing(name, times, vals, fb.limit(self.settings.z_limit, spec.min_rel))
            if fc is not None:
                out.append(fc.to_dict() | {"cause": spec.cause})
        return out

    def summary(self) -> dict[str, Any]:
        """The conveyor's summary for ``monitor --json`` (``conveyors``)."""
        return {
            "conveyor": self.profile.id,
            "calibration": self.calibration_source,
            "recordings": len(self.history),
            "baseline": {
                "complete": self.baselines is not None,
                "recordings": len(self.baseline_rows),
                "since": self.baseline_since,
                "outliers": {
                    k: v.outliers for k, v in (self.baselines or {}).items() if v.outliers
                },
            },
            "open_alarms": self.open_alarms(),
            "forecasts": self.forecasts(),
            "events": [e for e in self.events],
            "notes": self.notes,
        }

    # ---------------------------------------------------------- state
    def to_state(self) -> dict[str, Any]:
        """Everything learned, JSON-ready (see :meth:`from_state`)."""
        return {
            "conveyor": self.profile.id,
            "profile_sha256": self.profile.content_hash(),
            "settings": {
                "baseline_n": self.settings.baseline_n,
                "x": self.settings.x,
                "y": self.settings.y,
                "z_limit": self.settings.z_limit,
            },
            "calibration": None if self.calibration is None else self.calibration.to_dict(),
            "calibration_source": self.calibration_source,
            "pending": [
                {"path": path, "file": rec.source, "sha256": sha, "warnings": extra}
                for path, rec, (sha, extra) in zip(
                    self.pending_files, self.pending, self._pending_meta, strict=True
                )
            ],
            "baseline_rows": self.baseline_rows,
            "late_rows": self.late_rows,
            "baseline_spectra": self.baseline_spectra,
            "baselines": None
            if self.baselines is None
            else {k: v.to_dict() for k, v in self.baselines.items()},
            "baseline_spectrum": self.baseline_spectrum,
            "baseline_since": self.baseline_since,
            "belt_last": self.belt_last,
            "belt_prev": self.belt_prev,
            "windows": self.windows,
            "window_times": self.window_times,
            "alarms": self.alarms,
            "events": self.events,
            "history": self.history,
            "notes": self.notes,
            "last_recorded_at": self.last_recorded_at,
        }

    @classmethod
    def from_state(
        cls,
        data: dict[str, Any],
        profile: ConveyorProfile,
        *,
        loader: Callable[[str], Recording] | None = None,
        source: str = "<state>",
    ) -> ConveyorMonitor:
        """Continue from :meth:`to_state` output.

        Raises
        ------
        StoreError
            When the state belongs to another profile or is damaged.
        """
        if data.get("profile_sha256") != profile.content_hash():
            raise StoreError(
                f"{source}: conveyor '{profile.id}' was monitored with another version of its "
                "profile; give the profile it was monitored with, or start a new state file "
                "for the changed conveyor"
            )
        try:
            s = data["settings"]
            mon = cls(
                profile,
                MonitorSettings(
                    int(s["baseline_n"]), int(s["x"]), int(s["y"]), float(s["z_limit"])
                ),
                loader=loader,
            )
            if data["calibration"] is not None:
                mon.calibration = Calibration.from_dict(data["calibration"], source)
            mon.calibration_source = str(data["calibration_source"])
            mon.baseline_rows = list(data["baseline_rows"])
            mon.late_rows = list(data["late_rows"])
            mon.baseline_spectra = [
                None if sp is None else (list(sp[0]), list(sp[1]), float(sp[2]))
                for sp in data["baseline_spectra"]
            ]
            if data["baselines"] is not None:
                mon.baselines = {
                    k: FeatureBaseline.from_dict(v) for k, v in data["baselines"].items()
                }
            bs = data["baseline_spectrum"]
            mon.baseline_spectrum = None if bs is None else (bs[0], bs[1], float(bs[2]))
            mon.baseline_since = data["baseline_since"]
            mon.belt_last = list(data["belt_last"])
            mon.belt_prev = list(data["belt_prev"])
            mon.windows = {k: list(v) for k, v in data["windows"].items()}
            mon.window_times = {k: list(v) for k, v in data["window_times"].items()}
            mon.alarms = list(data["alarms"])
            mon.events = list(data["events"])
            mon.history = list(data["history"])
            mon.notes = list(data["notes"])
            mon.last_recorded_at = data["last_recorded_at"]
            mon.processed = {h["sha256"]: k for k, h in enumerate(mon.history) if h.get("sha256")}
            pending = [
                (str(p["path"]), str(p["file"]), p["sha256"], list(p["warnings"]))
                for p in data["pending"]
            ]
        except (KeyError, TypeError, ValueError, IndexError, AttributeError) as exc:
            raise StoreError(
                f"{source}: monitoring state of '{profile.id}' is damaged ({exc!r}); restore it "
                "from a backup or start a new state file"
            ) from None
        for path, name, sha, extra in pending:
            try:
                if loader is None:
                    raise StoreError("no reader given")
                rec = dataclasses.replace(loader(path), source=name)
            except ChaintwinError as exc:  # the file is gone or no longer readable
                mon.notes.append(
                    RecordingWarning(
                        "pending_lost",
                        f"{name}, waiting for the learned calibration, cannot be read again "
                        f"({exc}); it is left out",
                    ).to_dict()
                )
                continue
            mon.pending.append(rec)
            mon.pending_files.append(path)
            mon._pending_meta.append((sha, extra))
        return mon
