"""The results store (SQLite or PostgreSQL) and ingest of many recordings into it.

The names below are imported on first use (PEP 562): the ingest's worker
processes import ``chaintwin.store.worker`` without the store's database code.
"""

import typing as _typing

from chaintwin._lazy import lazy_getattr

if _typing.TYPE_CHECKING:
    from chaintwin.store.engine import store_url
    from chaintwin.store.ingest import IngestSummary, ingest
    from chaintwin.store.migrate import HEAD_REVISION, upgrade
    from chaintwin.store.store import Store

_LAZY: dict[str, str] = {
    "HEAD_REVISION": "chaintwin.store.migrate",
    "IngestSummary": "chaintwin.store.ingest",
    "Store": "chaintwin.store.store",
    "ingest": "chaintwin.store.ingest",
    "store_url": "chaintwin.store.engine",
    "upgrade": "chaintwin.store.migrate",
}

__all__ = ["HEAD_REVISION", "IngestSummary", "Store", "ingest", "store_url", "upgrade"]


__getattr__ = lazy_getattr(__name__, _LAZY)
