"""Time series of virtual recordings: a conveyor's life over simulated days.

``generate`` writes, for each simulated day, ``per_day`` recordings of the
virtual conveyor with

* a payload drawn uniformly from ``payload_range_kg`` (unknown to the
  recording: no ``payload_kg`` in its metadata);
* the gear losses drifting with temperature: a slow seasonal swing of
  ``drift`` (default ±5 %) over a 30-day period plus a daily swing of half
  that (cold mornings, warm afternoons);
* each fault growing linearly from severity 0 on the onset day to the given
  severity on the last day;
* the motor angle carried from one recording to the next (with unrecorded
  moves between), so that positions are absolute and a place on the belt
  can be followed across recordings.

Beside the recordings it writes ``truth.jsonl``, one JSON object per
recording: ``file``, ``recorded_at``, ``payload_kg``, ``faults`` (every
fault's severity at that recording), ``loss_scale``. Ground truth never goes
into the recordings' metadata, except ``payload_kg`` on the calibration
recordings (``calibration/``), which are meant to carry a known load.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import numpy as np

from chaintwin.errors import ModelError
from chaintwin.read.files import write_atomic
from chaintwin.read.profile import ConveyorProfile, ModelSpec
from chaintwin.read.writer import write_recording
from chaintwin.simulate.faults import Fault
from chaintwin.simulate.virtual import Realism, run_virtual

__all__ = ["CALIBRATION_RUNS", "GenerateSummary", "fault_severity", "generate"]

#: Calibration runs: (payload kg, share of nominal speed). Empty tray at one
#: speed (what the published method used), a known reference load, and empty
#: runs at two more speeds, so that either protocol can be tried.
CALIBRATION_RUNS: tuple[tuple[float, float], ...] = (
    (0.0, 1.0),
    (0.0, 1.0),
    (0.0, 1.0),
    (50.0, 1.0),
    (0.0, 0.5),
    (0.0, 0.75),
)


@dataclass(frozen=True, slots=True)
class GenerateSummary:
    """What :func:`generate` wrote."""

    folder: Path
    recordings: int
    calibration_recordings: int
    truth_file: Path


def fault_severity(fault: Fault, day: int, days: int, onset_day: int) -> float:
    """Severity of a growing fault on a given day (0-based).

    Zero before ``onset_day``, then linear to ``fault.severity`` on the last
    day (``days - 1``); a fault with its onset on the last day has the full
    severity that day.
    """
    if day < onset_day:
        return 0.0
    span = max(days - 1 - onset_day, 0)
    if span == 0:
        return fault.severity
    return fault.severity * (day - onset_day) / span


def _loss_scale(t_days: float, drift: float) -> float:
    seasonal = drift * math.sin(2.0 * math.pi * t_days / 30.0)
    daily = 0.5 * drift * math.sin(2.0 * math.pi * (t_days % 1.0) - 0.5 * math.pi)
    return 1.0 + seasonal + daily


def generate(
    profile: ConveyorProfile,
    out: str | Path,
    *,
    days: int,
    per_day: int,
    faults: Sequence[Fault] = (),
    onset_day: int = 0,
    sample_time_s: float = 0.006,
    payload_range_kg: tuple[float, float] = (10.0, 40.0),
    drift: float = 0.05,
    realism: Realism | None = None,
    seed: int = 0,
    start: datetime | None = None,
    calibration: bool = True,
    model: ModelSpec | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> GenerateSummary:
    """Write a conveyor's virtual recordings over simulated days.

    Parameters
    ----------
    profile : ConveyorProfile
        The conveyor.
    out : str or Path
        Folder to write into (created).
    days, per_day : int
        Simulated days and recordings per day.
    faults : sequence of Fault
        Faults at their final severity (on the last day).
    onset_day : int
        0-based day from which the faults grow.
    sample_time_s : float
        Scope sample time, s.
    payload_range_kg : (float, float)
        Payload drawn uniformly from this range, kg.
    drift : float
        Amplitude of the losses' temperature drift (0.05 = ±5 %).
    realism : Realism, optional
        Default: everything on.
    seed : int
        Random seed; the same seed writes the same files.
    start : datetime, optional
        First day (default 2026-01-05 06:00 UTC).
    calibration : bool
        Also write calibration recordings (with ``payload_kg``) in
        ``calibration/``, on the first day, healthy.
    model : ModelSpec, optional
        Plant parameters (default: the profile's ``model:``, else typical values).
    progress : callable, optional
        Called with (done, total) after each recording.

    Returns
    -------
    GenerateSummary
    """
    if days < 1:
        raise ModelError(f"days {days} must be at least 1", field="days")
    if per_day < 1:
        raise ModelError(f"per_day {per_day} must be at least 1", field="per_day")
    if not 0 <= onset_day < days:
        raise ModelError(
            f"onset_day {onset_day} must be a day from 0 to {days - 1}", field="onset_day"
        )
    if not 0.0 <= drift < 0.5:
        raise ModelError(f"drift {drift} must be from 0 to 0.5 (0.05 = ±5 %)", field="drift")
    lo, hi = payload_range_kg
    if not 0.0 <= lo <= hi:
        raise ModelError(f"payload range {lo}-{hi} kg must satisfy 0 <= low <= high")
    folder = Path(out)
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    start = start or datetime(2026, 1, 5, 6, 0, tzinfo=UTC)
    realism = realism or Realism()
    angle = float(rng.uniform(0.0, 1000.0 * 2.0 * math.pi))
    rows: list[dict[str, Any]] = []
    total = days * per_day + (len(CALIBRATION_RUNS) if calibration else 0)
    done = 0

    def tick() -> None:
        nonlocal done
        done += 1
        if progress is not None:
            progress(done, total)

    n_cal = 0
    if calibration:
        cal_dir = folder / "calibration"
        cal_dir.mkdir(exist_ok=True)
        nominal_rpm = profile.motor.nominal_speed_rpm or 1400.0
        for j, (load, share) in enumerate(CALIBRATION_RUNS):
            when = start - timedelta(hours=2) + timedelta(minutes=10 * j)
            name = f"calibration/{profile.id}-cal-{j:02d}.csv"
            run = run_virtual(
                profile,
                payload_kg=load,
                sample_time_s=sample_time_s,
                realism=realism,
                seed=int(rng.integers(2**31)),
                speed_rpm=nominal_rpm * share,
                model=model,
                recorded_at=when,
                calibration=True,
                loss_scale=_loss_scale(-2.0 / 24.0, drift),
                initial_motor_angle=angle,
                source=name,
            )
            write_recording(run.recording, folder / name)
            angle = float(run.simulation.position[-1]) + float(rng.uniform(0, 200.0))
            rows.append({"file": name, **run.truth})
            n_cal += 1
            tick()

    for day in range(days):
        severities = [Fault(f.name, fault_severity(f, day, days, onset_day)) for f in faults]
        active = [f for f in severities if f.severity > 0.0]
        for j in range(per_day):
            hours = 16.0 * (j + rng.uniform(0.1, 0.9)) / per_day  # 06:00 to 22:00
            when = start + timedelta(days=day, hours=hours)
            payload = float(rng.uniform(lo, hi))
            t_days = day + (6.0 + hours) / 24.0
            name = f"{profile.id}-{when:%Y%m%dT%H%M%S}.csv"
            run = run_virtual(
                profile,
                payload_kg=payload,
                sample_time_s=sample_time_s,
                faults=active,
                realism=realism,
                seed=int(rng.integers(2**31)),
                model=model,
                recorded_at=when.replace(microsecond=0),
                loss_scale=_loss_scale(t_days, drift),
                initial_motor_angle=angle,
                source=name,
            )
            write_recording(run.recording, folder / name)
            # unrecorded moves between scopes advance the belt
            angle = float(run.simulation.position[-1]) + float(rng.uniform(0, 5000.0))
            truth = {**run.truth, "faults": {f.name: f.severity for f in severities}}
            rows.append({"file": name, **truth})
            tick()
    truth_file = folder / "truth.jsonl"
    write_atomic(
        truth_file,
        "".join(json.dumps(r, sort_keys=True) + "\n" for r in rows),
        what="truth file",
        error=lambda t, m: ModelError(f"{t}: {m}"),
    )
    return GenerateSummary(folder, days * per_day, n_cal, truth_file)
