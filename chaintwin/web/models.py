"""The JSON API's bodies: what each endpoint answers and accepts (pydantic models).

They are the OpenAPI document's schemas. The endpoints that answer much or
often (the fleet, a conveyor, its trends, a page of results, a recording, a
waterfall) encode their answers with orjson directly and declare these
models for the document; the others are validated against them as they
answer. Every answer matches its model (``tests/test_api_schema.py`` checks
it with schemathesis). Models marked closed (``extra="forbid"``) document
every field; the open ones (a result's ``features``, a profile) hold
whatever the named record holds.

Units as everywhere in the API: SI but where a name says otherwise
(``_kg``, ``_rpm``, ``_nm``, ``_days``); times are ISO 8601 strings in UTC.
"""

from __future__ import annotations

from datetime import datetime
from typing import Annotated, Any, Literal

from fastapi import UploadFile
from pydantic import AfterValidator, BaseModel, ConfigDict, Field

from chaintwin.diagnose.alarm_actions import MAX_SHELVE_MINUTES
from chaintwin.diagnose.records import date_in_span
from chaintwin.diagnose.state import MAINTENANCE_KINDS

__all__ = [
    "AcknowledgeBody",
    "Alarm",
    "AlarmKpis",
    "AuditEntry",
    "CommentBody",
    "ConveyorDetail",
    "ConveyorRow",
    "ErrorBody",
    "Health",
    "MaintenanceBody",
    "MaintenanceEvent",
    "NewToken",
    "OutOfServiceBody",
    "OutOfServiceWindow",
    "RecordingDetail",
    "ResultsPage",
    "ShelveBody",
    "StoreCounts",
    "TokenBody",
    "TokenInfo",
    "Trend",
    "Trends",
    "UploadForm",
    "UploadResult",
    "UploadedFile",
    "Waterfall",
]

Time = Annotated[str, Field(description="ISO 8601 time, UTC")]
"""A time as the store holds it."""

Number = int | float
"""A number that may be whole (kept as given: JSON ``3`` stays ``3``)."""


class Closed(BaseModel):
    """A body whose every field is documented (no others)."""

    model_config = ConfigDict(extra="forbid")


class Open(BaseModel):
    """A record whose named fields are documented; it may hold more."""

    model_config = ConfigDict(extra="allow")


# ------------------------------------------------------------------ errors
class ErrorDetail(Closed):
    """What went wrong: a stable code and a one-line message."""

    code: str
    message: str


class ErrorBody(Closed):
    """Every error of the API."""

    error: ErrorDetail


# ------------------------------------------------------------------ service
class StoreState(Closed):
    """The store behind the service."""

    url: str | None = Field(description="Its address, password hidden; null without a token")
    revision: str | None = Field(description="Its schema revision")
    conveyors: int = Field(description="Conveyors it holds")


class Health(Closed):
    """The service's state."""

    status: Literal["ok"]
    version: str = Field(description="chaintwin's version")
    store: StoreState
    live: dict[str, Any] | None = Field(
        default=None,
        description="With a token, in a process running live sources: each source's state "
        "and the ingest queue's depth",
    )


class StoreCounts(Closed):
    """How much the store holds."""

    url: str = Field(description="The store's address, password hidden")
    recordings: int
    results: int
    alarms: int
    calibrations: int


# ------------------------------------------------------------------ alarms
class Acknowledged(Closed):
    """Who acknowledged an alarm, why and when."""

    by: str
    why: str
    at: Time


class Shelved(Closed):
    """Who shelved an alarm, why, when and until when."""

    by: str
    why: str
    at: Time
    until: Time


class Comment(Closed):
    """A comment on an alarm."""

    by: str
    at: Time
    text: str


class Evidence(Closed):
    """A feature that exceeded with an alarm's cause."""

    feature: str
    kind: str = Field(description="statistical (against the baseline) or limit")
    value: float | None = Field(description="Its latest value that met the rule (feature units)")
    z: float | None = Field(description="Its distance from the baseline, robust scales")
    since: Time | None


class Alarm(Closed):
    """An alarm: one probable cause of a conveyor, its evidence and lifecycle.

    ``merged`` and ``limit`` appear only when they apply, ``closed_at`` and
    ``closed_by`` only on a closed alarm.
    """

    id: str
    conveyor: str
    feature: str
    cause: str
    change: Number | None = Field(
        description="Relative change of the feature that opened it against its baseline "
        "(0.2 = 20 % above); null where none is known (a baseline of zero, as an impact "
        "count's)"
    )
    since: Time | None
    opened_at: Time | None
    last_seen: Time | None
    status: str = Field(description="open or closed")
    acknowledged: Acknowledged | None
    rule: str
    kind: str
    lifecycle: str = Field(
        description="unacknowledged, acknowledged, returned_unacknowledged, shelved, "
        "out_of_service or closed"
    )
    evidence: list[Evidence]
    active: bool
    shelved_until: Time | None
    shelved: Shelved | None
    out_of_service: bool
    out_of_service_until: Time | None
    comments: list[Comment]
    merged: list[str] | None = None
    limit: Number | None = None
    closed_at: Time | None = None
    closed_by: str | None = None


