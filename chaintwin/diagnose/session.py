"""Going on with a conveyor's health model: the one orchestration of ``monitor`` and ``ingest``.

Both commands do the same around :class:`~chaintwin.diagnose.monitor.ConveyorMonitor`:
take up the saved model (from a state file or from the store) or start one,
reconcile it with the calibration and settings given now (:func:`resume`),
then hand it the conveyor's recordings in recorded order, a recording
without a recorded time marked as such (:func:`undated`). Only where the
model is kept differs.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Literal

from chaintwin.errors import StoreError
from chaintwin.identify.calibration import Calibration
from chaintwin.read.profile import ConveyorProfile
from chaintwin.read.recording import Recording, RecordingWarning

from .monitor import ConveyorMonitor
from .records import MonitorSettings, RecordingResult

__all__ = ["OtherCalibration", "resume", "undated"]

OtherCalibration = Literal["refuse", "replace"]
"""What to do when the model was made with another calibration from a file:
``refuse`` (a state file given another ``--calibration``: most likely the
wrong file) or ``replace`` (the store's calibration was made anew with
``calibrate --db``: the newest one is meant)."""


def _same_parameters(a: Calibration, b: Calibration) -> bool:
    return bool(a.to_dict()["parameters"] == b.to_dict()["parameters"])


def resume(
    saved: ConveyorMonitor | None,
    profile: ConveyorProfile,
    settings: MonitorSettings,
    calibration: Calibration | None,
    *,
    loader: Callable[[str], Recording] | None = None,
    other_calibration: OtherCalibration = "refuse",
    source: str = "<state>",
) -> tuple[ConveyorMonitor, list[RecordingResult]]:
    """The health model to go on with, and results it gives at once.

    Parameters
    ----------
    saved : ConveyorMonitor, optional
        The model restored from where it is kept (None: the conveyor is new).
    profile : ConveyorProfile
        The conveyor.
    settings : MonitorSettings
        The settings to monitor with from now on.
    calibration : Calibration, optional
        The calibration given now (None: the model's own, or learned).
    loader : callable, optional
        Reads a recording again by file name (a new model's pending recordings).
    other_calibration : {"refuse", "replace"}
        See :data:`OtherCalibration`.
    source : str
        Where the model is kept, for messages.

    Returns
    -------
    (ConveyorMonitor, list of RecordingResult)
        The model, and the results of recordings that waited for a
        calibration and are weighed now with the given one.

    Raises
    ------
    StoreError
        When the model was made with another calibration from a file and
        ``other_calibration`` is ``refuse``.
    """
    if saved is None:
        return ConveyorMonitor(profile, settings, calibration, loader=loader), []
    mon = saved
    if settings.residual != mon.settings.residual:
        # the residual features mean something else: the baseline starts again
        mon.restart_baseline()
    mon.settings = settings
    if calibration is None or (
        mon.calibration is not None and _same_parameters(calibration, mon.calibration)
    ):
        return mon, []
    if mon.calibration_source == "file" and other_calibration == "refuse":
        raise StoreError(
            f"{source}: conveyor '{profile.id}' is monitored with another calibration; "
            "use a new state file to monitor it with this one"
        )
    # a calibration replaces a learned one, a sibling's or an older one: the
    # features change with the model, so the baseline starts again
    mon.set_calibration(calibration)
    mon.restart_baseline()
    return mon, mon.flush_pending()


def undated(recording: Recording) -> Recording:
    """The recording marked as having no recorded time (monitored after its predecessor)."""
    return recording.with_warnings(
        RecordingWarning(
            "no_recorded_at",
            "no recorded_at in the metadata: processed in file order after the recording before it",
        )
    )
