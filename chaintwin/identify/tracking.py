"""Tracking the rigid model's parameters over a conveyor's recordings with RLS.

The gear losses drift with temperature, running-in and lubrication; weighing
needs to know by how much since the calibration. :class:`ParameterTracker`
feeds each recording's windowed integrals (the rows of the batch regression,
:func:`chaintwin.identify.regression.design_matrix`) into
:class:`~chaintwin.identify.rls.RecursiveLeastSquares` with directional
forgetting, one recording after the other, and keeps the estimate after
each.

Rows
----
Per recording: the short and whole-ramp windows of
:func:`~chaintwin.model.windows.window_integrals`, weighted by
``1/√duration`` as the batch fit weights them, with the power-flow direction
from the current estimate. The polygon effect's tooth-pass ripple (the batch
fit's per-recording nuisance columns) is projected out of each recording's
rows, which is what fitting those columns for that recording alone would do.
Columns are scaled to a common size from the first recording's rows, so that
one forgetting factor means the same for every parameter.

Parameters that are held (``fixed``, e.g. BmA when every recording carries
the same load) are subtracted from the target and not tracked.

Forgetting
----------
Directional forgetting discounts old information only in the directions new
rows excite, so the memory is about ``p/(1 − λ)`` rows for p tracked
parameters; docs/methods/rls.md gives the measured trade-off between
following a step and the scatter when nothing changes.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from chaintwin._types import FloatArray
from chaintwin.errors import EstimationError
from chaintwin.identify.defaults import DEFAULT_FORGETTING
from chaintwin.identify.regression import design_matrix
from chaintwin.identify.rls import RecursiveLeastSquares
from chaintwin.model.rigid import PARAMETER_NAMES, RigidParameters, motoring_mask
from chaintwin.model.windows import window_integrals
from chaintwin.read.profile import ConveyorProfile
from chaintwin.read.recording import Recording

__all__ = [
    "DEFAULT_FORGETTING",
    "DEFAULT_TRACKED",
    "ParameterTracker",
    "TrackPoint",
    "track_losses",
]


DEFAULT_TRACKED: tuple[str, ...] = ("BmA", "BmB")
"""What :func:`track_losses` tracks: the constant and viscous gear losses. J_d and μ
do not drift with the gear oil; BmC is so weakly determined at a few speeds that
tracking it too raises the scatter of BmB from 0.7 % to 5 % (docs/methods/rls.md)."""


@dataclass(frozen=True, slots=True)
class TrackPoint:
    """The estimate after one recording.

    Parameters
    ----------
    file : str
        The recording's source.
    values : dict of str to float
        Every parameter of :data:`~chaintwin.model.rigid.PARAMETER_NAMES`
        (J_d kg·m², mu -, BmA Nm, BmB Nm·s/rad, BmC Nm·s²/rad²); held ones at
        their fixed value.
    stderr : dict of str to float
        Standard errors (0 for held ones).
    rows : int
        Rows (windows) this recording added.
    """

    file: str
    values: dict[str, float]
    stderr: dict[str, float]
    rows: int

    def to_dict(self) -> dict[str, object]:
        """JSON-ready."""
        return {
            "file": self.file,
            "values": dict(self.values),
            "stderr": dict(self.stderr),
            "rows": self.rows,
        }


class ParameterTracker:
    """Recursive least squares of the rigid model over recordings, in order.

    Parameters
    ----------
    profile : ConveyorProfile
        The conveyor (its ``model:`` section is not read).
    forgetting : float
        Forgetting factor λ in (0, 1] of the directional forgetting.
    fixed : mapping of str to float, optional
        Parameters held at a value and not tracked (names of
        :data:`~chaintwin.model.rigid.PARAMETER_NAMES`).
    start : mapping of str to float, optional
        Values the power-flow direction of the first recording is computed
        with (default the profile's motor + gear inertia and no losses).

    Raises
    ------
    EstimationError
        For a forgetting factor outside (0, 1], an unknown parameter name or
        nothing left to track.
    """

    def __init__(
        self,
        profile: ConveyorProfile,
        *,
        forgetting: float = DEFAULT_FORGETTING,
        fixed: Mapping[str, float] | None = None,
        start: Mapping[str, float] | None = None,
    ) -> None:
        if not (math.isfinite(forgetting) and 0.0 < forgetting <= 1.0):
            raise EstimationError(f"forgetting={forgetting!r} must lie in (0, 1]")
        fixed = dict(fixed or {})
        unknown = sorted(set(fixed) - set(PARAMETER_NAMES))
        if unknown:
            raise EstimationError(
                f"fixed: unknown parameter(s) {', '.join(unknown)}; choose from "
                f"{', '.join(PARAMETER_NAMES)}"
            )
        self.profile = profile
        self.forgetting = forgetting
        self.fixed = fixed
        self.free = tuple(n for n in PARAMETER_NAMES if n not in fixed)
        if not self.free:
            raise EstimationError("every parameter is fixed; nothing to track")
        self._cols = np.array([PARAMETER_NAMES.index(n) for n in self.free])
        self._held = np.array([PARAMETER_NAMES.index(n) for n in fixed], dtype=np.int64)
        self._held_values = np.array([fixed[n] for n in fixed], dtype=np.float64)
        jd0 = profile.motor.inertia_kgm2 + profile.gear.inertia_kgm2
        current = {"J_d": jd0, "mu": 0.0, "BmA": 0.0, "BmB": 0.0, "BmC": 0.0}
        current.update(start or {})
        current.update(fixed)
        self._current = current
        self._rls = RecursiveLeastSquares(forgetting=forgetting, delta=1.0e6)
        self._scale: FloatArray | None = None
        self.history: list[TrackPoint] = []

    def _rows(self, recording: Recording, payload_kg: float) -> tuple[FloatArray, FloatArray]:
        c = self._current
        tray = recording.metadata.tray_kg
        tray_kg = tray if tray is not None else self.profile.tray_mass_kg
        mot = motoring_mask(
            recording, drive_inertia_kgm2=c["J_d"], losses=(c["BmA"], c["BmB"], c["BmC"])
        )
        wi = window_integrals(recording, self.profile, motoring=mot)
        if wi.count == 0:
            raise EstimationError(
                f"{recording.source}: no window to track from; give a recording with a move"
            )
        x, y = design_matrix(wi, self.profile, payload_kg=payload_kg, tray_kg=tray_kg)
        w = 1.0 / np.sqrt(wi.duration)
        x = x * w[:, None]
        y = y * w
        if self._held.size:
            y = y - x[:, self._held] @ self._held_values
        x = x[:, self._cols]
        rip = wi.ripple * w[:, None]
        if rip.shape[1] and rip.shape[0] > rip.shape[1]:
            # project the recording's own ripple columns out of its rows
            q, _ = np.linalg.qr(rip)
            x = x - q @ (q.T @ x)
            y = y - q @ (q.T @ y)
        return x, y

    def update(self, recording: Recording, payload_kg: float | None = None) -> TrackPoint:
        """Add one recording's rows and return the estimate after it.

        Parameters
        ----------
        recording : Recording
            The next recording of the conveyor (SI).
        payload_kg : float, optional
            Its payload, kg; default its ``payload_kg`` metadata.

        Raises
        ------
        EstimationError
            When the payload is unknown or the recording holds no window.
        """
        if payload_kg is None:
            payload_kg = recording.metadata.payload_kg
        if payload_kg is None:
            raise EstimationError(
                f"{recording.source}: no payload_kg in its metadata; tracking needs a known "
                "load (add '# payload_kg: <kg>')"
            )
        x, y = self._rows(recording, payload_kg)
        if self._scale is None:
            scale = np.sqrt(np.mean(x * x, axis=0))
            scale[~(scale > 0.0)] = 1.0
            self._scale = scale
        self._rls.partial_fit(x / self._scale, y)
        theta = self._rls.theta_ / self._scale
        err = self._rls.stderr_ / self._scale
        values = dict(self._current)
        stderr = dict.fromkeys(PARAMETER_NAMES, 0.0)
        for name, v, e in zip(self.free, theta, err, strict=True):
            values[name] = float(v)
            stderr[name] = float(e)
        self._current = values
        point = TrackPoint(recording.source, values, stderr, int(x.shape[0]))
        self.history.append(point)
        return point

    def track(
        self, recordings: Sequence[Recording], payloads_kg: Sequence[float] | None = None
    ) -> list[TrackPoint]:
        """:meth:`update` with each recording in order; the estimate after each."""
        return [
            self.update(rec, None if payloads_kg is None else payloads_kg[k])
            for k, rec in enumerate(recordings)
        ]

    def parameters(self, held: RigidParameters | None = None) -> RigidParameters:
        """The current estimate with its covariance.

        Parameters
        ----------
        held : RigidParameters, optional
            Where the held values came from: their covariance (and its list
            of fixed names) is kept for them; without it held parameters get
            zero rows and count as fixed.
        """
        if self._scale is None:
            raise EstimationError("no recording tracked yet; call update() first")
        n = len(PARAMETER_NAMES)
        cov = np.zeros((n, n)) if held is None else np.array(held.covariance, dtype=np.float64)
        cov[self._cols, :] = 0.0
        cov[:, self._cols] = 0.0
        cov_free = self._rls.covariance_ / np.outer(self._scale, self._scale)
        cov[np.ix_(self._cols, self._cols)] = cov_free
        values = np.array([self._current[n] for n in PARAMETER_NAMES])
        if held is None:
            fixed = tuple(n for n in PARAMETER_NAMES if n in self.fixed)
        else:
            fixed = tuple(n for n in held.fixed if n not in self.free)
        return RigidParameters(values, cov, fixed)


def track_losses(
    recordings: Sequence[Recording],
    profile: ConveyorProfile,
    held: RigidParameters,
    *,
    forgetting: float = DEFAULT_FORGETTING,
    tracked: Sequence[str] = DEFAULT_TRACKED,
    payloads_kg: Sequence[float] | None = None,
) -> tuple[list[TrackPoint], RigidParameters]:
    """Track gear losses over recordings in order, the other parameters held.

    Parameters
    ----------
    recordings : sequence of Recording
        A conveyor's recordings with known payloads, oldest first.
    profile : ConveyorProfile
        The conveyor.
    held : RigidParameters
        Values (and covariance) of the parameters that are not tracked, e.g.
        a calibration's or a batch fit's; the tracked ones start from them
        for the first power-flow mask.
    forgetting : float
        Forgetting factor λ.
    tracked : sequence of str
        Parameters to track (default BmA, BmB).
    payloads_kg : sequence of float, optional
        Payload per recording, kg (default each one's metadata).

    Returns
    -------
    points : list of TrackPoint
        The estimate after each recording.
    parameters : RigidParameters
        The estimate after the last, the held parameters' covariance kept.
    """
    names = tuple(tracked)
    unknown = sorted(set(names) - set(PARAMETER_NAMES))
    if unknown or not names:
        raise EstimationError(
            f"tracked: give one or more of {', '.join(PARAMETER_NAMES)}; got {', '.join(names)}"
        )
    values = held.as_dict()
    fixed = {n: v for n, v in values.items() if n not in names}
    tracker = ParameterTracker(profile, forgetting=forgetting, fixed=fixed, start=values)
    points = tracker.track(recordings, payloads_kg)
    return points, tracker.parameters(held)
