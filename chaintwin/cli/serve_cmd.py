"""``chaintwin serve`` (the web dashboard and API) and ``chaintwin token``."""

from __future__ import annotations

import sys
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer
from rich.console import Console
from rich.table import Table

from chaintwin.cli.common import (
    DbOption,
    JsonListOption,
    JsonObjectOption,
    print_json,
    printable,
    safe,
)
from chaintwin.errors import StoreError

if TYPE_CHECKING:
    from chaintwin.live.notify import MailSettings
    from chaintwin.store.store import Store

__all__ = [
    "SERVE_POOL_SIZE",
    "SERVE_SQLITE_CACHE_KIB",
    "SERVE_SQLITE_POOL_SIZE",
    "register",
    "serve_store",
]

SERVE_POOL_SIZE = 16
"""Database connections ``serve`` keeps open on PostgreSQL (and as many more for a
while): its web requests run in a pool of 40 threads, 50 polling dashboards come in
bursts of 10-20, and a new PostgreSQL connection costs 10-40 ms. At most twice as many
are open at once on SQLite too."""

SERVE_SQLITE_POOL_SIZE = 4
"""SQLite connections ``serve`` keeps open; more (up to twice :data:`SERVE_POOL_SIZE`
at once) are opened for a burst and closed when given back.

A SQLite connection costs about 0.5 ms to open but holds memory of its own
as long as it is open (its page cache, up to :data:`SERVE_SQLITE_CACHE_KIB`,
and its prepared statements: 0.6 MB or more). Connections kept are opened one by
one as the service's work happens to overlap, and kept for its life: with 16
kept, the live service's memory grew over hours as more were opened."""

SERVE_SQLITE_CACHE_KIB = 1024
"""Each of ``serve``'s SQLite connections' page cache at most, KiB (SQLite's default:
2 000 KiB). The store's file stays in the system's file cache; an ingest's pages
are found there (measured: no slower ingest at 256-2 000 KiB)."""


def serve_store(url: str) -> Store:
    """The store as ``serve`` opens it: its connection pool and SQLite's page caches.

    On PostgreSQL the pool keeps :data:`SERVE_POOL_SIZE` connections (a burst
    of requests beyond SQLAlchemy's default 5 opened and closed connections
    each time, 10-40 ms each, traced). On SQLite it keeps
    :data:`SERVE_SQLITE_POOL_SIZE`, each with a page cache of at most
    :data:`SERVE_SQLITE_CACHE_KIB` KiB, so that SQLite's memory has a small
    bound: 4 connections, each with its cache and at most 128 prepared
    statements (the live benchmark's hour: 6.1 MB for the 3 it needed, against
    14-17 MB and still rising with 16 kept and SQLite's default cache). Up to
    twice :data:`SERVE_POOL_SIZE` are open at once on both.

    Raises
    ------
    StoreError
        As :class:`~chaintwin.store.store.Store` (an older schema: ``chaintwin db upgrade``).
    """
    from chaintwin.store.store import Store

    if url.startswith("sqlite"):
        return Store(
            url,
            pool_size=SERVE_SQLITE_POOL_SIZE,
            max_overflow=2 * SERVE_POOL_SIZE - SERVE_SQLITE_POOL_SIZE,
            sqlite_cache_kib=SERVE_SQLITE_CACHE_KIB,
        )
    return Store(url, pool_size=SERVE_POOL_SIZE)


@dataclass
class LiveArgs:
    """The live service's options of ``chaintwin serve``."""

    watch: list[Path] = field(default_factory=list)
    settle_s: float = 2.0
    order_window_s: float = 60.0
    poll: bool = False
    no_web: bool = False
    notify_urls: list[str] = field(default_factory=list)
    notify_secret_file: Path | None = None
    public_url: str | None = None
    log_json: bool = False
    keep_samples_days: float | None = None
    lease_s: float = 15.0
    opcua: Path | None = None
    notify_smtp: str | None = None
    notify_mail_to: list[str] = field(default_factory=list)
    notify_mail_from: str | None = None
    notify_smtp_starttls: bool = False
    notify_smtp_login_file: Path | None = None
    escalate_after_min: float | None = None
    """Notify again (``escalated``) of an alarm unacknowledged this many minutes after it opened."""
    opcua_endpoint: str | None = None
    """``opc.tcp://HOST:PORT`` of the OPC UA server of the results (None: no server)."""
    opcua_security: str = "basic256sha256"
    """``basic256sha256`` (sign and encrypt) or ``none``."""
    opcua_cert_dir: Path | None = None
    """The OPC UA server's certificate and trust lists (default ``opcua-pki``)."""
    opcua_allow_anonymous: bool = False
    """Let OPC UA sessions in without a user."""


