"""Which torque channel a conveyor weighs with, chosen by its calibration's data.

A drive exports two torques: the actual torque (its model estimate from the
currents) and the speed controller's set point. Neither is better by nature:
the actual torque carries the current measurement's noise, the set point
the speed controller's reaction to its own speed measurement (encoder
quantisation and noise times the controller's gain, not smoothed by the
torque lag). :func:`measure_spreads` measures, on the calibration's own
recordings, the residual spread of the rigid model on each channel and on
their inverse-variance combination (with the measured correlation of the
two residuals), and :func:`choose_channel` takes the smallest, once per
calibration. :func:`on_channel` gives a recording whose ``torque`` is the
chosen channel, so that calibration and weighing run on it unchanged.
"""

from __future__ import annotations

import copy
import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from chaintwin._types import FloatArray
from chaintwin.identify.regression import RigidModelRegression, design_matrix
from chaintwin.model.rigid import motoring_mask
from chaintwin.model.windows import window_integrals
from chaintwin.read.profile import ConveyorProfile
from chaintwin.read.recording import Recording

__all__ = [
    "TORQUE_CHANNELS",
    "ChannelSpreads",
    "choose_channel",
    "measure_spreads",
    "on_channel",
]

TORQUE_CHANNELS = ("torque", "torque_setpoint", "combined")
"""What a calibration may weigh with: the actual torque, the set point, or their
inverse-variance combination (``ChannelSpreads.torque_weight`` of the actual)."""


@dataclass(frozen=True, slots=True)
class ChannelSpreads:
    """The rigid model's residual spread on each torque channel, N·m.

    Attributes
    ----------
    torque, torque_setpoint : float
        Root mean square of the per-window torque residual (the window's
        integral residual over its duration) of a fit on that channel, N·m.
    correlation : float
        Correlation of the two channels' per-window residuals, 1.
    combined : float
        Spread of their inverse-variance combination with that correlation, N·m.
    torque_weight : float
        Share of the actual torque in the combination, 1: the inverse-variance
        weight with the measured correlation, kept within [0, 1].
    """

    torque: float
    torque_setpoint: float
    correlation: float
    combined: float
    torque_weight: float

    def to_dict(self) -> dict[str, float]:
        """JSON-ready."""
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: Any) -> ChannelSpreads:
        """Inverse of :meth:`to_dict`; KeyError, TypeError or ValueError when damaged."""
        out = cls(**{f.name: float(data[f.name]) for f in dataclasses.fields(cls)})
        if not all(math.isfinite(getattr(out, f.name)) for f in dataclasses.fields(cls)):
            raise ValueError("torque channel spreads must be numbers")
        return out


def on_channel(recording: Recording, channel: str, torque_weight: float = 1.0) -> Recording:
    """The recording with its ``torque`` replaced by ``channel``'s values.

    ``combined``: ``torque_weight``·actual + (1 - ``torque_weight``)·set point.
    The caller checks that the set point is there (``recording.torque_setpoint``).
    """
    if channel == "torque":
        return recording
    tsp = recording.torque_setpoint
    if tsp is None:
        raise ValueError(f"{recording.source}: no torque set point for channel {channel}")
    torque = (
        tsp
        if channel == "torque_setpoint"
        else (torque_weight * recording.torque + (1.0 - torque_weight) * tsp)
    )
    return dataclasses.replace(recording, channels={**recording.channels, "torque": torque})


def _window_residuals(
    recordings: Sequence[Recording],
    profile: ConveyorProfile,
    fit: RigidModelRegression,
    channel: str,
    motorings: list[np.ndarray],
) -> FloatArray:
    """Per-window torque residuals (N·m) of ``fit`` on ``channel``, every recording's windows."""
    values = fit.parameters_.values
    out: list[FloatArray] = []
    for rec, mot, load, tray in zip(
        recordings, motorings, fit.loads_kg_, fit.trays_kg_, strict=True
    ):
        wi = window_integrals(rec, profile, motoring=mot, torque_channel=channel)
        x, y = design_matrix(wi, profile, payload_kg=load, tray_kg=tray)
        out.append((y - x @ values) / wi.duration)
    return np.concatenate(out)


def measure_spreads(
    recordings: Sequence[Recording],
    profile: ConveyorProfile,
    settings: RigidModelRegression,
    torque_fit: RigidModelRegression,
) -> ChannelSpreads:
    """Fit the rigid model on the set point too and compare the channels' residuals.

    Parameters
    ----------
    recordings : sequence of Recording
        The calibration recordings, each with a torque set point.
    profile : ConveyorProfile
        The identification profile.
    settings : RigidModelRegression
        The regression's settings (its channel is replaced).
    torque_fit : RigidModelRegression
        The fit on the actual torque.

    Returns
    -------
    ChannelSpreads
        Both channels' residuals on the same windows (the actual torque's
        power-flow directions), their correlation and their combination.

    Raises
    ------
    EstimationError
        When the set point does not determine the model.
    """
    on_sp = copy.copy(settings)
    on_sp.torque_channel = "torque_setpoint"
    sp_fit = on_sp.fit(recordings, profile)
    losses = torque_fit.parameters_.losses
    motorings = [
        motoring_mask(rec, drive_inertia_kgm2=torque_fit.parameters_["J_d"], losses=losses)
        for rec in recordings
    ]
    r_a = _window_residuals(recordings, profile, torque_fit, "torque", motorings)
    r_s = _window_residuals(recordings, profile, sp_fit, "torque_setpoint", motorings)
    var_a = float(np.mean(r_a * r_a))
    var_s = float(np.mean(r_s * r_s))
    cov = float(np.mean(r_a * r_s))
    den = var_a + var_s - 2.0 * cov
    rho = cov / math.sqrt(var_a * var_s) if var_a > 0.0 and var_s > 0.0 else 0.0
    # the inverse-variance weight, kept within [0, 1]: beyond, the combination
    # would extrapolate the two channels' difference (the torque lag, the
    # controller's noise) on the strength of a correlation that the model
    # error both share makes close to 1
    weight = min(max((var_s - cov) / den, 0.0), 1.0) if den > 0.0 else 1.0
    var_c = max(
        weight * weight * var_a + (1.0 - weight) ** 2 * var_s + 2.0 * weight * (1.0 - weight) * cov,
        0.0,
    )
    return ChannelSpreads(
        torque=math.sqrt(var_a),
        torque_setpoint=math.sqrt(var_s),
        correlation=rho,
        combined=math.sqrt(var_c),
        torque_weight=weight,
    )


COMBINE_GAIN = 0.95
"""The combination is chosen over the better single channel only when its spread
is below this share of that channel's: a combination of two nearly equal
channels gains little and its weight is itself an estimate."""


def choose_channel(spreads: ChannelSpreads) -> str:
    """The channel with the smallest residual spread (see :data:`COMBINE_GAIN`)."""
    best = "torque" if spreads.torque <= spreads.torque_setpoint else "torque_setpoint"
    single = min(spreads.torque, spreads.torque_setpoint)
    return "combined" if spreads.combined < COMBINE_GAIN * single else best
