"""The health model of one conveyor, recording by recording, with its state.

:class:`ConveyorMonitor` takes a conveyor's recordings in recorded order and
for each one

1. weighs it and extracts its condition features
   (:mod:`chaintwin.diagnose.features`) against the conveyor's calibration,
   or, without one, against a calibration learned from its first
   ``baseline_n`` recordings (:mod:`chaintwin.diagnose.learned`);
2. while the baseline is being learned (the first ``baseline_n`` recordings
   after calibration and after each maintenance event), adds them to it;
3. afterwards checks every feature against its baseline and applies the
   X-of-Y rule (:mod:`.alarms`), opens an alarm for a feature whose rule is
   met and names the probable cause (:mod:`.causes`);
4. closes an alarm once its feature has not exceeded in the last Y
   recordings, or at a maintenance event (:mod:`.state`).

The parts live beside it: settings and results (:mod:`.records`),
baselines and forecasts (:mod:`.baseline`), impacts (:mod:`.impacts`), the
saved state (:mod:`.monitor_state`, JSON-ready, so monitoring continues
without recomputing old recordings).
"""

from __future__ import annotations

import copy
import dataclasses
import math
from collections.abc import Callable, Mapping
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from chaintwin.errors import EstimationError, StoreError
from chaintwin.identify.calibration import Calibration
from chaintwin.model.frequencies import characteristic_orders, known_line_orders
from chaintwin.read.profile import ConveyorProfile
from chaintwin.read.recording import Recording, RecordingWarning
from chaintwin.validate.checks import Inspection
from chaintwin.validate.phases import Phase, segment
from chaintwin.weigh.tlf import (
    belt_travel_m,
    motor_shaft_transport_loss_factor,
    transport_loss_factor,
)
from chaintwin.weigh.weigh import WeighResult, reweigh
from chaintwin.weigh.zero_tracking import ZeroTracker

from . import alarms, baseline, monitor_state
from .alarm_actions import out_of_service_at
from .causes import (
    NOTE_CAUSES,
    cause_priority,
    impact_context,
    resolve_causes,
    shaft_harmonic,
)
from .confirmation import needs_confirmation
from .features import RecordingFeatures, feature_spec, is_tracked
from .features import recording_features as extract
from .health import FeatureBaseline
from .impacts import POOL, hits_per_revolution, pooled_hits
from .learned import learn_calibration
from .limits import check_limit_names, judge_limits
from .monitor_state import MonitorState
from .peaks import median_spectrum, spectrum_from_state, unexplained_peak
from .records import (
    Alarm,
    Event,
    MonitorSettings,
    RecordingResult,
    as_number,
    finite_or_none,
    iso_utc,
)
from .spectra import Spectrum
from .state import apply_events, close_alarms, new_event
from .wear import KG_M_PER_T_KM, known_usage, usage_of

__all__ = ["FRICTION_CAUSES", "ConveyorMonitor"]

FRICTION_CAUSES = frozenset({"friction", "lubrication", "obstruction"})
"""Causes under which the friction signature is not trusted for the payload."""

