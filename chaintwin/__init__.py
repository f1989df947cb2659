"""chaintwin: a digital twin of gearmotor-driven chain belt conveyors.

Built only on what the frequency inverter records. Each stage is a
subpackage with plain typed inputs and outputs; a subpackage imports only
those below it, in the order written in docs/design.md ("Layers") and
checked by ``make test``.

The names below are imported on first use (PEP 562), so that importing one
part (``chaintwin.errors``, the command line's entry point, the worker side of
an ingest) does not load them all: the simulator, the validation filters and
what they import cost most of a second. The subpackage ``chaintwin.simulate``
holds the simulator (``chaintwin.simulate.simulate``, ``run_virtual``, ...).
"""

import importlib as _importlib
import typing as _typing

if _typing.TYPE_CHECKING:
    from chaintwin.calibrating import calibrate
    from chaintwin.diagnose import ConveyorMonitor, MonitorSettings
    from chaintwin.errors import (
        CalibrationError,
        ChaintwinError,
        ColumnMapError,
        ConnectorError,
        ConvergenceWarning,
        DataError,
        EstimationError,
        ModelError,
        MonitorError,
        NotFittedError,
        ProfileError,
        RecordingError,
        StoreError,
    )
    from chaintwin.identify import (
        Calibration,
        OutputErrorFit,
        RecursiveLeastSquares,
        RigidModelRegression,
        TorqueLagEstimator,
        load_calibration,
    )
    from chaintwin.model import RigidParameters, characteristic_table, model_torque
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
    from chaintwin.simulate import Fault, PlantParameters, Realism, run_virtual
    from chaintwin.store import Store
    from chaintwin.validate import Inspection, Phase, inspect_recording, load_recording, segment
    from chaintwin.weigh import WeighResult, transport_loss_factor

__version__ = "0.1.0"

_LAZY: dict[str, str] = {
    "Calibration": "chaintwin.identify",
    "CalibrationError": "chaintwin.errors",
    "ChaintwinError": "chaintwin.errors",
    "ColumnMap": "chaintwin.read",
    "ColumnMapError": "chaintwin.errors",
    "ConnectorError": "chaintwin.errors",
    "ConvergenceWarning": "chaintwin.errors",
    "ConveyorMonitor": "chaintwin.diagnose",
    "ConveyorProfile": "chaintwin.read",
    "DataError": "chaintwin.errors",
    "EstimationError": "chaintwin.errors",
    "Fault": "chaintwin.simulate",
    "Inspection": "chaintwin.validate",
    "Metadata": "chaintwin.read",
    "ModelError": "chaintwin.errors",
    "MonitorError": "chaintwin.errors",
    "MonitorSettings": "chaintwin.diagnose",
    "NotFittedError": "chaintwin.errors",
    "OutputErrorFit": "chaintwin.identify",
    "Phase": "chaintwin.validate",
    "PlantParameters": "chaintwin.simulate",
    "ProfileError": "chaintwin.errors",
    "Realism": "chaintwin.simulate",
    "Recording": "chaintwin.read",
    "RecordingError": "chaintwin.errors",
    "RecordingWarning": "chaintwin.read",
    "RecursiveLeastSquares": "chaintwin.identify",
    "RigidModelRegression": "chaintwin.identify",
    "RigidParameters": "chaintwin.model",
    "Store": "chaintwin.store",
    "StoreError": "chaintwin.errors",
    "TorqueLagEstimator": "chaintwin.identify",
    "WeighResult": "chaintwin.weigh",
    "calibrate": "chaintwin.calibrating",
    "characteristic_table": "chaintwin.model",
    "format_recording": "chaintwin.read",
    "inspect_recording": "chaintwin.validate",
    "load_calibration": "chaintwin.identify",
    "load_column_map": "chaintwin.read",
    "load_profile": "chaintwin.read",
    "load_profiles": "chaintwin.read",
    "load_recording": "chaintwin.validate",
    "model_torque": "chaintwin.model",
    "parse_recording": "chaintwin.read",
    "read_recording": "chaintwin.read",
    "run_virtual": "chaintwin.simulate",
    "segment": "chaintwin.validate",
    "transport_loss_factor": "chaintwin.weigh",
    "write_recording": "chaintwin.read",
}
"""Module of each public name."""

__all__ = [
    "Calibration",
    "CalibrationError",
    "ChaintwinError",
    "ColumnMap",
    "ColumnMapError",
    "ConnectorError",
    "ConvergenceWarning",
    "ConveyorMonitor",
    "ConveyorProfile",
    "DataError",
    "EstimationError",
    "Fault",
    "Inspection",
    "Metadata",
    "ModelError",
    "MonitorError",
    "MonitorSettings",
    "NotFittedError",
    "OutputErrorFit",
    "Phase",
    "PlantParameters",
    "ProfileError",
    "Realism",
    "Recording",
    "RecordingError",
    "RecordingWarning",
    "RecursiveLeastSquares",
    "RigidModelRegression",
    "RigidParameters",
    "Store",
    "StoreError",
    "TorqueLagEstimator",
    "WeighResult",
    "__version__",
    "calibrate",
    "characteristic_table",
    "format_recording",
    "inspect_recording",
    "load_calibration",
    "load_column_map",
    "load_profile",
    "load_profiles",
    "load_recording",
    "model_torque",
    "parse_recording",
    "read_recording",
    "run_virtual",
    "segment",
    "transport_loss_factor",
    "write_recording",
]


_SUBPACKAGES = frozenset(
    {"calibrating", "cli", "diagnose", "errors", "identify", "ingest", "live", "model", "physics"}
    | {"read", "report", "simulate", "store", "units", "validate", "web", "weigh"}
)
"""Parts reachable as attributes (``chaintwin.read``) without importing them first."""


def __getattr__(name: str) -> _typing.Any:
    """Import a public name, or a part of the package, on first use."""
    if name in _SUBPACKAGES:
        return _importlib.import_module(f"chaintwin.{name}")
    try:
        module = _LAZY[name]
    except KeyError:
        raise AttributeError(f"module 'chaintwin' has no attribute {name!r}") from None
    value = getattr(_importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    """The public names, imported or not, and what the package holds."""
    return sorted(set(globals()) | set(__all__))
