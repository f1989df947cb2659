"""Impacts: short torque events the model does not explain (an obstacle hit, a caught item).

An obstacle on the rail that the tray hits, a damaged tooth, a worn
sprocket engaging: each shows in the torque residual (measured minus model
torque) as a short spike over a steady background. :func:`detect_impacts`
finds them without any position: the residual at constant speed, with its
slow part (a running median over :data:`BACKGROUND_S`) taken away, is
compared with its own robust scale, sample by sample and averaged over
:data:`SMOOTH_S` (a bump lasting tens of milliseconds, a guide rubbing,
stands out only averaged); runs beyond :data:`THRESHOLD_SIGMA` scales (and
:data:`MIN_SHARE` of the nominal torque, half that averaged, so that noise
on a quiet drive is no impact) are events. Each event has its time, duration,
sign (+1: it resisted the motion) and energy, the integral of the residual
times the speed over the event (J: positive, work the drive did against it).

The ramps are left out (the model's torque lag and the belt's wind-up
leave residuals there that are no impacts), and so are the first and last
:data:`EDGE_S` of each constant phase.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.ndimage import median_filter, uniform_filter1d

from chaintwin._types import FloatArray
from chaintwin.read.recording import Recording
from chaintwin.validate.phases import Phase

__all__ = ["POOL", "Impact", "detect_impacts", "hits_per_revolution", "impact_features", "periodic"]

BACKGROUND_S = 1.0
"""Window of the running median that is the residual's slow part, s."""

THRESHOLD_SIGMA = 6.0
"""An impact stands this many robust scales above the residual's background."""

MIN_SHARE = 0.03
"""And at least this share of the nominal torque (or of the peak torque without one)."""

EDGE_S = 0.1
"""Left out at both ends of a constant phase, s."""

SMOOTH_S = 0.05
"""Averaging window of the second, slower look at the residual, s."""

PERIODIC_CV = 0.15
"""Impacts whose spacings vary by less than this (coefficient of variation) are periodic."""

POOL = 10
"""Recordings pooled for the rate of isolated impacts per belt revolution."""


@dataclass(frozen=True, slots=True)
class Impact:
    """One impact: when, how long, which way and how much work, J."""

    t_s: float
    duration_s: float
    energy_j: float
    sign: int
    peak_nm: float

    def to_dict(self) -> dict[str, Any]:
        """``{t_s, duration_s, energy_j, sign, peak_nm}`` (the ``impacts`` of a result)."""
        return {
            "t_s": self.t_s,
            "duration_s": self.duration_s,
            "energy_j": self.energy_j,
            "sign": self.sign,
            "peak_nm": self.peak_nm,
        }


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """``[start, stop)`` of each run of True."""
    padded = np.concatenate(([False], mask, [False])).astype(np.int8)
    edges = np.flatnonzero(np.diff(padded))
    return [(int(a), int(b)) for a, b in zip(edges[0::2], edges[1::2], strict=True)]


def _beyond(x: FloatArray, floor: float) -> np.ndarray:
    """Samples beyond :data:`THRESHOLD_SIGMA` robust scales of ``x`` (and ``floor``)."""
    scale = 1.4826 * float(np.median(np.abs(x - np.median(x))))
    mask: np.ndarray = np.abs(x) > max(THRESHOLD_SIGMA * scale, floor)
    return mask


