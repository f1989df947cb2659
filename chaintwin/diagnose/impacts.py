"""Impacts: short torque events the model does not explain (an obstacle hit, a caught item).

An obstacle on the rail that the tray hits, a damaged tooth, a worn
sprocket engaging: each shows in the torque residual (measured minus model
torque) as a short spike over a steady background. :func:`detect_impacts`
finds them without any position: the residual at constant speed, less a
robust straight line through it (the medians of its two halves), is
compared with its own robust scale, sample by sample and averaged over
:data:`SMOOTH_S` (a bump lasting tens of milliseconds, a guide rubbing,
stands out only averaged); runs beyond :data:`THRESHOLD_SIGMA` scales (and
:data:`MIN_SHARE` of the nominal torque, half that averaged, so that noise
on a quiet drive is no impact) are events. Each event has its time, duration,
sign (+1: it resisted the motion) and energy, the integral of the residual
times the speed over the event (J: positive, work the drive did against it).

The ramps are left out (the model's torque lag and the belt's wind-up
leave residuals there that are no impacts), and so are the first
:data:`SETTLE_S` and the last :data:`EDGE_S` of each constant phase.

A hit resists the motion: a plateau whose residual spikes as far the other
way (aliased line content at a coarse sample time, a heavy-tailed noise)
has no hit of that size. Resisting events under :data:`ASYMMETRY` times the
largest assisting one (other than the ringing after a hit) are dropped.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import stats
from scipy.ndimage import median_filter, uniform_filter1d

from chaintwin._stats import median, phase_bins, subtract_binned_medians
from chaintwin._types import FloatArray
from chaintwin.read.recording import Recording
from chaintwin.validate.phases import Phase

__all__ = [
    "KNOCK_MAX_S",
    "POOL",
    "Impact",
    "background_knocks",
    "detect_impacts",
    "hits_per_revolution",
    "impact_features",
    "periodic",
    "residual_step",
]

SYNC_MIN_PERIODS = 4.0
"""Fewest periods of an order in a plateau for its synchronous average to be taken away."""

SYNC_BINS = 64
"""Most phase bins of a synchronous average."""

MIN_PLATEAU_S = 0.3
"""Shortest constant-speed stretch (after the edges) looked at, s."""

THRESHOLD_SIGMA = 6.0
"""An impact stands this many robust scales above the residual's background."""

MIN_SHARE = 0.03
"""And at least this share of the nominal torque (or of the peak torque without one)."""

SETTLE_S = 0.2
"""Left out at the start of a constant phase: the ramp's end still rings, s."""

HEAD_S = 0.5
"""After :data:`SETTLE_S`, looked at (the neighbourhoods and the averages reach
into it) but not searched: the drive's settling after a ramp lasts up to half
a second more on a long, heavy belt and reads as a lump, s."""

RING_WINDOW_S = 0.1
"""Window of the running RMS that tells a ringing head of a plateau, s."""

RING_RATIO = 1.5
"""A plateau's head rings while its running RMS is above this many times the median."""

ASYMMETRY = 1.5
"""A resisting event must stand this many times above the largest assisting one."""

EDGE_S = 0.1
"""Left out at both ends of a constant phase, s."""

SMOOTH_S = 0.05
"""Averaging window of the second, slower look at the residual, s."""

PERIODIC_CV = 0.15
"""Impacts whose spacings vary by less than this (coefficient of variation) are periodic."""

PATTERN_MIN = 4
"""Fewest alike knocks in one recording that make a pattern (:func:`_a_pattern`)."""

PATTERN_CV = 0.2
"""Largest coefficient of variation of their peaks that makes them alike."""

POOL = 20
"""Recordings pooled for the rate of isolated impacts per belt revolution."""

RINGING_MIN = 3
"""Alternating events that make a ringing (:func:`_without_ringing`)."""

RINGING_GAP_S = 0.5
"""Longest gap between two events of one ringing, s (half its period)."""

RINGING_LEAD = 2.0
"""A ringing's first event is a hit when its peak is this many times the others'."""

MERGE_S = 0.3
"""Runs of one sign closer than this belong to one event (a drag the drive
fights in swings, a knock and its echo), s."""

