"""Amplitude spectra of drive channels: Welch and order analysis (estimation only).

docs/design.md, section 3, "Spectra": FFT/Welch with log amplitude and order
analysis by resampling the torque to equal steps of motor angle. Amplitudes
at the characteristic lines are in :mod:`.lines`, peaks and the median of
spectra in :mod:`.peaks`, where lines appear (folding) and the line
catalogue in :mod:`chaintwin.model.frequencies`, the picture in
:mod:`chaintwin.report.spectrum_plot`.

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
lines often lie above it for 6 and 12 ms scopes;
:func:`~chaintwin.model.frequencies.apparent_order`
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
from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache
from typing import Literal

import numpy as np
import numpy.typing as npt
from scipy import fft as scipy_fft
from scipy.integrate import cumulative_trapezoid
from scipy.signal import ShortTimeFFT, get_window
from scipy.signal.windows import hann

from chaintwin._stats import column_medians
from chaintwin._types import FloatArray
from chaintwin.errors import EstimationError, RecordingError
from chaintwin.read.recording import Recording
from chaintwin.units import RPM_TO_RAD_S
from chaintwin.validate.phases import Phase, segment

__all__ = [
    "MIN_SPEED_RPM",
    "Spectrum",
    "SpectrumKind",
    "order_spectrum",
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


def _plateau(recording: Recording, phases: Sequence[Phase] | None = None) -> tuple[int, int]:
    """The longest constant-speed phase, or the whole recording when it is too short.

    ``phases`` is the recording's segmentation when validation made it
    already; the recording is segmented here otherwise.
    """
    if phases is None:
        phases = segment(recording)
    constant = [p for p in phases if p.kind == "constant"]
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
        out: FloatArray = column_medians(power) / bias  # np.median(power, axis=0)
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
    phases: Sequence[Phase] | None = None,
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
    phases : sequence of Phase, optional
        The recording's movement phases (validation's segmentation) that
        give the default plateau; segmented here when not given.

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
    start, stop = _plateau(recording, phases) if span is None else (int(span[0]), int(span[1]))
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
    and stay folded (see the module docstring and
    :func:`~chaintwin.model.frequencies.apparent_order`).
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