class AlarmMark(Closed):
    """An open alarm in a fleet row."""

    id: str
    feature: str
    cause: str
    since: Time | None
    lifecycle: str | None = Field(description="Its lifecycle now; null when damaged")


class Kpis(Closed):
    """Alarm KPIs over a window (EEMUA 191, ISA-18.2)."""

    alarms: int
    alarms_per_day: Number
    acknowledged: int
    median_time_to_acknowledge_s: Number | None
    standing: int
    stale: int
    chattering: int
    chattering_causes: list[str]
    flood_periods: int
    shelved: int
    out_of_service: int


class AlarmKpis(Closed):
    """Alarm KPIs per conveyor and for the fleet over ``[since, until)``."""

    since: Time
    until: Time
    days: Number = Field(description="The window's length, days")
    fleet: Kpis
    conveyors: dict[str, Kpis]


# ------------------------------------------------------------------ conveyors
class Verdict(BaseModel):
    """The conveyor's verdict, the same in every view."""

    health: str = Field(
        description="alarm, acknowledged, shelved, watch, relearning, out_of_service, "
        "learning, no_data or ok"
    )
    health_since: Time | None
    ne107: str = Field(
        description="NAMUR NE 107: failure, check_function, off_spec, maintenance_required "
        "or normal"
    )
    ne107_since: Time | None
    health_index: float | None = Field(
        description="Largest normalised deviation (0 at the baseline, 1 at the limit); "
        "higher is worse"
    )
    deviation: float | None
    worst_feature: str | None


class ConveyorRow(Verdict):
    """A conveyor in the fleet: its verdict and latest result."""

    model_config = ConfigDict(extra="forbid")

    id: str
    last_recorded_at: Time | None
    payload_kg: float | None
    tlf: float | None = Field(description="Torque load factor of the latest result")
    status: str | None = Field(description="The latest result's status")
    alarm: bool
    open_alarms: list[AlarmMark]


class CalibrationSummary(Closed):
    """What a conveyor's calibration found."""

    case: str
    created_at: Time
    mu: float = Field(description="Rail friction coefficient")
    mu_stderr: float | None
    payload_sensitivity_rel_uncertainty: float | None
    recommendation: str | None
    directions: list[int]
    warnings: list[dict[str, Any]] = Field(description="What it found weak: code, message")


class MaintenanceEvent(Closed):
    """A maintenance event."""

    id: str
    kind: str
    at: Time
    by: str
    why: str
    recorded: Time
    applied: bool = Field(description="Whether the baseline restarted after it")


class ConveyorDetail(Verdict):
    """One conveyor: profile, calibration, baselines, verdict and forecasts."""

    model_config = ConfigDict(extra="forbid")

    id: str
    profile: dict[str, Any] = Field(description="Its profile, as its YAML file holds it")
    calibration: CalibrationSummary | None
    baseline_since: Time | None
    summary: dict[str, Any] = Field(
        description="The monitor's summary: baseline, usage, wear, events, forecasts, "
        "forecasts_as_of, open_alarms, notes"
    )
    forecasts: list[dict[str, Any]] = Field(
        description="Per trending feature: when it crosses its limit, remaining life"
    )
    status: str | None = Field(description="The latest result's status")
    features: list[str] = Field(description="Its tracked features")
    open_alarms: list[Alarm]
    recordings: int
    notes: list[str]


class StoredResult(Open):
    """A stored result (the monitor's record of one recording)."""

    file: str
    recorded_at: Time | None = None
    status: str | None = None
    alarm: bool | None = None
    payload_kg: float | None = None
    tlf: float | None = None
    features: dict[str, Any] | None = None
    conveyor: str
    recording_id: str = Field(description="The recording's content SHA-256")
    stored_at: Time | None


class ResultsPage(Closed):
    """Stored results, newest first, and where the next page starts."""

    items: list[StoredResult]
    next_cursor: str | None


class Series(Closed):
    """A recording's channels, thinned for plotting."""

    time_s: list[float]
    speed_rpm: list[float]
    torque_nm: list[float]
    model_torque_nm: list[float] | None = Field(
        description="The calibrated model's torque at the result's payload; null without"
    )


class RecordingDetail(Closed):
    """A stored result with its measured and model torque and speed."""

    result: StoredResult
    series: Series


