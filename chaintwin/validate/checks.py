"""Checks that make a usable recording's weaknesses visible as warnings.

Each check returns :class:`~chaintwin.read.recording.RecordingWarning`
objects with a stable code (see ``WARNING_CODES``); :func:`inspect_recording`
runs them all and attaches the warnings to the recording, so that they
travel to every later result.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from chaintwin._stats import median
from chaintwin._types import FloatArray
from chaintwin.read.columns import ColumnMap
from chaintwin.read.formats import read_recording
from chaintwin.read.profile import ConveyorProfile
from chaintwin.read.recording import Recording, RecordingWarning
from chaintwin.units import RPM_TO_RAD_S
from chaintwin.validate.phases import Phase, segment

__all__ = [
    "Inspection",
    "check_sampling",
    "check_speed_following",
    "check_torque_saturation",
    "inspect_recording",
    "load_recording",
    "tray_mass_kg",
]

SATURATION_MIN_S = 0.010
"""A torque limit held for at least this long (and 3 samples) is noticeable, s."""


@dataclass(frozen=True, slots=True)
class Inspection:
    """A recording with its movement phases and warnings attached.

    Parameters
    ----------
    recording : Recording
        The recording, its ``warnings`` filled in.
    phases : tuple of Phase
        Movement phases covering every sample.
    complete_cycle : bool
        True when the recording starts and ends at standstill with motion
        between.
    """

    recording: Recording
    phases: tuple[Phase, ...]
    complete_cycle: bool

    @property
    def warnings(self) -> tuple[RecordingWarning, ...]:
        """The recording's warnings."""
        return self.recording.warnings


def tray_mass_kg(recording: Recording, profile: ConveyorProfile | None) -> float | None:
    """Tray mass for a recording, kg: its ``tray_kg`` metadata, else the profile's."""
    if recording.metadata.tray_kg is not None:
        return recording.metadata.tray_kg
    return profile.tray_mass_kg if profile is not None else None


def check_sampling(recording: Recording) -> list[RecordingWarning]:
    """Warn about non-uniform time steps and a metadata sample time that disagrees."""
    out: list[RecordingWarning] = []
    t = recording.time
    with np.errstate(all="ignore"):
        dt = np.diff(t)
        med = median(dt)
        bad = np.abs(dt - med) > max(0.01 * med, 1e-6)
    if bad.any():
        first = int(np.flatnonzero(bad)[0])
        out.append(
            RecordingWarning(
                "irregular_sample_time",
                f"{int(bad.sum())} of {dt.shape[0]} time steps differ from the median "
                f"{med * 1e3:.4g} ms by more than 1 % (steps from {dt.min() * 1e3:.4g} to "
                f"{dt.max() * 1e3:.4g} ms), first at t = {t[first + 1]:.6g} s",
            )
        )
    nominal = recording.metadata.sample_time_s
    if nominal is not None and abs(med / nominal - 1.0) > 0.01:
        out.append(
            RecordingWarning(
                "sample_time_mismatch",
                f"metadata sample_time_s is {nominal:g} s but the time column steps by "
                f"{med:.6g} s; the time column is used",
            )
        )
    return out