LOCAL_S = 0.5
"""Neighbourhood whose median level an event must stand out of, s."""

KNOCK_MAX_S = 0.1
"""Longest time above half its peak of an event that is a knock (an obstacle,
a tooth); longer ones drag, s.

A tray hitting an obstacle fixed to the rail is over in a few tens of
milliseconds; an item caught between a tray and a guide drags for a good
part of a second (a ``payload_event``)."""


STEP_BOX_S = 2.0 * KNOCK_MAX_S
"""Averaging time of :func:`residual_step`, s: a knock (at most :data:`KNOCK_MAX_S`
above half its peak) keeps at most half its height averaged over it, a drag
lasting as long or longer keeps all of it."""


@dataclass(frozen=True, slots=True)
class Impact:
    """One impact: when, how long, which way and how much work, J."""

    t_s: float
    duration_s: float
    energy_j: float
    sign: int
    peak_nm: float
    width_s: float = 0.0
    """Time the event spends above half its peak, s: short for a knock, long for a drag."""

    def to_dict(self) -> dict[str, Any]:
        """``{t_s, duration_s, energy_j, sign, peak_nm, width_s}`` (a result's ``impacts``)."""
        return {
            "t_s": self.t_s,
            "duration_s": self.duration_s,
            "energy_j": self.energy_j,
            "sign": self.sign,
            "peak_nm": self.peak_nm,
            "width_s": self.width_s,
        }


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """``[start, stop)`` of each run of True."""
    padded = np.concatenate(([False], mask, [False])).astype(np.int8)
    edges = np.flatnonzero(np.diff(padded))
    return [(int(a), int(b)) for a, b in zip(edges[0::2], edges[1::2], strict=True)]


def less_periodic(x: FloatArray, angle_rad: FloatArray, orders: Sequence[float]) -> FloatArray:
    """``x`` less its synchronous average at each order (one after the other).

    The samples are binned by the phase of ``order x motor angle`` (the
    position channel: its offset does not matter within a recording) and
    each bin's median is taken away; an order seen for fewer than
    :data:`SYNC_MIN_PERIODS` periods is left alone. What repeats at that
    order goes, a single hit (one period in many) stays.
    """
    out = x.copy()
    span = float(abs(angle_rad[-1] - angle_rad[0])) if angle_rad.shape[0] else 0.0
    turned: FloatArray | None = None
    for order in orders:
        periods = span * order / (2.0 * np.pi)
        if not np.isfinite(periods) or periods < SYNC_MIN_PERIODS:
            continue
        per_period = x.shape[0] / periods
        bins = int(min(SYNC_BINS, max(4.0, per_period)))
        if turned is None:
            turned = angle_rad - angle_rad[0]
        idx = phase_bins(turned, order, bins)
        # the samples grouped by bin and each bin's median taken away in
        # compiled passes (the same numbers as np.median per bin, at a
        # fraction of the calls)
        subtract_binned_medians(out, idx, bins)
    return out


def _robust_line(r: FloatArray) -> FloatArray:
    """A straight line through the medians of the two halves of ``r`` (hits barely move it)."""
    n = r.shape[0]
    h = n // 2
    m1, m2 = median(r[:h]), median(r[h:])
    slope = (m2 - m1) / max(n - h, 1)  # the halves' centres lie n/2 samples apart
    line: FloatArray = 0.5 * (m1 + m2) + slope * (np.arange(n) - 0.5 * (n - 1))
    return line


def _merged(runs: list[tuple[int, int]], x: FloatArray, gap: int) -> list[tuple[int, int]]:
    """Runs of the same sign (of ``x`` at their largest) joined where fewer than ``gap``
    samples part them; a swing the other way starts a new run (a ringing's half cycles
    stay apart for :func:`_without_ringing`)."""
    out: list[tuple[int, int]] = []
    signs: list[float] = []
    for a, b in runs:
        seg = x[a:b]
        sign = float(np.sign(seg[int(np.argmax(np.abs(seg)))]))
        if out and a - out[-1][1] < gap and sign == signs[-1]:
            out[-1] = (out[-1][0], b)
        else:
            out.append((a, b))
            signs.append(sign)
    return out


