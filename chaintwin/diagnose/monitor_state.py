"""A conveyor's health model saved and restored: :class:`MonitorState`.

The state holds everything the monitor learned (settings, calibration,
recordings waiting for a learned calibration, baselines, the belt map, the
X-of-Y windows, alarms, events, recent history), so that monitoring goes on
with new recordings without recomputing old ones. Its JSON form
(:meth:`MonitorState.to_dict`) is a conveyor's entry of the state file
(:mod:`.state`, format version :data:`~.state.STATE_VERSION`) and of the
store's ``monitor_states`` table.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from chaintwin.errors import ChaintwinError, StoreError
from chaintwin.identify.calibration import Calibration
from chaintwin.read.recording import Recording, RecordingWarning
from chaintwin.weigh.zero_tracking import ZeroTracker

from . import baseline
from .alarms import group_by_cause
from .health import FeatureBaseline
from .records import Alarm, Event, MonitorSettings
from .state import STATE_VERSION
from .state_model import check_state_shape
from .wear import usage_summary, wear_rates

if TYPE_CHECKING:
    from .monitor import ConveyorMonitor

__all__ = [
    "HEALTH_RECENT",
    "LEARNED",
    "MonitorState",
    "PendingFile",
    "StoredHealth",
    "StoredSpectrum",
    "derived_inputs",
    "derived_of",
    "read_health",
    "restore",
    "state_of",
    "summary_of",
]

StoredSpectrum = tuple[list[float], list[float], float]
"""A spectrum as a state keeps it: orders, amplitudes (Nm) and speed (rpm)."""


@dataclass(frozen=True, slots=True)
class PendingFile:
    """A recording kept for a calibration still being learned: read again on restore."""

    path: str
    file: str
    sha256: str | None
    warnings: list[dict[str, str]]


def _spectrum(sp: Any) -> StoredSpectrum | None:
    return (
        None if sp is None else ([float(v) for v in sp[0]], [float(v) for v in sp[1]], float(sp[2]))
    )


@dataclass(slots=True)
class MonitorState:
    """Everything a :class:`~chaintwin.diagnose.monitor.ConveyorMonitor` learned.

    ``version`` is the state format version it was written with
    (:data:`~chaintwin.diagnose.state.STATE_VERSION`); the other attributes
    are the monitor's, under the same names.
    """

    conveyor: str
    profile_sha256: str
    settings: MonitorSettings
    calibration: Calibration | None
    calibration_source: str
    pending: list[PendingFile] = field(default_factory=list)
    baseline_rows: list[dict[str, Any]] = field(default_factory=list)
    late_rows: list[dict[str, Any]] = field(default_factory=list)
    baseline_spectra: list[StoredSpectrum | None] = field(default_factory=list)
    baselines: dict[str, FeatureBaseline] | None = None
    baseline_spectrum: StoredSpectrum | None = None
    baseline_since: str | None = None
    belt_last: list[float | None] = field(default_factory=list)
    belt_prev: list[float | None] = field(default_factory=list)
    windows: dict[str, list[bool]] = field(default_factory=dict)
    window_times: dict[str, list[str | None]] = field(default_factory=dict)
    alarms: list[Alarm] = field(default_factory=list)
    events: list[Event] = field(default_factory=list)
    history: list[dict[str, Any]] = field(default_factory=list)
    notes: list[dict[str, str]] = field(default_factory=list)
    last_recorded_at: str | None = None
    out_of_service: dict[str, Any] | None = None
    zero_tracking: ZeroTracker = field(default_factory=ZeroTracker)
    zero_tracking_undo: dict[str, Any] | None = None
    version: int = STATE_VERSION

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (a conveyor's entry of the state file)."""
        return {
            "conveyor": self.conveyor,
            "profile_sha256": self.profile_sha256,
            "settings": dataclasses.asdict(self.settings),
            "calibration": None if self.calibration is None else self.calibration.to_dict(),
            "calibration_source": self.calibration_source,
            "pending": [
                {"path": p.path, "file": p.file, "sha256": p.sha256, "warnings": p.warnings}
                for p in self.pending
            ],
            "baseline_rows": self.baseline_rows,
            "late_rows": self.late_rows,
            "baseline_spectra": [None if sp is None else list(sp) for sp in self.baseline_spectra],
            "baselines": None
            if self.baselines is None
            else {k: v.to_dict() for k, v in self.baselines.items()},
            "baseline_spectrum": None
            if self.baseline_spectrum is None
            else list(self.baseline_spectrum),
            "baseline_since": self.baseline_since,
            "belt_last": self.belt_last,
            "belt_prev": self.belt_prev,
            "windows": self.windows,
            "window_times": self.window_times,
            "alarms": [a.to_dict() for a in self.alarms],
            "events": [e.to_dict() for e in self.events],
            "history": self.history,
            "notes": self.notes,
            "last_recorded_at": self.last_recorded_at,
            "out_of_service": self.out_of_service,
            "zero_tracking": self.zero_tracking.to_dict(),
            "zero_tracking_undo": self.zero_tracking_undo,
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any], *, source: str = "<state>") -> MonitorState:
        """Inverse of :meth:`to_dict`.

        Raises
        ------
        StoreError
            When the state is damaged (the message names ``source`` and, for
            a value of the wrong type or size, its field).
        """
        check_state_shape(data, source)
        try:
            s = data["settings"]
            settings = MonitorSettings(
                int(s["baseline_n"]),
                int(s["x"]),
                int(s["y"]),
                float(s["z_limit"]),
                # states written before the option existed used the inverse model
                str(s.get("residual", "inverse")),
            )
            cal = data["calibration"]
            stored = data["baselines"]
            return cls(
                conveyor=str(data["conveyor"]),
                profile_sha256=str(data["profile_sha256"]),
                settings=settings,
                calibration=None if cal is None else Calibration.from_dict(cal, source),
                calibration_source=str(data["calibration_source"]),
                pending=[
                    PendingFile(str(p["path"]), str(p["file"]), p["sha256"], list(p["warnings"]))
                    for p in data["pending"]
                ],
                baseline_rows=list(data["baseline_rows"]),
                late_rows=list(data["late_rows"]),
                baseline_spectra=[_spectrum(sp) for sp in data["baseline_spectra"]],
                baselines=None
                if stored is None
                else {k: FeatureBaseline.from_dict(v) for k, v in stored.items()},
                baseline_spectrum=_spectrum(data["baseline_spectrum"]),
                baseline_since=data["baseline_since"],
                belt_last=list(data["belt_last"]),
                belt_prev=list(data["belt_prev"]),
                windows={k: list(v) for k, v in data["windows"].items()},
                window_times={k: list(v) for k, v in data["window_times"].items()},
                alarms=[Alarm.from_dict(a) for a in data["alarms"]],
                events=[Event.from_dict(e) for e in data["events"]],
                history=list(data["history"]),
                notes=list(data["notes"]),
                last_recorded_at=data["last_recorded_at"],
                # states kept before conveyors could be out of service have none
                out_of_service=_window(data.get("out_of_service")),
                # states kept before zero tracking have none: nothing known yet
                zero_tracking=_tracking(data.get("zero_tracking")),
                zero_tracking_undo=_tracking_undo(data.get("zero_tracking_undo")),
            )
        except ChaintwinError as exc:
            raise StoreError(f"{source}: monitoring state is damaged ({exc})") from None
        except (KeyError, TypeError, ValueError, IndexError, AttributeError) as exc:
            conveyor = data.get("conveyor") if isinstance(data, dict) else None
            raise StoreError(
                f"{source}: monitoring state of '{conveyor}' is damaged ({exc!r}); restore it "
                "from a backup or start a new state file"
            ) from None