def system_malloc_command(
    args: list[str], environ: Mapping[str, str], orig_argv: list[str]
) -> tuple[list[str], dict[str, str]] | None:
    """The command line and environment to run ``serve`` again with
    ``PYTHONMALLOC=malloc``, or None to go on as it is.

    The service runs for weeks: with Python's own allocator its memory grew
    over an hour by 0.10 MB a minute in the last third (Python's arenas kept
    resident by a few blocks each: fragmentation, not more objects); with
    Python's objects in glibc's heap, whose free pages the service hands
    back every minute, by -0.04 (flat) and 26 MB less in all, at no cost in
    ingest speed measured (docs/live-service.md). Only ``serve`` run from
    the command line (``args``: the process's arguments after the program),
    and only when ``PYTHONMALLOC`` is not set: a value set by the user
    (``PYTHONMALLOC=pymalloc`` to keep Python's) is kept.
    """
    command = next((a for a in args if not a.startswith("-")), None)
    if command != "serve" or "PYTHONMALLOC" in environ:
        return None
    return list(orig_argv), dict(environ, PYTHONMALLOC="malloc")


def serve(
    db: str | None,
    profiles: Path | None,
    host: str,
    port: int,
    max_upload_mb: float,
    ssl_certfile: Path | None = None,
    ssl_keyfile: Path | None = None,
    live: LiveArgs | None = None,
    forwarded_allow_ips: str | None = None,
) -> None:
    """Run the service until SIGTERM or Ctrl-C, then exit 0.

    On SIGTERM the live sources stop, the recording in hand is committed, the
    web server finishes the requests in hand.
    """
    import asyncio

    from chaintwin.extras import require_extra

    live = live or LiveArgs()
    require_extra("web", needed_by="chaintwin serve")
    if live.watch:
        require_extra("live", "watchfiles", needed_by="--watch")
    if live.opcua is not None:
        require_extra("live", "asyncua", needed_by="--opcua")
    if live.opcua_endpoint is not None:
        require_extra("live", "asyncua", needed_by="--opcua-endpoint")
        _check_opcua_server(live)
    if live.notify_urls or live.notify_secret_file or live.notify_mail_to or live.notify_smtp:
        require_extra("live", "httpx", needed_by="the alarm notifications")
    from chaintwin.cli.common import load_profiles
    from chaintwin.live.logs import setup_logging
    from chaintwin.live.service import LiveOptions, LiveService
    from chaintwin.store.engine import safe_url, store_url
    from chaintwin.web.app import create_app
    from chaintwin.web.connections import server_config

    drives = None
    if live.opcua is not None:
        from chaintwin.live.opcua import load_opcua_config

        drives = load_opcua_config(live.opcua)  # a one-line error naming the field
    if (ssl_certfile is None) != (ssl_keyfile is None):
        raise StoreError("give both --ssl-certfile and --ssl-keyfile, or neither")
    if max_upload_mb <= 0:
        raise StoreError(f"--max-upload-mb {max_upload_mb} must be positive")
    if forwarded_allow_ips is not None:
        _check_proxies(forwarded_allow_ips)
    if live.settle_s < 0:
        raise StoreError(f"--settle-s {live.settle_s} must be zero or more")
    if not 0 <= live.order_window_s <= 86_400:
        raise StoreError(
            f"--order-window-s {live.order_window_s} must be from 0 (no ordering) to 86400 s"
        )
    if live.lease_s <= 0:
        raise StoreError(f"--lease-s {live.lease_s} must be positive")
    if live.keep_samples_days is not None and live.keep_samples_days <= 0:
        raise StoreError(f"--keep-samples-days {live.keep_samples_days} must be positive")
    for folder in live.watch:
        if not folder.is_dir():
            raise StoreError(f"--watch {folder}: no such folder; give a folder to follow")
    secret: bytes | None = None
    if live.notify_urls:
        from chaintwin.live.notify import read_secret

        if live.notify_secret_file is None:
            raise StoreError(
                "--notify-url needs --notify-secret-file FILE: the notifications are signed "
                "with its secret (X-Chaintwin-Signature)"
            )
        for u in live.notify_urls:
            if not u.startswith(("http://", "https://")):
                raise StoreError(f"--notify-url {u}: not an http:// or https:// URL")
        secret = read_secret(live.notify_secret_file)
    elif live.notify_secret_file is not None:
        from chaintwin.live.notify import read_secret

        secret = read_secret(live.notify_secret_file)  # signs the mails' JSON
    mail = _mail_settings(live)
    profs = load_profiles(None, profiles) if profiles is not None else {}
    setup_logging(live.log_json)
    url = store_url(db)
    store = serve_store(url)  # an older schema is refused here, naming `chaintwin db upgrade`
    scheme = "https" if ssl_certfile is not None else "http"
    options = LiveOptions(
        settle_s=live.settle_s,
        order_window_s=live.order_window_s,
        poll=live.poll,
        notify_urls=live.notify_urls,
        notify_secret=secret,
        mail=mail,
        public_url=live.public_url or f"{scheme}://{host}:{port}",
        keep_samples_days=live.keep_samples_days,
        lease_s=live.lease_s,
        profiles_dir=profiles,
    )
    try:

        async def main() -> None:
            service = LiveService(store, profs, options)
            for folder in live.watch:
                service.add_folder(folder)
            if drives is not None:
                service.add_opcua(drives)
            if live.opcua_endpoint is not None:
                _add_results_server(service, store, live)
            config = None
            if not live.no_web:
                app = create_app(
                    store,
                    profs,
                    max_upload_mb=max_upload_mb,
                    secure_cookies=ssl_certfile is not None,
                    live=service,
                )
                from chaintwin.web.app import freeze_heap

                freeze_heap(app)  # no full garbage collection walks the start-up heap
                config = server_config(
                    app,
                    host=host,
                    port=port,
                    ssl_certfile=ssl_certfile,
                    ssl_keyfile=ssl_keyfile,
                    forwarded_allow_ips=forwarded_allow_ips,
                )
            followed = [str(f) for f in live.watch]
            if drives is not None:
                followed += [f"{d.conveyor} at {d.endpoint}" for d in drives.drives]
            following = ", ".join(followed) or "no folders or drives"
            where = "no web" if live.no_web else f"{scheme}://{host}:{port}/ (API docs at /docs)"
            if live.opcua_endpoint is not None:
                where += f"; OPC UA at {live.opcua_endpoint} ({live.opcua_security})"
            print(
                f"chaintwin serve: {safe_url(url)} at {where}; following {printable(following)}; "
                "Ctrl-C or SIGTERM stops it",
                file=sys.stderr,
                flush=True,
            )
            from chaintwin.live.shelves import unshelve_forever

            timers = [asyncio.create_task(unshelve_forever(store))]
            if live.escalate_after_min is not None:
                from chaintwin.live.escalation import escalate_forever

                timers.append(asyncio.create_task(escalate_forever(store, live.escalate_after_min)))
            try:
                await service.run(config)
            finally:
                for timer in timers:
                    timer.cancel()

        asyncio.run(main())
    finally:
        store.close()


