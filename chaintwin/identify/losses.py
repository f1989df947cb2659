"""Whether the runs separate the gear unit's speed-dependent losses: a verdict.

The rigid model's gear loss is ``BmA·sign(ω) + BmB·ω + BmC·ω·|ω|``: BmB the
viscous (mechanical: bearings, seals, tooth friction growing with speed) and
BmC the quadratic loss (oil churning, growing with the square of speed). At
one plateau speed both only add a torque at that speed; the ramps are all
that tells them apart, and the ramps are where the rigid model is weakest
(the belt's ringing, breakaway, the torque lag). The split is then biased
well beyond its standard errors (on the virtual conveyor at one speed: BmB
12 % low, BmC 56 % high, at 1.4 and 1.5 standard errors), while the gear loss
at the run's speed, ``BmA + BmB·ω + BmC·ω²``, is known to a fraction of a
percent (BmA too trades with the speed-dependent part at one speed).

:func:`loss_verdict` says which case a calibration is in: ``separated``
(plateaus at two or more speeds, both relative standard errors at most
:data:`MAX_REL_STDERR`), ``not_separable`` (one speed, or errors above that)
or ``quadratic_fixed`` (BmC was not fitted). In every case it gives the
gear loss ``BmA + BmB·ω + BmC·ω·|ω|`` at each plateau speed with its
standard error: the number that is known.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from chaintwin.model.rigid import PARAMETER_NAMES, RigidParameters
from chaintwin.units import RPM_TO_RAD_S

__all__ = ["MAX_REL_STDERR", "LossVerdict", "loss_verdict"]

MAX_REL_STDERR = 0.5
"""Largest relative standard error of BmB and BmC for them to count as separated."""


@dataclass(frozen=True, slots=True)
class LossVerdict:
    """What the runs tell of the speed-dependent gear losses.

    Attributes
    ----------
    verdict : str
        ``separated``, ``not_separable`` or ``quadratic_fixed``.
    message : str
        The verdict in words, with the numbers.
    speeds_rpm : list of float
        The distinct plateau speeds of the runs, rpm.
    at_speed : list of dict
        Per plateau speed: ``speed_rpm``, ``loss_nm`` (the gear loss
        ``BmA + BmB·ω + BmC·ω·|ω|``, Nm) and ``loss_nm_stderr``.
    """

    verdict: str
    message: str
    speeds_rpm: list[float]
    at_speed: list[dict[str, float]] = field(default_factory=list)

    @property
    def separated(self) -> bool:
        """Whether BmB and BmC can be reported on their own."""
        return self.verdict != "not_separable"

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        return {
            "verdict": self.verdict,
            "message": self.message,
            "speeds_rpm": list(self.speeds_rpm),
            "at_speed": [dict(a) for a in self.at_speed],
        }


def loss_verdict(parameters: RigidParameters, speeds_rpm: Sequence[float]) -> LossVerdict:
    """Whether BmB and BmC are separated by runs at these plateau speeds.

    Parameters
    ----------
    parameters : RigidParameters
        Identified parameters with their covariance.
    speeds_rpm : sequence of float
        Distinct plateau speeds of the runs, rpm (e.g. a calibration's
        ``plateau_speeds_rpm``).

    Returns
    -------
    LossVerdict
    """
    idx = [PARAMETER_NAMES.index(n) for n in ("BmA", "BmB", "BmC")]
    cov = np.asarray(parameters.covariance, dtype=np.float64)[np.ix_(idx, idx)]
    speeds = [abs(float(s)) for s in speeds_rpm]
    at_speed = []
    for rpm in speeds:
        w = rpm * RPM_TO_RAD_S
        g = np.array([1.0, w, w * w])
        loss = float(parameters["BmA"] + parameters["BmB"] * w + parameters["BmC"] * w * w)
        at_speed.append(
            {
                "speed_rpm": rpm,
                "loss_nm": loss,
                "loss_nm_stderr": math.sqrt(max(float(g @ cov @ g), 0.0)),
            }
        )
    known = "; ".join(
        f"{a['loss_nm']:.4g} ± {a['loss_nm_stderr']:.2g} Nm at {a['speed_rpm']:.0f} rpm"
        for a in at_speed
    )
    if "BmC" in parameters.fixed:
        return LossVerdict(
            "quadratic_fixed",
            f"BmC was not fitted (held at {parameters['BmC']:g}); the speed-dependent loss "
            f"is BmB alone; the gear loss: {known}",
            speeds,
            at_speed,
        )
    rel = {
        name: parameters.stderr(name) / abs(parameters[name])
        if parameters[name] != 0.0
        else math.inf
        for name in ("BmB", "BmC")
    }
    if len(speeds) < 2:
        where = f"at {speeds[0]:.0f} rpm" if speeds else "without a constant-speed part"
        return LossVerdict(
            "not_separable",
            f"all runs are {where}: the viscous (mechanical) loss BmB and the quadratic "
            "(churning) loss BmC are told apart only by the ramps, where the rigid model is "
            "weakest, and their split is not reported. Known is the gear loss at that speed: "
            f"{known or 'none'}. Add runs at two or three other speeds to separate them",
            speeds,
            at_speed,
        )
    worst = max(rel, key=lambda n: rel[n])
    if rel[worst] > MAX_REL_STDERR:
        return LossVerdict(
            "not_separable",
            f"the runs' speeds ({', '.join(f'{s:.0f}' for s in speeds)} rpm) do not separate "
            f"BmB from BmC ({worst} ± {rel[worst]:.0%}); known is the gear loss: {known}. Add "
            "runs at speeds further apart",
            speeds,
            at_speed,
        )
    return LossVerdict(
        "separated",
        f"BmB ± {rel['BmB']:.0%} and BmC ± {rel['BmC']:.0%} from runs at "
        f"{', '.join(f'{s:.0f}' for s in speeds)} rpm",
        speeds,
        at_speed,
    )
