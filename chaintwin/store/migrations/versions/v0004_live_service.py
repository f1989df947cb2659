"""The live service: refused files, the notification outbox, sources, leases.

``refused_files`` the files the live service refused (by content, read
again only once changed); ``outbox`` and ``outbox_deliveries`` the alarm
notifications and their delivery to each receiver; ``live_sources`` each
watched folder's and drive's state and counts (scopes missed); ``leases``
which ``serve`` process follows which source, until when.

Revision ID: 0004
Revises: 0003
Create Date: 2026-11-25
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0004"
down_revision = "0003"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        "refused_files",
        sa.Column("id", sa.Integer(), primary_key=True, autoincrement=True),
        sa.Column("sha256", sa.String(64), nullable=False, unique=True),
        sa.Column("path", sa.Text(), nullable=False),
        sa.Column("source", sa.String(300), nullable=False),
        sa.Column("reason", sa.Text(), nullable=False),
        sa.Column("refused_at", sa.String(40), nullable=False),
    )
    op.create_index("ix_refused_files_refused_at", "refused_files", ["refused_at"])
    op.create_table(
        "outbox",
        sa.Column("id", sa.String(40), primary_key=True),
        sa.Column("event", sa.String(20), nullable=False),
        sa.Column("alarm_id", sa.String(16), nullable=False),
        sa.Column("conveyor_id", sa.String(200), nullable=False),
        sa.Column("feature", sa.String(80), nullable=False),
        sa.Column("cause", sa.String(40), nullable=False),
        sa.Column("at", sa.String(40), nullable=True),
        sa.Column("created_at", sa.String(40), nullable=False),
    )
    op.create_index("ix_outbox_created_at", "outbox", ["created_at"])
    op.create_table(
        "outbox_deliveries",
        sa.Column("outbox_id", sa.String(40), sa.ForeignKey("outbox.id"), primary_key=True),
        sa.Column("target", sa.String(64), primary_key=True),
        sa.Column("attempts", sa.Integer(), nullable=False),
        sa.Column("next_at", sa.Float(), nullable=False),
        sa.Column("delivered_at", sa.String(40), nullable=True),
        sa.Column("last_error", sa.Text(), nullable=True),
    )
    op.create_table(
        "live_sources",
        sa.Column("key", sa.String(300), primary_key=True),
        sa.Column("kind", sa.String(20), nullable=False),
        sa.Column("holder", sa.String(200), nullable=True),
        sa.Column("state", sa.String(20), nullable=False),
        sa.Column("ingested", sa.Integer(), nullable=False),
        sa.Column("refused", sa.Integer(), nullable=False),
        sa.Column("missed", sa.Integer(), nullable=False),
        sa.Column("last_error", sa.Text(), nullable=True),
        sa.Column("updated_at", sa.String(40), nullable=False),
    )
    op.create_table(
        "leases",
        sa.Column("source", sa.String(300), primary_key=True),
        sa.Column("holder", sa.String(200), nullable=False),
        sa.Column("expires_at", sa.Float(), nullable=False),
        sa.Column("acquired_at", sa.String(40), nullable=False),
    )


def downgrade() -> None:
    op.drop_table("leases")
    op.drop_table("live_sources")
    op.drop_table("outbox_deliveries")
    op.drop_index("ix_outbox_created_at", table_name="outbox")
    op.drop_table("outbox")
    op.drop_index("ix_refused_files_refused_at", table_name="refused_files")
    op.drop_table("refused_files")