def _beyond(x: FloatArray, floor: float, local: int) -> np.ndarray:
    """Samples beyond :data:`THRESHOLD_SIGMA` robust scales of ``x`` (and ``floor``).

    The scale is the larger of the whole span's and the neighbourhood's
    (a running median of ``|x|`` over ``local`` samples; 0: the whole span's
    alone): a hit stands out of its surroundings, a ringing or a rough
    stretch does not. A drag, lasting as long as the neighbourhood, is looked
    for averaged and against the whole span.
    """
    scale = 1.4826 * median(np.abs(x - median(x)))
    if local <= 0:
        whole: np.ndarray = np.abs(x) > max(THRESHOLD_SIGMA * scale, floor)
        return whole
    near = 1.4826 * median_filter(np.abs(x), size=max(3, local | 1), mode="nearest")
    mask: np.ndarray = np.abs(x) > np.maximum(THRESHOLD_SIGMA * np.maximum(scale, near), floor)
    return mask


def detect_impacts(
    recording: Recording,
    model_torque_nm: FloatArray,
    phases: list[Phase],
    orders: Sequence[float] = (),
) -> list[Impact]:
    """The impacts in a recording's constant-speed phases (see the module notes).

    :func:`scan_impacts` without the spans looked at.
    """
    return scan_impacts(recording, model_torque_nm, phases, orders)[0]


def scan_impacts(
    recording: Recording,
    model_torque_nm: FloatArray,
    phases: list[Phase],
    orders: Sequence[float] = (),
) -> tuple[list[Impact], list[tuple[int, int]]]:
    """The impacts in a recording's constant-speed phases, and where they were looked for.

    Parameters
    ----------
    recording : Recording
        The recording (torque in Nm, speed in rad/s).
    model_torque_nm : FloatArray
        The rigid model's torque per sample, Nm.
    phases : list of Phase
        The recording's movement phases.
    orders : sequence of float
        Speed-locked orders (per motor revolution) whose periodic content is
        taken away first (:func:`less_periodic`): the polygon effect, a
        shaft's or the sprocket's knocks repeat and are judged by their
        spectral lines, not as impacts.

    Returns
    -------
    (list of Impact, list of (int, int))
        The impacts, and the ``[start, stop)`` sample spans looked at (a
        plateau less its edges and the ringing the ramp left).
    """
    dt = recording.sample_time_s
    residual = recording.torque - model_torque_nm
    edge = int(np.ceil(EDGE_S / dt))
    settle = int(np.ceil(SETTLE_S / dt))
    shortest = max(8, round(MIN_PLATEAU_S / dt))
    nominal = recording.metadata.nominal_torque_nm
    floor = MIN_SHARE * (nominal if nominal else float(np.max(np.abs(recording.torque)) or 1.0))
    # the motor angle orders are locked to: the position, or the speed integrated
    angle = recording.position
    if angle is None:
        angle = np.cumsum(recording.speed) * dt
    out: list[Impact] = []
    spans: list[tuple[int, int]] = []
    for ph in phases:
        if ph.kind != "constant" or ph.stop - ph.start - settle - edge < shortest:
            continue
        lo, hi = ph.start + settle, ph.stop - edge
        r = residual[lo:hi]
        # what is left of the residual over a robust line through it: a drag
        # lasting a good part of the plateau stays whole (a running median
        # would follow it), and a 1 ms scope's short plateau is looked at too
        fast = less_periodic(r - _robust_line(r), angle[lo:hi], orders)
        # a soft belt may still ring from the ramp: start where that has died down
        quiet = max(_quiet_from(fast, max(3, round(RING_WINDOW_S / dt))), round(HEAD_S / dt))
        if fast.shape[0] - quiet < shortest:
            continue
        # the neighbourhoods reach back into the ringing: its tail stands out of nothing
        beyond = _beyond(fast, floor, round(LOCAL_S / dt))
        # a bump lasting tens of ms (a guide rubbing) stands out once averaged;
        # its runs count where no sample stood out on its own (a knock keeps
        # its own time and duration, not the averaging's)
        box = max(1, round(SMOOTH_S / dt))
        if box > 1:
            slow = _beyond(uniform_filter1d(fast, size=box, mode="nearest"), floor / 2.0, 0)
            for a, b in _runs(slow):
                if not beyond[a:b].any():
                    beyond[a:b] = True
        lo, fast, beyond = lo + quiet, fast[quiet:], beyond[quiet:]
        spans.append((lo, hi))
        if not beyond.any():
            continue
        speed = recording.speed[lo:hi]
        direction = 1.0 if median(speed) >= 0.0 else -1.0
        found: list[Impact] = []
        least: dict[float, float] = {}  # per event (by time): the least work of a hit, J
        for a, b in _merged(_runs(beyond), fast, round(MERGE_S / dt)):
            seg = fast[a:b]
            k = int(np.argmax(np.abs(seg)))
            energy = float(np.sum(seg * speed[a:b]) * dt)
            t0 = float(recording.time[lo + a])
            # one sample cannot be told from a glitch; less work than the floor
            # torque does in MIN_IMPACT_S is the polygon's or the quantisation's
            least[t0] = (
                math.inf
                if b - a < MIN_SAMPLES
                else floor * abs(float(np.mean(speed[a:b]))) * MIN_IMPACT_S
            )
            found.append(
                Impact(
                    t_s=t0,
                    duration_s=float((b - a) * dt),
                    width_s=float(np.count_nonzero(np.abs(seg) >= 0.5 * abs(seg[k])) * dt),
                    energy_j=energy,
                    sign=1 if seg[k] * direction > 0 else -1,
                    peak_nm=float(seg[k]),
                )
            )
        # judged after the ringing is told apart: a chain's small tail still marks it
        kept = _resisting_above_noise(_without_ringing(found))
        out += [e for e in kept if abs(e.energy_j) >= least[e.t_s]]
    return out, spans