class TrendPoint(Closed):
    """One result of a trend."""

    recorded_at: Time | None
    value: float | None
    exceeded: bool
    represents: int = Field(description="Results this point stands for (thinned history)")


class TrendAlarm(Closed):
    """An alarm of the trend's feature."""

    id: str
    since: Time | None
    closed_at: Time | None
    cause: str


class Trend(Closed):
    """A feature's series with its baseline band, alarms and forecast."""

    conveyor: str
    feature: str
    cause: str | None
    unit: str
    expected: float | None
    limit: float | None
    lower_limit: float | None
    points: list[TrendPoint]
    alarms: list[TrendAlarm]
    health_index: float | None
    forecast: dict[str, Any] | None = Field(
        description="When it crosses its limit, remaining life and band; null: none"
    )
    recordings: int
    max_points: int


class Trends(Closed):
    """Several features' trends, read in one pass."""

    conveyor: str
    trends: list[Trend]
    recordings: int
    max_points: int
    as_of: dict[str, Any] | None = Field(
        description="When the forecasts were computed: computed_at, latest, current, "
        "recordings_behind"
    )


class WaterfallRecording(Closed):
    """A recording of a waterfall."""

    recording_id: str | None
    file: str
    recorded_at: Time | None


class Waterfall(Closed):
    """The torque spectra of the latest recordings on one axis."""

    conveyor: str
    kind: Literal["order", "frequency"]
    x_unit: str
    x: list[float]
    recordings: list[WaterfallRecording]
    amplitude_nm: list[list[float | None]]
    lines: dict[str, float] = Field(description="Where speed-locked lines appear, on x")
    left_out: list[str] = Field(description="Recordings without readable samples")


class OutOfServiceWindow(Closed):
    """A conveyor's out-of-service window."""

    conveyor: str
    by: str
    why: str
    from_: Time = Field(alias="from")
    until: Time | None


# ------------------------------------------------------------------ admin
class TokenInfo(Closed):
    """A token (never the token itself)."""

    name: str
    role: str
    created_at: Time
    expires_at: Time | None
    revoked_at: Time | None
    active: bool


class NewToken(Closed):
    """A new token: the only time it is shown."""

    token: str
    name: str
    role: str


class AuditEntry(Closed):
    """An entry of the audit log."""

    at: Time
    who: str
    action: str
    detail: dict[str, Any]


# ------------------------------------------------------------------ request bodies
class AcknowledgeBody(BaseModel):
    """Why an alarm is acknowledged."""

    why: str = Field(min_length=1, max_length=2000)


class MaintenanceBody(BaseModel):
    """A maintenance event (the CLI's kinds)."""

    # the kinds are listed in the document (clients and schemathesis send only those);
    # another kind is answered 400 with the list, as the command line says it
    kind: str = Field(
        min_length=1, max_length=20, json_schema_extra={"enum": list(MAINTENANCE_KINDS)}
    )
    why: str = Field(min_length=1, max_length=2000)
    at: Annotated[
        datetime | None,
        AfterValidator(date_in_span),
        Field(description="When it was done (default now), within 1970-01-01..2200-01-01."),
    ] = None


class TokenBody(BaseModel):
    """A token to create."""

    name: str = Field(min_length=1, max_length=100)
    role: Literal["viewer", "maintainer", "admin"]
    expires_days: float | None = Field(default=None, gt=0, le=36500)


class ShelveBody(BaseModel):
    """Why and for how long an alarm is shelved."""

    why: str = Field(min_length=1, max_length=2000)
    minutes: float = Field(ge=1, le=MAX_SHELVE_MINUTES)


class CommentBody(BaseModel):
    """A comment on an alarm."""

    text: str = Field(min_length=1, max_length=4000)


class OutOfServiceBody(BaseModel):
    """Why and until when a conveyor is out of service (no ``until``: until put back)."""

    why: str = Field(min_length=1, max_length=2000)
    until: Annotated[
        datetime | None,
        AfterValidator(date_in_span),
        Field(description="Until when (default: until put back), within 1970-01-01..2200-01-01."),
    ] = None


class UploadForm(BaseModel):
    """An upload: files, and nothing else (any other part is refused, 422)."""

    model_config = ConfigDict(extra="forbid")
    files: list[UploadFile] = Field(min_length=1)


class UploadedFile(BaseModel):
    """What became of one uploaded file."""

    file: str
    status: Literal["stored", "already_stored", "refused"]
    reason: str | None
    """Why a refused file was refused (null for the others)."""
    recording_id: str | None
    """The stored recording's id (its content's SHA-256); null for a refused file."""


class UploadResult(BaseModel):
    """What became of each uploaded file."""

    files: list[UploadedFile]
