"""Dynamic weighing and the transport loss factor, from a calibration."""

from chaintwin.weigh.tlf import MIN_PAYLOAD_KG, sprocket_work_and_distance, transport_loss_factor
from chaintwin.weigh.weigh import CONSISTENCY_SIGMA, Segment, WeighResult, weigh

__all__ = [
    "CONSISTENCY_SIGMA",
    "MIN_PAYLOAD_KG",
    "Segment",
    "WeighResult",
    "sprocket_work_and_distance",
    "transport_loss_factor",
    "weigh",
]
