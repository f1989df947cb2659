"""Auto-unshelve: a shelf that ends by itself is told like the other lifecycle changes.

A shelved alarm returns to its state when its shelf ends
(:meth:`~chaintwin.diagnose.records.Alarm.lifecycle`) without anyone
changing it, so nothing stored changes then. The live service looks every
:data:`UNSHELVE_EVERY_S` seconds for open alarms whose shelf has ended and
puts one ``unshelved`` notification per shelf in the outbox
(:func:`~chaintwin.store.rows.notify_alarm`, its ``time`` the shelf's end),
which the notifier sends like any other. A store written without the
service (``chaintwin ingest``) tells it when it next stores the alarm.
"""

from __future__ import annotations

import asyncio
import functools
import logging
from datetime import UTC, datetime

from sqlalchemy.orm import Session

from chaintwin.errors import ChaintwinError
from chaintwin.store.rows import notify_alarm
from chaintwin.store.store import Store
from chaintwin.store.verdicts import conveyor_verdict

__all__ = ["UNSHELVE_EVERY_S", "unshelve_due", "unshelve_forever"]

UNSHELVE_EVERY_S = 30.0
"""How often the service looks for shelves that have ended, s."""

_log = logging.getLogger("chaintwin.shelves")


def unshelve_due(store: Store, now: datetime | None = None) -> list[str]:
    """Tell of the open alarms whose shelf ended by ``now`` (default: the clock).

    Returns
    -------
    list of str
        Ids of the alarms told now (each once per shelf).
    """
    at = now or datetime.now(UTC)
    due = [
        a for a in store.alarms() if a.is_open and a.shelved is not None and not a.is_shelved(at)
    ]
    done = []
    with Session(store.engine) as s, s.begin():
        for alarm in due:
            assert alarm.shelved is not None
            if notify_alarm(
                s,
                alarm.conveyor,
                alarm,
                "unshelved",
                alarm.shelved.until,
                functools.partial(conveyor_verdict, store, alarm.conveyor),
            ):
                done.append(alarm.id)
    return done


async def unshelve_forever(store: Store, every_s: float = UNSHELVE_EVERY_S) -> None:
    """Tell of ended shelves every ``every_s`` seconds until cancelled."""
    while True:
        try:
            done = await asyncio.to_thread(unshelve_due, store)
            if done:
                _log.info("shelves ended: alarms %s", ", ".join(done))
        except ChaintwinError as exc:  # a damaged alarm, a store away: tried again later
            _log.warning("auto-unshelve: %s", exc)
        await asyncio.sleep(every_s)
