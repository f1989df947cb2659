"""Refused files: why (their profile, or the file itself) and their conveyor; files by path.

``refused_files.cause`` is ``profile`` for a file refused because its
conveyor had no profile, or the store monitors that conveyor with another
one (the live service reads it again when a profile is added or changed),
and ``recording`` for a file refused for what it holds.
``refused_files.conveyor`` is the conveyor the file names. The refusals
already kept are sorted by their reason, in the words chaintwin wrote them;
their conveyor is taken from the same words where they name it.
``recordings.file`` and ``refused_files.path`` are indexed: a watched
folder's rescan asks the store which of the files it no longer remembers
are stored or refused, by path.

Revision ID: 0005
Revises: 0004
Create Date: 2026-11-26
"""

from __future__ import annotations

import re

import sqlalchemy as sa
from alembic import op

revision = "0005"
down_revision = "0004"
branch_labels = None
depends_on = None

_NO_PROFILE = re.compile(r"is a recording of conveyor '([^']+)', for which no profile was given")
_OTHER_PROFILE = re.compile(r"conveyor '([^']+)' is monitored with another")


def upgrade() -> None:
    with op.batch_alter_table("refused_files") as batch:
        batch.add_column(
            sa.Column("cause", sa.String(20), nullable=False, server_default="recording")
        )
        batch.add_column(sa.Column("conveyor", sa.String(200), nullable=True))
        batch.create_index("ix_refused_files_conveyor", ["conveyor"])
        batch.create_index("ix_refused_files_path", ["path"])
    op.create_index("ix_recordings_file", "recordings", ["file"])
    table = sa.table(
        "refused_files",
        sa.column("id", sa.Integer()),
        sa.column("reason", sa.Text()),
        sa.column("cause", sa.String(20)),
        sa.column("conveyor", sa.String(200)),
    )
    bind = op.get_bind()
    rows = bind.execute(sa.select(table.c.id, table.c.reason)).all()
    for rid, reason in rows:
        found = _NO_PROFILE.search(reason) or _OTHER_PROFILE.search(reason)
        if found is not None:
            bind.execute(
                table.update()
                .where(table.c.id == rid)
                .values(cause="profile", conveyor=found.group(1))
            )


def downgrade() -> None:
    op.drop_index("ix_recordings_file", table_name="recordings")
    with op.batch_alter_table("refused_files") as batch:
        batch.drop_index("ix_refused_files_path")
        batch.drop_index("ix_refused_files_conveyor")
        batch.drop_column("conveyor")
        batch.drop_column("cause")
