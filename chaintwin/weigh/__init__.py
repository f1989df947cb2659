"""Dynamic weighing and the transport loss factor, from a calibration."""

from chaintwin.weigh.drift import LossDrift
from chaintwin.weigh.tlf import MIN_PAYLOAD_KG, sprocket_work_and_distance, transport_loss_factor
from chaintwin.weigh.weigh import (
    CONSISTENCY_SIGMA,
    Segment,
    Signatures,
    WeighResult,
    reweigh,
    weigh,
)

__all__ = [
    "CONSISTENCY_SIGMA",
    "MIN_PAYLOAD_KG",
    "LossDrift",
    "Segment",
    "Signatures",
    "WeighResult",
    "reweigh",
    "sprocket_work_and_distance",
    "transport_loss_factor",
    "weigh",
]
