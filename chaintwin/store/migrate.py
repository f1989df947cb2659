"""The store's schema version and its migrations (Alembic).

Every change of the store's tables is an Alembic revision in
``chaintwin/store/migrations/versions/``; :data:`HEAD_REVISION` is the
newest, the one this chaintwin reads and writes. A store is at one of:

* **empty** (no tables): a command that writes creates it at the head;
* **legacy** (tables of chaintwin 0.1.0, a ``schema`` row with version 1,
  no ``alembic_version``): the baseline revision ``0001``;
* a **revision** (``alembic_version``).

:func:`check` refuses a store older than the code with a one-line message
naming ``chaintwin db upgrade``, and one newer than the code (written by a
newer chaintwin); :func:`upgrade` brings a store to the head, stamping a
legacy store with the baseline first (its tables are the baseline's).

Adding a revision (maintainers)
-------------------------------
1. Change the tables in :mod:`chaintwin.store.schema`.
2. Write ``migrations/versions/vNNNN_what.py`` with ``revision = "NNNN"``,
   ``down_revision`` the previous head, and ``upgrade()``/``downgrade()``
   in Alembic operations (``op.add_column``, ``op.create_index``, ...;
   SQLite alters tables in batch mode, which ``env.py`` switches on).
   ``alembic revision --autogenerate`` can draft it: run it with a
   ``script_location`` of ``chaintwin/store/migrations`` against a store at
   the previous head.
3. Set :data:`HEAD_REVISION` to the new revision. ``tests/test_migrations.py``
   checks that the migrated tables equal the models, on SQLite and
   PostgreSQL, and upgrades the fixture store of chaintwin 0.1.0.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from sqlalchemy import inspect, text
from sqlalchemy.engine import Connection, Engine

from chaintwin.errors import StoreError

if TYPE_CHECKING:
    from alembic.config import Config

__all__ = [
    "BASELINE_REVISION",
    "HEAD_REVISION",
    "LEGACY_TABLES",
    "check",
    "head_from_scripts",
    "require_head",
    "revision_of",
    "upgrade",
]

HEAD_REVISION = "0013"
"""The revision of the tables this chaintwin reads and writes."""

BASELINE_REVISION = "0001"
"""The tables of chaintwin 0.1.0, the first revision."""

LEGACY_TABLES = frozenset(
    {"schema", "conveyors", "calibrations", "recordings", "results"}
    | {"monitor_states", "alarms", "events"}
)
"""The tables chaintwin 0.1.0 created (revision 0001)."""

_MIGRATIONS = Path(__file__).with_name("migrations")


def revision_of(connection: Connection, where: str = "") -> str | None:
    """The store's revision: ``None`` for an empty database, else the revision.

    A store of chaintwin 0.1.0 (its tables and a ``schema`` row, no
    ``alembic_version``) is at :data:`BASELINE_REVISION`. ``where`` is the
    store's URL for messages (without its password).

    Raises
    ------
    StoreError
        When the database holds tables but not a chaintwin store's (another
        program's database), or a ``schema`` row of a newer chaintwin.
    """
    tables = set(inspect(connection).get_table_names())
    if "alembic_version" in tables:
        row = connection.execute(text("SELECT version_num FROM alembic_version")).first()
        if row is not None:
            return str(row[0])
    if not tables or tables == {"alembic_version"}:
        return None
    if "schema" in tables and tables >= LEGACY_TABLES:
        row = connection.execute(text("SELECT version FROM schema WHERE id = 1")).first()
        if row is not None and int(row[0]) == 1:
            return BASELINE_REVISION
        raise StoreError(
            f"url {where}: the store's schema version is {None if row is None else row[0]}, "
            "not one chaintwin knows; it was written by a newer chaintwin (upgrade chaintwin)",
            field="url",
        )
    raise StoreError(
        f"url {where}: the database holds other tables than a chaintwin store's "
        f"({', '.join(sorted(tables)[:5])}); give an empty database or a chaintwin store",
        field="url",
    )


def _order() -> list[str]:
    """Every revision from the baseline to the head, in order (from the scripts' names)."""
    names = sorted(p.stem for p in (_MIGRATIONS / "versions").glob("v[0-9][0-9][0-9][0-9]_*.py"))
    return [name[1:5] for name in names]


def check(engine: Engine, where: str) -> str | None:
    """Refuse a store that is not at :data:`HEAD_REVISION`; return its revision.

    Parameters
    ----------
    engine : Engine
        The store's engine.
    where : str
        The store's URL as shown to the user (without its password).

    Returns
    -------
    str or None
        The head revision, or None for an empty database (to be created).

    Raises
    ------
    StoreError
        Older than the code (naming ``chaintwin db upgrade``), newer than the
        code, or not a chaintwin store.
    """
    with engine.connect() as connection:
        revision = revision_of(connection, where)
    return require_head(revision, where)


def require_head(revision: str | None, where: str) -> str | None:
    """Refuse a revision other than :data:`HEAD_REVISION` (None: empty); as :func:`check`."""
    if revision is None or revision == HEAD_REVISION:
        return revision
    if revision in _order():
        raise StoreError(
            f"url {where}: the store's schema is at revision {revision}, this chaintwin "
            f"needs {HEAD_REVISION}; run `chaintwin db upgrade --db {where}` (back up the "
            "store first)",
            field="url",
        )
    raise StoreError(
        f"url {where}: the store's schema is at revision {revision}, which this chaintwin "
        f"does not know (it knows up to {HEAD_REVISION}): a newer chaintwin wrote it; "
        "upgrade chaintwin",
        field="url",
    )


def _config(connection: Connection | None = None) -> Config:
    """Alembic's configuration: the scripts in the package, run on ``connection``."""
    from alembic.config import Config  # Alembic is imported only to migrate

    config = Config()
    config.set_main_option("script_location", str(_MIGRATIONS))
    if connection is not None:
        config.attributes["connection"] = connection
    return config


def upgrade(engine: Engine, where: str = "") -> tuple[str | None, str]:
    """Bring a store to :data:`HEAD_REVISION`; create an empty one.

    A store of chaintwin 0.1.0 is stamped with the baseline first (its
    tables are the baseline's), then upgraded. Runs in one transaction where
    the database allows DDL in transactions (PostgreSQL; SQLite per statement).

    Returns
    -------
    (str or None, str)
        The revision before (None: empty) and after.

    Raises
    ------
    StoreError
        A store newer than the code or not a chaintwin store.
    """
    from alembic import command

    with engine.begin() as connection:
        before = revision_of(connection, where)
        if before is not None and before not in _order():
            raise StoreError(
                f"url {where}: the store's schema is at revision {before}, newer than this "
                f"chaintwin knows ({HEAD_REVISION}); upgrade chaintwin",
                field="url",
            )
        config = _config(connection)
        if (
            before == BASELINE_REVISION
            and "alembic_version" not in inspect(connection).get_table_names()
        ):
            command.stamp(config, BASELINE_REVISION)
        if before != HEAD_REVISION:
            command.upgrade(config, "head")
    return before, HEAD_REVISION


def head_from_scripts() -> str:
    """The head revision as Alembic reads it from the scripts (for the tests)."""
    from alembic.script import ScriptDirectory

    head = ScriptDirectory.from_config(_config()).get_current_head()
    if head is None:  # pragma: no cover - the scripts ship with the package
        raise StoreError("the store's migration scripts are missing; reinstall chaintwin")
    return head
