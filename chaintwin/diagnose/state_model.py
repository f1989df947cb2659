"""The shape of a saved health model, checked field by field when it is read.

A conveyor's entry of a state file (or of the store's ``monitor_states``)
comes from a file a user may edit: :func:`check_state_shape` validates every
field's type (and integers' size) with pydantic before
:class:`~chaintwin.diagnose.monitor_state.MonitorState` is built from it, so
that a tampered value is refused in one line naming its field
(``baseline_rows: "x"``, ``windows: {"comb_rotor": "abc"}``) instead of
failing later, deep inside monitoring. Alarms, events, baselines and the
calibration are checked by their own readers; here only their container's
shape. Unknown keys are ignored, as readers of older states did.
"""

from __future__ import annotations

from typing import Annotated, Any

from pydantic import BaseModel, ConfigDict, Field, Strict, TypeAdapter, ValidationError

from chaintwin.errors import StoreError
from chaintwin.read.profile import _format_validation_error

__all__ = ["MAX_COUNT", "check_state_shape"]

MAX_COUNT = 2**63 - 1
"""Largest integer a state holds (a 64-bit count: what SQLite and numpy hold)."""

Int = Annotated[int, Strict(), Field(ge=-MAX_COUNT, le=MAX_COUNT)]
Count = Annotated[int, Strict(), Field(ge=0, le=MAX_COUNT)]
Number = Annotated[float, Strict()]
Text = Annotated[str, Strict()]
Flag = Annotated[bool, Strict()]
Spectrum = tuple[list[Number], list[Number], Number]


class _Entry(BaseModel):
    """A part of a state: its known fields checked, others ignored."""

    model_config = ConfigDict(extra="ignore")


class _Settings(_Entry):
    baseline_n: Count
    x: Count
    y: Count
    z_limit: Number
    residual: Text = "inverse"


class _Pending(_Entry):
    path: Text
    file: Text
    sha256: Text | None
    warnings: list[dict[Text, Text]]


class _Baseline(_Entry):
    intercept: Number
    slope: Number
    scale: Number
    count: Count
    outliers: Count
    mean_payload_kg: Number
    regressor: Text | None = None
    top_residual: Number | None = None
    bottom_residual: Number | None = None
    payload_range_kg: tuple[Number, Number] | None = None
    curve: tuple[list[Number], list[Number]] | None = None


class _Result(_Entry):
    """A recording's result in the recent history (what forecasts and wear read)."""

    file: Text
    conveyor: Text | None = None
    recorded_at: Text | None = None
    status: Text | None = None
    alarm: Flag = False
    causes: list[dict[Text, Any]] = []
    payload_kg: Number | None = None
    uncertainty_kg: Number | None = None
    tlf: Number | None = None
    features: dict[Text, Number | None] | None = None
    exceeded: list[Text] = []
    warnings: list[dict[Text, Text]] = []
    sha256: Text | None = None


class _State(_Entry):
    conveyor: Text
    profile_sha256: Text
    settings: _Settings
    calibration: dict[Text, Any] | None
    calibration_source: Text
    pending: list[_Pending]
    baseline_rows: list[dict[Text, Number | None]]
    late_rows: list[dict[Text, Number | None]]
    baseline_spectra: list[Spectrum | None]
    baselines: dict[Text, _Baseline] | None
    baseline_spectrum: Spectrum | None
    baseline_since: Text | None
    belt_last: list[Number | None]
    belt_prev: list[Number | None]
    windows: dict[Text, list[Flag]]
    window_times: dict[Text, list[Text | None]]
    alarms: list[dict[Text, Any]]
    events: list[dict[Text, Any]]
    history: list[_Result]
    notes: list[dict[Text, Text]]
    last_recorded_at: Text | None


_STATE = TypeAdapter(_State)


def check_state_shape(data: Any, source: str) -> None:
    """Refuse a saved health model whose fields do not have their types.

    Parameters
    ----------
    data : Any
        A conveyor's entry of a state file, as parsed from JSON.
    source : str
        Where it came from, for messages.

    Raises
    ------
    StoreError
        Naming the first fields that are wrong (``field 'windows.comb_rotor'``).
    """
    try:
        _STATE.validate_python(data)
    except ValidationError as exc:
        conveyor = data.get("conveyor") if isinstance(data, dict) else None
        where = f"{source}: monitoring state of '{conveyor}' is damaged"
        raise StoreError(
            _format_validation_error(where, exc)
            + "; restore it from a backup or start a new state file"
        ) from None
