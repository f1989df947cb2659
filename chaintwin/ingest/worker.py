"""The part of an ingest that runs in a worker process: read, validate and weigh.

Kept apart from :mod:`chaintwin.ingest.pipeline` so that a worker imports only
the pipeline (reader, validation, weighing, features) and not the store
(SQLAlchemy) or the health model (statsmodels): the fork server that starts
local workers then holds about half the memory, and forks, and its workers
start, exit and touch their copied pages, faster. A Dask worker imports the
same module.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from typing import NamedTuple

from chaintwin.diagnose.features import RecordingFeatures, recording_features
from chaintwin.errors import ChaintwinError, EstimationError
from chaintwin.identify.calibration import Calibration
from chaintwin.read.columns import ColumnMap
from chaintwin.read.profile import ConveyorProfile
from chaintwin.read.recording import Recording
from chaintwin.store.samples import PackedChannels
from chaintwin.validate.checks import load_recording

__all__ = ["Prepared", "prepare", "prepare_many"]


class Prepared(NamedTuple):
    """What a worker sends back for one recording."""

    recording: Recording | None
    features: RecordingFeatures | None
    error: str | None
    samples: bytes | None
    """The packed channels (``recording.channels.blob``), as the store keeps them."""


def prepare(
    path: str,
    profile: ConveyorProfile,
    column_map: ColumnMap | None,
    calibration: Calibration | None,
) -> Prepared:
    """Read, validate and (with a calibration) weigh one recording: the parallel part.

    Parameters
    ----------
    path : str
        Recording file.
    profile : ConveyorProfile
        Its conveyor's profile.
    column_map : ColumnMap, optional
        For exports named otherwise.
    calibration : Calibration, optional
        The conveyor's calibration; without one only reading and validation run.

    Returns
    -------
    Prepared
        The recording (its channels packed), its features, or why it was refused.
        Any failure of this one recording, expected or not, is its refusal with
        the reason: one bad file must not cost the batch.
    """
    try:
        return _prepare(path, profile, column_map, calibration)
    except Exception as exc:
        reason = (
            f"{path}: could not be processed ({type(exc).__name__}: {exc}); the other "
            "recordings go on. This is a chaintwin bug: please report it with the file"
        )
        return Prepared(None, None, reason, None)


def _prepare(
    path: str,
    profile: ConveyorProfile,
    column_map: ColumnMap | None,
    calibration: Calibration | None,
) -> Prepared:
    try:
        inspection = load_recording(path, profile=profile, column_map=column_map)
    except ChaintwinError as exc:
        return Prepared(None, None, str(exc), None)
    rec = inspection.recording
    # the recording travels back packed (a third of its size), and the same
    # bytes are what the store keeps
    channels = PackedChannels.of(rec.channels)
    rec = replace(rec, channels=channels)
    samples = channels.blob
    if calibration is None:
        return Prepared(rec, None, None, samples)
    try:
        features = recording_features(replace(inspection, recording=rec), calibration)
        return Prepared(rec, features, None, samples)
    except EstimationError:
        return Prepared(rec, None, None, samples)  # the monitor reports it in its own words


def prepare_many(
    paths: Sequence[str],
    profile: ConveyorProfile,
    column_map: ColumnMap | None,
    calibration: Calibration | None,
) -> list[Prepared]:
    """:func:`prepare` for several recordings: one task, one round trip to a worker."""
    return [prepare(p, profile, column_map, calibration) for p in paths]
