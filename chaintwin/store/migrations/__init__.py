"""Alembic migrations of the results store (see :mod:`chaintwin.store.migrate`)."""
