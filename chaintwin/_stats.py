"""Lean exact medians for the per-recording analysis (internal).

:func:`numpy.median` costs about 20 µs a call on a few hundred samples,
most of it dispatch and checks around one :func:`numpy.partition`; the
pipeline calls it many times per recording. :func:`median` does the same
partition and gives the same number, bit for bit: the middle element, or
for an even count the two middle ones added and halved as :func:`numpy.mean`
does (a sum that starts from +0.0: a median of -0.0 is 0.0), and NaN when
any value is NaN. :func:`subtract_bin_medians` takes
away each bin's median in one compiled pass (numba), instead of one
:func:`numpy.median` call per bin.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from chaintwin._types import FloatArray

__all__ = [
    "column_medians",
    "median",
    "phase_bins",
    "subtract_bin_medians",
    "subtract_binned_medians",
]


def median(x: FloatArray) -> float:
    """The median of a 1-D float array, exactly as ``float(np.median(x))``.

    Parameters
    ----------
    x : FloatArray
        Values (any finite or non-finite floats; not empty).

    Returns
    -------
    float
        The median (NaN when any value is NaN).

    Examples
    --------
    >>> median(np.array([3.0, 1.0, 2.0, 10.0]))
    2.5
    """
    n = x.shape[0]
    if n == 0:
        return float(np.median(x))  # numpy's warning and NaN
    k = n // 2
    if n % 2:
        part = np.partition(x, (k, n - 1))
        mid = part[k]
    else:
        part = np.partition(x, (k - 1, k, n - 1))
        mid = (part[k - 1] + part[k]) / 2.0
    # NaN sorts last: partitioning at the end puts one there if there is any
    if np.isnan(part[n - 1]):
        return float("nan")
    return float(mid + 0.0)  # numpy's mean sums from +0.0: -0.0 comes out as 0.0


@njit(cache=True, nogil=True)
def _sort_small(buf: np.ndarray, m: int) -> None:  # pragma: no cover - compiled
    """Sort ``buf[:m]`` (no NaN: the callers check) in place: by insertion when
    short (no allocation), else by ``np.sort``."""
    if m > 48:
        buf[:m] = np.sort(buf[:m])
        return
    for r in range(1, m):
        v = buf[r]
        j = r
        while j > 0 and buf[j - 1] > v:
            buf[j] = buf[j - 1]
            j -= 1
        buf[j] = v


@njit(cache=True, nogil=True)
def _buffer_median(buf: np.ndarray, m: int, has_nan: bool) -> float:  # pragma: no cover
    """np.median of ``buf[:m]`` (sorted here in place): NaN if it holds one, as numpy."""
    _sort_small(buf, m)
    if has_nan:
        return np.nan
    med: float = buf[m // 2] if m % 2 else (buf[m // 2 - 1] + buf[m // 2]) / 2.0
    return med + 0.0  # numpy's mean sums from +0.0: a median of -0.0 is 0.0


@njit(cache=True, nogil=True)
def _subtract_bin_medians(
    out: np.ndarray, members: np.ndarray, bounds: np.ndarray
) -> None:  # pragma: no cover - compiled; tested through subtract_bin_medians
    nbins = bounds.shape[0] - 1
    widest = 0
    for b in range(nbins):
        widest = max(widest, bounds[b + 1] - bounds[b])
    buf = np.empty(widest, dtype=out.dtype)
    for b in range(nbins):
        lo = bounds[b]
        m = bounds[b + 1] - lo
        if m == 0:
            continue
        has_nan = False
        for r in range(m):
            v = out[members[lo + r]]
            has_nan = has_nan or np.isnan(v)
            buf[r] = v
        med = _buffer_median(buf, m, has_nan)
        for j in range(m):
            out[members[lo + j]] -= med


def subtract_bin_medians(out: FloatArray, members: np.ndarray, bounds: np.ndarray) -> None:
    """Take each bin's median away from its samples, in place.

    The same numbers as, for each bin ``b``, ``out[idx] -= np.median(out[idx])``
    with ``idx = members[bounds[b]:bounds[b + 1]]``.

    Parameters
    ----------
    out : FloatArray
        Samples (float64), changed in place.
    members : ndarray of intp
        Sample indices grouped by bin (each index once).
    bounds : ndarray of intp
        ``bins + 1`` offsets into ``members``: bin ``b`` is
        ``members[bounds[b]:bounds[b + 1]]``.

    Examples
    --------
    >>> x = np.array([1.0, 5.0, 2.0, 7.0])
    >>> subtract_bin_medians(x, np.array([0, 2, 1, 3]), np.array([0, 2, 4]))
    >>> x.tolist()
    [-0.5, -1.0, 0.5, 1.0]
    """
    _subtract_bin_medians(out, members, bounds)


@njit(cache=True, nogil=True)
def _group_by_bin(
    idx: np.ndarray, bins: int
) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover - compiled; tested through its callers
    bounds = np.zeros(bins + 1, dtype=np.intp)
    for i in range(idx.shape[0]):
        bounds[idx[i] + 1] += 1
    for b in range(bins):
        bounds[b + 1] += bounds[b]
    fill = bounds[:-1].copy()
    members = np.empty(idx.shape[0], dtype=np.intp)
    for i in range(idx.shape[0]):
        b = idx[i]
        members[fill[b]] = i
        fill[b] += 1
    return members, bounds


def subtract_binned_medians(out: FloatArray, idx: np.ndarray, bins: int) -> None:
    """:func:`subtract_bin_medians` with the samples' bins given per sample, in place.

    ``idx`` holds each sample's bin (``0 <= idx < bins``); the samples are
    grouped by bin in one compiled counting pass, in the order of
    ``np.argsort(idx, kind="stable")`` with ``np.searchsorted`` bounds.

    Examples
    --------
    >>> x = np.array([1.0, 5.0, 2.0, 7.0])
    >>> subtract_binned_medians(x, np.array([0, 1, 0, 1]), 2)
    >>> x.tolist()
    [-0.5, -1.0, 0.5, 1.0]
    """
    idx = np.ascontiguousarray(idx, dtype=np.intp)
    if idx.shape[0] and not (int(idx.min()) >= 0 and int(idx.max()) < bins):
        # out of range (a NaN angle): grouped as numpy groups them
        members = np.argsort(idx, kind="stable")
        bounds = np.searchsorted(idx[members], np.arange(bins + 1))
    else:
        members, bounds = _group_by_bin(idx, int(bins))
    _subtract_bin_medians(out, members, bounds)


@njit(cache=True, nogil=True)
def _column_medians(x: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled; tested
    rows, cols = x.shape
    out = np.empty(cols, dtype=np.float64)
    buf = np.empty(rows, dtype=np.float64)
    for c in range(cols):
        has_nan = False
        for r in range(rows):
            v = x[r, c]
            has_nan = has_nan or np.isnan(v)
            buf[r] = v
        out[c] = _buffer_median(buf, rows, has_nan)
    return out


def column_medians(x: FloatArray) -> FloatArray:
    """``np.median(x, axis=0)`` of a 2-D float64 array with rows, the same numbers.

    Examples
    --------
    >>> column_medians(np.array([[1.0, 4.0], [3.0, 2.0], [2.0, 9.0]])).tolist()
    [2.0, 4.0]
    """
    if x.ndim != 2 or x.shape[0] == 0 or x.dtype != np.float64:
        out: FloatArray = np.median(x, axis=0)
        return out
    medians: FloatArray = _column_medians(np.ascontiguousarray(x))
    return medians


@njit(cache=True, nogil=True)
def _phase_bins(
    turned: np.ndarray, order: float, bins: int
) -> tuple[bool, np.ndarray]:  # pragma: no cover - compiled; tested through phase_bins
    two_pi = 2.0 * np.pi
    n = turned.shape[0]
    idx = np.empty(n, dtype=np.intp)
    for i in range(n):
        phase = np.mod(order * turned[i], two_pi)
        if not np.isfinite(phase):
            return False, idx
        k = int(phase / two_pi * bins)  # truncation, as astype(np.intp)
        idx[i] = k if k < bins - 1 else bins - 1
    return True, idx


def phase_bins(turned: FloatArray, order: float, bins: int) -> np.ndarray:
    """Each sample's bin of the phase ``order x turned`` (rad) among ``bins`` per period.

    The same numbers as ``np.minimum((np.mod(order * turned, 2π) / (2π) * bins)
    .astype(np.intp), bins - 1)`` (tested), in one compiled pass; numpy's
    own where a phase is not finite.

    Examples
    --------
    >>> phase_bins(np.array([0.0, 1.0, 4.0, 7.0]), 1.0, 4).tolist()
    [0, 0, 2, 0]
    """
    ok, idx = _phase_bins(np.ascontiguousarray(turned, dtype=np.float64), float(order), int(bins))
    if ok:
        return idx
    phase = np.mod(order * turned, 2.0 * np.pi)
    out: np.ndarray = np.minimum((phase / (2.0 * np.pi) * bins).astype(np.intp), bins - 1)
    return out
