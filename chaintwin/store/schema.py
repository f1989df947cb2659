"""The results store's tables (SQLAlchemy), the same on SQLite and PostgreSQL.

=================  =============================================================
table              what a row holds
=================  =============================================================
``schema``         the schema version before Alembic (one row): 2 from revision
                   0002 on, so that chaintwin 0.1.0 refuses newer stores
``alembic_version`` the Alembic revision of the tables (:mod:`.migrate`)
``conveyors``      a conveyor: id, its profile (YAML as JSON) and the profile's
                   SHA-256
``calibrations``   a calibration file's content, per conveyor, newest used
``recordings``     a recording: content SHA-256 (unique: the same file twice is
                   stored once), file as given, conveyor, recorded_at,
                   metadata, warnings, and the samples (compressed), so that any
                   result can be recomputed
``results``        what monitoring said of a recording (the ``monitor --json``
                   object), with its main numbers as columns for queries
``monitor_states`` the health model of a conveyor (baseline, belt map, alarm
                   windows): :meth:`ConveyorMonitor.to_state` as JSON
``derived_health`` what is computed from a conveyor's health model after ingest
                   (trend forecasts with their bands, wear rates), with the
                   fingerprint of the model's inputs it was computed from, so
                   that pages read it rather than refit it
``trend_series``   each conveyor's trends as built after ingest (every tracked
                   feature's points, pre-serialised JSON, and its fixed
                   fields), with the fingerprint of what they were built
                   from, so that the trends endpoint reads them
``alarms``         alarms with their life: opened, acknowledged, closed
``alarm_aliases``  alarm ids that now name another alarm (alarms of one cause
                   grouped into one): old id, the alarm's id
``events``         maintenance events with who, when, why
``api_tokens``     the web service's access tokens: name, role, a keyed SHA-256
                   of the token (never the token), created, expires, revoked
``audit_log``      who did what when through the web service (logins, changes)
``secrets``        random keys the web service needs, created on first use and
                   shared by every process on the store (token-hash key,
                   session-cookie key)
``web_sessions``   the browser sessions: a SHA-256 of the session id (never the
                   id), its token's name, CSRF nonce, created, expires; logging
                   out deletes the row
``refused_files``  files the live service refused (content SHA-256, path, the
                   one-line reason, its cause and conveyor): not read again until
                   their content changes, or (cause ``profile``) until a profile
                   is added or changed, or ``chaintwin refused retry``
``outbox``         alarm notifications to send (one row per alarm opened or
                   closed, written in the transaction that changed the alarm)
``outbox_deliveries`` each notification's delivery to each receiver: attempts,
                   next attempt, delivered
``live_sources``   the live service's sources (folders, drives): holder, state,
                   counts, scopes missed
``leases``         who follows a source, until when: several ``serve``
                   processes share the sources, a dead holder's lease expires
=================  =============================================================

One recording is stored in one transaction together with its result and the
conveyor's updated health model: a crash or a kill leaves a recording either
entirely stored or not at all.
"""

from __future__ import annotations

from typing import Any

from sqlalchemy import (
    JSON,
    Boolean,
    Float,
    ForeignKey,
    Index,
    Integer,
    LargeBinary,
    String,
    Text,
)
from sqlalchemy.orm import DeclarativeBase, Mapped, mapped_column

__all__ = [
    "SCHEMA_VERSION",
    "AlarmAliasRow",
    "AlarmRow",
    "AuditRow",
    "Base",
    "CalibrationRow",
    "ConveyorRow",
    "DeliveryRow",
    "EventRow",
    "LeaseRow",
    "LiveSourceRow",
    "MonitorStateRow",
    "OutboxRow",
    "RecordingRow",
    "RefusedFileRow",
    "ResultRow",
    "SchemaRow",
    "SecretRow",
    "TokenRow",
    "TrendSeriesRow",
    "WebSessionRow",
]

SCHEMA_VERSION = 2
"""The ``schema`` table's version at the head revision (0.1.0 wrote 1).

The tables' version proper is the Alembic revision (:mod:`chaintwin.store.migrate`);
this number only makes chaintwin 0.1.0 refuse a store it cannot read."""


