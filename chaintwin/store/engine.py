"""Opening a store's database: the URL, the engine, JSON columns and SQLite's settings."""

from __future__ import annotations

import json
import os
import re
from functools import partial
from typing import Any
from urllib.parse import quote, unquote

import orjson
from sqlalchemy import create_engine, event
from sqlalchemy.engine import Engine
from sqlalchemy.exc import SQLAlchemyError

from chaintwin.diagnose.state import json_ready
from chaintwin.errors import StoreError

__all__ = [
    "DEFAULT_URL",
    "QUICK_CHECK_MAX_MB",
    "WAL_AUTOCHECKPOINT_PAGES",
    "engine_for",
    "hide_password",
    "safe_url",
    "sqlite_path",
    "store_url",
    "writable_place",
]

DEFAULT_URL = "sqlite:///chaintwin.db"
"""The embedded default: a SQLite file in the working folder."""


def store_url(given: str | None) -> str:
    """The store URL: as given, else ``CHAINTWIN_DB``, else :data:`DEFAULT_URL`."""
    return given or os.environ.get("CHAINTWIN_DB") or DEFAULT_URL


def _to_json(value: Any) -> str:
    """The JSON text of a column's value (the engine's serializer).

    orjson, about 20 times faster than the standard library on the health
    model (0.3 ms against 5.5 ms for 400 kB), which is stored with every
    group of recordings. Like :func:`chaintwin.diagnose.state.json_ready`,
    it writes non-finite floats as null (standard JSON); numpy numbers and
    arrays are written as numbers and lists, other keys than strings as strings.
    """
    try:
        return orjson.dumps(
            value, option=orjson.OPT_NON_STR_KEYS | orjson.OPT_SERIALIZE_NUMPY
        ).decode()
    except orjson.JSONEncodeError:  # what orjson does not take (an int over 64 bits, ...)
        return json.dumps(json_ready(value), allow_nan=False)


def _from_json(text: str | bytes) -> Any:
    """A column's value from its JSON text (the engine's deserializer).

    Stores written before :func:`_to_json` may hold ``NaN`` (the standard
    library's extension, which orjson refuses): those values are read by the
    standard library.
    """
    try:
        return orjson.loads(text)
    except orjson.JSONDecodeError:
        return json.loads(text)


def safe_url(url: str) -> str:
    """The URL for messages: without its password, control characters escaped (one line).

    The password is hidden whatever its form: in the user information
    (``user:***@host``, even when the password holds ``@`` or ``/``: the user
    information runs to the *last* ``@``), and as a query parameter
    (``?password=***``, and every parameter whose name speaks of a password,
    secret, token or key).
    """
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in _without_password(url))


def hide_password(text: str, url: str) -> str:
    """``text`` (a driver's error message about ``url``) with the URL's password hidden.

    A driver names the host it could not reach, and a password holding
    ``@`` is cut there by URL parsers: its tail is taken for the host and
    would be shown. Each piece of the password (split at ``@``, ``:`` and
    ``/``) and each secret query value is replaced by ``***`` wherever it
    appears, longest first.
    """
    _scheme, sep, rest = url.partition("://")
    where, _question, query = rest.partition("?")
    secrets: list[str] = []
    if sep and "@" in where and not where.startswith("/"):
        cred = where.rpartition("@")[0]
        password = cred.partition(":")[2]
        secrets += [password, unquote(password), *re.split(r"[@:/]", password)]
    for item in query.split("&") if query else ():
        name, equals, value = item.partition("=")
        if equals and _SECRET_PARAMETER.search(unquote(name)):
            secrets += [value, unquote(value)]
    for secret in sorted({s for s in secrets if len(s) >= 2}, key=len, reverse=True):
        text = text.replace(secret, "***")
    return text


_SECRET_PARAMETER = re.compile(r"pass|pwd|secret|token|key", re.IGNORECASE)
"""Query parameters of a URL whose values are hidden in messages."""


def _without_password(url: str) -> str:
    """The URL with its password, if any, replaced by ``***`` (user information and query)."""
    scheme, sep, rest = url.partition("://")
    if not sep:
        return url
    where, question, query = rest.partition("?")
    if "@" in where and not where.startswith("/"):  # a host, user information before it
        cred, _, host = where.rpartition("@")
        user, colon, _password = cred.partition(":")
        where = f"{user}:***@{host}" if colon else f"{user}@{host}"
    if question:
        parts = []
        for item in query.split("&"):
            name, equals, _value = item.partition("=")
            hidden = equals and _SECRET_PARAMETER.search(unquote(name))
            parts.append(f"{name}=***" if hidden else item)
        query = "&".join(parts)
    return f"{scheme}://{where}{question}{query}"


