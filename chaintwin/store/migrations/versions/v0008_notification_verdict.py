"""Notifications carry the conveyor's verdict: ``outbox.health`` and ``outbox.ne107``.

Each notification says the conveyor's ``health`` and its NAMUR NE 107
category as they were when the alarm changed (written in the same
transaction). Notifications kept before have neither (null): they are sent
without them.

Revision ID: 0008
Revises: 0007
Create Date: 2026-11-28
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0008"
down_revision = "0007"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("outbox") as batch:
        batch.add_column(sa.Column("health", sa.String(20), nullable=True))
        batch.add_column(sa.Column("ne107", sa.String(30), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table("outbox") as batch:
        batch.drop_column("ne107")
        batch.drop_column("health")