_BY_INERTIA = ("weighed_by_inertia", "unweighable", "friction_changed")


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
        check_limit_names(profile)
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
        self.pending_meta: list[tuple[str | None, list[dict[str, str]]]] = []
        self.baseline_rows: list[dict[str, Any]] = []
        self.late_rows: list[dict[str, Any]] = []
        self.baseline_spectra: list[tuple[list[float], list[float], float] | None] = []
        self.baselines: dict[str, FeatureBaseline] | None = None
        self.baseline_spectrum: tuple[list[float], list[float], float] | None = None
        self.baseline_since: str | None = None
        # the retired belt map: kept empty, for the state's format
        self.belt_last: list[float | None] = []
        self.belt_prev: list[float | None] = []
        self.windows: dict[str, list[bool]] = {}
        self.window_times: dict[str, list[str | None]] = {}
        self.alarms: list[Alarm] = []
        self.events: list[Event] = []
        # the conveyor out of service (by, why, from, until: :mod:`.alarm_actions`) or None
        self.out_of_service: dict[str, Any] | None = None
        self.zero_tracking = ZeroTracker()
        """The loss-drift allowance tracked from known runs
        (:mod:`chaintwin.weigh.zero_tracking`)."""
        self.zero_tracking_undo: dict[str, Any] | None = None
        """The tracker as it was before the latest recording (``sha256``, ``before``), so
        that a superseded latest recording is taken back from it too."""
        self.history: list[dict[str, Any]] = []
        self.processed: dict[str, int] = {}
        self.last_recorded_at: str | None = None
        # usage carried since the baseline (kg·m): derived from the history when None
        self._usage_kg_m: float | None = None
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
            calibration = dataclasses.replace(calibration, profile=self.profile)
            self.calibration_source = "sibling"
        else:
            self.calibration_source = "file"
        self.calibration = calibration

    # ---------------------------------------------------------- events
    def add_event(self, kind: str, at: datetime, by: str, why: str) -> Event:
        """Record a maintenance event (:func:`~chaintwin.diagnose.state.new_event`).

        Recordings made after ``at`` form a new baseline; open alarms are
        closed by it.
        """
        event = new_event(kind, by, why, at)
        self.events.append(event)
        self.events.sort(key=lambda e: e.at)
        close_alarms(self.alarms, event)
        return event

    def _apply_events(self, when: datetime | None) -> list[dict[str, str]]:
        """Apply maintenance events made before this recording: a new baseline."""
        notes = apply_events(self.events, self.alarms, when)
        if notes:
            self.restart_baseline()
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
        self._usage_kg_m = None

    def forget(self, sha256s: set[str]) -> bool:
        """Take back recordings superseded by their complete version (a stored partial file).

        Those waiting for a learned calibration leave the waiting list;
        results leave :attr:`history` (pooled impacts, usage, trends,
        duplicates). When the latest recording monitored is one of them, its
        marks in the alarm windows and, while the baseline is still being
        learned, its baseline row are taken back too, so that the next
        recording is judged as if it had never come. What an earlier one
        left there (and any alarm it opened) stays.

        Parameters
        ----------
        sha256s : set of str
            Content SHA-256 of the recordings to take back.

        Returns
        -------
        bool
            Whether all of them were taken back whole (each was the latest
            monitored, in turn).
        """
        whole = True
        keep = [k for k, (sha, _x) in enumerate(self.pending_meta) if sha not in sha256s]
        if len(keep) < len(self.pending):  # waiting for a learned calibration: dropped
            self.pending = [self.pending[k] for k in keep]
            self.pending_files = [self.pending_files[k] for k in keep]
            self.pending_meta = [self.pending_meta[k] for k in keep]
        for sha in sha256s:
            k = self.processed.get(sha)
            if k is None:
                continue
            entry = self.history.pop(k)
            if k == len(self.history):
                self._unmark(entry)
                undo = self.zero_tracking_undo
                if undo is not None and undo.get("sha256") == sha:
                    self.zero_tracking = ZeroTracker.from_dict(undo["before"])
                    self.zero_tracking_undo = None
            else:
                whole = False
            self.processed = {h["sha256"]: n for n, h in enumerate(self.history) if h.get("sha256")}
            self._usage_kg_m = None
        return whole

    def _unmark(self, entry: dict[str, Any]) -> None:
        """Take the latest recording's marks out of the alarm windows and the baseline."""
        at = entry.get("recorded_at")
        if at is not None:
            for name, times in self.window_times.items():
                if times and times[-1] == at:
                    times.pop()
                    self.windows[name].pop()
        codes = {w.get("code") for w in entry.get("warnings") or []}
        if (
            self.baselines is None
            and entry.get("status") == "baseline"
            and "baseline_learning" in codes
            and self.baseline_rows
        ):
            self.baseline_rows.pop()
            if self.baseline_spectra:
                self.baseline_spectra.pop()
            if not self.baseline_rows:
                self.baseline_since = None

    # ---------------------------------------------------------- processing
    def process(
        self,
        recording: Recording | Inspection,
        sha256: str | None = None,
        *,
        features: RecordingFeatures | None = None,
    ) -> list[RecordingResult]:
        """Take the next recording (in recorded order).

        Give the validated :class:`~chaintwin.validate.checks.Inspection`
        where there is one: its phases are used as they are (a bare recording
        is segmented here). ``features``, when given, are the recording's
        features computed elsewhere (a worker process) against this
        monitor's calibration.

        Returns
        -------
        list of RecordingResult
            Usually one; none while a calibration is being learned (the
            recordings wait), all waiting ones when it has been learned.
        """
        phases = recording.phases if isinstance(recording, Inspection) else None
        recording = recording.recording if isinstance(recording, Inspection) else recording
        when = recording.metadata.recorded_at
        if sha256 is not None and any(sha == sha256 for sha, _x in self.pending_meta):
            return [
                RecordingResult(
                    file=recording.source,
                    conveyor=self.profile.id,
                    recorded_at=iso_utc(when),
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
        stamp = iso_utc(when)
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
        if "position" not in recording.channels and all(
            n["code"] != "no_position" for n in self.notes
        ):
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
            self.pending_meta.append((sha256, extra))
            if len(self.pending) < self.settings.baseline_n:
                return []
            return self._learn()
        return [self._monitor(recording, sha256, extra, features, phases)]

    def waiting(self) -> list[tuple[Recording, str | None]]:
        """The recordings held back until a calibration is learned, with their content hashes."""
        return [(rec, sha) for rec, (sha, _x) in zip(self.pending, self.pending_meta, strict=True)]

    def flush_pending(self) -> list[RecordingResult]:
        """Monitor the recordings that waited for a calibration (after :meth:`set_calibration`)."""
        if self.calibration is None:
            return []
        recs, meta = self.pending, self.pending_meta
        self.pending, self.pending_files, self.pending_meta = [], [], []
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
                    recorded_at=iso_utc(rec.metadata.recorded_at),
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
        return unexplained_peak(spectrum, bx, ba, floor, self._line_orders(self.calibration))

    def _output_harmonic(self, spectrum: Spectrum | None, order: float) -> bool:
        """Whether an unexplained peak lies on the output shaft's comb (:func:`shaft_harmonic`)."""
        if spectrum is None or self.calibration is None or not math.isfinite(order):
            return False
        speed_hz = spectrum.speed_rpm / 60.0
        if speed_hz <= 0.0:
            return False
        shaft = characteristic_orders(self.calibration.id_profile)["output_shaft"]
        return shaft_harmonic(order, shaft, 1.5 * spectrum.resolution / speed_hz)

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

    def _monitor(
        self,
        recording: Recording,
        sha256: str | None,
        extra: list[dict[str, str]],
        features: RecordingFeatures | None = None,
        phases: tuple[Phase, ...] | None = None,
    ) -> RecordingResult:
        assert self.calibration is not None
        when = recording.metadata.recorded_at
        base = RecordingResult(
            file=recording.source,
            conveyor=self.profile.id,
            recorded_at=iso_utc(when),
            status="monitored",
        )
        try:
            feats = (
                features
                if features is not None
                else extract(
                    Inspection(
                        recording,
                        tuple(segment(recording)) if phases is None else phases,
                        not recording.has_warning("incomplete_cycle"),
                    ),
                    self.calibration,
                    residual=self.settings.residual,
                )
            )
        except EstimationError as exc:
            base.status = "refused"
            text = str(exc)
            base.error = (
                text if text.startswith(recording.source) else f"{recording.source}: {text}"
            )
            return base
        # zero tracking: the history narrows the loss-drift allowance; with the profile's
        # (experimental) zero_tracking a known payload measures the drift, the others are
        # weighed with what it can have moved since
        self.zero_tracking_undo = {"sha256": sha256, "before": self.zero_tracking.to_dict()}
        w = self.zero_tracking.track(
            feats.weighing,
            when,
            recording.metadata.payload_kg,
            self.calibration.zero_reference,
            known_runs=self.profile.zero_tracking,
        )
        values = dict(feats.values)
        # usage (chaintwin.diagnose.wear): payload times belt travel, kg·m
        payload = values.get("payload_kg", float("nan"))
        values["usage_kg_m"] = (
            payload * belt_travel_m(recording, self.calibration.id_profile)
            if math.isfinite(payload)
            else float("nan")
        )
        # retired: scope positions are not comparable across recordings
        values["belt_bump"] = float("nan")
        # an obstacle is hit once per belt revolution: isolated impacts pooled
        # over this recording and the last ones of the conveyor
        pooled: list[Mapping[str, Any]] = [
            h.get("features") or {} for h in self.history[-(POOL - 1) :]
        ]
        values["impact_hits_per_rev"] = hits_per_revolution(
            [*pooled, values],
            self.calibration.id_profile.loop_length_m,
            self.baseline_rows if self.baselines is not None else None,
        )
        values["impact_pooled_hits"] = pooled_hits([*pooled, values])
        travelled = sum(float(r.get("belt_travel_m") or 0.0) for r in [*pooled, values])
        loop = self.calibration.id_profile.loop_length_m
        values["impact_pooled_revs"] = travelled / loop if loop > 0 else float("nan")
        warnings = [x.to_dict() for x in w.warnings] + [x.to_dict() for x in feats.warnings]
        # features computed elsewhere (an ingest worker) may predate a warning
        # the recording got since (e.g. no_recorded_at): none is lost
        warnings += [d for d in (x.to_dict() for x in recording.warnings) if d not in warnings]
        warnings += extra
        if self.calibration_source != "file":
            warnings.append(
                RecordingWarning(
                    "payload_uncalibrated",
                    f"payload from a {self.calibration_source} calibration, not one made on "
                    "known loads: it may be offset by several kg (see chaintwin calibrate)",
                ).to_dict()
            )
        causes: list[dict[str, Any]] = []
        if w.segments:
            first, last = w.segments[0], w.segments[-1]
            causes.append(
                {
                    "cause": "payload_changed",
                    "feature": "payload_kg",
                    "change": (last.payload_kg - first.payload_kg)
                    / max(abs(first.payload_kg), 1.0),
                    "since": iso_utc(when),
                }
            )
        if w.segments:
            # the load changed during the movement: its features mix two loads
            base.status = "baseline" if self.baselines is None else "monitored"
            base.features = {k: finite_or_none(v) for k, v in values.items()}
            warnings.append(
                RecordingWarning(
                    "not_judged",
                    "the load changed during the movement: this recording's features are "
                    "reported but neither learned nor compared with the baseline",
                ).to_dict()
            )
        elif out_of_service_at(self.out_of_service, when):
            # work on the conveyor: shown, neither judged nor learned
            base.status = "baseline" if self.baselines is None else "monitored"
            base.features = {k: finite_or_none(v) for k, v in values.items()}
            oos = self.out_of_service or {}
            warnings.append(
                RecordingWarning(
                    "out_of_service",
                    f"made while the conveyor is out of service ({oos.get('why')}, by "
                    f"{oos.get('by')}): its features are reported but neither learned nor "
                    "compared with the baseline",
                ).to_dict()
            )
        elif self.baselines is None:
            base.status = "baseline"
            if self.baseline_since is None:
                self.baseline_since = iso_utc(when)
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
            base.features = {k: finite_or_none(v) for k, v in values.items()}
            base.alarm = self._judge_limits(values, when, causes, warnings)
            if n >= self.settings.baseline_n:
                self._form_baseline()
        else:
            peak, peak_order = self._unexplained_peak(feats.spectrum)
            values["unexplained_peak"] = peak
            judged = self._after_expected_wear(values)
            base.features = {k: finite_or_none(v) for k, v in values.items()}
            zs: dict[str, float] = {}
            # an item caught moves this recording's features alone: where the
            # impact search found a drag, or could look at no span (an event
            # would go unnoticed), an exceedance waits for a neighbour to confirm
            # it; where it could not look, a step of the plateau's level is the
            # drag it would have found (caught too; where it looked, its verdict
            # stands: an obstacle's hit rings the belt, which steps the level)
            confirm, caught = needs_confirmation(
                values, (self.baselines or {}).get("residual_step")
            )
            met, change, exceeded = alarms.judge(
                self.baselines,
                judged,
                self.windows,
                self.window_times,
                self.settings,
                when,
                zs,
                confirm=confirm,
                caught=caught,
            )
            base.exceeded.extend(exceeded)
            self._late_baselines(values)
            context = impact_context(values, exceeded)
            resolved = resolve_causes(met, context, {a.cause for a in self.open_alarms()})
            if resolved.get("unexplained_peak") == "bearing" and self._output_harmonic(
                feats.spectrum, peak_order
            ):
                resolved["unexplained_peak"] = "gear"
            noted = [n for n in met if resolved[n] in NOTE_CAUSES]
            met = [n for n in met if n not in noted]
            for name in noted:
                # an event of operation (an item caught): reported, not alarmed
                causes.append(
                    {
                        "cause": resolved[name],
                        "feature": name,
                        "change": change.get(name),
                        "since": iso_utc(when),
                    }
                )
            for name in met:
                alarm = self._open_alarm(
                    name, resolved[name], change.get(name), when, values.get(name), zs.get(name)
                )
                detail = {
                    "cause": resolved[name],
                    "feature": name,
                    "change": alarm.change,
                    "since": alarm.since,
                }
                if name == "unexplained_peak" and math.isfinite(peak_order):
                    detail["order"] = peak_order
                causes.append(detail)
            limit_met = self._judge_limits(values, when, causes, warnings)
            self._close_alarms(when)
            base.alarm = bool(met) or limit_met
            if any(feature_spec(e).cause in FRICTION_CAUSES for e in exceeded) or any(
                a.cause in FRICTION_CAUSES for a in self.open_alarms()
            ):
                # a friction rise must not read as payload: weigh by inertia, and
                # carry the friction feature's measured change (relative to its
                # baseline) in the friction signature's uncertainty
                moved = change.get("friction")
                if moved is None:
                    moved = next(
                        (
                            a.change
                            for a in self.open_alarms()
                            if a.feature == "friction" and a.change is not None
                        ),
                        None,
                    )
                w = self._by_inertia(w, recording, moved)
                warnings = [x for x in warnings if x.get("code") not in _BY_INERTIA]
                warnings += [x.to_dict() for x in w.warnings if x.code in _BY_INERTIA]
        if (
            (values.get("impact_count") or 0.0) > 0.0
            and impact_context(values, base.exceeded) == "payload_event"
            and not any(c["cause"] == "payload_event" for c in causes)
        ):
            # impacts that are no wear (an item caught, a tray dropped): a note
            causes.append(
                {
                    "cause": "payload_event",
                    "feature": "impact_count",
                    "change": None,
                    "since": iso_utc(when),
                }
            )
        base.payload_kg = finite_or_none(w.payload_kg)
        base.uncertainty_kg = finite_or_none(w.uncertainty_kg)
        base.loss_drift = w.loss_drift.to_dict()
        base.since_known_run_s = w.since_known_run_s
        base.tlf = finite_or_none(w.tlf)
        base.tlf_motor_shaft = finite_or_none(w.tlf_motor_shaft)
        base.impacts = [i.to_dict() for i in feats.impacts]
        causes.sort(key=lambda c: (cause_priority(c["cause"]), -abs(c["change"] or 0.0)))
        base.causes = causes
        base.warnings = warnings
        self.history.append(base.to_dict() | {"sha256": sha256})
        if sha256 is not None:
            self.processed[sha256] = len(self.history) - 1
        return base

    def _by_inertia(
        self, w: WeighResult, recording: Recording, friction_change: float | None = None
    ) -> WeighResult:
        """The weighing combined again trusting the inertia signature alone, with its TLF.

        A recording whose signatures disagreed (the friction rise itself) was
        unweighable and had no TLF; weighed by inertia it has a payload, and
        the TLF is that of this payload (the same work over the same travel),
        also where the combined payload had one (that TLF was of another payload).
        ``friction_change`` (relative, the friction feature's measured change) joins
        the friction signature's uncertainty.
        """
        w = reweigh(w, w.loss_drift, friction=False, friction_change=friction_change)
        if w.payload_kg is None or self.calibration is None:
            return w
        prof = self.calibration.id_profile
        return dataclasses.replace(
            w,
            tlf=transport_loss_factor(recording, prof, self.calibration.parameters, w.payload_kg),
            tlf_motor_shaft=motor_shaft_transport_loss_factor(recording, prof, w.payload_kg),
        )

    def _usage_so_far(self) -> float:
        """Usage since the baseline before this recording, kg·m, from the history.

        The latest monitored result since the baseline carries it
        (``usage_since_baseline_t_km``): the history the store keeps is its
        latest results only, so summing it would come up short. Results
        stored before that feature existed are summed.
        """
        since = self.baseline_since or ""
        mine = [
            h
            for h in self.history
            if h.get("status") == "monitored" and (h.get("recorded_at") or "") >= since
        ]
        if mine:
            last = as_number((mine[-1].get("features") or {}).get("usage_since_baseline_t_km"))
            if math.isfinite(last):
                return last * KG_M_PER_T_KM
        return sum(usage_of(h) for h in mine)

    def _after_expected_wear(self, values: dict[str, float]) -> dict[str, float]:
        """The values the baselines judge: the profile's expected wear taken off.

        Sets ``usage_since_baseline_t_km`` (this recording included) in
        ``values``; each feature of the profile's ``expected_wear`` is judged
        less its rate times that usage (:mod:`.wear`), so wear that usage
        explains does not alarm.
        """
        if self._usage_kg_m is None:
            self._usage_kg_m = self._usage_so_far()
        self._usage_kg_m += known_usage(values.get("usage_kg_m", float("nan")))
        used = self._usage_kg_m / KG_M_PER_T_KM
        values["usage_since_baseline_t_km"] = used
        judged = dict(values)
        for name, rate in (self.profile.expected_wear or {}).items():
            if name in judged:
                judged[name] = judged[name] - rate * used
        return judged

    def _form_baseline(self) -> None:
        rows = self.baseline_rows
        own = [None if sp is None else spectrum_from_state(*sp) for sp in self.baseline_spectra]
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
        self.baselines = baseline.fit_features(rows)

    def _late_fits_fed(self, values: Mapping[str, Any]) -> list[str]:
        """Tracked features with a cause and no baseline yet that ``values`` holds a
        finite value of: the late-baseline fits a row of them would feed."""
        assert self.baselines is not None
        return [
            k
            for k in values
            if k not in self.baselines
            and is_tracked(k)
            and feature_spec(k).cause is not None
            and math.isfinite(as_number(values.get(k)))
        ]

    def _late_baselines(self, values: dict[str, float]) -> None:
        """Baselines of features the first recordings could not tell (no value
        yet, e.g. no belt travel at constant speed), learned from the recordings
        that follow."""
        assert self.baselines is not None
        # a feature's fit reads only the rows that hold a finite value of it
        # (:func:`.health.fit_baseline`): a recording without a finite value of
        # any missing feature changes no fit now or later, so it is not kept.
        # Keeping every recording grew the health model by about 2 kB per
        # recording for ever (the retired belt_bump is never finite), in memory
        # and in the stored state read and written with each recording.
        changed = self._late_fits_fed(values)
        if not changed:
            return
        self.late_rows.append(values)
        need = max(5, self.settings.baseline_n // 2)
        self.baselines.update(baseline.fit_features(self.late_rows, changed, min_rows=need))

    def prune_late_rows(self) -> int:
        """Drop the late-baseline rows that can feed no fit (see :meth:`_late_baselines`).

        States stored before that rule kept every recording after the
        baseline; a row without a finite value of any feature still missing a
        baseline changes no fit, so dropping it changes no result.

        Returns
        -------
        int
            Rows dropped.
        """
        if self.baselines is None or not self.late_rows:
            return 0
        keep = [row for row in self.late_rows if self._late_fits_fed(row)]
        dropped = len(self.late_rows) - len(keep)
        self.late_rows = keep
        return dropped

    def _open_alarm(
        self,
        feature: str,
        cause: str,
        change: float | None,
        when: datetime | None,
        value: float | None,
        z: float | None,
    ) -> Alarm:
        """The open alarm of a cause, opened now if there is none (:func:`.alarms.open_alarm`)."""
        return alarms.open_alarm(
            self.alarms,
            conveyor=self.profile.id,
            feature=feature,
            cause=cause,
            change=change,
            when=when,
            window=self.windows.get(feature, []),
            window_times=self.window_times.get(feature, []),
            value=value,
            z=z,
        )

    def _judge_limits(
        self,
        values: Mapping[str, float],
        when: datetime | None,
        causes: list[dict[str, Any]],
        warnings: list[dict[str, str]],
    ) -> bool:
        """Judge the profile's absolute limits (:mod:`.limits`); whether one alarms."""
        limits = self.profile.limits
        if not limits:
            return False
        checks = judge_limits(
            limits, values, self.windows, self.window_times, self.settings, iso_utc(when)
        )
        any_met = False
        for c in checks:
            if c.warning is not None:
                warnings.append(c.warning)
            if not c.met:
                continue
            any_met = True
            key = alarms.window_key(c.feature, "limit")
            alarm = alarms.open_alarm(
                self.alarms,
                conveyor=self.profile.id,
                feature=c.feature,
                cause=feature_spec(c.feature).cause or "limit",
                change=None,
                when=when,
                window=self.windows.get(key, []),
                window_times=self.window_times.get(key, []),
                rule=c.limit.rule,
                kind="limit",
                limit=c.limit.alarm,
                value=c.value,
            )
            causes.append(
                {
                    "cause": alarm.cause,
                    "feature": c.feature,
                    "change": None,
                    "since": alarm.since,
                    "rule": c.limit.rule,
                    "limit": c.limit.alarm,
                    "value": c.value,
                }
            )
        alarms.close_quiet_alarms(self.alarms, self.windows, self.settings.y, when)
        return any_met

    def _close_alarms(self, when: datetime | None) -> None:
        alarms.close_quiet_alarms(self.alarms, self.windows, self.settings.y, when)

    # ---------------------------------------------------------- summary
    def open_alarms(self) -> list[Alarm]:
        """Open alarms (acknowledged ones included)."""
        return [a for a in self.alarms if a.is_open]

    def forecasts(self) -> list[dict[str, Any]]:
        """When each tracked feature's trend crosses its limit (:func:`.baseline.forecasts`)."""
        if not self.baselines:
            return []
        return baseline.forecasts(
            self.baselines,
            self.history,
            self.baseline_since or "",
            self.settings.z_limit,
            x=self.settings.x,
            y=self.settings.y,
        )

    def summary(self) -> dict[str, Any]:
        """The conveyor's summary for ``monitor --json`` (:func:`.monitor_state.summary_of`)."""
        return monitor_state.summary_of(self)

    # ---------------------------------------------------------- state
    def to_state(self) -> MonitorState:
        """Everything learned (:func:`.monitor_state.state_of`, sharing the monitor's lists)."""
        return monitor_state.state_of(self)

    @classmethod
    def from_state(
        cls,
        state: MonitorState | dict[str, Any],
        profile: ConveyorProfile,
        *,
        loader: Callable[[str], Recording] | None = None,
        source: str = "<state>",
    ) -> ConveyorMonitor:
        """Continue from a saved state (:meth:`to_state`, or its JSON form).

        Raises
        ------
        StoreError
            When the state belongs to another profile or is damaged.
        """
        if isinstance(state, MonitorState):
            state = copy.deepcopy(state)
        else:  # its JSON form
            state = MonitorState.from_dict(state, source=source)
        if state.profile_sha256 != profile.content_hash():
            raise StoreError(
                f"{source}: conveyor '{profile.id}' was monitored with another version of its "
                "profile; give the profile it was monitored with, or start a new state file "
                "for the changed conveyor"
            )
        mon = cls(profile, state.settings, loader=loader)
        monitor_state.restore(mon, state, loader=loader)
        mon.prune_late_rows()
        return mon
