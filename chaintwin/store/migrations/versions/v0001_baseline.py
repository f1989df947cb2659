"""Baseline: the store's tables as chaintwin 0.1.0 (commit c909904) created them.

Stores written before migrations existed have exactly these tables and a
``schema`` row with version 1; :func:`chaintwin.store.migrate.upgrade` stamps
them with this revision instead of running it.

Revision ID: 0001
Revises:
Create Date: 2026-11-25
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0001"
down_revision = None
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        "schema",
        sa.Column("id", sa.Integer(), primary_key=True),
        sa.Column("version", sa.Integer(), nullable=False),
    )
    op.create_table(
        "conveyors",
        sa.Column("id", sa.String(200), primary_key=True),
        sa.Column("profile", sa.JSON(), nullable=False),
        sa.Column("profile_sha256", sa.String(64), nullable=False),
    )
    op.create_table(
        "calibrations",
        sa.Column("id", sa.Integer(), primary_key=True, autoincrement=True),
        sa.Column("conveyor_id", sa.String(200), sa.ForeignKey("conveyors.id"), nullable=False),
        sa.Column("created_at", sa.String(40), nullable=False),
        sa.Column("content", sa.JSON(), nullable=False),
    )
    op.create_index("ix_calibrations_conveyor_id", "calibrations", ["conveyor_id"])
    op.create_table(
        "recordings",
        sa.Column("id", sa.Integer(), primary_key=True, autoincrement=True),
        sa.Column("sha256", sa.String(64), nullable=False, unique=True),
        sa.Column("conveyor_id", sa.String(200), sa.ForeignKey("conveyors.id"), nullable=False),
        sa.Column("file", sa.Text(), nullable=False),
        sa.Column("recorded_at", sa.String(40), nullable=True),
        sa.Column("meta", sa.JSON(), nullable=False),
        sa.Column("warnings", sa.JSON(), nullable=False),
        sa.Column("samples", sa.LargeBinary(), nullable=False),
    )
    op.create_index("ix_recordings_conveyor_id", "recordings", ["conveyor_id"])
    op.create_index("ix_recordings_recorded_at", "recordings", ["recorded_at"])
    op.create_table(
        "results",
        sa.Column("id", sa.Integer(), primary_key=True, autoincrement=True),
        sa.Column(
            "recording_id",
            sa.Integer(),
            sa.ForeignKey("recordings.id"),
            nullable=False,
            unique=True,
        ),
        sa.Column("conveyor_id", sa.String(200), sa.ForeignKey("conveyors.id"), nullable=False),
        sa.Column("recorded_at", sa.String(40), nullable=True),
        sa.Column("status", sa.String(20), nullable=False),
        sa.Column("alarm", sa.Boolean(), nullable=False),
        sa.Column("payload_kg", sa.Float(), nullable=True),
        sa.Column("tlf", sa.Float(), nullable=True),
        sa.Column("content", sa.JSON(), nullable=False),
    )
    op.create_index("ix_results_conveyor_id", "results", ["conveyor_id"])
    op.create_index("ix_results_recorded_at", "results", ["recorded_at"])
    op.create_table(
        "monitor_states",
        sa.Column("conveyor_id", sa.String(200), sa.ForeignKey("conveyors.id"), primary_key=True),
        sa.Column("state", sa.JSON(), nullable=False),
        sa.Column("updated_at", sa.String(40), nullable=False),
        sa.Column("version", sa.Integer(), nullable=False),
    )
    op.create_table(
        "alarms",
        sa.Column("id", sa.String(16), primary_key=True),
        sa.Column("conveyor_id", sa.String(200), sa.ForeignKey("conveyors.id"), nullable=False),
        sa.Column("feature", sa.String(80), nullable=False),
        sa.Column("cause", sa.String(40), nullable=False),
        sa.Column("status", sa.String(10), nullable=False),
        sa.Column("since", sa.String(40), nullable=True),
        sa.Column("content", sa.JSON(), nullable=False),
    )
    op.create_index("ix_alarms_conveyor_id", "alarms", ["conveyor_id"])
    op.create_table(
        "events",
        sa.Column("id", sa.String(16), primary_key=True),
        sa.Column("conveyor_id", sa.String(200), sa.ForeignKey("conveyors.id"), nullable=False),
        sa.Column("kind", sa.String(20), nullable=False),
        sa.Column("at", sa.String(40), nullable=False),
        sa.Column("content", sa.JSON(), nullable=False),
    )
    op.create_index("ix_events_conveyor_id", "events", ["conveyor_id"])
    op.execute(sa.text("INSERT INTO schema (id, version) VALUES (1, 1)"))


def downgrade() -> None:
    for table in (
        "events",
        "alarms",
        "monitor_states",
        "results",
        "recordings",
        "calibrations",
        "conveyors",
        "schema",
    ):
        op.drop_table(table)
