"""chaintwin: a digital twin of gearmotor-driven chain belt conveyors.

Built only on what the frequency inverter records. Data flows one way:
read → validate → identify/weigh → diagnose → store → report; each stage is
a subpackage with plain typed inputs and outputs.
"""

from chaintwin.errors import (
    ChaintwinError,
    ColumnMapError,
    ConnectorError,
    DataError,
    EstimationError,
    ModelError,
    NotFittedError,
    ProfileError,
    RecordingError,
    StoreError,
)
from chaintwin.model import characteristic_table
from chaintwin.read import (
    ColumnMap,
    ConveyorProfile,
    Metadata,
    Recording,
    RecordingWarning,
    format_recording,
    load_column_map,
    load_profile,
    load_profiles,
    parse_recording,
    read_recording,
    write_recording,
)
from chaintwin.simulate import Fault, PlantParameters, Realism, run_virtual, simulate
from chaintwin.validate import Inspection, Phase, inspect_recording, load_recording, segment

__version__ = "0.1.0"

__all__ = [
    "ChaintwinError",
    "ColumnMap",
    "ColumnMapError",
    "ConnectorError",
    "ConveyorProfile",
    "DataError",
    "EstimationError",
    "Fault",
    "Inspection",
    "Metadata",
    "ModelError",
    "NotFittedError",
    "Phase",
    "PlantParameters",
    "ProfileError",
    "Realism",
    "Recording",
    "RecordingError",
    "RecordingWarning",
    "StoreError",
    "__version__",
    "characteristic_table",
    "format_recording",
    "inspect_recording",
    "load_column_map",
    "load_profile",
    "load_profiles",
    "load_recording",
    "parse_recording",
    "read_recording",
    "run_virtual",
    "segment",
    "simulate",
    "write_recording",
]
