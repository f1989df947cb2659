"""Default settings of the identification methods, importable without their numerics.

The command line shows them in its ``--help`` (which loads no NumPy or SciPy);
the uncertainty of a calibration's losses is used when weighing with it
(:class:`~chaintwin.weigh.drift.LossDrift`).
"""

from __future__ import annotations

__all__ = ["DEFAULT_FORGETTING", "DEFAULT_HOLD_FIRST", "LOSS_DRIFT_HALF_RANGE", "LOSS_DRIFT_REL"]

DEFAULT_FORGETTING = 0.98
"""Forgetting factor of :func:`~chaintwin.identify.tracking.track_losses`.

docs/methods/rls.md explains the trade-off.
"""

DEFAULT_HOLD_FIRST = 20
"""Recordings whose batch fit gives the parameters RLS holds (J_d, μ, BmC)."""

LOSS_DRIFT_HALF_RANGE = 0.10
"""How far the losses drift from the calibration's with oil temperature, each
way, 1: within ±10 %. Two recordings may then see losses up to 20 % of the
calibration's apart (the condition features' drift allowance,
:mod:`chaintwin.diagnose.features`)."""

LOSS_DRIFT_REL = 0.06
"""Standard uncertainty of the losses relative to the calibration's when
nothing is known of today's, 1: a drift uniform within ±:data:`LOSS_DRIFT_HALF_RANGE`
has a standard deviation of 5.8 %."""
