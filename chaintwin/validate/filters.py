"""Derivatives and smoothing of a recording's 1-D signals, without per-call set-up.

:func:`gradient` is ``numpy.gradient(f, t)`` for 1-D arrays, bit for bit,
without its general-purpose argument handling (which cost several times
the arithmetic on a recording's 2000 samples).

:func:`savgol` computes what ``scipy.signal.savgol_filter(x, window, polyorder,
deriv=deriv, delta=delta)`` (``mode="interp"``) computes, for a 1-D float
array, but keeps what depends only on the window, the order, the derivative
and the sample time (the convolution coefficients and the edge operators)
in a small cache, since every recording of a conveyor asks for the same
ones. scipy fits a polynomial to the first and last window with
``polyfit`` on every call, which was most of the filter's time.

* The interior is the same convolution (``scipy.ndimage.convolve1d`` with
  ``mode="constant"`` and scipy's own coefficients): bit for bit scipy's.
* The ``window // 2`` samples at each end are the fitted polynomial (or its
  derivative) of the first and last window. The fit is linear in the
  samples, so it is applied as a precomputed matrix; the result agrees with
  scipy's to rounding (a few ulp of the window's values), not bit for bit.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from scipy.ndimage import convolve1d
from scipy.signal import savgol_coeffs

from chaintwin._types import FloatArray

__all__ = ["gradient", "savgol"]


@lru_cache(maxsize=64)
def _operators(
    window: int, polyorder: int, deriv: int, delta: float
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Convolution coefficients and the left and right edge operators.

    Returns
    -------
    coeffs : FloatArray
        ``scipy.signal.savgol_coeffs(window, polyorder, deriv=deriv, delta=delta)``.
    left, right : FloatArray
        ``(window // 2, window)`` matrices: the first (last) ``window // 2``
        outputs are ``left @ x[:window]`` (``right @ x[-window:]``), the
        least-squares polynomial of the window (its ``deriv``-th derivative,
        divided by ``delta**deriv``) evaluated there.
    """
    coeffs = np.asarray(savgol_coeffs(window, polyorder, deriv=deriv, delta=delta))
    half = window // 2
    pos = np.arange(window, dtype=np.float64)
    # the polynomial fit of the window as a matrix: its coefficients (highest
    # power first, as numpy.polyfit and scipy give them) are ``fit @ x``
    fit = np.polyfit(pos, np.eye(window), polyorder)
    if deriv:
        fit = np.stack([np.polyder(fit[:, j], deriv) for j in range(window)], axis=1)
    powers = np.arange(fit.shape[0] - 1, -1, -1)
    scale = delta**deriv

    def evaluate(at: FloatArray) -> FloatArray:
        out: FloatArray = (at[:, None] ** powers @ fit) / scale
        return out

    left = evaluate(pos[:half])
    right = evaluate(pos[window - half :])
    for op in (coeffs, left, right):
        op.setflags(write=False)
    return coeffs, left, right


def savgol(
    x: FloatArray, window: int, polyorder: int, *, deriv: int = 0, delta: float = 1.0
) -> FloatArray:
    """Savitzky-Golay filter of a 1-D signal, ``mode="interp"``.

    Parameters
    ----------
    x : FloatArray
        The signal, at least ``window`` samples (any unit).
    window : int
        Window length, samples (odd, greater than ``polyorder``).
    polyorder : int
        Order of the fitted polynomial.
    deriv : int
        Order of the derivative (0: smoothing).
    delta : float
        Sample spacing, s (the derivative is per ``delta**deriv``).

    Returns
    -------
    FloatArray
        The filtered signal (its unit per s**deriv), same length as ``x``.

    Raises
    ------
    ValueError
        When the window is longer than the signal, or as
        ``scipy.signal.savgol_coeffs`` for a bad window or order.
    """
    data = np.asarray(x, dtype=np.float64)
    if data.ndim != 1 or window > data.shape[0]:
        raise ValueError(
            f"savgol needs a 1-D signal of at least window={window} samples; got shape {data.shape}"
        )
    coeffs, left, right = _operators(int(window), int(polyorder), int(deriv), float(delta))
    out: FloatArray = convolve1d(data, coeffs, mode="constant")
    half = window // 2
    if half:
        out[:half] = left @ data[:window]
        out[-half:] = right @ data[-window:]
    return out


def gradient(f: FloatArray, t: FloatArray) -> FloatArray:
    """``numpy.gradient(f, t)`` of a 1-D signal, the same numbers.

    Second-order central differences inside (for the uneven steps of ``t``
    when they are not all equal), first-order one-sided differences at the
    ends (``edge_order=1``).

    Parameters
    ----------
    f : FloatArray
        The signal (any unit), at least 2 samples.
    t : FloatArray
        Its sample times, s, same length.

    Returns
    -------
    FloatArray
        df/dt (the signal's unit per s).

    Raises
    ------
    ValueError
        When fewer than 2 samples are given or the lengths differ.
    """
    f = np.asarray(f, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)
    if f.ndim != 1 or f.shape != t.shape or f.shape[0] < 2:
        raise ValueError(
            f"gradient needs two 1-D arrays of the same length >= 2; got {f.shape}, {t.shape}"
        )
    dx = np.diff(t)
    out: FloatArray = np.empty_like(f)
    if (dx == dx[0]).all():
        step = dx[0]
        out[1:-1] = (f[2:] - f[:-2]) / (2.0 * step)
        out[0] = (f[1] - f[0]) / step
        out[-1] = (f[-1] - f[-2]) / step
        return out
    dx1 = dx[0:-1]
    dx2 = dx[1:]
    a = -(dx2) / (dx1 * (dx1 + dx2))
    b = (dx2 - dx1) / (dx1 * dx2)
    c = dx1 / (dx2 * (dx1 + dx2))
    out[1:-1] = a * f[:-2] + b * f[1:-1] + c * f[2:]
    out[0] = (f[1] - f[0]) / dx[0]
    out[-1] = (f[-1] - f[-2]) / dx[-1]
    return out
