"""Alembic keeps the schema's version from now on; the old marker says 2.

The ``schema`` table stays with version 2: chaintwin before migrations
(0.1.0, which only knows version 1) then refuses these stores as written by a
newer chaintwin instead of writing into tables it does not know the shape of.
Its composite index serves the per-conveyor queries by recording time (trends,
the dashboard's pages) without a sort.

Revision ID: 0002
Revises: 0001
Create Date: 2026-11-25
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0002"
down_revision = "0001"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.execute(sa.text("UPDATE schema SET version = 2 WHERE id = 1"))
    op.create_index("ix_results_conveyor_recorded", "results", ["conveyor_id", "recorded_at"])


def downgrade() -> None:
    op.drop_index("ix_results_conveyor_recorded", table_name="results")
    op.execute(sa.text("UPDATE schema SET version = 1 WHERE id = 1"))