def _check_opcua_server(live: LiveArgs) -> None:
    """Refuse ``--opcua-*`` options the OPC UA server could not use, naming the option.

    Raises
    ------
    ConnectorError
        A bad endpoint or security; ``--opcua-cert-dir`` that is a file.
    """
    from chaintwin.errors import ConnectorError
    from chaintwin.live.opcua_server import SECURITY, parse_endpoint

    assert live.opcua_endpoint is not None
    parse_endpoint(live.opcua_endpoint)
    if live.opcua_security not in SECURITY:
        raise ConnectorError(
            f"--opcua-security {live.opcua_security}: give one of {', '.join(SECURITY)}"
        )
    if live.opcua_cert_dir is not None and live.opcua_cert_dir.is_file():
        raise ConnectorError(
            f"--opcua-cert-dir {live.opcua_cert_dir}: is a file; give a folder (made if missing)"
        )


def _add_results_server(service: Any, store: Store, live: LiveArgs) -> None:
    """Run the OPC UA server of the results under the lease ``opcua-server``: with several
    ``serve`` processes on one store, one of them serves it (another takes over when
    that one stops)."""
    from chaintwin.live.opcua_server import LEASE, ResultsServer
    from chaintwin.live.service import Source
    from chaintwin.web.access import verify_token

    assert live.opcua_endpoint is not None
    server = ResultsServer(
        store,
        live.opcua_endpoint,
        security=live.opcua_security,
        cert_dir=None
        if live.opcua_security == "none"
        else (live.opcua_cert_dir or Path(DEFAULT_OPCUA_CERT_DIR)),
        anonymous=live.opcua_allow_anonymous,
        token_check=verify_token,
    )
    service.sources.append(Source(LEASE, "opcua_server", server.run))