class Base(DeclarativeBase):
    """Declarative base of the store's tables."""


class SchemaRow(Base):
    """The schema version of the store."""

    __tablename__ = "schema"
    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    version: Mapped[int] = mapped_column(Integer)


class ConveyorRow(Base):
    """A conveyor and its profile."""

    __tablename__ = "conveyors"
    id: Mapped[str] = mapped_column(String(200), primary_key=True)
    profile: Mapped[dict[str, Any]] = mapped_column(JSON)
    profile_sha256: Mapped[str] = mapped_column(String(64))


class CalibrationRow(Base):
    """A calibration (the calibration file's JSON)."""

    __tablename__ = "calibrations"
    id: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=True)
    conveyor_id: Mapped[str] = mapped_column(ForeignKey("conveyors.id"), index=True)
    created_at: Mapped[str] = mapped_column(String(40))
    content: Mapped[dict[str, Any]] = mapped_column(JSON)


class RecordingRow(Base):
    """A recording with its samples."""

    __tablename__ = "recordings"
    id: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=True)
    sha256: Mapped[str] = mapped_column(String(64), unique=True)
    conveyor_id: Mapped[str] = mapped_column(ForeignKey("conveyors.id"), index=True)
    file: Mapped[str] = mapped_column(Text, index=True)
    recorded_at: Mapped[str | None] = mapped_column(String(40), index=True)
    meta: Mapped[dict[str, Any]] = mapped_column(JSON)
    warnings: Mapped[list[Any]] = mapped_column(JSON)
    samples: Mapped[bytes] = mapped_column(LargeBinary)
    superseded_by: Mapped[int | None] = mapped_column(Integer, nullable=True, index=True)
    """The id of the complete recording that replaced this partial one (same conveyor,
    file name and recorded time); None while it stands. Revision 0010."""

    __table_args__ = (
        # a conveyor's superseded recordings counted from the index alone (revision 0013)
        Index("ix_recordings_conveyor_superseded", "conveyor_id", "superseded_by"),
    )


class ResultRow(Base):
    """Monitoring's result for one recording."""

    __tablename__ = "results"
    id: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=True)
    recording_id: Mapped[int] = mapped_column(ForeignKey("recordings.id"), unique=True)
    conveyor_id: Mapped[str] = mapped_column(ForeignKey("conveyors.id"), index=True)
    recorded_at: Mapped[str | None] = mapped_column(String(40), index=True)
    status: Mapped[str] = mapped_column(String(20))
    alarm: Mapped[bool] = mapped_column(Boolean)
    payload_kg: Mapped[float | None] = mapped_column(Float)
    tlf: Mapped[float | None] = mapped_column(Float)
    content: Mapped[dict[str, Any]] = mapped_column(JSON)
    stored_at: Mapped[str | None] = mapped_column(String(40), nullable=True)
    """When the result was written (UTC, ISO 8601); None in stores before revision 0003."""

    __table_args__ = (
        Index("ix_results_conveyor_recorded", "conveyor_id", "recorded_at"),
        Index("ix_results_conveyor_id_id", "conveyor_id", "id"),
    )


class MonitorStateRow(Base):
    """A conveyor's health model."""

    __tablename__ = "monitor_states"
    conveyor_id: Mapped[str] = mapped_column(ForeignKey("conveyors.id"), primary_key=True)
    state: Mapped[dict[str, Any]] = mapped_column(JSON)
    updated_at: Mapped[str] = mapped_column(String(40))
    version: Mapped[int] = mapped_column(Integer)
    """Raised by every write: a writer that read an older version lost a race
    with another ingest and processes its recording again on the newer state."""


