"""Condition monitoring: residuals, spectra, features, health model and alarms.

The names below are imported on first use (PEP 562): a worker process that
needs the features does not load the health model with them.
"""

import typing as _typing

from chaintwin._lazy import lazy_getattr

if _typing.TYPE_CHECKING:
    from chaintwin.diagnose.causes import resolve_causes
    from chaintwin.diagnose.features import RecordingFeatures, recording_features
    from chaintwin.diagnose.monitor import ConveyorMonitor
    from chaintwin.diagnose.records import MonitorSettings, RecordingResult, SettingsGiven
    from chaintwin.diagnose.residuals import ResidualReport, residual_analysis
    from chaintwin.diagnose.spectra import Spectrum, order_spectrum, welch_spectrum
    from chaintwin.diagnose.state import load_state, save_state

_LAZY: dict[str, str] = {
    "ConveyorMonitor": "chaintwin.diagnose.monitor",
    "MonitorSettings": "chaintwin.diagnose.records",
    "RecordingFeatures": "chaintwin.diagnose.features",
    "RecordingResult": "chaintwin.diagnose.records",
    "ResidualReport": "chaintwin.diagnose.residuals",
    "SettingsGiven": "chaintwin.diagnose.records",
    "Spectrum": "chaintwin.diagnose.spectra",
    "load_state": "chaintwin.diagnose.state",
    "order_spectrum": "chaintwin.diagnose.spectra",
    "recording_features": "chaintwin.diagnose.features",
    "residual_analysis": "chaintwin.diagnose.residuals",
    "resolve_causes": "chaintwin.diagnose.causes",
    "save_state": "chaintwin.diagnose.state",
    "welch_spectrum": "chaintwin.diagnose.spectra",
}

__all__ = [
    "ConveyorMonitor",
    "MonitorSettings",
    "RecordingFeatures",
    "RecordingResult",
    "ResidualReport",
    "SettingsGiven",
    "Spectrum",
    "load_state",
    "order_spectrum",
    "recording_features",
    "residual_analysis",
    "resolve_causes",
    "save_state",
    "welch_spectrum",
]


__getattr__ = lazy_getattr(__name__, _LAZY)