def _quiet_from(x: FloatArray, box: int) -> int:
    """Where ``x`` stops ringing: a window after the first sample whose running
    RMS is under :data:`RING_RATIO` times the median, when ``x`` starts above
    it (else 0).

    At most half of ``x`` is given up.
    """
    env = np.sqrt(uniform_filter1d(x * x, size=box, mode="nearest"))
    loud = env > RING_RATIO * median(env)
    if not bool(loud[0]):
        return 0
    half = int(x.shape[0]) // 2
    quiet = np.flatnonzero(~loud[:half])
    # the running RMS lags: a window more and the ringing's tail is past
    return min(int(quiet[0]) + box, half) if quiet.size else half


def _resisting_above_noise(events: list[Impact]) -> list[Impact]:
    """Events less the resisting ones no larger than the plateau's assisting spikes.

    An assisting event within :data:`RINGING_GAP_S` after a resisting one is
    its ringing and sets no floor.
    """
    floor = 0.0
    last_hit = -np.inf
    for e in events:
        if e.sign > 0:
            last_hit = e.t_s
        elif e.t_s - last_hit > RINGING_GAP_S:
            floor = max(floor, abs(e.peak_nm))
    return [e for e in events if e.sign < 0 or abs(e.peak_nm) >= ASYMMETRY * floor]


def _without_ringing(events: list[Impact]) -> list[Impact]:
    """Events less those that are a ringing: an oscillation, not a hit.

    A long, soft belt rings at its two-mass frequency after a ramp or a
    hit: runs of alternating sign a regular half period apart. A chain of
    :data:`RINGING_MIN` or more such events is dropped, save its first when
    that stands out (:data:`RINGING_LEAD` times the others' median peak: the
    hit that set the belt ringing).
    """
    out: list[Impact] = []
    k = 0
    while k < len(events):
        j = k + 1
        while (
            j < len(events)
            and events[j].sign != events[j - 1].sign
            and events[j].t_s - events[j - 1].t_s < RINGING_GAP_S
        ):
            j += 1
        chain = events[k:j]
        if len(chain) >= RINGING_MIN:
            rest = float(np.median([abs(e.peak_nm) for e in chain[1:]]))
            if abs(chain[0].peak_nm) >= RINGING_LEAD * rest:
                out.append(chain[0])
        else:
            out += chain
        k = j
    return out


