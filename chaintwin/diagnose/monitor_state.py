"""A conveyor's health model saved and restored: :meth:`ConveyorMonitor.to_state` as JSON.

The state holds everything the monitor learned (settings, calibration,
recordings waiting for a learned calibration, baselines, the belt map, the
X-of-Y windows, alarms, events, recent history), so that monitoring goes on
with new recordings without recomputing old ones.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from chaintwin.errors import ChaintwinError, StoreError
from chaintwin.identify.calibration import Calibration
from chaintwin.read.recording import Recording, RecordingWarning

from . import baseline
from .health import FeatureBaseline

if TYPE_CHECKING:
    from .monitor import ConveyorMonitor

__all__ = ["StoredHealth", "read_health", "restore", "state_of", "summary_of"]


def state_of(mon: ConveyorMonitor) -> dict[str, Any]:
    """Everything ``mon`` learned, JSON-ready (:func:`restore` reads it back)."""
    return {
        "conveyor": mon.profile.id,
        "profile_sha256": mon.profile.content_hash(),
        "settings": {
            "baseline_n": mon.settings.baseline_n,
            "x": mon.settings.x,
            "y": mon.settings.y,
            "z_limit": mon.settings.z_limit,
        },
        "calibration": None if mon.calibration is None else mon.calibration.to_dict(),
        "calibration_source": mon.calibration_source,
        "pending": [
            {"path": path, "file": rec.source, "sha256": sha, "warnings": extra}
            for path, rec, (sha, extra) in zip(
                mon.pending_files, mon.pending, mon.pending_meta, strict=True
            )
        ],
        "baseline_rows": mon.baseline_rows,
        "late_rows": mon.late_rows,
        "baseline_spectra": mon.baseline_spectra,
        "baselines": None
        if mon.baselines is None
        else {k: v.to_dict() for k, v in mon.baselines.items()},
        "baseline_spectrum": mon.baseline_spectrum,
        "baseline_since": mon.baseline_since,
        "belt_last": mon.belt_last,
        "belt_prev": mon.belt_prev,
        "windows": mon.windows,
        "window_times": mon.window_times,
        "alarms": mon.alarms,
        "events": mon.events,
        "history": mon.history,
        "notes": mon.notes,
        "last_recorded_at": mon.last_recorded_at,
    }


def restore(
    mon: ConveyorMonitor,
    data: dict[str, Any],
    *,
    source: str,
    loader: Callable[[str], Recording] | None,
) -> None:
    """Put a state's content into a new monitor of the same profile and settings.

    Recordings that were waiting for a learned calibration are read again
    with ``loader``; one that cannot be is left out with a note.

    Raises
    ------
    StoreError
        When the state is damaged.
    """
    profile = mon.profile
    try:
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
            mon.baselines = {k: FeatureBaseline.from_dict(v) for k, v in data["baselines"].items()}
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
        mon.pending_meta.append((sha, extra))


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
    calibration : dict or None
        The calibration the monitor uses, as its file's JSON.
    """

    summary: dict[str, Any]
    baselines: dict[str, FeatureBaseline]
    z_limit: float
    baseline_since: str | None
    calibration: dict[str, Any] | None


def read_health(data: dict[str, Any]) -> StoredHealth:
    """A saved state's health: summary, baselines and forecasts, from its JSON alone.

    Raises
    ------
    KeyError, TypeError, ValueError
        When the state is damaged.
    """
    stored = data["baselines"]
    baselines = {k: FeatureBaseline.from_dict(v) for k, v in (stored or {}).items()}
    z_limit = float(data["settings"]["z_limit"])
    since = data["baseline_since"]
    summary = {
        "conveyor": data["conveyor"],
        "calibration": data["calibration_source"],
        "recordings": len(data["history"]),
        "baseline": {
            "complete": stored is not None,
            "recordings": len(data["baseline_rows"]),
            "since": since,
            "outliers": {k: v.outliers for k, v in baselines.items() if v.outliers},
        },
        "open_alarms": [a for a in data["alarms"] if a["status"] == "open"],
        "forecasts": baseline.forecasts(baselines, data["history"], since or "", z_limit)
        if baselines
        else [],
        "events": list(data["events"]),
        "notes": data["notes"],
    }
    return StoredHealth(summary, baselines, z_limit, since, data["calibration"])


def summary_of(mon: ConveyorMonitor) -> dict[str, Any]:
    """The conveyor's summary for ``monitor --json`` (``conveyors``): :func:`read_health`
    of its state."""
    return read_health(state_of(mon)).summary
