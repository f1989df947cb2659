"""Amplitude spectra of drive channels: Welch, order analysis, band amplitudes.

DESIGN.md, section 3, "Spectra": FFT/Welch with log amplitude, order
analysis by resampling the torque to equal steps of motor angle, and band
amplitudes at the conveyor's characteristic lines as features.

Amplitude scale
---------------
Every :class:`Spectrum` holds a single-sided *amplitude* spectrum in the
channel's SI unit (Nm for torque): a sinusoid ``A·sin(2πft)`` shows as ``A``
at its bin. The Hann window's coherent gain (0.5) is divided out, that is the
spectrum is normalised by ``Σw`` instead of the number of samples. A line
that falls between two bins reads low (the Hann window's scalloping loss);
both spectra are zero-padded to twice the segment length, so the bin spacing
(:attr:`Spectrum.resolution`) is half the true resolution ``1/(N·Ts)`` and
the worst-case loss is about 4 % instead of 15 %. Broadband noise is not
calibrated by this scale (it would need the noise bandwidth instead).

Aliasing
--------
Drive scopes sample without an anti-alias filter: a line above the Nyquist
frequency ``fs/2`` folds into ``[0, fs/2]``
(:func:`~chaintwin.model.frequencies.fold_frequency`). Bearing and gear
lines often lie above it for 6 and 12 ms scopes; :func:`apparent_order`
gives where to look for them. Order analysis cannot undo this: the samples
are already aliased when they are resampled to equal angle steps, so in an
order spectrum too a line above ``fs/2`` appears folded. At constant speed
the folded line sits at ``apparent_order(order, speed_rpm, Ts)``; while the
speed changes it moves and smears, like any line in a plain FFT. That is
why :func:`welch_spectrum` defaults to the constant-speed plateau, where
folded lines stay put.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Literal

import numpy as np
import numpy.typing as npt
from scipy import fft as scipy_fft
from scipy.integrate import cumulative_trapezoid
from scipy.signal import ShortTimeFFT, get_window
from scipy.signal.windows import hann

from chaintwin._types import FloatArray
from chaintwin.errors import EstimationError, RecordingError
from chaintwin.model.frequencies import (
    characteristic_orders,
    fold_frequencies,
    fold_frequency,
)
from chaintwin.read.profile import ConveyorProfile
from chaintwin.read.recording import Recording
from chaintwin.units import RPM_TO_RAD_S
from chaintwin.validate.phases import segment

__all__ = [
    "MIN_SPEED_RPM",
    "Spectrum",
    "SpectrumKind",
    "apparent_order",
    "apparent_orders",
    "band_amplitude",
    "band_amplitudes",
    "line_amplitudes",
    "line_orders",
    "median_spectrum",
    "novel_peaks",
    "order_spectrum",
    "plot_spectrum",
    "strongest_peaks",
    "welch_spectrum",
]

SpectrumKind = Literal["frequency", "order"]

MIN_SPEED_RPM = 1.0
"""Below this mean speed, rpm, the motor counts as standing: no speed-locked lines."""

_ZERO_PAD = 2
"""FFT length over segment length: halves the bin spacing, cuts the scalloping loss."""

_MIN_SAMPLES = 16
"""Fewest samples a spectrum is computed from."""

_MIN_NPERSEG = 64
"""Shortest default Welch segment, samples."""

_WELCH_AVERAGES = 8
"""Segments the default Welch segment length aims at (50 % overlap)."""

_TREND_DEGREE = 3
"""Degree of the polynomial in angle removed before the order FFT."""

_POSITION_TOLERANCE = 0.1
"""Largest relative disagreement between position and integrated speed over a run."""


@dataclass(frozen=True)
class Spectrum:
    """A single-sided amplitude spectrum of one channel.

    Parameters
    ----------
    x : FloatArray
        Bin positions: frequency, Hz, for kind ``"frequency"``; order (cycles
        per motor revolution) for kind ``"order"``. Equally spaced from 0.
    amplitude : FloatArray
        Amplitude at each bin in the channel's SI unit (Nm for torque): a
        sinusoid of amplitude A reads A at its bin (Hann coherent gain divided
        out; see the module docstring for the scalloping loss).
    kind : {"frequency", "order"}
        What ``x`` measures.
    resolution : float
        Bin spacing, Hz or orders (half the true resolution: zero-padded ×2).
    channel : str
        The channel analysed (``torque``, ``speed``, ...).
    speed_rpm : float
        Mean absolute motor speed over the analysed samples, rpm.
    """

    x: FloatArray
    amplitude: FloatArray
    kind: SpectrumKind
    resolution: float
    channel: str
    speed_rpm: float


# ------------------------------------------------------------------ helpers
def _channel(recording: Recording, channel: str) -> FloatArray:
    """The channel's samples as float64, checked to be finite."""
    if channel not in recording.channels:
        raise RecordingError(
            recording.source,
            f"has no channel '{channel}' (it has {', '.join(recording.channels)}); "
            "choose a recorded channel",
        )
    data = np.asarray(recording.channels[channel], dtype=np.float64)
    if not np.all(np.isfinite(data)):
        raise RecordingError(
            recording.source, f"channel '{channel}' holds non-finite values; cannot analyse it"
        )
    return data


