"""Movement-cycle segmentation: standstill, accelerate, constant, decelerate.

A conveyor's scope usually holds one movement: standstill, a ramp up, a
constant-speed run, a ramp down and standstill again. Identification needs
to know which samples belong where (sign terms are left out near standstill,
the inertia signature lives in the ramps, friction in the constant part).

The segmentation uses the speed set point when it is recorded (clean, it is
what the drive was told to do) and the actual speed otherwise (smoothed with
a Savitzky-Golay filter, thresholds above its noise).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from chaintwin._stats import median
from chaintwin._types import FloatArray
from chaintwin.read.recording import Recording
from chaintwin.units import RPM_TO_RAD_S
from chaintwin.validate.filters import gradient, savgol

__all__ = ["Phase", "PhaseKind", "segment", "segment_speed"]

PhaseKind = Literal["standstill", "accelerate", "constant", "decelerate"]

_STANDSTILL_FLOOR = 1.0 * RPM_TO_RAD_S
"""Speeds below 1 rpm count as standstill, whatever the peak speed."""


@dataclass(frozen=True, slots=True)
class Phase:
    """One phase of a movement cycle.

    Parameters
    ----------
    kind : {"standstill", "accelerate", "constant", "decelerate"}
        What the (absolute) speed does; accelerate means its magnitude grows.
    direction : int
        +1 forward, -1 backward, 0 at standstill.
    start, stop : int
        Sample index range ``[start, stop)``.
    start_s, end_s : float
        Time of the first sample and of the first sample after the phase (the
        last sample's time for the last phase), s.
    """

    kind: PhaseKind
    direction: int
    start: int
    stop: int
    start_s: float
    end_s: float

    @property
    def moving(self) -> bool:
        """True unless the phase is a standstill."""
        return self.kind != "standstill"

    def to_dict(self) -> dict[str, object]:
        """Return the ``inspect --json`` form ``{kind, direction, start_s, end_s}``."""
        return {
            "kind": self.kind,
            "direction": self.direction,
            "start_s": round(self.start_s, 9),
            "end_s": round(self.end_s, 9),
        }


def _noise_sigma(x: FloatArray) -> float:
    """Robust white-noise standard deviation from first differences."""
    d = np.diff(x)
    mad = median(np.abs(d - median(d)))
    return float(1.4826 * mad / np.sqrt(2.0))


def _runs(labels: np.ndarray) -> list[tuple[int, int, int]]:
    """Run-length encode: list of (label, start, stop)."""
    change = np.flatnonzero(np.diff(labels)) + 1
    starts = np.concatenate(([0], change))
    stops = np.concatenate((change, [labels.shape[0]]))
    return [(int(labels[a]), int(a), int(b)) for a, b in zip(starts, stops, strict=True)]


def _merge_short(labels: np.ndarray, min_len: int) -> np.ndarray:
    """Absorb runs shorter than ``min_len`` into their longer neighbour."""
    labels = labels.copy()
    for _ in range(8):
        runs = _runs(labels)
        if len(runs) == 1:
            break
        changed = False
        for k, (_lab, a, b) in enumerate(runs):
            if b - a >= min_len:
                continue
            left = runs[k - 1] if k > 0 else None
            right = runs[k + 1] if k + 1 < len(runs) else None
            if left is None and right is None:
                continue
            if right is None or (left is not None and left[2] - left[1] >= right[2] - right[1]):
                labels[a:b] = left[0]  # type: ignore[index]
            else:
                labels[a:b] = right[0]
            changed = True
            break
        if not changed:
            break
    return labels


# label codes: 0 standstill, 1 accelerate, 2 constant, 3 decelerate
_KINDS: tuple[PhaseKind, ...] = ("standstill", "accelerate", "constant", "decelerate")


def segment_speed(time: FloatArray, speed: FloatArray, *, clean: bool) -> list[Phase]:
    """Segment a speed signal into movement phases.

    Parameters
    ----------
    time : FloatArray
        Sample times, s (strictly increasing).
    speed : FloatArray
        Motor speed, rad/s: a set point (``clean=True``) or a measured speed.
    clean : bool
        True for a set point (no noise); False smooths and estimates noise.

    Returns
    -------
    list of Phase
        Contiguous phases covering every sample, in time order.
    """
    n = speed.shape[0]
    with np.errstate(all="ignore"):
        dt = median(np.diff(time))
        if clean:
            w = speed.astype(np.float64, copy=True)
            sigma = 0.0
        else:
            win = min(n if n % 2 else n - 1, 11)
            w = savgol(speed, win, 2) if win >= 5 else speed.astype(np.float64)
            sigma = _noise_sigma(speed)
        peak = float(np.max(np.abs(w))) if n else 0.0
        if not np.isfinite(peak) or not np.isfinite(dt) or dt <= 0:
            return [Phase("standstill", 0, 0, n, float(time[0]), float(time[-1]))]
        v_floor = max(_STANDSTILL_FLOOR, 4.0 * sigma)
        v0 = max((0.005 if clean else 0.02) * peak, v_floor)
        moving = np.abs(w) >= v0
        labels = np.zeros(n, dtype=np.int64)
        if moving.any():
            # rate of change of |speed|
            mag = np.abs(w)
            if clean:
                rate = gradient(mag, time)
            else:
                win = min(n if n % 2 else n - 1, 15)
                rate = savgol(mag, win, 2, deriv=1, delta=dt) if win >= 5 else gradient(mag, time)
            moving_rate = np.abs(rate[moving])
            top = float(np.percentile(moving_rate, 98)) if moving_rate.size else 0.0
            a0 = 0.05 * top
            if not clean:
                # noise of a 15-point quadratic Savitzky-Golay slope is about
                # 0.06·sigma/dt; stay four of those above it
                a0 = max(a0, 0.25 * sigma / dt)
            a0 = max(a0, 1e-9)
            labels[:] = 2
            labels[rate > a0] = 1
            labels[rate < -a0] = 3
            labels[~moving] = 0
        min_len = max(2, round(0.015 / dt)) if clean else max(3, round(0.03 / dt))
        labels = _merge_short(labels, min_len)

    phases: list[Phase] = []
    runs = _runs(labels)
    for k, (lab, a, b) in enumerate(runs):
        kind = _KINDS[lab]
        if kind == "standstill":
            direction = 0
        else:
            mean = float(np.mean(w[a:b]))
            direction = 1 if mean > 0 else -1
        end_s = float(time[b]) if k + 1 < len(runs) else float(time[-1])
        phases.append(Phase(kind, direction, a, b, float(time[a]), end_s))
    return phases


def segment(recording: Recording) -> list[Phase]:
    """Segment a recording's movement, from its speed set point when recorded.

    Parameters
    ----------
    recording : Recording
        A recording as read.

    Returns
    -------
    list of Phase
        Contiguous phases covering every sample.
    """
    setpoint = recording.speed_setpoint
    if setpoint is not None and np.any(setpoint != 0.0):
        return segment_speed(recording.time, setpoint, clean=True)
    return segment_speed(recording.time, recording.speed, clean=False)