def detect_impacts(
    recording: Recording, model_torque_nm: FloatArray, phases: list[Phase]
) -> list[Impact]:
    """The impacts in a recording's constant-speed phases (see the module notes).

    Parameters
    ----------
    recording : Recording
        The recording (torque in Nm, speed in rad/s).
    model_torque_nm : FloatArray
        The rigid model's torque per sample, Nm.
    phases : list of Phase
        The recording's movement phases.
    """
    dt = recording.sample_time_s
    residual = recording.torque - model_torque_nm
    edge = int(np.ceil(EDGE_S / dt))
    width = max(3, round(BACKGROUND_S / dt) | 1)
    nominal = recording.metadata.nominal_torque_nm
    floor = MIN_SHARE * (nominal if nominal else float(np.max(np.abs(recording.torque)) or 1.0))
    out: list[Impact] = []
    for ph in phases:
        if ph.kind != "constant" or ph.stop - ph.start - 2 * edge < 3 * width:
            continue
        lo, hi = ph.start + edge, ph.stop - edge
        r = residual[lo:hi]
        fast = r - median_filter(r, size=width, mode="nearest")
        beyond = _beyond(fast, floor)
        # a bump lasting tens of ms (a guide rubbing) stands out once averaged;
        # its runs count where no sample stood out on its own (a knock keeps
        # its own time and duration, not the averaging's)
        box = max(1, round(SMOOTH_S / dt))
        if box > 1:
            slow = _beyond(uniform_filter1d(fast, size=box, mode="nearest"), floor / 2.0)
            for a, b in _runs(slow):
                if not beyond[a:b].any():
                    beyond[a:b] = True
        if not beyond.any():
            continue
        speed = recording.speed[lo:hi]
        direction = 1.0 if float(np.median(speed)) >= 0.0 else -1.0
        for a, b in _runs(beyond):
            seg = fast[a:b]
            k = int(np.argmax(np.abs(seg)))
            energy = float(np.sum(seg * speed[a:b]) * dt)
            out.append(
                Impact(
                    t_s=float(recording.time[lo + a]),
                    duration_s=float((b - a) * dt),
                    energy_j=energy,
                    sign=1 if seg[k] * direction > 0 else -1,
                    peak_nm=float(seg[k]),
                )
            )
    return out


def periodic(impacts: list[Impact]) -> bool:
    """Whether three or more impacts come at a regular spacing (a shaft, mesh or tooth order).

    A damaged tooth or a worn sprocket hits at every revolution or
    engagement: regular within a recording. An obstacle on the rail is hit
    once per belt revolution, longer than most scopes: isolated.
    """
    if len(impacts) < 3:
        return False
    gaps = np.diff([i.t_s for i in impacts])
    return bool(gaps.mean() > 0 and gaps.std() / gaps.mean() < PERIODIC_CV)


def impact_features(
    impacts: list[Impact], recording: Recording, phases: list[Phase], belt_per_rad_m: float
) -> dict[str, float]:
    """A recording's impact features.

    ``impact_count``; ``impact_rate_per_m`` (per metre of belt travel at
    constant speed); ``impact_energy_max`` (J; 0 without an impact);
    ``impact_isolated`` (the impacts when they are not periodic, else 0) and
    ``belt_travel_m`` (the travel they were looked for over), which the
    monitor pools over recordings (:func:`hits_per_revolution`).
    """
    dt = recording.sample_time_s
    travel = 0.0
    edge = int(np.ceil(EDGE_S / dt))
    for ph in phases:
        if ph.kind == "constant" and ph.stop - ph.start > 2 * edge:
            w = recording.speed[ph.start + edge : ph.stop - edge]
            travel += float(np.sum(np.abs(w)) * dt) * belt_per_rad_m
    return {
        "impact_count": float(len(impacts)),
        "impact_rate_per_m": len(impacts) / travel if travel > 0 else float("nan"),
        "impact_energy_max": max((abs(i.energy_j) for i in impacts), default=0.0),
        "impact_isolated": 0.0 if periodic(impacts) else float(len(impacts)),
        "belt_travel_m": travel,
    }


def hits_per_revolution(rows: Sequence[Mapping[str, Any]], loop_length_m: float) -> float:
    """Isolated impacts per belt revolution over recordings' features (pooled).

    An obstacle fixed to the rail is hit once per revolution wherever the
    scopes start, so the pooled rate nears 1 while the single recordings
    show 0 or 1 hit. NaN until some belt travel is known.
    """
    hits = sum(float(r.get("impact_isolated") or 0.0) for r in rows)
    travel = sum(float(r.get("belt_travel_m") or 0.0) for r in rows)
    return hits / travel * loop_length_m if travel > 0 else float("nan")