def _runs(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return the starts and lengths of the runs of True values."""
    padded = np.concatenate(([False], mask, [False])).astype(np.int8)
    edges = np.flatnonzero(np.diff(padded))
    starts, stops = edges[0::2], edges[1::2]
    return starts, stops - starts


def check_torque_saturation(
    recording: Recording, torque_limit_nm: float | None
) -> list[RecordingWarning]:
    """Warn when the torque set point sits at the limit for a noticeable time.

    Parameters
    ----------
    recording : Recording
        The recording.
    torque_limit_nm : float or None
        The drive's torque limit (from the profile), Nm. Without it, a torque
        set point held flat at its extreme while the speed lags its set point
        counts as saturated.
    """
    t = recording.time
    dt = recording.sample_time_s
    # a set point at the known limit is the controller's output clamped: one
    # sample says so (at 12 ms a hard ramp shows the limit in 1-3 samples);
    # the actual torque near it, or a flat top without a known limit, needs more
    span = int(np.ceil(SATURATION_MIN_S / dt - 1e-9))  # samples in SATURATION_MIN_S
    need = max(3, span)
    tsp = recording.torque_setpoint
    with np.errstate(all="ignore"):
        if torque_limit_nm is not None:
            signal = tsp if tsp is not None else recording.torque
            share = 0.995 if tsp is not None else 0.95
            at_limit = np.abs(signal) >= share * torque_limit_nm
            what = "torque set point" if tsp is not None else "torque"
            level = torque_limit_nm
            if tsp is not None:
                need = 1
        else:
            wsp = recording.speed_setpoint
            if tsp is None or wsp is None:
                return []
            extreme = float(np.max(np.abs(tsp)))
            if extreme <= 0.0 or not np.isfinite(extreme):
                return []
            # the clamped set point carries the scope's noise and rounding (up to
            # 0.025 Nm at 7.5 Nm at 12 ms): within 0.5 % keeps a clamp one run. A
            # normal ramp's torque is flat too and its speed lags a little: a
            # clamp's lag is over 5 % of the top speed for SATURATION_MIN_S and
            # 2 samples (docs/data-contract.md)
            flat = np.abs(tsp) >= extreme * (1.0 - 5e-3)
            peak = float(np.max(np.abs(wsp)))
            lag = np.abs(wsp - recording.speed) > max(0.05 * peak, 2.0 * RPM_TO_RAD_S)
            at_limit = flat & lag
            what = "torque set point (held flat at its extreme while the speed lags)"
            level = extreme
            need = max(2, span)
    starts, lengths = _runs(at_limit)
    if not lengths.size or int(lengths.max()) < need:
        return []
    k = int(np.argmax(lengths))
    start, length = int(starts[k]), int(lengths[k])
    out = [
        RecordingWarning(
            "torque_saturated",
            f"{what} at {level:.4g} Nm for {length * dt * 1e3:.4g} ms from t = {t[start]:.6g} s; "
            "the drive could not deliver the torque asked for, so the speed did not follow",
        )
    ]
    # a ramp up and a ramp down can both clamp: the windup follows whichever
    # (the longest run is reported, every long-enough run is looked after)
    for s, n in zip(starts, lengths, strict=True):
        if n >= need:
            windup = _windup(recording, int(s + n))
            if windup:
                return out + windup
    return out


def _windup(recording: Recording, after: int) -> list[RecordingWarning]:
    """``speed_windup`` when the speed overshoots its set point after a saturation.

    While the torque is clamped the speed controller's integral keeps
    growing; when the limit releases, the stored integral drives the speed
    past its set point. An overshoot of more than 2 % of the top speed
    (and 5 rpm) in the second after the saturation, for two samples or
    more, is that windup.
    """
    wsp = recording.speed_setpoint
    if wsp is None or after >= recording.samples:
        return []
    stop = min(recording.samples, after + max(2, int(1.0 / recording.sample_time_s)))
    w, ref = recording.speed[after:stop], wsp[after:stop]
    peak = float(np.max(np.abs(wsp)))
    direction = np.sign(ref)
    over = (w - ref) * direction
    limit = max(0.02 * peak, 5.0 * RPM_TO_RAD_S)
    beyond = (over > limit) & (direction != 0)
    if int(np.count_nonzero(beyond)) < 2:
        return []
    worst = float(np.max(over[beyond])) / RPM_TO_RAD_S
    k = after + int(np.argmax(beyond))
    return [
        RecordingWarning(
            "speed_windup",
            f"after the torque limit the speed overshoots its set point by up to {worst:.0f} "
            f"rpm from t = {recording.time[k]:.6g} s: the controllers wound up while the torque "
            "was clamped (the position lag or the speed integral); a gentler ramp avoids it",
        )
    ]


def check_speed_following(recording: Recording, phases: list[Phase]) -> list[RecordingWarning]:
    """Warn when, at constant set point, the speed stays far from it (blockage, overload)."""
    wsp = recording.speed_setpoint
    if wsp is None:
        return []
    w = recording.speed
    worst = 0.0
    at = 0.0
    for ph in phases:
        if ph.kind != "constant" or ph.stop - ph.start < 8:
            continue
        half = ph.start + (ph.stop - ph.start) // 2  # after the ramp's settling
        ref = float(np.mean(np.abs(wsp[half : ph.stop])))
        if ref <= 0.0:
            continue
        err = float(np.mean(np.abs(wsp[half : ph.stop] - w[half : ph.stop]))) / ref
        if err > worst:
            worst, at = err, ph.start_s
    if worst > 0.05:
        return [
            RecordingWarning(
                "speed_not_following",
                f"at constant set point from t = {at:.6g} s the speed is off by {worst:.1%} "
                "on average; look for a blockage or an overload",
            )
        ]
    return []


def _cycle_warnings(
    recording: Recording, phases: list[Phase], speed: FloatArray
) -> tuple[bool, list[RecordingWarning]]:
    moving = [p for p in phases if p.moving]
    if not moving:
        peak = float(np.max(np.abs(speed)))
        return False, [
            RecordingWarning(
                "no_motion",
                f"the speed never leaves standstill (largest |speed| "
                f"{peak / RPM_TO_RAD_S:.3g} rpm); nothing to identify or weigh",
            )
        ]
    out: list[RecordingWarning] = []
    first, last = phases[0], phases[-1]
    if first.moving:
        out.append(
            RecordingWarning(
                "incomplete_cycle",
                f"starts in motion ({first.kind}, {speed[0] / RPM_TO_RAD_S:.4g} rpm); "
                "trigger the scope before the move",
            )
        )
    if last.moving:
        out.append(
            RecordingWarning(
                "incomplete_cycle",
                f"ends in motion ({last.kind}, {speed[-1] / RPM_TO_RAD_S:.4g} rpm); "
                "record longer or at a longer sample time",
            )
        )
    return not out, out


def inspect_recording(recording: Recording, profile: ConveyorProfile | None = None) -> Inspection:
    """Segment a recording and attach every warning.

    Parameters
    ----------
    recording : Recording
        As read by :func:`~chaintwin.read.formats.read_recording`.
    profile : ConveyorProfile, optional
        Supplies the torque limit; its id is compared with the recording's.

    Returns
    -------
    Inspection
    """
    phases = segment(recording)
    basis = recording.speed_setpoint
    if basis is None or not np.any(basis != 0.0):
        basis = recording.speed
    complete, found = _cycle_warnings(recording, phases, basis)
    found += check_sampling(recording)
    limit = profile.torque_limit_nm if profile is not None else None
    found += check_torque_saturation(recording, limit)
    found += check_speed_following(recording, phases)
    conveyor = recording.metadata.conveyor
    if profile is not None and conveyor is not None and conveyor != profile.id:
        found.append(
            RecordingWarning(
                "profile_mismatch",
                f"recording is of conveyor '{conveyor}' but the profile is '{profile.id}'; "
                "give the matching profile",
            )
        )
    return Inspection(recording.with_warnings(*found), tuple(phases), complete)


def load_recording(
    path: str | Path,
    *,
    profile: ConveyorProfile | None = None,
    column_map: ColumnMap | None = None,
) -> Inspection:
    """Read and validate one recording: the first stage of every pipeline.

    Raises
    ------
    RecordingError
        When the recording cannot be used.
    """
    recording = read_recording(path, profile=profile, column_map=column_map)
    return inspect_recording(recording, profile)
