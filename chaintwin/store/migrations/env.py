"""Alembic's environment for the results store: run on the connection it is handed.

:func:`chaintwin.store.migrate.upgrade` opens the connection and passes it in
``config.attributes["connection"]``; there is no ``alembic.ini`` and no URL
here, so the store's URL (and its password) stays in the caller.
"""

from __future__ import annotations

from alembic import context

from chaintwin.store.schema import Base

connection = context.config.attributes["connection"]
context.configure(
    connection=connection,
    target_metadata=Base.metadata,
    render_as_batch=connection.dialect.name == "sqlite",  # SQLite alters by copying tables
)
with context.begin_transaction():
    context.run_migrations()
