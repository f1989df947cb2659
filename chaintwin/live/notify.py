"""Alarm notifications: the outbox sent as signed JSON to each ``--notify-url``.

Every alarm that opens or closes puts one row in the store's ``outbox`` in
the transaction that changed the alarm (:func:`chaintwin.store.rows.notify_alarm`),
whoever changed it (this service, ``chaintwin ingest``, an upload, a
maintenance event). The :class:`Notifier` POSTs each row to each receiver as

.. code-block:: json

    {"id": "3f2a9c1e0b7d4a55-opened", "event": "opened", "alarm_id": "3f2a9c1e0b7d4a55",
     "conveyor": "white-belt-01", "feature": "friction_nm", "cause": "friction",
     "time": "2026-01-07T13:11:27+00:00", "link": "https://twin.plant/conveyors/white-belt-01",
     "health": "alarm", "ne107": "failure"}

(``health`` and ``ne107``: the conveyor's verdict as the change left it,
:func:`chaintwin.diagnose.verdict.verdict`; left out of notifications kept
before they were told) with the header ``X-Chaintwin-Signature: sha256=<hex
HMAC-SHA256 of the raw body>`` keyed by the secret of
``--notify-secret-file``. A delivery is done when the receiver answers 2xx;
otherwise it is tried again with backoff (1 s, 2 s, 4 s, ... up to
:data:`MAX_BACKOFF_S`), through restarts (the attempts are in the store's
``outbox_deliveries``), for up to :data:`MAX_AGE_S`. A notification may
arrive more than once (a kill between the receiver's answer and the store's
note of it): ``id`` is the same every time, so the receiver drops repeats.
Each receiver gets the notifications in the order they were made.

E-mail is a second channel (:class:`MailSettings`, ``--notify-smtp``): the
same outbox, one delivery per recipient (``mailto:<address>``), each
message to one recipient through the SMTP server, with the notification's
``id`` in the subject and in the ``X-Chaintwin-Notification-Id`` and
``Message-ID`` headers (the same at every attempt), the JSON document
attached, and its signature in ``X-Chaintwin-Signature`` when a secret is
given. A message the server does not accept (a 4xx/5xx answer, the server
away) is tried again with the same backoff.
"""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import hmac
import json
import logging
import smtplib
import ssl
import time
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from email.message import EmailMessage
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
    "ID_HEADER",
    "MAX_AGE_S",
    "MAX_BACKOFF_S",
    "SIGNATURE_HEADER",
    "MailSettings",
    "Notifier",
    "document",
    "mail_message",
    "parse_mail_address",
    "parse_smtp",
    "read_login",
    "read_secret",
    "send_mail",
    "sign",
]

log = logging.getLogger("chaintwin.live")

SIGNATURE_HEADER = "X-Chaintwin-Signature"

ID_HEADER = "X-Chaintwin-Notification-Id"
"""An e-mail notification's ``id`` (also in its subject and Message-ID)."""

SMTP_PORT = 25
"""The SMTP server's port when ``--notify-smtp`` gives none."""

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
    if row.health is not None:  # the conveyor's verdict as the change left it
        doc |= {"health": row.health, "ne107": row.ne107}
    return json.dumps(doc, separators=(",", ":")).encode()


# ------------------------------------------------------------------ e-mail
@dataclass(frozen=True, slots=True)
class MailSettings:
    """The e-mail channel (``--notify-smtp`` and its options)."""

    host: str
    port: int
    to: tuple[str, ...]
    """Recipients (``--notify-mail-to``), each a delivery of its own."""
    sender: str
    """``From`` and the envelope sender (``--notify-mail-from``)."""
    starttls: bool = False
    """Upgrade the connection with STARTTLS (the server's certificate checked against
    the system's CAs, or ``SSL_CERT_FILE``)."""
    username: str | None = None
    password: str | None = None


def parse_smtp(value: str) -> tuple[str, int]:
    """``--notify-smtp HOST[:PORT]`` as (host, port); port :data:`SMTP_PORT` when not given.

    Raises
    ------
    StoreError
        When it is not a host with an optional port in 1-65535.
    """
    host, sep, port_s = value.strip().rpartition(":")
    if not sep:
        host, port_s = value.strip(), str(SMTP_PORT)
    host = host.strip("[]")  # [::1]:25
    ok = bool(host) and not any(c.isspace() or c in "/@" for c in host)
    try:
        port = int(port_s)
    except ValueError:
        ok = False
        port = 0
    if not ok or not 1 <= port <= 65535:
        raise StoreError(
            f"--notify-smtp {value}: not HOST or HOST:PORT (port 1-65535); give the SMTP "
            "server, e.g. mail.plant.example:587"
        )
    return host, port


def parse_mail_address(value: str, option: str) -> str:
    """An e-mail address given on the command line, checked for the obvious.

    Raises
    ------
    StoreError
        When it has no ``@`` with something on both sides, or holds spaces,
        line breaks or angle brackets.
    """
    local, at, domain = value.rpartition("@")
    if not at or not local or not domain or any(c.isspace() or c in "<>,;" for c in value):
        raise StoreError(
            f"{option} {value!r}: not an e-mail address; give one like ops@plant.example"
        )
    return value


