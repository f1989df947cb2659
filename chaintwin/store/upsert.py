"""Write a row keyed by its conveyor: insert it, or update the one stored.

The rows computed after ingest (:mod:`.derived`'s derived health,
:mod:`chaintwin.report.trend_series`'s trends) are one per conveyor and are
written by whichever refit or reader gets there; two writers may insert the
same conveyor's row at once, and the second then updates the first's.
"""

from __future__ import annotations

from typing import Any

from sqlalchemy.exc import IntegrityError, OperationalError
from sqlalchemy.orm import Session

from chaintwin.errors import StoreError

from .engine import safe_url
from .schema import Base
from .store import Store

__all__ = ["upsert_conveyor_row"]


def upsert_conveyor_row(
    store: Store,
    row_type: type[Base],
    conveyor: str,
    values: dict[str, Any],
    *,
    what: str,
    replace: bool = True,
) -> None:
    """Insert the conveyor's row of ``row_type`` with ``values``, or update the stored one.

    Parameters
    ----------
    store : Store
        The store.
    row_type : type
        A table whose primary key is ``conveyor_id``.
    conveyor : str
        Conveyor id.
    values : dict
        The row's other columns.
    what : str
        What the row holds, for the error ("the trends").
    replace : bool
        Update a stored row (False: leave it, only insert where none is).

    Raises
    ------
    StoreError
        When the database fails.
    """
    for _attempt in range(2):
        try:
            with Session(store.engine) as s, s.begin():
                row = s.get(row_type, conveyor)
                if row is None:
                    s.add(row_type(conveyor_id=conveyor, **values))
                elif replace:
                    for k, v in values.items():
                        setattr(row, k, v)
            return
        except IntegrityError:
            if not replace:
                return  # another writer stored it meanwhile
            continue  # another writer inserted the row first: update it
        except OperationalError as exc:
            raise StoreError(
                f"{safe_url(store.url)}: cannot store {what} of '{conveyor}' "
                f"({exc.orig}); run the ingest again"
            ) from None
