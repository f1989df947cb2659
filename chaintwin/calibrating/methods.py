"""The three ways ``chaintwin identify`` can identify the rigid model.

* ``ls``: windowed batch least squares (:func:`~chaintwin.calibrating.procedure.calibrate`).
* ``rls``: recursive least squares with directional forgetting over the
  recordings in time order (:func:`~chaintwin.identify.tracking.track_losses`):
  J_d, μ and BmC held at a batch fit of the first ``hold_first`` recordings,
  BmA and BmB tracked; the estimate after the last recording is reported and
  the estimate after each one is kept (``track``).
* ``oe``: output-error fit of the closed loop
  (:class:`~chaintwin.identify.output_error.OutputErrorFit`): μ, BmB and the
  drive inertia always, BmA when the loads differ by 5 kg or more, BmC when the
  plateaus are at two speeds or more (held at 0 otherwise, with a warning).

Each returns a :class:`~chaintwin.identify.calibration.Calibration` whose
parameters are the method's, so that one JSON shape serves all three.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from dataclasses import replace
from typing import Any, Literal

import numpy as np

from chaintwin.calibrating.procedure import calibrate
from chaintwin.errors import ConvergenceWarning, EstimationError
from chaintwin.identify.calibration import Calibration, identification_profile
from chaintwin.identify.defaults import DEFAULT_HOLD_FIRST
from chaintwin.identify.output_error import OutputErrorFit
from chaintwin.identify.regression import RigidModelRegression, speed_clusters
from chaintwin.identify.tracking import DEFAULT_FORGETTING, TrackPoint, track_losses
from chaintwin.model.rigid import PARAMETER_NAMES, RigidParameters
from chaintwin.read.profile import ConveyorProfile
from chaintwin.read.recording import Recording, RecordingWarning

__all__ = [
    "DEFAULT_HOLD_FIRST",
    "METHODS",
    "Method",
    "identify_oe",
    "identify_rls",
    "in_time_order",
]

Method = Literal["ls", "rls", "oe"]
METHODS: tuple[Method, ...] = ("ls", "rls", "oe")
"""The identification methods of ``chaintwin identify --method``."""

MIN_LOAD_SPREAD_KG = 5.0
"""Loads must differ by this much for the output-error fit to fit BmA."""


def in_time_order(recordings: Sequence[Recording]) -> list[Recording]:
    """The recordings oldest first when every one has ``recorded_at``, else as given."""
    stamps = [r.metadata.recorded_at for r in recordings]
    if any(t is None for t in stamps):
        return list(recordings)
    order = sorted(range(len(recordings)), key=lambda k: stamps[k])  # type: ignore[arg-type,return-value]
    return [recordings[k] for k in order]


def identify_rls(
    recordings: Sequence[Recording],
    profile: ConveyorProfile,
    *,
    forgetting: float = DEFAULT_FORGETTING,
    hold_first: int = DEFAULT_HOLD_FIRST,
    version: str = "",
) -> tuple[Calibration, list[TrackPoint]]:
    """Track BmA and BmB over the recordings in time order with RLS.

    Parameters
    ----------
    recordings : sequence of Recording
        Recordings with a known ``payload_kg``, in time order (see
        :func:`in_time_order`).
    profile : ConveyorProfile
        The conveyor (its ``model:`` section is not read).
    forgetting : float
        Forgetting factor λ of the directional forgetting.
    hold_first : int
        J_d, μ and BmC are held at the batch fit of this many first recordings.
    version : str
        chaintwin version to record.

    Returns
    -------
    calibration : Calibration
        The batch calibration of all recordings (cases, torque lag, recording
        list) with the parameters after the last recording.
    track : list of TrackPoint
        The estimate after each recording.
    """
    if hold_first < 1:
        raise EstimationError(f"hold_first={hold_first!r} must be at least 1")
    id_prof = identification_profile(profile)
    held = RigidModelRegression().fit(recordings[:hold_first], id_prof).parameters_
    track, params = track_losses(recordings, id_prof, held, forgetting=forgetting)
    cal = calibrate(recordings, profile, version=version)
    cal = replace(
        cal,
        parameters=params,
        residual_rms_nm=math.nan,
        method=f"recursive least squares, directional forgetting λ = {forgetting:g}, "
        f"J_d, mu and BmC held at the batch fit of the first {min(hold_first, len(recordings))} "
        "recordings",
    )
    return cal, track


def identify_oe(
    recordings: Sequence[Recording],
    profile: ConveyorProfile,
    *,
    version: str = "",
) -> tuple[Calibration, dict[str, Any]]:
    """Fit the closed loop's output to the recordings (output error).

    Returns
    -------
    calibration : Calibration
        The batch calibration's other fields with the output-error fit's
        parameters and torque residual.
    details : dict
        ``rms_speed_rad_s``, ``agree`` (the starting points ended together),
        ``nfev`` (simulations) and ``fitted`` (names).
    """
    payloads = [r.metadata.payload_kg for r in recordings]
    if any(p is None for p in payloads):
        raise EstimationError("every recording needs payload_kg metadata for the output-error fit")
    loads = [float(p) for p in payloads if p is not None]
    names = ["mu", "loss_viscous_nm_s_rad", "drive_inertia_scale"]
    notes: list[RecordingWarning] = []
    if max(loads) - min(loads) >= MIN_LOAD_SPREAD_KG:
        names.append("loss_constant_nm")
    else:
        notes.append(
            RecordingWarning(
                "friction_not_separable",
                "all recordings carry the same load: rail friction and the constant gear "
                "loss BmA cannot be told apart; BmA was held at 0 Nm and mu absorbs it",
            )
        )
    peaks = []
    for r in recordings:
        sp = r.channels.get("speed_setpoint")
        peaks.append(float(np.max(np.abs(sp if sp is not None else r.speed))))
    if len(speed_clusters(peaks)) >= 2:
        names.append("loss_quadratic_nm_s2_rad2")
    else:
        notes.append(
            RecordingWarning(
                "losses_not_separable",
                "all recordings run at one speed: the quadratic gear loss BmC cannot be told "
                "from BmB and mu; BmC was held at 0",
            )
        )
    fit = OutputErrorFit(parameters=tuple(names))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", ConvergenceWarning)
        fit.fit(list(recordings), profile, payload_kg=loads)
    for w in caught:
        if issubclass(w.category, ConvergenceWarning):
            notes.append(RecordingWarning("fit_not_converged", str(w.message)))
    listed = profile.motor.inertia_kgm2 + profile.gear.inertia_kgm2
    theta, err = fit.theta_, fit.stderr_
    oe_name = {
        "J_d": "drive_inertia_scale",
        "mu": "mu",
        "BmA": "loss_constant_nm",
        "BmB": "loss_viscous_nm_s_rad",
        "BmC": "loss_quadratic_nm_s2_rad2",
    }
    values = np.zeros(len(PARAMETER_NAMES))
    cov = np.zeros((len(PARAMETER_NAMES), len(PARAMETER_NAMES)))
    fixed: list[str] = []
    for k, name in enumerate(PARAMETER_NAMES):
        key = oe_name[name]
        factor = listed if name == "J_d" else 1.0
        if key in theta:
            values[k] = theta[key] * factor
            cov[k, k] = (err[key] * factor) ** 2
        else:
            values[k] = 1.0 * factor if name == "J_d" else 0.0
            fixed.append(name)
    cal = calibrate(recordings, profile, version=version)
    recording_notes = tuple(w for w in cal.warnings if w.code not in ("friction_not_separable",))
    cal = replace(
        cal,
        parameters=RigidParameters(values, cov, tuple(fixed)),
        residual_rms_nm=fit.rms_torque_nm_,
        warnings=(*notes, *recording_notes),
        method="output-error fit of the closed loop (controller replica and rigid plant "
        "driven by the recorded set points)",
    )
    details = {
        "rms_speed_rad_s": fit.rms_speed_rad_s_,
        "agree": fit.agree_,
        "nfev": fit.nfev_,
        "fitted": list(names),
    }
    return cal, details
