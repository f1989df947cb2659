"""Recognising a store before anything writes to it.

A command that writes to a store (``ingest``, ``db upgrade``, ``token``,
``serve``, ...) switches a SQLite file to its WAL journal and may create
tables as soon as it opens it for writing. :func:`recognise` looks at the
database first through a read-only connection (SQLite: ``mode=ro``, or
``immutable=1`` on a read-only file system), so that another program's
database or a damaged file is refused with its bytes unchanged: the file's
header, its size against the page count the header gives, SQLite's
``quick_check``, then its tables and schema revision.
"""

from __future__ import annotations

import os

from sqlalchemy.exc import DatabaseError, OperationalError

from chaintwin.errors import StoreError

from . import migrate
from .engine import QUICK_CHECK_MAX_MB, _first_line, engine_for, hide_password, sqlite_path

__all__ = ["SQLITE_HEADER", "recognise"]

SQLITE_HEADER = b"SQLite format 3\x00"
"""The first 16 bytes of every SQLite database file."""

_HEADER_BYTES = 100
"""Length of a SQLite database file's header, bytes."""


def recognise(url: str, where: str, *, check_all: bool = False) -> str | None:
    """The store's revision, read without writing; refuse what is not a usable store.

    Parameters
    ----------
    url : str
        The store's URL.
    where : str
        The URL as shown to the user (without its password).
    check_all : bool
        Run SQLite's ``quick_check`` whatever the file's size (``db
        upgrade``); otherwise only up to :data:`~.engine.QUICK_CHECK_MAX_MB`.

    Returns
    -------
    str or None
        The schema revision; None for a database to be created (no file yet,
        an empty file, or a database without tables).

    Raises
    ------
    StoreError
        A file that is not a SQLite database, a damaged one, a database with
        another program's tables, or a schema revision this chaintwin does
        not know. Nothing was written to it.
    """
    path = sqlite_path(url)
    if path is not None:
        if not os.path.exists(path) or os.path.getsize(path) == 0:
            return None
        _check_header(path, where)
    engine = engine_for(url, read_only=True)
    try:
        with engine.connect() as connection:
            if path is not None and (
                check_all or os.path.getsize(path) <= QUICK_CHECK_MAX_MB * 1_000_000
            ):
                rows = connection.exec_driver_sql("PRAGMA quick_check(3)").fetchall()
                found = [str(r[0]) for r in rows]
                if found != ["ok"]:
                    raise StoreError(
                        f"url {where}: the store is damaged ({'; '.join(found)[:200]}); "
                        "nothing was changed: restore it from a backup",
                        field="url",
                    )
            return migrate.revision_of(connection, where)
    except OperationalError as exc:
        raise StoreError(
            f"url {where}: cannot open the store "
            f"({hide_password(_first_line(exc.orig or exc), url)}); check the "
            "path or server",
            field="url",
        ) from None
    except DatabaseError as exc:
        raise StoreError(
            f"url {where}: the file is not a usable SQLite database "
            f"({hide_password(_first_line(exc.orig or exc), url)}); nothing was changed: "
            "restore the store from "
            "a backup",
            field="url",
        ) from None
    finally:
        engine.dispose()


def _check_header(path: str, where: str) -> None:
    """Refuse a file without SQLite's header, or shorter than the pages its header counts."""
    try:
        with open(path, "rb") as f:
            header = f.read(_HEADER_BYTES)
        size = os.path.getsize(path)
    except OSError as exc:
        raise StoreError(
            f"url {where}: cannot read the store ({exc.strerror}); check the path and its "
            "permissions",
            field="url",
        ) from None
    if len(header) < _HEADER_BYTES or not header.startswith(SQLITE_HEADER):
        raise StoreError(
            f"url {where}: the file is not a usable SQLite database (it does not start with "
            "SQLite's header); nothing was changed: give a chaintwin store, or restore it "
            "from a backup",
            field="url",
        )
    page_size = int.from_bytes(header[16:18], "big")
    page_size = 65536 if page_size == 1 else page_size
    pages = int.from_bytes(header[28:32], "big")
    counts_valid = header[24:28] == header[92:96]  # the page count is valid for this change
    if page_size < 512 or page_size & (page_size - 1):
        raise StoreError(
            f"url {where}: the store is damaged (its header gives a page size of "
            f"{page_size} bytes); nothing was changed: restore it from a backup",
            field="url",
        )
    if counts_valid and pages and size < pages * page_size:
        raise StoreError(
            f"url {where}: the store is damaged (truncated: {size} bytes of the "
            f"{pages * page_size} its header counts); nothing was changed: restore it from "
            "a backup",
            field="url",
        )