def periodic(impacts: list[Impact]) -> bool:
    """Whether three or more impacts come at a regular spacing (a shaft, mesh or tooth order).

    A damaged tooth or a worn sprocket hits at every revolution or
    engagement: regular within a recording, though a hit below the
    threshold now and then leaves a gap of two or three periods. So the
    spacings are compared with the smallest: all within
    :data:`PERIODIC_CV` of a whole multiple of it is regular. An obstacle on
    the rail is hit once per belt revolution, longer than most scopes: isolated.
    """
    if len(impacts) < 3:
        return False
    gaps = np.diff([i.t_s for i in impacts])
    base = float(gaps.min())
    if base <= 0:
        return False
    ratios = gaps / base
    return bool(np.all(np.abs(ratios - np.round(ratios)) < PERIODIC_CV))


def _a_pattern(hits: list[Impact], revolution_s: float | None) -> bool:
    """Whether resisting events repeat as a pattern of the drive, not as hits.

    Regular spacings (:func:`periodic`) belong to an order (a tooth, a
    sprocket, a line aliased by the sampling), unless the spacing is the
    belt's revolution (an obstacle on a short belt, hit again and again
    within one long scope). So do :data:`PATTERN_MIN` or more knocks as alike
    as a line's samples (peaks within :data:`PATTERN_CV`): a sampled line
    beating against the sample rate leaves spikes in a few repeating gaps.
    """
    if revolution_s is not None and len(hits) >= 2:
        gaps = np.diff([i.t_s for i in hits])
        ratios = gaps / revolution_s
        if np.all(np.abs(ratios - np.round(ratios)) < PERIODIC_CV) and np.all(ratios > 0.5):
            return False  # once per belt revolution: the obstacle itself
    if periodic(hits):
        return True
    if len(hits) >= PATTERN_MIN:
        peaks = np.abs([i.peak_nm for i in hits])
        return bool(peaks.std() < PATTERN_CV * peaks.mean())
    return False


def _one_obstacle(knocks: list[Impact], revolution_s: float | None) -> bool:
    """Whether one obstacle fixed to the rail could have made all of a recording's knocks.

    It is passed once per belt revolution: two knocks of one recording are
    its only when a whole number of revolutions (at the recording's mean
    belt speed, within :data:`PERIODIC_CV`) lies between them. On a 23 m
    loop, two knocks 1.5 m apart are something else (an item, a polygon
    spike), and pooled they read as an obstacle on a healthy conveyor.
    """
    if len(knocks) < 2:
        return True
    if revolution_s is None:
        return False
    ratios = np.diff([i.t_s for i in knocks]) / revolution_s
    return bool(np.all(ratios > 0.5) and np.all(np.abs(ratios - np.round(ratios)) < PERIODIC_CV))


