"""Alarm notifications: the outbox sent as signed JSON to each ``--notify-url``.

Every alarm that opens or closes puts one row in the store's ``outbox`` in
the transaction that changed the alarm (:func:`chaintwin.store.rows.notify_alarm`),
whoever changed it (this service, ``chaintwin ingest``, an upload, a
maintenance event). The :class:`Notifier` POSTs each row to each receiver as

.. code-block:: json

    {"id": "3f2a9c1e0b7d4a55-opened", "event": "opened", "alarm_id": "3f2a9c1e0b7d4a55",
     "conveyor": "white-belt-01", "feature": "friction_nm", "cause": "friction",
     "time": "2026-01-07T13:11:27+00:00", "link": "https://twin.plant/conveyors/white-belt-01"}

with the header ``X-Chaintwin-Signature: sha256=<hex HMAC-SHA256 of the raw
body>`` keyed by the secret of ``--notify-secret-file``. A delivery is done
when the receiver answers 2xx; otherwise it is tried again with backoff
(1 s, 2 s, 4 s, ... up to :data:`MAX_BACKOFF_S`), through restarts (the
attempts are in the store's ``outbox_deliveries``), for up to
:data:`MAX_AGE_S`. A notification may arrive more than once (a kill between
the receiver's answer and the store's note of it): ``id`` is the same
every time, so the receiver drops repeats. Each receiver gets the
notifications in the order they were made.
"""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import hmac
import json
import logging
import time
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from pathlib import Path
from urllib.parse import quote

import httpx
from sqlalchemy import and_, func, or_, select
from sqlalchemy.orm import Session

from chaintwin.errors import StoreError
from chaintwin.store.schema import DeliveryRow, OutboxRow
from chaintwin.store.store import Store

from .metrics import Metrics

__all__ = [
    "MAX_AGE_S",
    "MAX_BACKOFF_S",
    "SIGNATURE_HEADER",
    "Notifier",
    "document",
    "read_secret",
    "sign",
]

log = logging.getLogger("chaintwin.live")

SIGNATURE_HEADER = "X-Chaintwin-Signature"

MAX_BACKOFF_S = 600.0
"""Longest wait between two attempts of one delivery, s."""

MAX_AGE_S = 7 * 86400.0
"""Notifications older than this are not sent to a receiver (a receiver added
later does not get the store's whole past), s."""

TIMEOUT_S = 10.0
"""How long a receiver has to answer, s."""


def read_secret(path: Path) -> bytes:
    """The signing secret of ``--notify-secret-file`` (its bytes, trailing newline dropped).

    Raises
    ------
    StoreError
        When the file cannot be read or is empty.
    """
    try:
        raw = path.read_bytes().rstrip(b"\r\n")
    except OSError as exc:
        raise StoreError(
            f"--notify-secret-file {path}: cannot read it ({exc.strerror}); give a file "
            "holding the receivers' shared secret"
        ) from None
    if not raw.strip():
        raise StoreError(
            f"--notify-secret-file {path}: the file is empty; put the receivers' shared "
            "secret in it (e.g. `openssl rand -hex 32 > FILE`)"
        )
    return raw


def sign(secret: bytes, body: bytes) -> str:
    """The signature header's value: ``sha256=<hex HMAC-SHA256 of body>``."""
    return "sha256=" + hmac.new(secret, body, hashlib.sha256).hexdigest()


def document(row: OutboxRow, public_url: str) -> bytes:
    """A notification's JSON body (the same bytes at every attempt)."""
    link = f"{public_url.rstrip('/')}/conveyors/{quote(row.conveyor_id, safe='')}"
    doc = {
        "id": row.id,
        "event": row.event,
        "alarm_id": row.alarm_id,
        "conveyor": row.conveyor_id,
        "feature": row.feature,
        "cause": row.cause,
        "time": row.at,
        "link": link,
    }
    return json.dumps(doc, separators=(",", ":")).encode()


@dataclass(frozen=True, slots=True)
class _Due:
    row: OutboxRow
    attempts: int


def _target(url: str) -> str:
    return hashlib.sha256(url.encode()).hexdigest()


