"""Window integrals of a recording: the regressors of the rigid model.

The rigid model on the motor shaft (docs/design.md, section 2) is linear in the
unknowns::

    T_m = J_d·α + M·(r/i)·g_f·α                    drive and belt inertia
        + g·cosβ·μ·M·g_f·sign(ω) + g·sinβ·(m_t+m_p)·g_f     belt resistance
        + BmA·sign(ω) + BmB·ω + BmC·ω·|ω|          gear and motor losses

with ``g_f = r/(i·η)`` while power flows motor → belt and ``r·η/i`` while the
belt drives the motor, M = m_b + m_t + m_p. Rather than differentiate a noisy
speed, each term is integrated over short windows (the integral form
``J·(ω(t₂) − ω(t₁)) = ∫(T_m − ...)dt``): the inertia regressor becomes a
speed difference, everything else a time integral of measured quantities.

Which side the power flows from is decided per sample by the one power-flow
rule, :func:`chaintwin.model.rigid.motoring_mask`. It needs J_d and the
losses, so estimators start from the profile's motor + gear inertia with zero
losses and repeat with their own estimates.

Windows lie inside the moving part of the recording, away from standstill
(the Coulomb sign terms and stiction make standstill samples useless), and
hold ``window`` samples each (non-overlapping, so that their noise is
nearly independent).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import numpy.typing as npt
from numba import njit

from chaintwin._types import FloatArray
from chaintwin.errors import EstimationError
from chaintwin.model.rigid import motoring_mask
from chaintwin.physics import gear_factor
from chaintwin.read.profile import ConveyorProfile
from chaintwin.read.recording import Recording
from chaintwin.validate.filters import gradient
from chaintwin.validate.phases import Phase, segment

__all__ = [
    "DEFAULT_WINDOW_S",
    "WindowIntegrals",
    "window_integrals",
]

DEFAULT_WINDOW_S = 0.05
"""Default window length, s (at least 4 samples)."""

MIN_SPEED_SHARE = 0.08
"""Samples below this share of the peak speed are left out (stiction, sign)."""


@dataclass(frozen=True, slots=True)
class WindowIntegrals:
    """Per-window integrals of one recording (arrays of length n_windows).

    All integrals are over the window's time span, SI units.

    Attributes
    ----------
    t0, t1 : FloatArray
        Window start and end, s.
    torque : FloatArray
        ∫T_m dt, N·m·s.
    d_speed : FloatArray
        ω(t₁) − ω(t₀), rad/s (inertia regressor of the drive side).
    sign : FloatArray
        ∫sign(ω) dt, s (BmA).
    speed : FloatArray
        ∫ω dt, rad (BmB).
    speed_sq : FloatArray
        ∫ω·|ω| dt, rad²/s (BmC).
    gf_sign : FloatArray
        ∫g_f·sign(ω) dt, m·s (friction: × μ·g·cosβ·M; payload: × g·cosβ·μ).
    gf : FloatArray
        ∫g_f dt, m·s (incline: × g·sinβ·mass).
    gf_accel : FloatArray
        Σ g_f·Δω over the window, m/s (belt inertia: × M·r/i).
    constant : np.ndarray
        True for windows at (nearly) constant set point speed.
    mean_speed : FloatArray
        Mean |ω| in the window, rad/s.
    duration : FloatArray
        t₁ − t₀, s.
    kind : np.ndarray
        0 for a short window, 1 for a whole-ramp window.
    ripple : FloatArray
        n × 4: ∫ω²·cos(k·z·ψ) dt and ∫ω²·sin(k·z·ψ) dt for k = 1, 2, with ψ
        the sprocket angle from the position channel (tooth-pass ripple of
        the polygon effect); n × 0 when position or tooth count is unknown.
    """

    t0: FloatArray
    t1: FloatArray
    torque: FloatArray
    d_speed: FloatArray
    sign: FloatArray
    speed: FloatArray
    speed_sq: FloatArray
    gf_sign: FloatArray
    gf: FloatArray
    gf_accel: FloatArray
    constant: np.ndarray
    mean_speed: FloatArray
    duration: FloatArray
    kind: np.ndarray
    ripple: FloatArray

    @property
    def count(self) -> int:
        """Number of windows."""
        return int(self.t0.shape[0])

    def select(self, mask: np.ndarray) -> WindowIntegrals:
        """Return the windows where ``mask`` is True."""
        return WindowIntegrals(**{name: getattr(self, name)[mask] for name in self.__slots__})


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    padded = np.concatenate(([False], mask, [False])).astype(np.int8)
    edges = np.flatnonzero(np.diff(padded))
    return [(int(a), int(b)) for a, b in zip(edges[0::2], edges[1::2], strict=True)]


def _misses(mask: np.ndarray) -> npt.NDArray[np.int64]:
    """Prefix count of the False entries of a mask, length n + 1.

    ``mask[a:b].all()`` is ``misses[b] == misses[a]`` for ``0 <= a <= b <= n``:
    the window loops ask that a few hundred times per recording, where a
    numpy reduction per slice cost more than the integrals themselves.
    """
    out: npt.NDArray[np.int64] = np.zeros(mask.shape[0] + 1, dtype=np.int64)
    np.cumsum(~mask.astype(bool), out=out[1:])
    return out


def _window_bounds(
    recording: Recording,
    phases: list[Phase],
    moving: np.ndarray,
    n_win: int,
    corner_s: float,
    settle_s: float,
    average_s: float,
    dt: float | None = None,
) -> npt.NDArray[np.int64]:
    """Windows as rows (start_lo, start_hi, end_lo, end_hi, kind) of sample indices.

    Kind 0: a short window (single start and end). Kind 1: a ramp window
    between the ramp's middle half and the plateau; its ends are averaged over
    spans of samples (``average_s`` in the plateau), which averages out the
    belt's ringing (a lightly damped belt still swings after a corner, so its
    momentum differs from the rigid model's at any one instant). ``dt`` is
    the median sample time, s (computed from the recording when not given).
    """
    if dt is None:
        dt = recording.sample_time_s
    corner = max(1, round(corner_s / dt))
    settle = max(1, round(settle_s / dt))
    spread = max(0, round(average_s / dt))
    n = int(moving.shape[0])
    misses = _misses(moving)
    out: list[npt.NDArray[np.int64]] = []
    for k, ph in enumerate(phases):
        if not ph.moving:
            continue
        prev = phases[k - 1] if k > 0 else None
        nxt = phases[k + 1] if k + 1 < len(phases) else None
        # short windows, away from the phase's corners (belt ringing, breakaway):
        # every n_win samples from a while the window fits before b, where the
        # speed is above the threshold throughout (the end sample included)
        a = ph.start + (settle if ph.kind == "constant" else corner)
        b = ph.stop - corner
        starts = np.arange(a, b - n_win + 1, n_win, dtype=np.int64)
        starts = starts[misses[np.minimum(starts + n_win + 1, n)] == misses[starts]]
        ends = starts + n_win
        out.append(np.column_stack((starts, starts, ends, ends, np.zeros_like(starts))))
        # one window per ramp between steady states: from the middle of the ramp
        # (belt and motor accelerate alike there; the start's breakaway and the
        # stop's wind-up of an elastic belt are left out) to the plateau, or from
        # the plateau into the ramp. Ends are averaged over a span, which also
        # averages out the ringing of a lightly damped belt.
        if ph.kind not in ("accelerate", "decelerate"):
            continue
        lo, hi = ph.start + corner, ph.stop - corner
        if hi <= lo or misses[min(hi + 1, n)] != misses[lo]:
            continue
        row: tuple[int, int, int, int, int] | None = None
        if nxt is not None and nxt.kind == "constant" and ph.kind == "accelerate":
            e_lo = min(nxt.stop - 1, nxt.start + settle)
            e_hi = min(nxt.stop - 1, e_lo + spread)
            row = (lo, max(lo, hi - corner), e_lo, e_hi, 1)
        elif prev is not None and prev.kind == "constant" and ph.kind == "decelerate":
            s_hi = max(prev.start, ph.start - corner)
            s_lo = min(s_hi, max(prev.start + settle, s_hi - spread))
            row = (s_lo, s_hi, min(lo + corner, hi), hi, 1)
        if row is not None:
            out.append(np.array([row], dtype=np.int64))
    if not out:
        return np.zeros((0, 5), dtype=np.int64)
    return np.concatenate(out)


@lru_cache(maxsize=256)
def _hann_weights(length: int) -> tuple[FloatArray, float]:
    """Interior of ``np.hanning(length + 2)`` (``length`` positive weights) and their sum."""
    weights = np.hanning(length + 2)[1:-1]
    weights.setflags(write=False)
    return weights, float(weights.sum())


@njit(cache=True, nogil=True)
def _running_integrals(
    f: np.ndarray, t: np.ndarray, w: np.ndarray, gf: np.ndarray, h: np.ndarray
) -> np.ndarray:  # pragma: no cover - compiled; tested through window_integrals
    """The table of :func:`window_integrals`: t, ω, then the running trapezoid
    integrals (from 0) of each row of ``f``, of Σ g_f·Δω and of ∫|ω| dt.

    The arithmetic of ``np.cumsum`` over the per-step trapezoids
    ``0.5 · (f[i + 1] + f[i]) · h[i]`` (the same numbers), in one pass.
    """
    m, n = f.shape
    table = np.empty((n, m + 4))
    for i in range(n):
        table[i, 0] = t[i]
        table[i, 1] = w[i]
    for c in range(m + 2):
        table[0, 2 + c] = 0.0
    for i in range(n - 1):
        for c in range(m):
            step = 0.5 * (f[c, i + 1] + f[c, i]) * h[i]
            table[i + 1, 2 + c] = step if i == 0 else table[i, 2 + c] + step
        step = 0.5 * (gf[i + 1] + gf[i]) * (w[i + 1] - w[i])  # Σ g_f·Δω
        table[i + 1, 2 + m] = step if i == 0 else table[i, 2 + m] + step
        step = abs(0.5 * (w[i + 1] + w[i])) * h[i]  # ∫|ω| dt
        table[i + 1, 3 + m] = step if i == 0 else table[i, 3 + m] + step
    return table


def window_integrals(
    recording: Recording,
    profile: ConveyorProfile,
    *,
    motoring: np.ndarray | None = None,
    window_s: float = DEFAULT_WINDOW_S,
    torque_channel: str = "torque",
    min_speed_share: float = MIN_SPEED_SHARE,
    corner_s: float = 0.1,
    settle_s: float = 0.4,
    average_s: float = 0.6,
    span: tuple[float, float] | None = None,
    phases: list[Phase] | None = None,
) -> WindowIntegrals:
    """Integrate the rigid model's regressors over windows of a recording.

    Two kinds of window: short ones (``window_s``) inside each moving phase,
    ``corner_s`` away from the ramp corners and ``settle_s`` into a constant
    phase (the belt rings after a corner), which resolve how the torque
    depends on speed; and one per ramp between two steady states, from the
    ramp's middle to the plateau (``settle_s`` in, averaged over
    ``average_s``) or back, over which the integral form holds for an elastic
    belt too: belt and motor move alike at both ends. The start of motion
    (breakaway, the belt winding up) and the stop (the belt overshooting and
    staying wound up against the holding drive) are left out of them.

    Parameters
    ----------
    recording : Recording
        The recording (SI).
    profile : ConveyorProfile
        Supplies r, i, η (its ``model:`` section is not read).
    motoring : np.ndarray of bool, optional
        Power-flow direction per sample (:func:`motoring_mask`); default from
        the profile's motor + gear inertia and zero losses.
    window_s : float
        Short window length, s (at least 4 samples).
    torque_channel : {"torque", "torque_setpoint"}
        Which torque to explain: the actual torque (default) or the speed
        controller's set point (free of measurement noise, one lag earlier).
    min_speed_share : float
        Short windows leave out samples below this share of the peak speed.
    corner_s, settle_s : float
        Margins after ramp corners and into plateaus, s.
    average_s : float
        A whole-ramp window's end in a plateau is averaged over this span, s.
    span : (float, float), optional
        Only windows inside this time span, s.
    phases : list of Phase, optional
        The recording's movement phases, when already computed
        (:func:`~chaintwin.validate.phases.segment`).

    Returns
    -------
    WindowIntegrals

    Raises
    ------
    EstimationError
        When the recording holds no moving part long enough for one window.
    """
    t = recording.time
    w = recording.speed
    torque = recording.channels.get(torque_channel)
    if torque is None:
        raise EstimationError(f"{recording.source}: has no {torque_channel} channel")
    if motoring is None:
        motoring = motoring_mask(
            recording,
            drive_inertia_kgm2=profile.motor.inertia_kgm2 + profile.gear.inertia_kgm2,
            torque_channel=torque_channel,
        )
    r = profile.chordal_radius_m
    i = profile.kinematic_ratio
    eta = profile.gear.efficiency
    gf = (r / i) * np.where(
        motoring, gear_factor(eta, motoring=True), gear_factor(eta, motoring=False)
    )
    sgn = np.sign(w)

    wsp = recording.speed_setpoint
    basis = wsp if wsp is not None and np.any(wsp != 0.0) else w
    peak = float(np.max(np.abs(basis)))
    if peak <= 0.0:
        raise EstimationError(f"{recording.source}: the conveyor does not move")
    moving = (np.abs(w) >= min_speed_share * peak) & (np.abs(basis) >= min_speed_share * peak)
    if phases is None:
        phases = segment(recording)
    if basis is wsp:
        # constant set point: |dω_sp/dt| small against the peak acceleration
        dbasis = np.abs(gradient(basis, t))
        steady = dbasis <= 0.02 * max(float(np.max(dbasis)), 1e-12)
    else:
        # no set point: the differentiated actual speed is noise; the
        # segmentation's constant phases (smoothed speed, noise-based
        # thresholds) say where the speed is steady
        steady = np.zeros(t.shape[0], dtype=bool)
        for ph in phases:
            if ph.kind == "constant":
                steady[ph.start : ph.stop] = True

    h = np.diff(t)
    dt = recording.sample_time_s  # float(np.median(h)), computed once per recording
    n_win = max(4, round(window_s / dt))

    bounds = _window_bounds(recording, phases, moving, n_win, corner_s, settle_s, average_s, dt)
    if span is not None:
        keep = (t[bounds[:, 0]] >= span[0]) & (t[bounds[:, 3]] <= span[1])
        bounds = bounds[keep]
    if bounds.shape[0] == 0:
        raise EstimationError(
            f"{recording.source}: no moving part of {n_win} samples above "
            f"{min_speed_share:.0%} of peak speed; nothing to identify"
        )
    s_lo, s_hi, e_lo, e_hi, kind = bounds.T

    # the integrands per sample; their per-step trapezoid integrals (n − 1)
    # and the running integrals (n, from 0) in one table, beside t and ω
    teeth = profile.sprocket.teeth
    theta = recording.position
    samples = [torque, sgn, w, w * np.abs(w), gf * sgn, gf]
    if teeth and theta is not None:
        psi = theta * (teeth / i)  # tooth-pass phase from the motor angle
        w2 = w * w
        for harmonic in (1.0, 2.0):
            samples += [w2 * np.cos(harmonic * psi), w2 * np.sin(harmonic * psi)]
    m = len(samples)
    table = _running_integrals(
        np.array(samples, dtype=np.float64),
        np.ascontiguousarray(t, dtype=np.float64),
        np.ascontiguousarray(w, dtype=np.float64),
        np.ascontiguousarray(gf, dtype=np.float64),
        np.ascontiguousarray(h, dtype=np.float64),
    )

    def avg(lo: np.ndarray, hi: np.ndarray) -> FloatArray:
        """Hann-weighted mean of the table's rows over [lo, hi], per window.

        A taper rather than a plain mean: a sinusoid (the belt's ringing) leaks
        into a plain mean as 1/(f·L), into a Hann-weighted one as 1/(f·L)³.
        """
        out: FloatArray = table[lo]
        for j in np.flatnonzero(hi > lo).tolist():
            a, b = int(lo[j]), int(hi[j])
            weights, total = _hann_weights(b - a + 1)
            out[j] = (weights @ table[a : b + 1]) / total
        return out

    at_start = avg(s_lo, s_hi)
    at_end = avg(e_lo, e_hi)
    t0, t1 = at_start[:, 0], at_end[:, 0]
    integral = at_end[:, 2:] - at_start[:, 2:]  # from the (averaged) start to the end
    steady_misses = _misses(steady)
    steady_win = (steady_misses[np.minimum(e_hi + 1, t.shape[0])] == steady_misses[s_lo]) & (
        kind == 0
    )
    return WindowIntegrals(
        t0=t0,
        t1=t1,
        torque=integral[:, 0],
        d_speed=at_end[:, 1] - at_start[:, 1],
        sign=integral[:, 1],
        speed=integral[:, 2],
        speed_sq=integral[:, 3],
        gf_sign=integral[:, 4],
        gf=integral[:, 5],
        gf_accel=integral[:, m],
        constant=steady_win,
        mean_speed=integral[:, m + 1] / (t1 - t0),
        duration=t1 - t0,
        kind=kind,
        ripple=integral[:, 6:m],
    )