def _window(data: Any) -> dict[str, Any] | None:
    """An out-of-service window as stored (by, why, from, until), checked; None when absent."""
    if data is None:
        return None
    if not isinstance(data, dict) or not isinstance(data.get("from"), str):
        raise ValueError(f"out_of_service {data!r} is not a window with 'from'")
    return {k: data.get(k) for k in ("by", "why", "from", "until")}


def _tracking(data: Any) -> ZeroTracker:
    """The zero-tracking state as stored, checked; a new one when absent."""
    if data is None:
        return ZeroTracker()
    if not isinstance(data, dict):
        raise ValueError(f"zero_tracking {data!r} is not an object")
    return ZeroTracker.from_dict(data)


def _tracking_undo(data: Any) -> dict[str, Any] | None:
    """The tracker before the latest recording as stored, checked; None when absent."""
    if data is None:
        return None
    if not isinstance(data, dict) or not isinstance(data.get("before"), dict):
        raise ValueError(f"zero_tracking_undo {data!r} is not an object with 'before'")
    ZeroTracker.from_dict(data["before"])  # damaged: refused as the state's own tracker is
    return {"sha256": data.get("sha256"), "before": data["before"]}


LEARNED: tuple[str, ...] = (
    "calibration",
    "calibration_source",
    "baseline_rows",
    "late_rows",
    "baseline_spectra",
    "baselines",
    "baseline_spectrum",
    "baseline_since",
    "belt_last",
    "belt_prev",
    "windows",
    "window_times",
    "alarms",
    "events",
    "history",
    "notes",
    "last_recorded_at",
    "out_of_service",
    "zero_tracking",
    "zero_tracking_undo",
)
"""Attributes a monitor and its :class:`MonitorState` share by name (copied as they are)."""


def state_of(mon: ConveyorMonitor) -> MonitorState:
    """Everything ``mon`` learned (:func:`restore` puts it back into a monitor)."""
    return MonitorState(
        conveyor=mon.profile.id,
        profile_sha256=mon.profile.content_hash(),
        settings=mon.settings,
        pending=[
            PendingFile(path, rec.source, sha, extra)
            for path, rec, (sha, extra) in zip(
                mon.pending_files, mon.pending, mon.pending_meta, strict=True
            )
        ],
        **{name: getattr(mon, name) for name in LEARNED},
    )