DEFAULT_OPCUA_CERT_DIR = "opcua-pki"
"""``--opcua-cert-dir`` when not given (in the current folder)."""


def _check_proxies(given: str) -> None:
    """Refuse a ``--forwarded-allow-ips`` uvicorn could not read, naming the entry.

    Raises
    ------
    StoreError
        For an entry that is neither ``*``, an address, a network nor a
        Unix socket's path (``unix:...``).
    """
    import ipaddress

    for entry in (e.strip() for e in given.split(",")):
        if entry == "*" or entry.startswith("unix:"):
            continue
        try:
            ipaddress.ip_network(entry, strict=False)
        except ValueError:
            raise StoreError(
                f"--forwarded-allow-ips: '{entry}' is not an address or network; give the "
                "proxy's address (10.0.0.5), a network (10.0.0.0/24) or '*', comma-separated"
            ) from None


def _mail_settings(live: LiveArgs) -> MailSettings | None:
    """The e-mail channel of ``--notify-smtp`` and its options, checked (None: no e-mail).

    Raises
    ------
    StoreError
        On a bad host, address or login file, or mail options without
        ``--notify-smtp`` (or it without ``--notify-mail-to``).
    """
    import socket

    from chaintwin.live.notify import MailSettings, parse_mail_address, parse_smtp, read_login

    if live.notify_smtp is None:
        given = [
            name
            for name, value in (
                ("--notify-mail-to", live.notify_mail_to),
                ("--notify-mail-from", live.notify_mail_from),
                ("--notify-smtp-starttls", live.notify_smtp_starttls),
                ("--notify-smtp-login-file", live.notify_smtp_login_file),
            )
            if value
        ]
        if given:
            raise StoreError(
                f"{given[0]} needs --notify-smtp HOST[:PORT]: the SMTP server that sends the mail"
            )
        return None
    host, port = parse_smtp(live.notify_smtp)
    if not live.notify_mail_to:
        raise StoreError(
            "--notify-smtp needs --notify-mail-to ADDR (repeatable): whom to send the alarms to"
        )
    to = tuple(
        dict.fromkeys(parse_mail_address(a, "--notify-mail-to") for a in live.notify_mail_to)
    )
    sender = parse_mail_address(
        live.notify_mail_from or f"chaintwin@{socket.getfqdn() or 'localhost'}",
        "--notify-mail-from",
    )
    user = password = None
    if live.notify_smtp_login_file is not None:
        user, password = read_login(live.notify_smtp_login_file)
    return MailSettings(host, port, to, sender, live.notify_smtp_starttls, user, password)


