"""Forecasts computed once: ``derived_health`` keeps what is computed from a health model.

A conveyor's trend forecasts (with their bands) and wear rates are computed
after ingest from its health model and kept here with the fingerprint of the
model's inputs, so that the dashboard and the API read them instead of
refitting them on every request. The table starts empty; a store upgraded
from an older revision gets each conveyor's row at its next ingest (or the
first time its page is read).

Revision ID: 0009
Revises: 0008
Create Date: 2026-11-28
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0009"
down_revision = "0008"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        "derived_health",
        sa.Column("conveyor_id", sa.String(200), sa.ForeignKey("conveyors.id"), primary_key=True),
        sa.Column("inputs", sa.String(64), nullable=False),
        sa.Column("latest", sa.String(40), nullable=True),
        sa.Column("computed_at", sa.String(40), nullable=False),
        sa.Column("content", sa.JSON(), nullable=False),
    )


def downgrade() -> None:
    op.drop_table("derived_health")