def _amplitude_from_fft(
    fft: npt.NDArray[np.complex128], window_sum: float, nfft: int
) -> FloatArray:
    """Single-sided amplitude from an rfft of a windowed signal (coherent gain out)."""
    amp: FloatArray = 2.0 * np.abs(fft) / window_sum
    amp[0] *= 0.5  # DC is not folded onto a negative frequency
    if nfft % 2 == 0:
        amp[-1] *= 0.5  # nor is the Nyquist bin
    return amp


def _longest_run(mask: npt.NDArray[np.bool_]) -> tuple[int, int]:
    """``(start, stop)`` of the longest run of True in a boolean array ((0, 0) if none)."""
    padded = np.concatenate(([False], mask, [False])).astype(np.int8)
    edges = np.flatnonzero(np.diff(padded))
    if edges.size == 0:
        return 0, 0
    starts, stops = edges[0::2], edges[1::2]
    k = int(np.argmax(stops - starts))
    return int(starts[k]), int(stops[k])


def _plateau(recording: Recording) -> tuple[int, int]:
    """The longest constant-speed phase, or the whole recording when it is too short."""
    constant = [p for p in segment(recording) if p.kind == "constant"]
    if constant:
        best = max(constant, key=lambda p: p.stop - p.start)
        if best.stop - best.start >= _MIN_NPERSEG:
            return best.start, best.stop
    return 0, recording.samples


def _default_nperseg(n: int) -> int:
    """A power of two giving about eight 50 %-overlapping segments, at least 64, at most n."""
    target = 2.0 * n / (_WELCH_AVERAGES + 1)
    nperseg = 2 ** max(0, round(math.log2(max(target, 1.0))))
    return int(min(max(nperseg, _MIN_NPERSEG), n))


