"""The reference zero of zero tracking: what the calibration's own recordings read as drift.

A belt scale's zero is set relative to its reference: what the empty belt
read when it was calibrated. Zero tracking (:mod:`chaintwin.weigh.zero_tracking`)
reads the gear losses' drift δ from a recording with a known payload; the
calibration's own recordings, weighed with the calibration at their known
payloads, give the same reading with the losses as calibrated. What they
read is the model's own error at those payloads, not a drift:
:class:`ZeroReference` keeps those readings, the zero they imply (a constant,
or a straight line in the payload when the recordings span several loads)
and the scatter of the readings beyond their own uncertainties (the model
error a known run carries). A known run's drift is read relative to it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["MIN_PAYLOAD_SPREAD_KG", "ZeroReference"]

MIN_PAYLOAD_SPREAD_KG = 5.0
"""Payload spread of the readings above which the zero is a line in the payload, kg."""


@dataclass(frozen=True)
class ZeroReference:
    """The calibration's own known-run drift readings and the zero they imply.

    Attributes
    ----------
    readings : tuple of tuple of float
        ``(payload_kg, delta, variance)`` of each calibration recording that
        could be read: its payload (kg), the loss drift it reads at that
        payload with the calibration's losses (1) and that reading's
        variance (1).
    """

    readings: tuple[tuple[float, float, float], ...]

    def _fit(self) -> tuple[np.ndarray, np.ndarray, float] | None:
        """Coefficients ``[c, s]`` of ``zero = c + s·p``, their covariance and the
        model variance (the scatter beyond the readings' own variances), or None."""
        rows = [r for r in self.readings if all(math.isfinite(v) for v in r) and r[2] > 0.0]
        if not rows:
            return None
        p = np.array([r[0] for r in rows])
        y = np.array([r[1] for r in rows])
        w = 1.0 / np.array([r[2] for r in rows])
        line = float(np.ptp(p)) >= MIN_PAYLOAD_SPREAD_KG and len(rows) >= 3
        x = np.column_stack([np.ones_like(p), p]) if line else np.ones((len(rows), 1))
        cov = np.linalg.inv((x.T * w) @ x)
        beta = cov @ ((x.T * w) @ y)
        dof = len(rows) - x.shape[1]
        model_var = 0.0
        if dof > 0:
            res = y - x @ beta
            # the readings' scatter beyond their variances: the model's error at a reading
            excess = float(np.sum(w * res * res)) / dof
            model_var = max(0.0, excess - 1.0) * len(rows) / float(np.sum(w))
            cov = cov * max(1.0, excess)
        if not line:
            beta = np.array([float(beta[0]), 0.0])
            cov = np.array([[float(cov[0, 0]), 0.0], [0.0, 0.0]])
        return beta, cov, model_var

    def zero(self, payload_kg: float) -> tuple[float, float]:
        """The reference zero at a payload and its variance (fit and model error), 1 and 1.

        Parameters
        ----------
        payload_kg : float
            The known run's payload, kg.

        Returns
        -------
        tuple of float
            ``(zero, variance)``: the drift reading that means no drift, and the
            variance a known run's reading gains by being read relative to it
            (0, 0 without readings).
        """
        found = self._fit()
        if found is None:
            return 0.0, 0.0
        beta, cov, model_var = found
        x = np.array([1.0, payload_kg])
        return float(x @ beta), float(x @ cov @ x) + model_var

    @property
    def model_sigma(self) -> float:
        """The scatter of the readings beyond their own uncertainties, 1 (0: none seen)."""
        found = self._fit()
        return 0.0 if found is None else math.sqrt(found[2])

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        zero, var = self.zero(0.0)
        return {
            "readings": [
                {"payload_kg": p, "loss_drift": d, "variance": v} for p, d, v in self.readings
            ],
            "zero_at_empty": zero,
            "zero_at_empty_sigma": math.sqrt(var),
            "model_sigma": self.model_sigma,
        }

    @classmethod
    def from_dict(cls, data: Any) -> ZeroReference:
        """Inverse of :meth:`to_dict`; KeyError, TypeError or ValueError when damaged."""
        if not isinstance(data, dict) or not isinstance(data.get("readings"), list):
            raise ValueError("zero_reference needs a list of readings")
        rows = tuple(
            (float(r["payload_kg"]), float(r["loss_drift"]), float(r["variance"]))
            for r in data["readings"]
        )
        if not all(math.isfinite(v) for r in rows for v in r) or any(r[2] <= 0.0 for r in rows):
            raise ValueError("zero_reference holds a reading that is not a number")
        return cls(rows)