def register(app: typer.Typer) -> None:
    """Add ``serve`` and the ``token`` group to the application."""

    @app.command("serve")
    def serve_cmd(
        db: DbOption = None,
        profiles: Annotated[
            Path | None,
            typer.Option("--profiles", help="Folder of profiles uploads are weighed with."),
        ] = None,
        host: Annotated[
            str, typer.Option("--host", help="Address to bind (default: this machine only).")
        ] = "127.0.0.1",
        port: Annotated[int, typer.Option("--port", min=1, max=65535)] = 8000,
        max_upload_mb: Annotated[
            float, typer.Option("--max-upload-mb", help="Largest upload request, MB.")
        ] = 20.0,
        ssl_certfile: Annotated[Path | None, typer.Option("--ssl-certfile")] = None,
        ssl_keyfile: Annotated[Path | None, typer.Option("--ssl-keyfile")] = None,
        forwarded_allow_ips: Annotated[
            str | None,
            typer.Option(
                "--forwarded-allow-ips",
                help="Proxies whose X-Forwarded-For/-Proto are believed (comma-separated "
                "addresses or networks, '*' for any) [FORWARDED_ALLOW_IPS, else 127.0.0.1]: "
                "the client's address for the login limit, https for Secure cookies.",
            ),
        ] = None,
        watch: Annotated[
            list[Path] | None,
            typer.Option(
                "--watch",
                help="Folder to follow (recursively): every recording file that appears (*.csv, "
                "or a registered format's pattern) is ingested. "
                "Repeat for more folders.",
            ),
        ] = None,
        settle_s: Annotated[
            float,
            typer.Option(
                "--settle-s", help="A file is read once unchanged (size, mtime) this long, s."
            ),
        ] = 2.0,
        order_window_s: Annotated[
            float,
            typer.Option(
                "--order-window-s",
                help="The files found in the folders are held this long and taken in "
                "recorded order, s (0: as found). Adds this much latency.",
            ),
        ] = 60.0,
        poll: Annotated[
            bool, typer.Option("--poll", help="Poll the folders (network shares).")
        ] = False,
        no_web: Annotated[
            bool, typer.Option("--no-web", help="Run the live sources only, without the web.")
        ] = False,
        notify_url: Annotated[
            list[str] | None,
            typer.Option("--notify-url", help="POST alarm notifications (JSON) here. Repeatable."),
        ] = None,
        notify_secret_file: Annotated[
            Path | None,
            typer.Option(
                "--notify-secret-file",
                help="File holding the secret the notifications are signed with (HMAC-SHA256).",
            ),
        ] = None,
        public_url: Annotated[
            str | None,
            typer.Option(
                "--public-url", help="The dashboard's address as users reach it, for links."
            ),
        ] = None,
        log_json: Annotated[
            bool, typer.Option("--log-json", help="Log one JSON object a line.")
        ] = False,
        keep_samples_days: Annotated[
            float | None,
            typer.Option(
                "--keep-samples-days",
                help="Drop stored samples older than this (results are kept), days.",
            ),
        ] = None,
        lease_s: Annotated[
            float,
            typer.Option(
                "--lease-s",
                help="A source's lease (several serve processes on one store), s.",
            ),
        ] = 15.0,
        opcua: Annotated[
            Path | None,
            typer.Option("--opcua", help="Follow drives over OPC UA (config YAML)."),
        ] = None,
        notify_smtp: Annotated[
            str | None,
            typer.Option(
                "--notify-smtp", help="Mail alarm notifications through this SMTP HOST[:PORT]."
            ),
        ] = None,
        notify_mail_to: Annotated[
            list[str] | None,
            typer.Option("--notify-mail-to", help="Mail the notifications to ADDR. Repeatable."),
        ] = None,
        notify_mail_from: Annotated[
            str | None,
            typer.Option("--notify-mail-from", help="The mails' sender [chaintwin@this host]."),
        ] = None,
        notify_smtp_starttls: Annotated[
            bool,
            typer.Option("--notify-smtp-starttls", help="Upgrade the SMTP link with STARTTLS."),
        ] = False,
        notify_smtp_login_file: Annotated[
            Path | None,
            typer.Option(
                "--notify-smtp-login-file",
                help="File with the SMTP user (first line) and password (second line).",
            ),
        ] = None,
        escalate_after_min: Annotated[
            float | None,
            typer.Option(
                "--escalate-after-min",
                min=1,
                help="Notify again (event escalated) of an alarm still unacknowledged N minutes "
                "after it opened.",
            ),
        ] = None,
        opcua_endpoint: Annotated[
            str | None,
            typer.Option(
                "--opcua-endpoint",
                help="Serve the results over OPC UA at opc.tcp://HOST:PORT (docs/opcua-server.md).",
            ),
        ] = None,
        opcua_security: Annotated[
            str,
            typer.Option(
                "--opcua-security",
                help="basic256sha256 (sign and encrypt) or none (plain: only when asked for).",
            ),
        ] = "basic256sha256",
        opcua_cert_dir: Annotated[
            Path | None,
            typer.Option(
                "--opcua-cert-dir",
                help="The OPC UA server's own certificate (made on first start) and trust "
                "lists [opcua-pki].",
            ),
        ] = None,
        opcua_allow_anonymous: Annotated[
            bool,
            typer.Option(
                "--opcua-allow-anonymous",
                help="Let OPC UA clients in without a user (default: a token is needed).",
            ),
        ] = False,
    ) -> None:
        """Serve the dashboard and the HTTP API over a results store; follow live sources.

        Log in with a token from `chaintwin token create`. Binds to
        127.0.0.1 unless --host says otherwise; behind a reverse proxy with
        TLS, or with --ssl-certfile/--ssl-keyfile. With --watch DIR every
        recording that appears in the folder is ingested (docs/live-service.md).
        """
        live = LiveArgs(
            watch=list(watch or []),
            settle_s=settle_s,
            order_window_s=order_window_s,
            poll=poll,
            no_web=no_web,
            notify_urls=list(notify_url or []),
            notify_secret_file=notify_secret_file,
            public_url=public_url,
            log_json=log_json,
            keep_samples_days=keep_samples_days,
            lease_s=lease_s,
            opcua=opcua,
            notify_smtp=notify_smtp,
            notify_mail_to=list(notify_mail_to or []),
            notify_mail_from=notify_mail_from,
            notify_smtp_starttls=notify_smtp_starttls,
            notify_smtp_login_file=notify_smtp_login_file,
            escalate_after_min=escalate_after_min,
            opcua_endpoint=opcua_endpoint,
            opcua_security=opcua_security,
            opcua_cert_dir=opcua_cert_dir,
            opcua_allow_anonymous=opcua_allow_anonymous,
        )
        serve(
            db, profiles, host, port, max_upload_mb, ssl_certfile, ssl_keyfile, live,
            forwarded_allow_ips,
        )  # fmt: skip

    token = typer.Typer(
        name="token", help="Access tokens of the web service.", no_args_is_help=True
    )

    @token.command("create")
    def create(
        name: Annotated[str, typer.Option("--name", help="Who or what the token is for.")],
        role: Annotated[
            str, typer.Option("--role", help="viewer, maintainer or admin.")
        ] = "viewer",
        db: DbOption = None,
        expires_days: Annotated[
            float | None, typer.Option("--expires-days", help="Lifetime in days (default: none).")
        ] = None,
        as_json: JsonObjectOption = False,
    ) -> None:
        """Create a token and print it once (the store keeps only its hash)."""
        from chaintwin.store.engine import store_url
        from chaintwin.store.store import Store
        from chaintwin.web.access import create_token

        with Store(store_url(db)) as store:
            value = create_token(store, name, role, expires_days)
        if as_json:
            print_json({"token": value, "name": name, "role": role})
        else:
            print(value)
            print(
                f"token '{name}' ({role}) created; it is shown only now: keep it safe",
                file=sys.stderr,
            )

    @token.command("list")
    def list_cmd(
        db: DbOption = None,
        as_json: JsonListOption = False,
    ) -> None:
        """List the tokens (names, roles, lifetimes; never the tokens)."""
        from chaintwin.store.engine import store_url
        from chaintwin.store.store import Store
        from chaintwin.web.access import list_tokens

        with Store(store_url(db), create=False) as store:
            tokens = list_tokens(store)
        if as_json:
            print_json([t.to_dict() for t in tokens])
            return
        table = Table(title="chaintwin tokens")
        for col in ("name", "role", "created", "expires", "state"):
            table.add_column(col)
        for t in tokens:
            state = "revoked" if t.revoked_at else ("active" if t.active else "expired")
            table.add_row(safe(t.name), t.role, t.created_at, t.expires_at or "never", state)
        Console().print(table)

    @token.command("revoke")
    def revoke(
        name: Annotated[str, typer.Argument(help="The token's name.")],
        db: DbOption = None,
    ) -> None:
        """Revoke a token: it and its browser sessions stop working at once."""
        from chaintwin.store.engine import store_url
        from chaintwin.store.store import Store
        from chaintwin.web.access import revoke_token

        with Store(store_url(db), create=False) as store:
            info = revoke_token(store, name)
        print(f"token '{safe(info.name)}' revoked at {info.revoked_at}")

    app.add_typer(token)
