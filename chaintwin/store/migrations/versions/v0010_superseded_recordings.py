"""A recording replaced by its complete version: ``recordings.superseded_by``.

A file picked up while its writer paused could be stored with the
``incomplete_cycle`` warning; when its complete version arrives later (same
conveyor, file name and recorded time) it is stored too, and the partial
one's ``superseded_by`` holds the id of the recording that replaced it.
Nothing is deleted (results stay append-only); queries, exports, trends and
the dashboard leave superseded recordings out. The column is a plain
nullable integer (no constraint): SQLite adds it without copying the
table, whose samples are most of a store.

Revision ID: 0010
Revises: 0009
Create Date: 2026-11-28
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0010"
down_revision = "0009"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("recordings") as batch:
        batch.add_column(sa.Column("superseded_by", sa.Integer(), nullable=True))
    op.create_index("ix_recordings_superseded_by", "recordings", ["superseded_by"])


def downgrade() -> None:
    op.drop_index("ix_recordings_superseded_by", table_name="recordings")
    with op.batch_alter_table("recordings") as batch:
        batch.drop_column("superseded_by")
