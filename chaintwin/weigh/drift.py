"""How far a conveyor's losses may have drifted since its calibration.

Gear and motor losses drift with oil temperature and wear; at speed they are
worth tens of kilograms of payload on most conveyors (the loss torque over
the payload sensitivity), so the friction signature reads a few percent of
drift as kilograms of load, while the inertia signature does not depend on
the losses. :func:`~chaintwin.weigh.weigh.weigh` corrects the friction
signature by a :class:`LossDrift` and carries its uncertainty.

The drift ``δ`` is relative: today's losses are ``(1 + δ)`` times the
calibration's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from chaintwin.identify.defaults import LOSS_DRIFT_HALF_RANGE, LOSS_DRIFT_REL

__all__ = ["LOSS_DRIFT_HALF_RANGE", "LOSS_DRIFT_REL", "LossDrift"]


@dataclass(frozen=True, slots=True)
class LossDrift:
    """The relative loss drift ``δ`` assumed for a recording, and its standard uncertainty.

    Attributes
    ----------
    mean : float
        δ, 1 (the friction signature is corrected by ``δ`` times the loss payload).
    sigma : float
        Its standard uncertainty, 1 (0: the calibration's losses are trusted).
    """

    mean: float = 0.0
    sigma: float = 0.0

    @classmethod
    def unknown(cls) -> LossDrift:
        """Nothing known of today's losses: δ = 0 ± :data:`LOSS_DRIFT_REL`."""
        return cls(0.0, LOSS_DRIFT_REL)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        return {"mean": self.mean, "sigma": self.sigma}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> LossDrift:
        """Inverse of :meth:`to_dict`; KeyError, TypeError or ValueError when damaged."""
        out = cls(float(data["mean"]), float(data["sigma"]))
        if not (math.isfinite(out.mean) and math.isfinite(out.sigma) and out.sigma >= 0):
            raise ValueError(f"loss drift {out.mean} ± {out.sigma} is not a number")
        return out