class DerivedHealthRow(Base):
    """What was computed from a conveyor's health model after ingest (:mod:`.derived`)."""

    __tablename__ = "derived_health"
    conveyor_id: Mapped[str] = mapped_column(ForeignKey("conveyors.id"), primary_key=True)
    inputs: Mapped[str] = mapped_column(String(64))
    """SHA-256 of the health model's parts it was computed from (:func:`.derived.fingerprint`)."""
    latest: Mapped[str | None] = mapped_column(String(40), nullable=True)
    """recorded_at of the newest result it was computed from."""
    computed_at: Mapped[str] = mapped_column(String(40))
    content: Mapped[dict[str, Any]] = mapped_column(JSON)


class TrendSeriesRow(Base):
    """A conveyor's trends as built after ingest (:mod:`chaintwin.report.trend_series`)."""

    __tablename__ = "trend_series"
    conveyor_id: Mapped[str] = mapped_column(ForeignKey("conveyors.id"), primary_key=True)
    built_from: Mapped[str] = mapped_column(String(64))
    """SHA-256 of what they were built from (:func:`chaintwin.report.trend_series.built_from`)."""
    computed_at: Mapped[str] = mapped_column(String(40))
    header: Mapped[dict[str, Any]] = mapped_column(JSON)
    """Each feature's fixed fields and where its points lie in ``points``."""
    points: Mapped[bytes] = mapped_column(LargeBinary)
    """Every feature's points, one JSON array after another."""


class AlarmRow(Base):
    """An alarm and its life."""

    __tablename__ = "alarms"
    id: Mapped[str] = mapped_column(String(16), primary_key=True)
    conveyor_id: Mapped[str] = mapped_column(ForeignKey("conveyors.id"), index=True)
    feature: Mapped[str] = mapped_column(String(80))
    cause: Mapped[str] = mapped_column(String(40))
    status: Mapped[str] = mapped_column(String(10))
    since: Mapped[str | None] = mapped_column(String(40))
    content: Mapped[dict[str, Any]] = mapped_column(JSON)


class AlarmAliasRow(Base):
    """An alarm id that now names another alarm (alarms of one cause grouped into one)."""

    __tablename__ = "alarm_aliases"
    old_id: Mapped[str] = mapped_column(String(16), primary_key=True)
    alarm_id: Mapped[str] = mapped_column(String(16), index=True)


class EventRow(Base):
    """A maintenance event."""

    __tablename__ = "events"
    id: Mapped[str] = mapped_column(String(16), primary_key=True)
    conveyor_id: Mapped[str] = mapped_column(ForeignKey("conveyors.id"), index=True)
    kind: Mapped[str] = mapped_column(String(20))
    at: Mapped[str] = mapped_column(String(40))
    content: Mapped[dict[str, Any]] = mapped_column(JSON)


class TokenRow(Base):
    """An access token of the web service (its hash only)."""

    __tablename__ = "api_tokens"
    name: Mapped[str] = mapped_column(String(100), primary_key=True)
    role: Mapped[str] = mapped_column(String(20))
    token_hash: Mapped[str] = mapped_column(String(64), unique=True)
    created_at: Mapped[str] = mapped_column(String(40))
    expires_at: Mapped[str | None] = mapped_column(String(40), nullable=True)
    revoked_at: Mapped[str | None] = mapped_column(String(40), nullable=True)


class AuditRow(Base):
    """One login or change made through the web service."""

    __tablename__ = "audit_log"
    id: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=True)
    at: Mapped[str] = mapped_column(String(40), index=True)
    who: Mapped[str] = mapped_column(String(100))
    action: Mapped[str] = mapped_column(String(40))
    detail: Mapped[dict[str, Any]] = mapped_column(JSON)


class SecretRow(Base):
    """A random key of the web service (hex), created on first use."""

    __tablename__ = "secrets"
    name: Mapped[str] = mapped_column(String(40), primary_key=True)
    value: Mapped[str] = mapped_column(String(128))


class WebSessionRow(Base):
    """A browser session: its cookie's id (a SHA-256 of it), token and CSRF nonce."""

    __tablename__ = "web_sessions"
    id_hash: Mapped[str] = mapped_column(String(64), primary_key=True)
    token_name: Mapped[str] = mapped_column(String(100), index=True)
    csrf: Mapped[str] = mapped_column(String(64))
    created_at: Mapped[str] = mapped_column(String(40))
    expires_at: Mapped[str] = mapped_column(String(40), index=True)


