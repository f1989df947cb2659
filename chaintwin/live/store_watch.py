"""Whether a store may have changed since the last look, at next to no cost.

A SQLite store says so itself: ``PRAGMA data_version`` on a connection of
its own changes whenever another connection (of any process) committed. The
OPC UA server asks it twice a second and runs its query of the store's
counters only when it moved. Any other database (PostgreSQL) answers "may
have changed" every time: the caller's own query decides.
"""

from __future__ import annotations

import sqlite3
from dataclasses import dataclass, field
from pathlib import Path

from chaintwin.store.engine import sqlite_path

__all__ = ["StoreWatch"]


@dataclass
class StoreWatch:
    """Asks a store whether anything was committed since the last call.

    Parameters
    ----------
    url : str
        The store's SQLAlchemy URL.
    """

    url: str
    _path: str | None = field(init=False)
    _conn: sqlite3.Connection | None = field(default=None, init=False)
    _version: int | None = field(default=None, init=False)

    def __post_init__(self) -> None:
        self._path = sqlite_path(self.url)

    def moved(self) -> bool:
        """Whether the store may have changed since the last call (always True on the
        first call, for a store other than a SQLite file, and when SQLite cannot answer
        at once: the caller then looks for itself)."""
        if self._path is None:
            return True
        try:
            if self._conn is None:
                # read only, and no wait for a lock: a busy file counts as changed
                self._conn = sqlite3.connect(
                    f"{Path(self._path).resolve().as_uri()}?mode=ro",
                    uri=True,
                    timeout=0.0,
                    check_same_thread=False,
                )
            version = int(self._conn.execute("PRAGMA data_version").fetchone()[0])
        except sqlite3.Error:
            self.close()
            return True
        moved = version != self._version
        self._version = version
        return moved

    def close(self) -> None:
        """Close its connection (the next call opens another, and answers True)."""
        if self._conn is not None:
            self._conn.close()
        self._conn, self._version = None, None
