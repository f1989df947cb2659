"""The web service: access tokens, an audit log, shared secrets, result write times.

``api_tokens`` holds each token's name, role and keyed SHA-256 (never the
token); ``audit_log`` who did what when through the web service;
``secrets`` the random keys every ``serve`` process on the store shares;
``results.stored_at`` when a result was written (None for older rows), and
an index that finds each conveyor's latest result without a scan.

Revision ID: 0003
Revises: 0002
Create Date: 2026-11-25
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0003"
down_revision = "0002"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        "api_tokens",
        sa.Column("name", sa.String(100), primary_key=True),
        sa.Column("role", sa.String(20), nullable=False),
        sa.Column("token_hash", sa.String(64), nullable=False, unique=True),
        sa.Column("created_at", sa.String(40), nullable=False),
        sa.Column("expires_at", sa.String(40), nullable=True),
        sa.Column("revoked_at", sa.String(40), nullable=True),
    )
    op.create_table(
        "audit_log",
        sa.Column("id", sa.Integer(), primary_key=True, autoincrement=True),
        sa.Column("at", sa.String(40), nullable=False),
        sa.Column("who", sa.String(100), nullable=False),
        sa.Column("action", sa.String(40), nullable=False),
        sa.Column("detail", sa.JSON(), nullable=False),
    )
    op.create_index("ix_audit_log_at", "audit_log", ["at"])
    op.create_table(
        "secrets",
        sa.Column("name", sa.String(40), primary_key=True),
        sa.Column("value", sa.String(128), nullable=False),
    )
    with op.batch_alter_table("results") as batch:
        batch.add_column(sa.Column("stored_at", sa.String(40), nullable=True))
    # the dashboard's fleet: each conveyor's latest result by an index seek
    op.create_index("ix_results_conveyor_id_id", "results", ["conveyor_id", "id"])


def downgrade() -> None:
    op.drop_index("ix_results_conveyor_id_id", table_name="results")
    with op.batch_alter_table("results") as batch:
        batch.drop_column("stored_at")
    op.drop_table("secrets")
    op.drop_index("ix_audit_log_at", table_name="audit_log")
    op.drop_table("audit_log")
    op.drop_table("api_tokens")