def impact_features(
    impacts: list[Impact],
    recording: Recording,
    phases: list[Phase],
    belt_per_rad_m: float,
    spans: Sequence[tuple[int, int]] | None = None,
    loop_length_m: float | None = None,
) -> dict[str, float]:
    """A recording's impact features.

    ``spans`` are the sample spans the impacts were looked for in
    (:func:`scan_impacts`; default: the constant phases less their edges),
    over which the belt travel is counted; ``belt_per_rad_m`` is the belt
    travel per motor radian, m; ``loop_length_m`` the belt loop (hits once
    per revolution of it are the obstacle's, however regular).

    Only impacts that resist the motion (``sign`` +1) count: a hit does,
    the belt springing back after it does not; and none when they come at a
    regular spacing (:func:`periodic`: an order's, judged by its lines).
    ``impact_count``;
    ``impact_rate_per_m`` (per metre of belt travel at constant speed);
    ``impact_energy_max`` (J; 0 without an impact);
    ``impact_isolated`` (the knocks, impacts no longer than
    :data:`KNOCK_MAX_S` above half their peak, when they are not periodic,
    else 0);
    ``impact_rail_hits`` (the knocks, when one obstacle fixed to the rail
    could have made them all: :func:`_one_obstacle`; else 0);
    ``impact_drags`` (the longer ones: an item caught for a while) and
    ``belt_travel_m`` (the travel they were looked for over), which the
    monitor pools over recordings (:func:`hits_per_revolution`).
    """
    dt = recording.sample_time_s
    travel = 0.0
    if spans is None:
        edge = int(np.ceil(EDGE_S / dt))
        settle = int(np.ceil(SETTLE_S / dt))
        spans = [
            (ph.start + settle, ph.stop - edge)
            for ph in phases
            if ph.kind == "constant" and ph.stop - ph.start > settle + edge
        ]
    for a, b in spans:
        travel += float(np.sum(np.abs(recording.speed[a:b])) * dt) * belt_per_rad_m
    # a hit resists the motion; what drives it along is the belt springing back;
    # hits at a regular spacing belong to an order (a tooth, a sprocket, a line
    # aliased by the sampling) and are judged by its spectral lines
    hits = [i for i in impacts if i.sign > 0]
    revolution_s = None
    if loop_length_m and travel > 0 and spans:
        searched = sum(b - a for a, b in spans) * dt
        revolution_s = loop_length_m / (travel / searched)  # at the mean belt speed
    if _a_pattern(hits, revolution_s):
        hits = []
    knocks = [i for i in hits if i.width_s <= KNOCK_MAX_S]
    return {
        "impact_count": float(len(hits)),
        "impact_rate_per_m": len(hits) / travel if travel > 0 else float("nan"),
        "impact_energy_max": max((abs(i.energy_j) for i in hits), default=0.0),
        "impact_isolated": float(len(knocks)),
        "impact_rail_hits": float(len(knocks)) if _one_obstacle(knocks, revolution_s) else 0.0,
        "impact_drags": float(len(hits) - len(knocks)),
        "belt_travel_m": travel,
    }


MIN_SAMPLES = 2
"""Fewest samples an impact spans (one sample cannot be told from a glitch)."""
MIN_IMPACT_S = 0.02
"""An impact does at least the work of the floor torque (:data:`MIN_SHARE` of
nominal) at its speed over this time, s. Spikes of one or two samples at the
floor's height were the polygon's and the quantisation's (0.03-0.04 J on a
0.8 Nm drive, against 0.07 J so required) and pooled into obstruction alarms
on a healthy 8-tooth conveyor; the bundled conveyor's obstacle knocks last
18 ms and do 1.3-1.7 J."""

MIN_POOLED_HITS = 2
"""Fewest isolated knocks in the pool that give a rate per revolution (fewer: 0)."""


def pooled_hits(rows: Sequence[Mapping[str, Any]]) -> float:
    """Knocks one rail obstacle could have made, over recordings' features.

    What :func:`hits_per_revolution` pools: each recording's
    ``impact_rail_hits`` (its ``impact_isolated`` when stored before that
    feature existed).
    """
    return sum(float(r.get("impact_rail_hits", r.get("impact_isolated")) or 0.0) for r in rows)


def background_hits_per_m(rows: Sequence[Mapping[str, Any]]) -> float:
    """Knocks one rail obstacle could have made, per metre of belt travel, over
    recordings' features (a healthy conveyor's baseline: its random knocks), 1/m.

    0 without belt travel.
    """
    travel = sum(float(r.get("belt_travel_m") or 0.0) for r in rows)
    return pooled_hits(rows) / travel if travel > 0 else 0.0


BEYOND_BACKGROUND_P = 0.01
"""One-sided Poisson probability below which pooled knocks are more than the
conveyor's own random knocks (:func:`hits_per_revolution`)."""


def background_knocks(rows: Sequence[Mapping[str, Any]]) -> tuple[float, float]:
    """The random knocks of a healthy conveyor's baseline: (knocks, belt travel m)."""
    return pooled_hits(rows), sum(float(r.get("belt_travel_m") or 0.0) for r in rows)


