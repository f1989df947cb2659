"""Peaks of spectra: the strongest, those new against a reference, and the median spectrum."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import numpy.typing as npt
from numba import njit

from chaintwin._types import FloatArray
from chaintwin.errors import EstimationError
from chaintwin.model.frequencies import apparent_orders

from .spectra import Spectrum

__all__ = [
    "GUARD_BINS",
    "median_spectrum",
    "novel_peaks",
    "spectrum_from_state",
    "strongest_peaks",
    "unexplained_peak",
]

GUARD_BINS = 4
"""Bins either side of a known line left out of :func:`unexplained_peak`."""


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


def spectrum_from_state(x: list[float], amplitude: list[float], speed_rpm: float) -> Spectrum:
    """A plateau torque spectrum as a monitor's state keeps it (grid, amplitudes, speed)."""
    grid = np.asarray(x)
    return Spectrum(
        x=grid,
        amplitude=np.asarray(amplitude),
        kind="frequency",
        resolution=float(grid[1] - grid[0]),
        channel="torque",
        speed_rpm=speed_rpm,
    )


@njit(cache=True, nogil=True)
def _near_any(
    x: np.ndarray, centres: np.ndarray, width: float
) -> np.ndarray:  # pragma: no cover - compiled; tested through unexplained_peak
    """``(np.abs(x[:, None] - centres[None, :]) <= width).any(axis=1)``, without the
    bins × lines table."""
    out = np.zeros(x.shape[0], dtype=np.bool_)
    for i in range(x.shape[0]):
        for c in centres:
            if abs(x[i] - c) <= width:
                out[i] = True
                break
    return out


def unexplained_peak(
    spectrum: Spectrum,
    baseline_x: FloatArray,
    baseline_amplitude: FloatArray,
    floor: float,
    line_orders: FloatArray,
    guard_bins: int = GUARD_BINS,
) -> tuple[float, float]:
    """The largest ratio of a spectrum to its baseline away from the known lines, and its order.

    Bins within ``guard_bins`` of a line's apparent place (orders folded at
    the spectrum's sample time) or of 0 Hz do not count. 0 Hz holds the
    plateau's trend and whatever changes its level for a while (an item
    caught for part of it), which the segments' window spreads over its
    mainlobe as it spreads a line's: with two guard bins, a 6 ms healthy
    conveyor's items caught for 0.2-1 s raised the third bin (0.49 Hz) to
    5-6 times its baseline and opened a ``bearing`` alarm.

    Returns
    -------
    (float, float)
        The ratio and its order; NaN, NaN when the spectrum has no speed.
    """
    ref = np.interp(spectrum.x, baseline_x, baseline_amplitude)
    ratio = spectrum.amplitude / np.maximum(ref, floor)
    speed_hz = spectrum.speed_rpm / 60.0
    if speed_hz <= 0:
        return float("nan"), float("nan")
    if not spectrum.x[-1] > 0:
        return float("nan"), float("nan")
    ts = 1.0 / (2.0 * float(spectrum.x[-1]))
    res = spectrum.resolution
    lines = apparent_orders(line_orders, spectrum.speed_rpm, ts)
    x = np.ascontiguousarray(spectrum.x, dtype=np.float64)
    near = _near_any(x, np.ascontiguousarray(lines * speed_hz), float(guard_bins * res))
    # the trend (0 Hz) is a line too: its window's mainlobe reaches as far as any
    # line's (what changes within the plateau, an item caught, leaks into it)
    guard = near | (spectrum.x <= guard_bins * res)
    ratio = np.where(guard, 0.0, ratio)
    k = int(np.argmax(ratio))
    return float(ratio[k]), float(spectrum.x[k] / speed_hz)
