"""Browser sessions as rows: logging out ends a session on the server.

``web_sessions`` holds one row per browser session: a SHA-256 of the
session id the cookie carries (never the id itself), the name of the token
it was opened with, its CSRF nonce, when it was created and when it
expires. Logging out deletes the row, so the cookie stops working at once,
wherever a copy of it is kept. Sessions opened before this revision (signed
cookies without a row) end: their users log in again.

Revision ID: 0007
Revises: 0006
Create Date: 2026-11-28
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0007"
down_revision = "0006"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        "web_sessions",
        sa.Column("id_hash", sa.String(64), primary_key=True),
        sa.Column("token_name", sa.String(100), nullable=False),
        sa.Column("csrf", sa.String(64), nullable=False),
        sa.Column("created_at", sa.String(40), nullable=False),
        sa.Column("expires_at", sa.String(40), nullable=False),
    )
    op.create_index("ix_web_sessions_token_name", "web_sessions", ["token_name"])
    op.create_index("ix_web_sessions_expires_at", "web_sessions", ["expires_at"])


def downgrade() -> None:
    op.drop_index("ix_web_sessions_expires_at", table_name="web_sessions")
    op.drop_index("ix_web_sessions_token_name", table_name="web_sessions")
    op.drop_table("web_sessions")
