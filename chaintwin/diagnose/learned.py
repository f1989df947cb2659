"""A calibration learned from a conveyor's own recordings, payloads unknown.

Monitoring needs a model of the healthy conveyor to compute its features.
Without a calibration file it learns one from the first recordings (their
payloads vary and are not known):

1. Each recording is identified alone with its payload taken as zero, so
   the fitted drive inertia holds the payload's inertia too:
   ``J'_k = J_d + p_k·(r/i)²``. With J_d from the profile's motor and gear
   data (the datasheet inertias, not the ``model:`` section) that gives an
   estimate of each payload, p_k = (J'_k − J_d)·(i/r)².
2. The recordings are calibrated together with these payloads as if they
   were known (:func:`~chaintwin.calibrating.procedure.calibrate`): the
   payloads' spread separates the rail friction from the constant loss.

What this costs, compared with a calibration on known loads: a datasheet
inertia off by 1 % shifts every payload by ``0.01·J_d·(i/r)²`` (about 6 kg
on the reference conveyor) and the payloads' estimation scatter
(1-4 kg each) flattens the friction slope by ``σ_p²/var(p)`` (several
percent). Monitoring compares each conveyor with its own baseline, which
such offsets do not disturb, but the payloads it reports carry the warning
``payload_uncalibrated``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

from chaintwin.calibrating.procedure import calibrate
from chaintwin.errors import EstimationError
from chaintwin.identify.calibration import Calibration, identification_profile
from chaintwin.identify.regression import RigidModelRegression
from chaintwin.read.profile import ConveyorProfile
from chaintwin.read.recording import Recording, RecordingWarning

__all__ = ["LEARNED_METHOD", "learn_calibration"]

LEARNED_METHOD = (
    "learned from the conveyor's own recordings: payloads from each recording's inertia "
    "(profile datasheet J_d), then windowed least squares of the rigid model"
)
"""The ``method`` of a learned calibration."""


def learn_calibration(
    recordings: Sequence[Recording], profile: ConveyorProfile, *, version: str = ""
) -> Calibration:
    """Learn a calibration from recordings with unknown payloads.

    Parameters
    ----------
    recordings : sequence of Recording
        Healthy recordings of one conveyor, each with a ramp to and from a
        plateau (their ``payload_kg`` metadata, if any, is not used).
    profile : ConveyorProfile
        The conveyor (its ``model:`` section is not read).
    version : str
        chaintwin version to record.

    Returns
    -------
    Calibration
        With ``case`` ``learned``, ``method`` :data:`LEARNED_METHOD` and the
        warnings ``learned_calibration`` and ``calibration_weak`` (which run
        to record).

    Raises
    ------
    EstimationError
        When fewer than three recordings can be identified.
    """
    prof = identification_profile(profile)
    jd = prof.motor.inertia_kgm2 + prof.gear.inertia_kgm2
    per_kg = (prof.chordal_radius_m / prof.kinematic_ratio) ** 2
    usable: list[Recording] = []
    for rec in recordings:
        try:
            est = RigidModelRegression().fit([rec], prof, payloads_kg=[0.0])
        except EstimationError:
            continue
        payload = max(0.0, (float(est.theta_[0]) - jd) / per_kg)
        meta = dataclasses.replace(rec.metadata, payload_kg=payload)
        usable.append(dataclasses.replace(rec, metadata=meta))
    if len(usable) < 3:
        raise EstimationError(
            f"only {len(usable)} of {len(recordings)} recordings could be identified; "
            "learning a calibration needs at least three complete moves"
        )
    cal = calibrate(usable, profile, version=version)
    note = RecordingWarning(
        "learned_calibration",
        f"no calibration given: learned from {len(usable)} recordings with payloads estimated "
        "from their inertia and the profile's datasheet inertia; payloads are offset by that "
        "inertia's error, features are compared with this conveyor's own baseline",
    )
    # its payloads are estimates: no reference zero for known runs to be read against
    cal = dataclasses.replace(cal, case="learned", method=LEARNED_METHOD, zero_reference=None)
    weak = RecordingWarning("calibration_weak", cal.recommendation() or "")
    kept = tuple(w for w in cal.warnings if w.code != "calibration_weak")
    return dataclasses.replace(cal, warnings=(*kept, note, weak))