def read_login(path: Path) -> tuple[str, str]:
    """``--notify-smtp-login-file``: the SMTP user on its first line, the password on the second.

    Raises
    ------
    StoreError
        When the file cannot be read or lacks either line.
    """
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise StoreError(
            f"--notify-smtp-login-file {path}: cannot read it ({exc}); give a file with the "
            "SMTP user on the first line and the password on the second"
        ) from None
    if len(lines) < 2 or not lines[0].strip() or not lines[1]:
        raise StoreError(
            f"--notify-smtp-login-file {path}: needs the SMTP user on the first line and the "
            "password on the second"
        )
    return lines[0].strip(), lines[1]


def mail_message(
    row: OutboxRow, public_url: str, sender: str, to: str, secret: bytes | None
) -> EmailMessage:
    """A notification as an e-mail to one recipient (the same at every attempt).

    The subject and the headers ``X-Chaintwin-Notification-Id`` and
    ``Message-ID`` carry the notification's ``id``; the text says what
    happened with the link, and the JSON document of the webhooks is
    attached (signed in ``X-Chaintwin-Signature`` when ``secret`` is given).
    """
    body = document(row, public_url)
    doc = json.loads(body)
    msg = EmailMessage()
    msg["From"] = sender
    msg["To"] = to
    msg["Subject"] = (
        f"[chaintwin] {row.conveyor_id}: alarm {row.event} ({row.feature}, probable cause "
        f"{row.cause}) [{row.id}]"
    )
    msg["Message-ID"] = f"<{row.id}@chaintwin>"
    msg[ID_HEADER] = row.id
    if secret is not None:
        msg[SIGNATURE_HEADER] = sign(secret, body)
    when = row.at or "time not known"
    msg.set_content(
        f"The alarm on {row.conveyor_id} ({row.feature}, probable cause {row.cause}) "
        f"{row.event} at {when}.\n\n{doc['link']}\n\n"
        f"Notification {row.id}: the same id at every attempt; drop repeats.\n"
    )
    msg.add_attachment(body, maintype="application", subtype="json", filename="notification.json")
    return msg


def send_mail(settings: MailSettings, to: str, message: EmailMessage) -> None:
    """Hand one message to the SMTP server (blocking; run it in a worker thread).

    Raises
    ------
    smtplib.SMTPException, OSError
        When the server cannot be reached or does not take the message.
    """
    with smtplib.SMTP(settings.host, settings.port, timeout=TIMEOUT_S) as smtp:
        if settings.starttls:
            smtp.starttls(context=ssl.create_default_context())
        if settings.username is not None:
            smtp.login(settings.username, settings.password or "")
        smtp.send_message(message, from_addr=settings.sender, to_addrs=[to])


def _smtp_error(exc: Exception) -> str:
    """An SMTP failure in one line."""
    if isinstance(exc, smtplib.SMTPResponseException):
        text = exc.smtp_error.decode(errors="replace") if isinstance(exc.smtp_error, bytes) else ""
        return f"SMTP {exc.smtp_code} {text}".strip()
    if isinstance(exc, smtplib.SMTPRecipientsRefused):
        codes = [f"{addr}: {code}" for addr, (code, _m) in exc.recipients.items()]
        return "SMTP recipient refused (" + ", ".join(codes) + ")"
    return f"{type(exc).__name__}: {exc}".splitlines()[0]


# ------------------------------------------------------------------ the outbox
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
    secret : bytes or None
        The signing key (``--notify-secret-file``; needed with ``urls``).
    public_url : str
        The service's address as users reach it (``--public-url``), for links.
    metrics : Metrics
        Sent and failed counts.
    mail : MailSettings, optional
        The e-mail channel: each recipient is a receiver (``mailto:<address>``).
    """

    def __init__(
        self,
        store: Store,
        urls: list[str],
        secret: bytes | None,
        public_url: str,
        metrics: Metrics,
        mail: MailSettings | None = None,
    ) -> None:
        self.store = store
        self.mail = mail
        mailto = [f"mailto:{a}" for a in mail.to] if mail is not None else []
        self.urls = list(dict.fromkeys([*urls, *mailto]))
        """Every receiver: the webhooks' URLs, then ``mailto:<address>`` per recipient."""
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

    async def _deliver(self, client: httpx.AsyncClient, url: str, due: _Due) -> str | None:
        """One attempt of one notification to one receiver: None, or why it failed."""
        if url.startswith("mailto:"):
            assert self.mail is not None
            to = url[len("mailto:") :]
            msg = mail_message(due.row, self.public_url, self.mail.sender, to, self.secret)
            try:
                await asyncio.to_thread(send_mail, self.mail, to, msg)
            except (smtplib.SMTPException, OSError) as exc:
                return _smtp_error(exc)
            return None
        assert self.secret is not None
        body = document(due.row, self.public_url)
        try:
            response = await client.post(
                url,
                content=body,
                headers={
                    "Content-Type": "application/json",
                    SIGNATURE_HEADER: sign(self.secret, body),
                },
            )
        except httpx.HTTPError as exc:
            return f"{type(exc).__name__}: {exc}"
        if not 200 <= response.status_code < 300:
            return f"HTTP {response.status_code}"
        return None

    async def _send(self, client: httpx.AsyncClient, url: str) -> None:
        """One round for one receiver: everything due, in order, until one fails."""
        for due in await asyncio.to_thread(self._due, url):
            error = await self._deliver(client, url, due)
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
