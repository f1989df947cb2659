"""Escalation (``serve --escalate-after-min N``): an alarm left unacknowledged is told again.

An open alarm that counts (neither shelved nor of a conveyor out of service),
still unacknowledged ``N`` minutes after it opened, puts one ``escalated``
notification in the outbox (:func:`~chaintwin.store.rows.notify_alarm`),
which the notifier sends like any other.
"""

from __future__ import annotations

import asyncio
import functools
import logging
from datetime import UTC, datetime, timedelta

from sqlalchemy.orm import Session

from chaintwin.diagnose.records import parse_time
from chaintwin.errors import ChaintwinError
from chaintwin.store.rows import notify_alarm
from chaintwin.store.store import Store
from chaintwin.store.verdicts import conveyor_verdict

__all__ = ["ESCALATE_EVERY_S", "escalate_due", "escalate_forever"]

ESCALATE_EVERY_S = 60.0
"""How often the service looks for alarms to escalate, s."""

_log = logging.getLogger("chaintwin.escalation")


def escalate_due(store: Store, after_min: float, now: datetime | None = None) -> list[str]:
    """Escalate the alarms unacknowledged ``after_min`` minutes after they opened.

    Returns
    -------
    list of str
        Ids of the alarms escalated now (each is escalated once).
    """
    at = now or datetime.now(UTC)
    due = []
    for alarm in store.alarms():
        opened = parse_time(alarm.opened_at or alarm.since)
        if opened is None or alarm.acknowledged is not None or not alarm.counts(at):
            continue
        if opened.tzinfo is None:
            opened = opened.replace(tzinfo=UTC)
        if at - opened >= timedelta(minutes=after_min):
            due.append(alarm)
    done = []
    with Session(store.engine) as s, s.begin():
        for alarm in due:
            if notify_alarm(
                s,
                alarm.conveyor,
                alarm,
                "escalated",
                at.isoformat(),
                functools.partial(conveyor_verdict, store, alarm.conveyor),
            ):
                done.append(alarm.id)
    return done


async def escalate_forever(store: Store, after_min: float) -> None:
    """Escalate every :data:`ESCALATE_EVERY_S` seconds until cancelled."""
    while True:
        try:
            done = await asyncio.to_thread(escalate_due, store, after_min)
            if done:
                _log.info("escalated alarms %s", ", ".join(done))
        except ChaintwinError as exc:  # a damaged alarm, a store away: tried again later
            _log.warning("escalation: %s", exc)
        await asyncio.sleep(ESCALATE_EVERY_S)