def hits_per_revolution(
    rows: Sequence[Mapping[str, Any]],
    loop_length_m: float,
    baseline: Sequence[Mapping[str, Any]] | None = None,
) -> float:
    """Isolated impacts per belt revolution over recordings' features (pooled),
    beyond the conveyor's own random knocks.

    An obstacle fixed to the rail is hit once per revolution wherever the
    scopes start, so the pooled rate nears 1 while the single recordings
    show 0 or 1 hit. NaN until some belt travel is known; 0 while fewer than
    :data:`MIN_POOLED_HITS` knocks are pooled: one knock in twenty short
    scopes reads as "about one per revolution" as readily as an item caught
    does (a count of one says nothing of a rate).

    With a ``baseline`` (a healthy conveyor's recordings) the conveyor's own
    random knocks are its background: ``k0`` knocks over ``T0`` m of travel
    give the rate ``(k0 + 1/2) / T0`` (the Jeffreys estimate: a baseline
    that saw no knock has not shown that there are none; a healthy 6 ms
    conveyor on a 33 m loop knocked about once in 17 scopes and its
    20-recording baseline saw none). The pooled knocks count only when
    more than that background would give with probability
    :data:`BEYOND_BACKGROUND_P` (Poisson); then the rate is the knocks
    beyond the background's expectation, per revolution, else 0. Without
    a baseline (still learning) the knocks are taken whole.
    """
    hits = pooled_hits(rows)
    travel = sum(float(r.get("belt_travel_m") or 0.0) for r in rows)
    if not travel > 0:
        return float("nan")
    if hits < MIN_POOLED_HITS:
        return 0.0
    expected = 0.0
    if baseline is not None:
        known, seen_m = background_knocks(baseline)
        if seen_m > 0:
            expected = (known + 0.5) / seen_m * travel
            if float(stats.poisson.sf(hits - 1, expected)) >= BEYOND_BACKGROUND_P:
                return 0.0
    return max(hits - expected, 0.0) / travel * loop_length_m


def residual_step(
    recording: Recording,
    model_torque_nm: FloatArray,
    phases: list[Phase],
    orders: Sequence[float] = (),
    impacts: Sequence[Impact] = (),
    margin_s: tuple[float, float] = (0.0, 0.0),
) -> float:
    """How far the constant-speed residual's level moves within a plateau, Nm.

    An item caught for part of a plateau (a drag) lifts the torque for its
    duration: the residual (measured less model torque) averaged over
    :data:`STEP_BOX_S` steps up and back down. This is the largest range
    (highest less lowest) of that running average over the constant phases,
    each less its first :data:`SETTLE_S` and last :data:`EDGE_S` and less
    the speed-locked ``orders``' periodic content (:func:`less_periodic`,
    as the impact search takes it away). It needs no quiet head and no
    :data:`MIN_PLATEAU_S`, so a 1 ms scope's plateau, too short for the
    impact search, has one too. A healthy conveyor's value is its noise
    and slow ripple averaged (a baseline learns it); a change of the load
    or the losses moves the whole plateau and leaves it as it was.

    The samples of ``impacts`` the search found (from ``margin_s[0]``
    before each to ``margin_s[1]`` after it) are set to the plateau's
    median first: what the search explained (an obstacle's knock, which
    keeps up to half its height in the average) is no step of the level.

    Returns
    -------
    float
        The range, Nm; NaN when no constant phase spans two averaging
        windows after its edges.
    """
    dt = recording.sample_time_s
    residual = recording.torque - model_torque_nm
    edge = int(np.ceil(EDGE_S / dt))
    settle = int(np.ceil(SETTLE_S / dt))
    box = max(1, round(STEP_BOX_S / dt))
    angle = recording.position
    if angle is None:
        angle = np.cumsum(recording.speed) * dt
    best = float("nan")
    for ph in phases:
        lo, hi = ph.start + settle, ph.stop - edge
        if ph.kind != "constant" or hi - lo < 2 * box:
            continue
        r = residual[lo:hi] - median(residual[lo:hi])
        t = recording.time[lo:hi]
        for hit in impacts:
            r[(t >= hit.t_s - margin_s[0]) & (t <= hit.t_s + hit.duration_s + margin_s[1])] = 0.0
        flat = less_periodic(r, angle[lo:hi], orders)
        # only whole windows: the edges' partial averages would repeat the end samples
        level = uniform_filter1d(flat, size=box, mode="nearest")[
            box // 2 : flat.shape[0] - box // 2
        ]
        moved = float(np.max(level) - np.min(level))
        best = moved if not best >= moved else best
    return best