class Notifier:
    """Sends the outbox to each receiver.

    Parameters
    ----------
    store : Store
        Holds the outbox and the deliveries.
    urls : list of str
        The receivers (``--notify-url``).
    secret : bytes
        The signing key (``--notify-secret-file``).
    public_url : str
        The service's address as users reach it (``--public-url``), for links.
    metrics : Metrics
        Sent and failed counts.
    """

    def __init__(
        self, store: Store, urls: list[str], secret: bytes, public_url: str, metrics: Metrics
    ) -> None:
        self.store = store
        self.urls = list(dict.fromkeys(urls))
        self.secret = secret
        self.public_url = public_url
        self.metrics = metrics
        self.wake = asyncio.Event()
        metrics.outbox_pending = self.pending

    def _due(self, url: str, limit: int = 50) -> list[_Due]:
        """The notifications to send to ``url`` now, oldest first."""
        target = _target(url)
        cutoff = (datetime.now(UTC) - timedelta(seconds=MAX_AGE_S)).isoformat()
        with Session(self.store.engine, expire_on_commit=False) as s:
            q = (
                select(OutboxRow, DeliveryRow.attempts, DeliveryRow.next_at)
                .outerjoin(
                    DeliveryRow,
                    and_(DeliveryRow.outbox_id == OutboxRow.id, DeliveryRow.target == target),
                )
                .where(OutboxRow.created_at >= cutoff, DeliveryRow.delivered_at.is_(None))
                .order_by(OutboxRow.created_at, OutboxRow.id)
                .limit(limit)
            )
            rows = list(s.execute(q))
        now = time.time()
        out: list[_Due] = []
        for row, attempts, next_at in rows:
            if next_at is not None and next_at > now:
                break  # in order: the oldest waits for its next attempt, so do the others
            out.append(_Due(row, attempts or 0))
        return out

    def _note(self, url: str, due: _Due, error: str | None) -> None:
        """Write an attempt's outcome."""
        target = _target(url)
        attempts = due.attempts + 1
        with Session(self.store.engine) as s, s.begin():
            row = s.get(DeliveryRow, (due.row.id, target))
            if row is None:
                row = DeliveryRow(outbox_id=due.row.id, target=target, attempts=0, next_at=0.0)
                s.add(row)
            row.attempts = attempts
            if error is None:
                row.delivered_at = datetime.now(UTC).isoformat()
                row.last_error = None
            else:
                row.next_at = time.time() + min(MAX_BACKOFF_S, 2.0 ** (attempts - 1))
                row.last_error = error[:500]

    def pending(self) -> int:
        """Notifications (within :data:`MAX_AGE_S`) not yet delivered to every receiver."""
        if not self.urls:
            return 0
        cutoff = (datetime.now(UTC) - timedelta(seconds=MAX_AGE_S)).isoformat()
        with Session(self.store.engine) as s:
            delivered = (
                select(DeliveryRow.outbox_id)
                .where(DeliveryRow.delivered_at.is_not(None))
                .where(DeliveryRow.target.in_([_target(u) for u in self.urls]))
                .group_by(DeliveryRow.outbox_id)
                .having(func.count() >= len(self.urls))
            )
            n = s.scalar(
                select(func.count())
                .select_from(OutboxRow)
                .where(OutboxRow.created_at >= cutoff, or_(OutboxRow.id.not_in(delivered)))
            )
        return int(n or 0)

    async def _send(self, client: httpx.AsyncClient, url: str) -> None:
        """One round for one receiver: everything due, in order, until one fails."""
        for due in await asyncio.to_thread(self._due, url):
            body = document(due.row, self.public_url)
            error: str | None = None
            try:
                response = await client.post(
                    url,
                    content=body,
                    headers={
                        "Content-Type": "application/json",
                        SIGNATURE_HEADER: sign(self.secret, body),
                    },
                )
                if not 200 <= response.status_code < 300:
                    error = f"HTTP {response.status_code}"
            except httpx.HTTPError as exc:
                error = f"{type(exc).__name__}: {exc}"
            await asyncio.to_thread(self._note, url, due, error)
            if error is None:
                self.metrics.sent.inc()
                log.info(
                    "notification %s sent to %s",
                    due.row.id,
                    url,
                    extra={"notification": due.row.id, "receiver": url},
                )
            else:
                self.metrics.failed.inc()
                log.warning(
                    "notification %s to %s failed (%s); tried again later",
                    due.row.id,
                    url,
                    error,
                    extra={"notification": due.row.id, "receiver": url, "error": error},
                )
                return  # keep the order: the rest waits for this one

    async def run(self, stop: asyncio.Event, tick_s: float = 1.0) -> None:
        """Send until ``stop``: every ``tick_s``, and at once when woken (a result stored)."""
        async with httpx.AsyncClient(timeout=TIMEOUT_S) as client:
            while not stop.is_set():
                self.wake.clear()
                for url in self.urls:
                    try:
                        await self._send(client, url)
                    except Exception as exc:  # the store failed: the next round tries again
                        log.error("notifications to %s: %s", url, exc)
                waiters = [
                    asyncio.ensure_future(stop.wait()),
                    asyncio.ensure_future(self.wake.wait()),
                ]
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(
                        asyncio.wait(waiters, return_when=asyncio.FIRST_COMPLETED), tick_s
                    )
                for w in waiters:
                    w.cancel()
