"""The belt map: the residual's rise per place of the belt loop, over recent passes.

.. warning:: It assumes scope positions are comparable across recordings.
   They are not on real drives (the position counter's offset changes from
   recording to recording, docs/design.md, section 2), so on a real plant
   the map averages unrelated places. Kept as it is until the impact
   detector replaces it (issue 17); its feature is ``belt_bump``.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from .residuals import DEFAULT_BIN_WIDTH_M

__all__ = ["MIN_MAP_SHARE", "update"]

MIN_MAP_SHARE = 0.9
"""Share of the belt loop the belt map must have seen twice before ``belt_bump`` is computed."""


def update(
    last: list[float | None],
    prev: list[float | None],
    bins: npt.ArrayLike,
    values: npt.ArrayLike,
    loop_length_m: float,
) -> tuple[list[float | None], list[float | None], tuple[float, float | None]]:
    """Update the belt map; its largest local rise and where, m.

    The map holds, per place of the loop, the residual's rise on the last
    two passes. A place counts with the smaller of the two: an obstruction
    is there on every pass, a one-off disturbance (stick-slip, a knock)
    on one only. The rise is in robust standard deviations of the map
    over the loop (median absolute deviation), a number that does not
    depend on the conveyor's noise level.

    Parameters
    ----------
    last, prev : list of float or None
        The map's last and previous pass per bin (None: not seen).
    bins, values : array_like
        A recording's bump profile: bin indices and the residual's rise there.
    loop_length_m : float
        The belt loop's length, m.

    Returns
    -------
    (list, list, (float, float or None))
        The updated ``last`` and ``prev``, and the rise in robust standard
        deviations with its place on the loop, m (NaN and None until the map
        has seen :data:`MIN_MAP_SHARE` of the loop twice).
    """
    nbins = math.ceil(loop_length_m / DEFAULT_BIN_WIDTH_M)
    if len(last) != nbins or len(prev) != nbins:
        last, prev = [None] * nbins, [None] * nbins
    for b, v in zip(
        np.asarray(bins).tolist(), np.asarray(values, dtype=np.float64).tolist(), strict=True
    ):
        if math.isfinite(v):
            prev[int(b)] = last[int(b)]
            last[int(b)] = v
    last_a = np.array(last, dtype=np.float64)  # None -> NaN
    prev_a = np.array(prev, dtype=np.float64)
    both = np.where(np.isfinite(last_a) & np.isfinite(prev_a), np.minimum(last_a, prev_a), np.nan)
    if np.isfinite(both).sum() < MIN_MAP_SHARE * nbins:
        return last, prev, (float("nan"), None)
    # a bump spans a few bins (its width plus a tooth pitch of averaging)
    padded = np.concatenate((both[-1:], both, both[:1]))
    smooth = np.convolve(np.nan_to_num(padded, nan=0.0), np.ones(3), mode="valid")
    counts = np.convolve(np.isfinite(padded).astype(float), np.ones(3), mode="valid")
    with np.errstate(invalid="ignore", divide="ignore"):
        local = np.where(counts > 0, smooth / counts, np.nan)
    idx = int(np.nanargmax(local))
    width = loop_length_m / nbins
    centre = float(np.nanmedian(local))
    spread = 1.4826 * float(np.nanmedian(np.abs(local - centre)))
    if spread <= 0.0:
        return last, prev, (float("nan"), None)
    return last, prev, ((float(local[idx]) - centre) / spread, (idx + 0.5) * width)