def restore(
    mon: ConveyorMonitor,
    state: MonitorState,
    *,
    loader: Callable[[str], Recording] | None,
) -> None:
    """Put a state's content into a new monitor of the same profile and settings.

    Recordings that were waiting for a learned calibration are read again
    with ``loader``; one that cannot be is left out with a note.
    """
    for name in LEARNED:
        setattr(mon, name, getattr(state, name))
    group_by_cause(mon.alarms)  # a state kept before alarms were grouped by cause
    mon.processed = {h["sha256"]: k for k, h in enumerate(mon.history) if h.get("sha256")}
    for pending in state.pending:
        try:
            if loader is None:
                raise StoreError("no reader given")
            rec = dataclasses.replace(loader(pending.path), source=pending.file)
        except ChaintwinError as exc:  # the file is gone or no longer readable
            mon.notes.append(
                RecordingWarning(
                    "pending_lost",
                    f"{pending.file}, waiting for the learned calibration, cannot be read again "
                    f"({exc}); it is left out",
                ).to_dict()
            )
            continue
        mon.pending.append(rec)
        mon.pending_files.append(pending.path)
        mon.pending_meta.append((pending.sha256, pending.warnings))


@dataclass(frozen=True)
class StoredHealth:
    """What a saved state says of a conveyor's health, read without rebuilding the monitor.

    Attributes
    ----------
    summary : dict
        The ``monitor --json`` summary (``conveyors`` entry).
    baselines : dict of str to FeatureBaseline
        The features' baselines (empty while the baseline is being learned).
    z_limit : float
        The monitor's z limit.
    baseline_since : str or None
        ISO time the baseline dates from.
    calibration : Calibration or None
        The calibration the monitor uses.
    """

    summary: dict[str, Any]
    baselines: dict[str, FeatureBaseline]
    z_limit: float
    baseline_since: str | None
    calibration: Calibration | None


def derived_inputs(state: MonitorState) -> str:
    """SHA-256 of what a state's forecasts and wear rates are computed from.

    The baselines, the baseline's start, the z limit and the result history
    (its length and newest result): equal fingerprints give equal
    :func:`derived_of`.
    """
    history = state.history
    parts = {
        "baselines": None
        if state.baselines is None
        else {k: v.to_dict() for k, v in sorted(state.baselines.items())},
        "since": state.baseline_since,
        "z_limit": state.settings.z_limit,
        "results": len(history),
        "newest": history[-1] if history else None,
    }
    text = json.dumps(parts, sort_keys=True, default=str, allow_nan=True)
    return hashlib.sha256(text.encode()).hexdigest()


def derived_of(state: MonitorState) -> dict[str, Any]:
    """What is costly to compute from a state: forecasts (with their bands) and wear rates.

    Returns
    -------
    dict
        ``forecasts`` (:func:`.baseline.forecasts` with ``bands``) and
        ``wear`` (:func:`.wear.wear_rates`), JSON-ready.
    """
    baselines = state.baselines or {}
    since = state.baseline_since or ""
    z_limit = state.settings.z_limit
    return {
        "forecasts": baseline.forecasts(
            baselines,
            state.history,
            since,
            z_limit,
            bands=True,
            x=state.settings.x,
            y=state.settings.y,
        )
        if baselines
        else [],
        "wear": wear_rates(baselines, state.history, since) if baselines else [],
    }


def read_health(
    state: MonitorState, *, bands: bool = False, derived: dict[str, Any] | None = None
) -> StoredHealth:
    """A saved state's health: summary, baselines and forecasts, without rebuilding the monitor.

    ``bands``: the forecasts carry their ``band`` (path and interval ahead, for plotting).
    ``derived``: :func:`derived_of` as computed before (stored after ingest);
    None: computed here (the forecasts' fits: seconds on a long history).
    """
    baselines = state.baselines or {}
    since = state.baseline_since
    if derived is None:
        derived = derived_of(state)
    forecasts = [dict(f) for f in derived["forecasts"]]
    if not bands:
        for f in forecasts:
            f.pop("band", None)
    summary = {
        "conveyor": state.conveyor,
        "calibration": state.calibration_source,
        "recordings": len(state.history),
        "baseline": {
            "complete": state.baselines is not None,
            "recordings": len(state.baseline_rows),
            "since": since,
            "outliers": {k: v.outliers for k, v in baselines.items() if v.outliers},
        },
        "open_alarms": [a.to_dict() for a in state.alarms if a.is_open],
        "forecasts": forecasts,
        "events": [e.to_dict() for e in state.events],
        "notes": state.notes,
        "usage": usage_summary(state.history),
        "wear": derived["wear"],
    }
    return StoredHealth(summary, baselines, state.settings.z_limit, since, state.calibration)


def summary_of(mon: ConveyorMonitor) -> dict[str, Any]:
    """The conveyor's summary for ``monitor --json`` (``conveyors``): :func:`read_health`
    of its state, with its verdict (:meth:`~chaintwin.diagnose.verdict.Verdict.to_dict`)."""
    from .verdict import verdict

    state = state_of(mon)
    return read_health(state).summary | verdict(state).to_dict()


HEALTH_RECENT = 10
"""Recordings a feature's deviation looks at (the latest judged against the baseline)."""
