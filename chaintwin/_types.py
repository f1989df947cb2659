"""Array type aliases shared by every module (the one place they are defined)."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

__all__ = ["BoolArray", "FloatArray", "IntArray"]

FloatArray = npt.NDArray[np.float64]
"""A float64 array; units are given where it is used."""

BoolArray = npt.NDArray[np.bool_]
"""A boolean mask."""

IntArray = npt.NDArray[np.int64]
"""An int64 array (counts, indices)."""
