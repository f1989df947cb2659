"""The results store (SQLite or PostgreSQL) with its schema migrations.

The names below are imported on first use (PEP 562). Ingest of many
recordings into a store is :mod:`chaintwin.ingest`.
"""

import typing as _typing

from chaintwin._lazy import lazy_getattr

if _typing.TYPE_CHECKING:
    from chaintwin.store.engine import store_url
    from chaintwin.store.migrate import HEAD_REVISION, upgrade
    from chaintwin.store.store import Store

_LAZY: dict[str, str] = {
    "HEAD_REVISION": "chaintwin.store.migrate",
    "Store": "chaintwin.store.store",
    "store_url": "chaintwin.store.engine",
    "upgrade": "chaintwin.store.migrate",
}

__all__ = ["HEAD_REVISION", "Store", "store_url", "upgrade"]


__getattr__ = lazy_getattr(__name__, _LAZY)
