"""Amplitudes at the conveyor's characteristic lines in a spectrum.

Where a line is looked for comes from the line catalogue,
:func:`chaintwin.model.frequencies.line_orders`, folded to where the scope
shows it (:func:`chaintwin.model.frequencies.apparent_order`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from chaintwin.errors import EstimationError
from chaintwin.model.frequencies import apparent_order, line_orders
from chaintwin.read.profile import ConveyorProfile
from chaintwin.read.recording import Recording

from .spectra import MIN_SPEED_RPM, Spectrum, welch_spectrum

__all__ = ["band_amplitude", "band_amplitudes", "line_amplitudes"]


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