class RefusedFileRow(Base):
    """A file the live service refused, by content (read again only once it changes)."""

    __tablename__ = "refused_files"
    id: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=True)
    sha256: Mapped[str] = mapped_column(String(64), unique=True)
    path: Mapped[str] = mapped_column(Text, index=True)
    source: Mapped[str] = mapped_column(String(300))
    reason: Mapped[str] = mapped_column(Text)
    refused_at: Mapped[str] = mapped_column(String(40), index=True)
    cause: Mapped[str] = mapped_column(String(20), server_default="recording")
    """``profile`` (no profile for its conveyor, or the store's is another one: read
    again when a profile is added or changed) or ``recording`` (the file itself)."""
    conveyor: Mapped[str | None] = mapped_column(String(200), nullable=True, index=True)
    """The conveyor the file names (None: not known)."""


class OutboxRow(Base):
    """An alarm notification to send: an alarm opened or closed."""

    __tablename__ = "outbox"
    id: Mapped[str] = mapped_column(String(40), primary_key=True)
    """``<alarm id>-<event>``: the same for every attempt, so a receiver drops repeats."""
    event: Mapped[str] = mapped_column(String(20))
    alarm_id: Mapped[str] = mapped_column(String(16))
    conveyor_id: Mapped[str] = mapped_column(String(200))
    feature: Mapped[str] = mapped_column(String(80))
    cause: Mapped[str] = mapped_column(String(40))
    at: Mapped[str | None] = mapped_column(String(40), nullable=True)
    """When the alarm opened or closed (recording time, ISO 8601)."""
    created_at: Mapped[str] = mapped_column(String(40), index=True)
    health: Mapped[str | None] = mapped_column(String(20), nullable=True)
    """The conveyor's verdict when the alarm changed (None: kept before it was told)."""
    ne107: Mapped[str | None] = mapped_column(String(30), nullable=True)
    """That verdict's NAMUR NE 107 category."""


class DeliveryRow(Base):
    """A notification's delivery to one receiver (by the SHA-256 of its URL)."""

    __tablename__ = "outbox_deliveries"
    outbox_id: Mapped[str] = mapped_column(ForeignKey("outbox.id"), primary_key=True)
    target: Mapped[str] = mapped_column(String(64), primary_key=True)
    attempts: Mapped[int] = mapped_column(Integer)
    next_at: Mapped[float] = mapped_column(Float)
    """Earliest next attempt, s since the epoch."""
    delivered_at: Mapped[str | None] = mapped_column(String(40), nullable=True)
    last_error: Mapped[str | None] = mapped_column(Text, nullable=True)


class LiveSourceRow(Base):
    """A live source (a watched folder, a drive) and what it did."""

    __tablename__ = "live_sources"
    key: Mapped[str] = mapped_column(String(300), primary_key=True)
    kind: Mapped[str] = mapped_column(String(20))
    holder: Mapped[str | None] = mapped_column(String(200), nullable=True)
    state: Mapped[str] = mapped_column(String(20))
    ingested: Mapped[int] = mapped_column(Integer)
    refused: Mapped[int] = mapped_column(Integer)
    missed: Mapped[int] = mapped_column(Integer)
    """Scopes a drive overwrote before they were read (counter gaps)."""
    last_error: Mapped[str | None] = mapped_column(Text, nullable=True)
    updated_at: Mapped[str] = mapped_column(String(40))


class LeaseRow(Base):
    """Who follows a source until when (expires unless renewed: the holder died)."""

    __tablename__ = "leases"
    source: Mapped[str] = mapped_column(String(300), primary_key=True)
    holder: Mapped[str] = mapped_column(String(200))
    expires_at: Mapped[float] = mapped_column(Float)
    """s since the epoch (the hosts' clocks must agree: NTP)."""
    acquired_at: Mapped[str] = mapped_column(String(40))
