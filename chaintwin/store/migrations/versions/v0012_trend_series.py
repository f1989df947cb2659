"""Trends computed once: ``trend_series`` keeps each conveyor's trends as built after ingest.

A conveyor's trends (every tracked feature's series at the default
``max_points``, judged against its health model) are built after ingest,
beside its forecasts, and kept here pre-serialised with the fingerprint of
what they were built from (newest result, number of results, health model,
profile), so that the trends endpoint reads them rather than building them
per request. The table starts empty; a store upgraded from an older revision
gets each conveyor's row at its next ingest (or the first time its trends
are asked for).

Revision ID: 0012
Revises: 0011
Create Date: 2026-11-29
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0012"
down_revision = "0011"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        "trend_series",
        sa.Column("conveyor_id", sa.String(200), sa.ForeignKey("conveyors.id"), primary_key=True),
        sa.Column("built_from", sa.String(64), nullable=False),
        sa.Column("computed_at", sa.String(40), nullable=False),
        sa.Column("header", sa.JSON(), nullable=False),
        sa.Column("points", sa.LargeBinary(), nullable=False),
    )


def downgrade() -> None:
    op.drop_table("trend_series")
