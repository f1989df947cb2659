"""Compiled parser for the numeric body of a recording.

A scope's body is a grid of short decimal numbers. Parsing it with
:func:`numpy.fromstring` costs about 140 ns per number; this single pass over
the bytes costs a few, and checks the field count of every row on the way.

Numbers are converted exactly as ``float()`` would (correctly rounded):
a mantissa below 2**53 scaled by an exact power of ten up to 1e22 is
Clinger's fast path. Anything else (longer mantissas, huge exponents,
``nan``, empty fields, blank lines) stops the pass and the caller falls back
to the line-by-line parser, which handles it or names the bad line.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from chaintwin._types import FloatArray

__all__ = ["parse_grid"]

_POW10 = np.array([10.0**k for k in range(23)], dtype=np.float64)
_MAX_EXACT = 2**53


@njit(cache=True, nogil=True)
def _parse(
    buf: np.ndarray, sep: int, dec: int, out: np.ndarray, pow10: np.ndarray
) -> tuple[int, int]:  # pragma: no cover - compiled; tested through parse_grid
    """Fill ``out`` (rows × cols); return (-1, -1) or the (row, col) where it stopped."""
    n = buf.shape[0]
    nrows, ncols = out.shape
    i = 0
    for row in range(nrows):
        for col in range(ncols):
            # leading blanks
            while i < n and (buf[i] == 32 or buf[i] == 9):
                i += 1
            neg = False
            if i < n and (buf[i] == 45 or buf[i] == 43):
                neg = buf[i] == 45
                i += 1
            mant = 0
            digits = 0
            frac = 0
            while i < n and 48 <= buf[i] <= 57:
                mant = mant * 10 + (buf[i] - 48)
                digits += 1
                i += 1
                if digits > 17:
                    return row, col
            if i < n and buf[i] == dec:
                i += 1
                while i < n and 48 <= buf[i] <= 57:
                    mant = mant * 10 + (buf[i] - 48)
                    digits += 1
                    frac += 1
                    i += 1
                    if digits > 17:
                        return row, col
            if digits == 0:
                return row, col
            exp = 0
            if i < n and (buf[i] == 101 or buf[i] == 69):
                i += 1
                eneg = False
                if i < n and (buf[i] == 45 or buf[i] == 43):
                    eneg = buf[i] == 45
                    i += 1
                edig = 0
                while i < n and 48 <= buf[i] <= 57:
                    exp = exp * 10 + (buf[i] - 48)
                    edig += 1
                    i += 1
                    if edig > 3:
                        return row, col
                if edig == 0:
                    return row, col
                if eneg:
                    exp = -exp
            exp -= frac
            if mant >= 9007199254740992:
                return row, col
            value = float(mant)
            if exp > 0:
                if exp > 22:
                    return row, col
                value = value * pow10[exp]
            elif exp < 0:
                if exp < -22:
                    return row, col
                value = value / pow10[-exp]
            out[row, col] = -value if neg else value
            while i < n and (buf[i] == 32 or buf[i] == 9):
                i += 1
            if col < ncols - 1:
                if i >= n or buf[i] != sep:
                    return row, col
                i += 1
            else:
                if i < n:
                    if buf[i] != 10:
                        return row, col
                    i += 1
    if i < n:
        return nrows - 1, ncols - 1
    return -1, -1


def parse_grid(
    body: bytes | memoryview, sep: str, decimal: str, nrows: int, ncols: int
) -> FloatArray | None:
    """Parse ``nrows`` lines of ``ncols`` numbers; None when anything is unusual.

    Parameters
    ----------
    body : bytes or memoryview
        The data lines, ``\\n`` separated, no trailing newline (read in place).
    sep, decimal : str
        Field separator and decimal mark (``","``/``"."`` or ``";"``/``","``).
    nrows, ncols : int
        Expected shape.

    Returns
    -------
    FloatArray or None
        The grid, or None when the fast path cannot parse it exactly.
    """
    out = np.empty((nrows, ncols), dtype=np.float64, order="F")  # a channel is a column
    buf = np.frombuffer(body, dtype=np.uint8)
    row, _col = _parse(buf, ord(sep), ord(decimal), out, _POW10)
    return out if row < 0 else None