def engine_for(
    url: str,
    *,
    read_only: bool = False,
    pool_size: int | None = None,
    max_overflow: int | None = None,
    sqlite_cache_kib: int | None = None,
) -> Engine:
    """The SQLAlchemy engine of a store URL (psycopg 3 for PostgreSQL; SQLite's pragmas).

    With ``read_only`` a SQLite file is opened read-only (``mode=ro``): a
    command that only reads cannot change it, even by accident; on a
    read-only file system (or in a folder this process cannot write, without
    a write-ahead log) it is opened ``immutable=1``, as SQLite cannot take
    its locks there; PostgreSQL sessions are set read-only. ``pool_size``: the connections the pool
    keeps open (SQLAlchemy's default 5), and ``max_overflow`` more it may
    open for a while, each closed when given back (default: as many as
    ``pool_size``); a file or server store only. ``sqlite_cache_kib``: each
    SQLite connection's page cache at most, KiB (``PRAGMA cache_size``;
    SQLite's default is 2 000 KiB), so that a long-running process's caches
    have a known, small bound; the results are the same at any size.

    Raises
    ------
    StoreError
        When the URL is not a usable database URL.
    """
    target = url
    if url.startswith("postgresql"):
        from chaintwin.extras import require_extra

        require_extra("postgres", "psycopg", needed_by="a PostgreSQL store")
    if target.startswith("postgresql://"):
        target = "postgresql+psycopg://" + target[len("postgresql://") :]
    path = sqlite_path(url)
    if read_only and path is not None:
        mode = "immutable=1" if _unwritable_place(path) else "mode=ro"
        target = f"sqlite:///file:{quote(path)}?{mode}&uri=true"
    pooling: dict[str, int] = {}
    if pool_size is not None and (path is not None or url.startswith("postgresql")):
        overflow = pool_size if max_overflow is None else max_overflow
        pooling = {"pool_size": pool_size, "max_overflow": overflow}
    try:
        engine = create_engine(
            target,
            future=True,
            pool_pre_ping=True,
            json_serializer=_to_json,
            json_deserializer=_from_json,
            **pooling,
        )
    except (SQLAlchemyError, ImportError, ValueError) as exc:
        raise StoreError(
            f"url {safe_url(url)}: not a usable database URL "
            f"({hide_password(_first_line(exc), url)}); use "
            "sqlite:///file.db or postgresql://user:password@host/database",
            field="url",
        ) from None
    if engine.dialect.name == "sqlite":
        event.listen(engine, "connect", _sqlite_read_only if read_only else _sqlite_pragmas)
        if sqlite_cache_kib is not None:
            event.listen(engine, "connect", partial(_sqlite_cache, kib=sqlite_cache_kib))
    elif read_only:
        event.listen(engine, "connect", _postgresql_read_only)
    return engine


def _first_line(exc: BaseException) -> str:
    """An exception's message up to its first line break (a one-line error)."""
    return (str(exc).strip().splitlines() or [type(exc).__name__])[0]


def _unwritable_place(path: str) -> bool:
    """Whether SQLite cannot take a read-only file's locks where it lies.

    On a read-only file system, or in a folder this process cannot write to,
    SQLite cannot create a WAL store's shared-memory file, and ``mode=ro``
    fails ("unable to open database file"); no one can write the file
    there, so reading it as immutable is exact. Not when a write-ahead log
    lies beside it: its commits would be left out (``mode=ro`` then fails
    loudly instead).
    """
    if os.path.exists(path + "-wal"):
        return False
    return not writable_place(os.path.dirname(os.path.abspath(path)))


def writable_place(path: str) -> bool:
    """Whether ``path`` (a file or folder) can be written: a writable file system and rights.

    A store's file and its folder (where SQLite keeps its journal) must both
    be, for a command that writes.
    """
    try:
        if os.statvfs(path).f_flag & os.ST_RDONLY:
            return False
    except OSError:
        return False
    return os.access(path, os.W_OK)


def sqlite_path(url: str) -> str | None:
    """The file of a SQLite store URL (None for another database or an in-memory one)."""
    if not url.startswith("sqlite:///"):
        return None
    path = url[len("sqlite:///") :]
    return None if path in ("", ":memory:") or path.startswith("file:") else path


def _sqlite_read_only(dbapi_connection: Any, _record: Any) -> None:
    """A wait for the lock; nothing that writes (the journal mode stays the file's)."""
    cur = dbapi_connection.cursor()
    cur.execute("PRAGMA busy_timeout=30000")
    cur.close()


def _sqlite_cache(dbapi_connection: Any, _record: Any, *, kib: int) -> None:
    """The connection's page cache at most ``kib`` KiB (``PRAGMA cache_size=-kib``)."""
    cur = dbapi_connection.cursor()
    cur.execute(f"PRAGMA cache_size=-{int(kib)}")
    cur.close()


def _postgresql_read_only(dbapi_connection: Any, _record: Any) -> None:
    """Every transaction of the session read-only."""
    dbapi_connection.read_only = True


def _sqlite_pragmas(dbapi_connection: Any, _record: Any) -> None:
    """WAL journal (readers do not block the writer), a wait for the lock.

    ``synchronous=NORMAL`` is SQLite's advice for WAL (and set only when WAL
    took effect): a commit is durable against a crash or kill of the process
    (what ingest promises); only a power loss may take back the last
    commits, never half of one. The WAL is copied back into the database
    (checkpointed) once it holds :data:`WAL_AUTOCHECKPOINT_PAGES` pages
    rather than SQLite's 1,000; durability is the same, a checkpoint is a
    copy of what is already durable in the WAL.
    """
    cur = dbapi_connection.cursor()
    cur.execute("PRAGMA journal_mode=WAL")
    mode = cur.fetchone()
    if mode is not None and str(mode[0]).lower() == "wal":  # not on every file system
        cur.execute("PRAGMA synchronous=NORMAL")
        cur.execute(f"PRAGMA wal_autocheckpoint={WAL_AUTOCHECKPOINT_PAGES}")
    cur.execute("PRAGMA busy_timeout=30000")
    cur.execute("PRAGMA foreign_keys=ON")
    cur.close()


WAL_AUTOCHECKPOINT_PAGES = 8192
"""Pages (4 kB) the SQLite WAL grows to before a commit copies it back (32 MB).

At SQLite's default of 1,000 pages (4 MB) every other ingest transaction (a
group of 64 recordings, about 2.7 MB with their samples) paid a checkpoint;
at 8,192 about one in twelve does, and the WAL file stays
under about 35 MB (SQLite removes it when the last connection closes)."""

QUICK_CHECK_MAX_MB = 512
"""SQLite stores up to this size (MB) get ``PRAGMA quick_check`` when opened
(about a second per 100 MB); larger ones the schema check only."""