@lru_cache(maxsize=32)
def _welch_plan(
    nperseg: int, nfft: int, sample_time_s: float
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """What a Welch spectrum of one segment length needs, computed once.

    Returns
    -------
    window : FloatArray
        The periodic Hann window divided by its sum (amplitude scaling), as
        ``scipy.signal.welch`` builds it (its ``ShortTimeFFT``).
    freq : FloatArray
        The one-sided frequencies, Hz, as scipy gives them.
    detrend : FloatArray
        ``nperseg × 2`` regressors of the linear detrend (``scipy.signal.detrend``'s
        ramp ``1..N``/N and ones), followed by their pseudo-inverse (2 × nperseg),
        stacked as ``(nperseg + 2) × ...``: see :func:`_welch_power`.
    """
    sft = ShortTimeFFT(
        get_window("hann", nperseg),
        nperseg - nperseg // 2,
        1.0 / sample_time_s,
        fft_mode="onesided",
        mfft=nfft,
        scale_to="magnitude",
        phase_shift=None,
    )
    window = np.array(sft.win, dtype=np.float64)
    freq = np.array(sft.f, dtype=np.float64)
    ramp = np.ones((nperseg, 2))
    ramp[:, 0] = np.arange(1, nperseg + 1, dtype=np.float64) / nperseg
    fit = np.linalg.pinv(ramp)
    detrend = np.vstack((ramp.T, fit))  # rows: ramp, ones, then the fit's two rows
    for arr in (window, freq, detrend):
        arr.setflags(write=False)
    return window, freq, detrend


def _welch_power(
    data: FloatArray, sample_time_s: float, nperseg: int, nfft: int, average: str
) -> tuple[FloatArray, FloatArray]:
    """``scipy.signal.welch(data, 1/Ts, "hann", nperseg, nperseg // 2, nfft, "linear",
    scaling="spectrum", average=average)``, to rounding, without its per-call set-up.

    The segments (hop ``nperseg - nperseg // 2``, as many as fit) are detrended,
    windowed and transformed together; the one-sided power is averaged over
    them with the mean, or with the median divided by scipy's bias factor.
    """
    window, freq, plan = _welch_plan(nperseg, nfft, sample_time_s)
    hop = nperseg - nperseg // 2
    count = (data.shape[0] - nperseg // 2) // hop
    segments = np.lib.stride_tricks.sliding_window_view(data, nperseg)[::hop][:count]
    ramp, fit = plan[:2], plan[2:]
    detrended = segments - (segments @ fit.T) @ ramp
    spec = scipy_fft.rfft(detrended * window, n=nfft, axis=-1)
    power = spec.real**2 + spec.imag**2
    power[:, 1:-1] *= 2.0  # one-sided (nfft is even: the last bin is Nyquist)
    if count == 1:
        return freq, power[0]
    if average == "median":
        ii_2 = 2 * np.arange(1.0, (count - 1) // 2 + 1)
        bias = 1 + np.sum(1.0 / (ii_2 + 1) - 1.0 / ii_2)
        out: FloatArray = np.median(power, axis=0) / bias
        return freq, out
    return freq, power.mean(axis=0)


# ------------------------------------------------------------------ spectra
def welch_spectrum(
    recording: Recording,
    channel: str = "torque",
    *,
    span: tuple[int, int] | None = None,
    nperseg: int | None = None,
    average: Literal["mean", "median"] = "mean",
) -> Spectrum:
    """Welch amplitude spectrum of a channel, by default over the constant-speed plateau.

    Hann window, 50 % overlap, linear detrend per segment, zero-padded to
    twice the segment length; ``scipy.signal.welch`` with
    ``scaling="spectrum"`` converted to amplitude as ``sqrt(2·Pxx)`` (DC and
    Nyquist bins ``sqrt(Pxx)``). Lines above the Nyquist frequency appear
    folded (see the module docstring).

    Parameters
    ----------
    recording : Recording
        The recording.
    channel : str
        Channel name (``torque``, ``speed``, ...); the amplitude is in its SI unit.
    span : tuple of int, optional
        Sample index range ``[start, stop)`` to analyse. Default: the longest
        ``constant`` phase of :func:`~chaintwin.validate.phases.segment` (the
        plateau, where folded lines stay put), or the whole recording when
        there is none of at least 64 samples.
    nperseg : int, optional
        Segment length, samples. Default: the power of two giving about
        eight averages, at least 64 (at most the span).
    average : {"mean", "median"}
        How the segments' periodograms are averaged. The median ignores
        what only one segment holds (a transient: an obstruction passed once,
        a bump at a ramp corner) and keeps what repeats in every segment
        (shaft, mesh and bearing lines); scipy corrects its bias for a
        Gaussian background.

    Returns
    -------
    Spectrum
        Kind ``"frequency"``, ``x`` in Hz up to ``0.5/Ts``.

    Raises
    ------
    RecordingError
        When the channel is missing or not finite.
    EstimationError
        When the span is out of range or shorter than 16 samples, or
        ``nperseg`` is not between 16 and the span's length.
    """
    data = _channel(recording, channel)
    n_all = data.shape[0]
    start, stop = _plateau(recording) if span is None else (int(span[0]), int(span[1]))
    if not 0 <= start < stop <= n_all or stop - start < _MIN_SAMPLES:
        raise EstimationError(
            f"{recording.source}: span [{start}, {stop}) is not a range of at least "
            f"{_MIN_SAMPLES} samples within the recording's {n_all}"
        )
    n = stop - start
    seg = _default_nperseg(n) if nperseg is None else int(nperseg)
    if not _MIN_SAMPLES <= seg <= n:
        raise EstimationError(
            f"{recording.source}: nperseg={seg} must be between {_MIN_SAMPLES} and the "
            f"span's {n} samples"
        )
    ts = recording.sample_time_s
    nfft = _ZERO_PAD * seg
    freq, pxx = _welch_power(data[start:stop], ts, seg, nfft, average)
    amp = np.sqrt(2.0 * np.asarray(pxx, dtype=np.float64))
    amp[0] = math.sqrt(float(pxx[0]))
    amp[-1] = math.sqrt(float(pxx[-1]))  # nfft is even: the last bin is Nyquist
    speed_rpm = float(np.mean(np.abs(recording.speed[start:stop]))) / RPM_TO_RAD_S
    return Spectrum(
        x=np.asarray(freq, dtype=np.float64),
        amplitude=amp,
        kind="frequency",
        resolution=1.0 / (nfft * ts),
        channel=channel,
        speed_rpm=speed_rpm,
    )


def _motor_angle(recording: Recording, start: int, stop: int) -> FloatArray:
    """Motor angle over ``[start, stop)``, rad, from 0 and increasing.

    The position channel when it agrees with the integrated speed within
    10 % over the run (it may wrap, or be scaled wrongly), else the speed
    integrated with the trapezoidal rule.
    """
    integrated: FloatArray = cumulative_trapezoid(
        recording.speed[start:stop], recording.time[start:stop], initial=0.0
    )
    theta = integrated
    position = recording.position
    if position is not None:
        pos = np.asarray(position[start:stop], dtype=np.float64) - float(position[start])
        if np.all(np.isfinite(pos)) and math.isclose(
            float(pos[-1]), float(integrated[-1]), rel_tol=_POSITION_TOLERANCE
        ):
            theta = pos
    if theta[-1] < 0.0:
        theta = -theta  # backward movement: angle travelled
    return np.asarray(np.maximum.accumulate(theta), dtype=np.float64)


def order_spectrum(
    recording: Recording,
    channel: str = "torque",
    *,
    min_speed_share: float = 0.3,
    oversample: float = 1.0,
) -> Spectrum:
    """Order spectrum: the channel resampled to equal steps of motor angle.

    Speed-locked lines stay at their order while the speed changes, so a
    ramp does not smear them as it does in a plain FFT.

    1. Take the longest contiguous run of samples where
       ``|speed| ≥ min_speed_share × peak |speed|``.
    2. Motor angle: the position channel (made to increase for a backward
       move), or the integrated speed (cumulative trapezoid) when there is no
       position channel or it disagrees with the speed by more than 10 %.
    3. Resample the channel (linear interpolation) to equal angle steps
       ``Δθ = ω_mean·Ts/oversample``: as many samples per revolution as the
       scope took on average, times ``oversample``.
    4. Remove the slow trend (the torque follows the speed profile): a
       polynomial of degree 3 in angle, least squares. Steps in the trend
       (acceleration torque ending with a ramp) are not removed; they leak
       into the lowest few bins, which are therefore not lines.
    5. Hann window, FFT zero-padded to twice the length, coherent gain
       divided out.

    Lines above the scope's Nyquist frequency were folded before resampling
    and stay folded (see the module docstring and :func:`apparent_order`).
    Orders above ``π/Δθ`` per revolution do not exist in the result; with
    ``oversample > 1`` the orders above the scope's own Nyquist order hold
    only interpolation images.

    Parameters
    ----------
    recording : Recording
        The recording.
    channel : str
        Channel name; the amplitude is in its SI unit.
    min_speed_share : float
        Share of the peak absolute speed above which samples are used, in (0, 1].
    oversample : float
        Angle samples per scope sample at the mean speed, > 0.

    Returns
    -------
    Spectrum
        Kind ``"order"``, ``x`` in cycles per motor revolution.

    Raises
    ------
    RecordingError
        When the channel is missing or not finite.
    EstimationError
        When the options are out of range, the conveyor does not move, or the
        run above the speed threshold is shorter than 16 samples.
    """
    if not 0.0 < min_speed_share <= 1.0:
        raise EstimationError(f"min_speed_share={min_speed_share} must be in (0, 1]")
    if not math.isfinite(oversample) or oversample <= 0.0:
        raise EstimationError(f"oversample={oversample} must be a positive number")
    data = _channel(recording, channel)
    speed = np.abs(np.asarray(recording.speed, dtype=np.float64))
    peak = float(np.max(speed)) if speed.size else 0.0
    if not math.isfinite(peak) or peak <= 0.0:
        raise EstimationError(f"{recording.source}: the motor does not turn; no order spectrum")
    start, stop = _longest_run(speed >= min_speed_share * peak)
    if stop - start < _MIN_SAMPLES:
        raise EstimationError(
            f"{recording.source}: only {stop - start} samples at or above "
            f"{min_speed_share:g} × peak speed; need {_MIN_SAMPLES} for an order spectrum"
        )
    theta = _motor_angle(recording, start, stop)
    keep = np.concatenate(([True], np.diff(theta) > 0.0))
    theta, values = theta[keep], data[start:stop][keep]
    mean_speed = float(np.mean(speed[start:stop]))
    step = mean_speed * recording.sample_time_s / oversample
    n = math.floor(float(theta[-1]) / step) + 1
    if n < _MIN_SAMPLES:
        raise EstimationError(
            f"{recording.source}: the motor turns through only {theta[-1]:.3g} rad above the "
            "speed threshold; too little for an order spectrum"
        )
    grid = np.arange(n, dtype=np.float64) * step
    resampled = np.interp(grid, theta, values)
    trend = np.polynomial.Polynomial.fit(grid, resampled, _TREND_DEGREE)
    window = hann(n, sym=False)
    nfft = _ZERO_PAD * n
    fft = np.fft.rfft((resampled - trend(grid)) * window, nfft)
    amp = _amplitude_from_fft(fft, float(np.sum(window)), nfft)
    resolution = 2.0 * math.pi / (nfft * step)
    return Spectrum(
        x=np.arange(amp.shape[0], dtype=np.float64) * resolution,
        amplitude=amp,
        kind="order",
        resolution=resolution,
        channel=channel,
        speed_rpm=mean_speed / RPM_TO_RAD_S,
    )


# ------------------------------------------------------------------ lines
def band_amplitude(spectrum: Spectrum, centre: float, *, half_width_bins: int = 2) -> float:
    """Largest amplitude within ``±half_width_bins`` bins of ``centre``.

    The band absorbs a line's scatter in place (speed estimate, window
    leakage) and the zero-padded bin spacing (see :class:`Spectrum`).

    Parameters
    ----------
    spectrum : Spectrum
        The spectrum.
    centre : float
        Where to look, in the spectrum's ``x`` unit (Hz or order).
    half_width_bins : int
        Half width of the band, bins (≥ 0).

    Returns
    -------
    float
        The amplitude in the channel's SI unit; 0.0 when ``centre`` lies
        outside the spectrum's range.

    Raises
    ------
    EstimationError
        When ``half_width_bins`` is negative or ``centre`` is not finite.
    """
    if half_width_bins < 0:
        raise EstimationError(f"half_width_bins={half_width_bins} must be ≥ 0")
    if not math.isfinite(centre):
        raise EstimationError(f"band centre {centre!r} is not finite")
    x = spectrum.x
    if x.size == 0 or not float(x[0]) <= centre <= float(x[-1]):
        return 0.0
    k = int(np.argmin(np.abs(x - centre)))
    lo, hi = max(0, k - half_width_bins), min(x.shape[0], k + half_width_bins + 1)
    return float(np.max(spectrum.amplitude[lo:hi]))


def band_amplitudes(
    spectrum: Spectrum, centres: Sequence[float], *, half_width_bins: int = 2
) -> list[float]:
    """:func:`band_amplitude` at several centres at once, the same numbers.

    The bin nearest each centre is found by bisection of the ascending
    ``x`` (the nearer of the two bins around it, the lower one on a tie, as
    ``argmin`` of the distance picks it), and the band maximum by one
    gather, instead of a scan of the whole spectrum per centre.

    Parameters
    ----------
    spectrum : Spectrum
        The spectrum.
    centres : sequence of float
        Where to look, in the spectrum's ``x`` unit (Hz or order).
    half_width_bins : int
        Half width of the band, bins (≥ 0).

    Returns
    -------
    list of float
        The amplitude per centre in the channel's SI unit; 0.0 for a centre
        outside the spectrum's range.

    Raises
    ------
    EstimationError
        When ``half_width_bins`` is negative or a centre is not finite.
    """
    if half_width_bins < 0:
        raise EstimationError(f"half_width_bins={half_width_bins} must be ≥ 0")
    c = np.asarray(centres, dtype=np.float64).reshape(-1)
    if not np.all(np.isfinite(c)):
        bad = next(v for v in c.tolist() if not math.isfinite(v))
        raise EstimationError(f"band centre {bad!r} is not finite")
    x = spectrum.x
    size = x.shape[0]
    if size == 0 or c.shape[0] == 0:
        return [0.0] * c.shape[0]
    inside = (float(x[0]) <= c) & (c <= float(x[-1]))
    upper = np.clip(np.searchsorted(x, c), 0, size - 1)
    lower = np.maximum(upper - 1, 0)
    nearest = np.where(np.abs(x[lower] - c) <= np.abs(x[upper] - c), lower, upper)
    band = np.clip(nearest[:, None] + np.arange(-half_width_bins, half_width_bins + 1), 0, size - 1)
    peak = np.max(spectrum.amplitude[band], axis=1)
    out: list[float] = np.where(inside, peak, 0.0).tolist()
    return out


def apparent_order(order: float, speed_rpm: float, sample_time_s: float) -> float:
    """Where a line at ``order`` appears in a scope's spectrum, as an order.

    ``fold_frequency(order·f_rot, Ts) / f_rot`` with ``f_rot = |speed_rpm|/60``:
    a line above the Nyquist frequency ``0.5/Ts`` folds back (drive scopes
    have no anti-alias filter). Multiplied by ``f_rot`` it is the apparent
    frequency, Hz.

    Parameters
    ----------
    order : float
        The line's true order, cycles per motor revolution.
    speed_rpm : float
        Motor speed, rpm (the sign is ignored).
    sample_time_s : float
        The scope's sample time Ts, s.

    Returns
    -------
    float
        The apparent order, in ``[0, 30/(|speed_rpm|·Ts)]``.

    Raises
    ------
    EstimationError
        When the speed is zero or not finite.
    ModelError
        When the sample time is not positive or the order not finite.

    Examples
    --------
    A bearing line at order 3.57 and 1415 rpm is at 84.19 Hz, above the
    83.33 Hz Nyquist frequency of a 6 ms scope; it appears at 82.47 Hz:

    >>> round(apparent_order(3.57, 1415.0, 0.006), 4)
    3.4971
    """
    rot_hz = _rotation_hz(speed_rpm)
    return fold_frequency(order * rot_hz, sample_time_s) / rot_hz


def _rotation_hz(speed_rpm: float) -> float:
    """Motor revolutions per second, Hz, of a speed in rpm (the sign ignored).

    Raises
    ------
    EstimationError
        When the speed is zero or not finite.
    """
    rot_hz = abs(float(speed_rpm)) / 60.0
    if not math.isfinite(rot_hz) or rot_hz == 0.0:
        raise EstimationError(f"motor speed {speed_rpm!r} rpm: no apparent order without rotation")
    return rot_hz


def apparent_orders(
    orders: npt.ArrayLike, speed_rpm: float, sample_time_s: float
) -> npt.NDArray[np.float64]:
    """:func:`apparent_order` of many orders at once, with the same arithmetic.

    Parameters
    ----------
    orders : array_like
        True orders, cycles per motor revolution.
    speed_rpm : float
        Motor speed, rpm (the sign is ignored).
    sample_time_s : float
        The scope's sample time Ts, s.

    Returns
    -------
    ndarray
        The apparent orders, equal to ``apparent_order`` of each.

    Raises
    ------
    EstimationError
        When the speed is zero or not finite.
    ModelError
        When the sample time is not positive or an order not finite.
    """
    rot_hz = _rotation_hz(speed_rpm)
    return fold_frequencies(np.asarray(orders, dtype=np.float64) * rot_hz, sample_time_s) / rot_hz


def line_orders(profile: ConveyorProfile) -> dict[str, float]:
    """The speed-locked lines looked at, by name: orders per motor revolution.

    :func:`~chaintwin.model.frequencies.characteristic_orders` plus the 2nd
    and 3rd harmonics of the sprocket tooth pass (the polygon effect is not
    sinusoidal) as ``sprocket_tooth_pass_h2`` and ``sprocket_tooth_pass_h3``.

    Parameters
    ----------
    profile : ConveyorProfile
        The conveyor.

    Returns
    -------
    dict of str to float
        Line name to order.
    """
    orders = characteristic_orders(profile)
    tooth_pass = orders.get("sprocket_tooth_pass")
    if tooth_pass is not None:
        orders["sprocket_tooth_pass_h2"] = 2.0 * tooth_pass
        orders["sprocket_tooth_pass_h3"] = 3.0 * tooth_pass
    return orders


def line_amplitudes(
    recording: Recording, profile: ConveyorProfile, *, channel: str = "torque"
) -> dict[str, float]:
    """Band amplitudes at the characteristic lines in the plateau Welch spectrum.

    Each line of :func:`line_orders` is looked for where the scope shows it:
    at ``fold_frequency(order · f_rot, Ts)`` with ``f_rot`` the plateau's
    mean speed, ±2 bins (:func:`band_amplitude`). Lines slower than about
    two bins (output shaft and belt revolution on short plateaus) are not
    resolved: their value is leakage of the lowest bins, not the line.

    Parameters
    ----------
    recording : Recording
        The recording.
    profile : ConveyorProfile
        The conveyor.
    channel : str
        Channel name.

    Returns
    -------
    dict of str to float
        Line name to amplitude in the channel's SI unit (Nm for torque).

    Raises
    ------
    RecordingError
        When the channel is missing or not finite.
    EstimationError
        When the spectrum cannot be computed or the motor turns slower than
        :data:`MIN_SPEED_RPM` on the plateau.
    """
    spectrum = welch_spectrum(recording, channel)
    if spectrum.speed_rpm < MIN_SPEED_RPM:
        raise EstimationError(
            f"{recording.source}: the motor turns at {spectrum.speed_rpm:.2g} rpm on the "
            "analysed part; speed-locked lines need it to turn"
        )
    rot_hz = spectrum.speed_rpm / 60.0
    ts = recording.sample_time_s
    return {
        name: band_amplitude(spectrum, apparent_order(order, spectrum.speed_rpm, ts) * rot_hz)
        for name, order in line_orders(profile).items()
    }


# ------------------------------------------------------------------ peaks
def _local_maxima(amplitude: FloatArray) -> npt.NDArray[np.intp]:
    """Indices of interior local maxima (higher than the left, not lower than the right)."""
    a = amplitude
    if a.shape[0] < 3:
        return np.zeros(0, dtype=np.intp)
    inner = (a[1:-1] > a[:-2]) & (a[1:-1] >= a[2:])
    return np.flatnonzero(inner) + 1


def strongest_peaks(
    spectrum: Spectrum, *, top: int = 5, min_x: float = 0.0
) -> list[tuple[float, float]]:
    """The strongest local maxima of a spectrum.

    Parameters
    ----------
    spectrum : Spectrum
        The spectrum.
    top : int
        How many peaks at most.
    min_x : float
        Leave out peaks below this x (Hz or order), e.g. the lowest bins,
        which hold what the detrending left of the speed profile.

    Returns
    -------
    list of (float, float)
        ``(x, amplitude)`` per peak, strongest first; x in the spectrum's unit.
    """
    idx = _local_maxima(spectrum.amplitude)
    idx = idx[spectrum.x[idx] >= min_x]
    idx = idx[np.argsort(-spectrum.amplitude[idx], kind="stable")][: max(top, 0)]
    return [(float(spectrum.x[i]), float(spectrum.amplitude[i])) for i in idx]


def _check_same_kind(spectra: Sequence[Spectrum]) -> None:
    kinds = {s.kind for s in spectra}
    if len(kinds) > 1:
        raise EstimationError(
            f"cannot compare spectra of different kinds ({', '.join(sorted(kinds))}); "
            "use frequency or order spectra throughout"
        )


def novel_peaks(
    spectrum: Spectrum, reference: Spectrum, *, min_ratio: float = 3.0, top: int = 5
) -> list[tuple[float, float, float]]:
    """Peaks of a spectrum that stand out against a reference spectrum.

    The reference (e.g. a :func:`median_spectrum` of healthy recordings) is
    interpolated onto the spectrum's ``x`` and floored at its own median
    amplitude, so that bins where the reference is ~0 do not make any
    wiggle a novelty. A peak is a local maximum whose amplitude is at least
    ``min_ratio`` times that floored reference.

    Parameters
    ----------
    spectrum : Spectrum
        The spectrum to examine.
    reference : Spectrum
        The reference, of the same kind (Hz with Hz, orders with orders).
    min_ratio : float
        Smallest amplitude ratio to the reference, > 0.
    top : int
        How many peaks at most.

    Returns
    -------
    list of (float, float, float)
        ``(x, amplitude, ratio)`` per peak, strongest amplitude first.

    Raises
    ------
    EstimationError
        When the kinds differ, the reference is empty or ``min_ratio`` is not positive.
    """
    _check_same_kind([spectrum, reference])
    if not min_ratio > 0.0:
        raise EstimationError(f"min_ratio={min_ratio} must be positive")
    if reference.x.size == 0:
        raise EstimationError("the reference spectrum is empty")
    floor = float(np.median(reference.amplitude))
    ref = np.interp(spectrum.x, reference.x, reference.amplitude)
    ref = np.maximum(ref, floor)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(ref > 0.0, spectrum.amplitude / ref, np.inf)
    idx = _local_maxima(spectrum.amplitude)
    idx = idx[ratio[idx] >= min_ratio]
    idx = idx[np.argsort(-spectrum.amplitude[idx], kind="stable")][: max(top, 0)]
    return [(float(spectrum.x[i]), float(spectrum.amplitude[i]), float(ratio[i])) for i in idx]


def median_spectrum(spectra: Sequence[Spectrum]) -> Spectrum:
    """Bin-wise median of spectra on the first one's grid.

    The others are interpolated linearly onto the first spectrum's ``x``
    (edge values held beyond their range). For a baseline of healthy
    recordings: robust to one odd recording.

    Parameters
    ----------
    spectra : sequence of Spectrum
        Spectra of one kind.

    Returns
    -------
    Spectrum
        The first spectrum's grid, kind, resolution and channel; the median
        amplitude; the median ``speed_rpm``.

    Raises
    ------
    EstimationError
        When no spectrum is given or the kinds differ.
    """
    if not spectra:
        raise EstimationError("no spectrum to take the median of")
    _check_same_kind(spectra)
    first = spectra[0]
    stack = np.vstack([np.interp(first.x, s.x, s.amplitude) for s in spectra])
    return Spectrum(
        x=first.x.copy(),
        amplitude=np.asarray(np.median(stack, axis=0), dtype=np.float64),
        kind=first.kind,
        resolution=first.resolution,
        channel=first.channel,
        speed_rpm=float(np.median([s.speed_rpm for s in spectra])),
    )


# ------------------------------------------------------------------ plot
def _label_groups(lines: Mapping[str, float], x_max: float) -> list[tuple[float, str]]:
    """Lines within ``[0, x_max]``, those closer than 1 % of the range sharing one label."""
    inside = sorted((x, name) for name, x in lines.items() if 0.0 <= x <= x_max)
    groups: list[tuple[float, list[str]]] = []
    for x, name in inside:
        if groups and x - groups[-1][0] <= 0.01 * x_max:
            groups[-1][1].append(name)
        else:
            groups.append((x, [name]))
    return [(x, ", ".join(names)) for x, names in groups]


def plot_spectrum(
    spectrum: Spectrum,
    path: str | Path,
    *,
    lines: Mapping[str, float] | None = None,
    title: str | None = None,
) -> Path:
    """Write a spectrum as a PNG: log amplitude, characteristic lines marked.

    Uses the Agg canvas directly (no pyplot, no global state). The file is
    written to a temporary name beside the target and renamed, so a reader
    never sees half a file.

    Parameters
    ----------
    spectrum : Spectrum
        The spectrum.
    path : str or Path
        The PNG to write.
    lines : Mapping of str to float, optional
        Label → x position (in the spectrum's unit, e.g. apparent Hz) of
        vertical lines to draw; those outside the spectrum's range are left out.
    title : str, optional
        Plot title.

    Returns
    -------
    Path
        The path written.

    Raises
    ------
    OSError
        When the file cannot be written.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    target = Path(path)
    amp = spectrum.amplitude
    positive = amp[amp > 0.0]
    floor = float(np.max(positive)) * 1e-6 if positive.size else 1e-12

    fig = Figure(figsize=(10.0, 5.0), dpi=100)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    ax.semilogy(spectrum.x, np.maximum(amp, floor), linewidth=0.8, color="tab:blue")
    unit = "Nm" if spectrum.channel.startswith("torque") else "SI"
    ax.set_xlabel("frequency [Hz]" if spectrum.kind == "frequency" else "order [1/rev]")
    ax.set_ylabel(f"{spectrum.channel} amplitude [{unit}]")
    ax.set_xlim(float(spectrum.x[0]), float(spectrum.x[-1]))
    ax.grid(True, which="both", alpha=0.3)
    x_max = float(spectrum.x[-1])
    for position, label in _label_groups(lines or {}, x_max):
        ax.axvline(position, color="tab:red", linewidth=0.7, alpha=0.6, linestyle="--")
        ax.text(
            position,
            0.98,
            label,
            transform=ax.get_xaxis_transform(),
            rotation=90,
            va="top",
            ha="right",
            fontsize=7,
            color="tab:red",
        )
    ax.set_title(
        title or f"{spectrum.channel}, {spectrum.kind} spectrum at {spectrum.speed_rpm:.0f} rpm"
    )
    fig.tight_layout()

    tmp = target.with_name(f".{target.name}.{os.getpid()}.tmp")
    try:
        fig.savefig(tmp, format="png")
        tmp.replace(target)
    finally:
        tmp.unlink(missing_ok=True)
    return target
