"""``chaintwin serve`` (the web dashboard and API) and ``chaintwin token``."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.table import Table

from chaintwin.cli.common import print_json, safe
from chaintwin.errors import StoreError

__all__ = ["register"]

_DB_HELP = (
    "Results store URL (sqlite:///file.db, postgresql://...); default CHAINTWIN_DB, "
    "else sqlite:///chaintwin.db."
)


def serve(
    db: str | None,
    profiles: Path | None,
    host: str,
    port: int,
    max_upload_mb: float,
    ssl_certfile: Path | None = None,
    ssl_keyfile: Path | None = None,
) -> None:
    """Run the web service until SIGTERM or Ctrl-C (graceful: requests in hand finish)."""
    import uvicorn

    from chaintwin.cli.monitor_cmd import load_profiles
    from chaintwin.store.engine import safe_url, store_url
    from chaintwin.store.store import Store
    from chaintwin.web.app import create_app

    if (ssl_certfile is None) != (ssl_keyfile is None):
        raise StoreError("give both --ssl-certfile and --ssl-keyfile, or neither")
    if max_upload_mb <= 0:
        raise StoreError(f"--max-upload-mb {max_upload_mb} must be positive")
    profs = load_profiles(None, profiles) if profiles is not None else {}
    url = store_url(db)
    store = Store(url)
    try:
        app = create_app(
            store, profs, max_upload_mb=max_upload_mb, secure_cookies=ssl_certfile is not None
        )
        scheme = "https" if ssl_certfile is not None else "http"
        print(
            f"chaintwin serve: {safe_url(url)} at {scheme}://{host}:{port}/ "
            f"(API docs at /docs); Ctrl-C or SIGTERM stops it",
            file=sys.stderr,
        )
        config = uvicorn.Config(
            app,
            host=host,
            port=port,
            log_level="warning",
            ssl_certfile=str(ssl_certfile) if ssl_certfile else None,
            ssl_keyfile=str(ssl_keyfile) if ssl_keyfile else None,
            proxy_headers=True,
            # dashboards poll every few seconds: keep their connections open
            # longer than that (uvicorn's default of 5 s races a 5 s poll)
            timeout_keep_alive=75,
        )
        uvicorn.Server(config).run()
    finally:
        store.close()


def register(app: typer.Typer) -> None:
    """Add ``serve`` and the ``token`` group to the application."""

    @app.command("serve")
    def serve_cmd(
        db: Annotated[str | None, typer.Option("--db", help=_DB_HELP)] = None,
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
    ) -> None:
        """Serve the dashboard and the HTTP API over a results store.

        Log in with a token from `chaintwin token create`. Binds to
        127.0.0.1 unless --host says otherwise; behind a reverse proxy with
        TLS, or with --ssl-certfile/--ssl-keyfile.
        """
        serve(db, profiles, host, port, max_upload_mb, ssl_certfile, ssl_keyfile)

    token = typer.Typer(
        name="token", help="Access tokens of the web service.", no_args_is_help=True
    )

    @token.command("create")
    def create(
        name: Annotated[str, typer.Option("--name", help="Who or what the token is for.")],
        role: Annotated[
            str, typer.Option("--role", help="viewer, maintainer or admin.")
        ] = "viewer",
        db: Annotated[str | None, typer.Option("--db", help=_DB_HELP)] = None,
        expires_days: Annotated[
            float | None, typer.Option("--expires-days", help="Lifetime in days (default: none).")
        ] = None,
        as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
    ) -> None:
        """Create a token and print it once (the store keeps only its hash)."""
        from chaintwin.store.access import create_token
        from chaintwin.store.engine import store_url
        from chaintwin.store.store import Store

        store = Store(store_url(db))
        try:
            value = create_token(store, name, role, expires_days)
        finally:
            store.close()
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
        db: Annotated[str | None, typer.Option("--db", help=_DB_HELP)] = None,
        as_json: Annotated[bool, typer.Option("--json", help="Print one JSON list.")] = False,
    ) -> None:
        """List the tokens (names, roles, lifetimes; never the tokens)."""
        from chaintwin.store.access import list_tokens
        from chaintwin.store.engine import store_url
        from chaintwin.store.store import Store

        store = Store(store_url(db), create=False)
        try:
            tokens = list_tokens(store)
        finally:
            store.close()
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
        db: Annotated[str | None, typer.Option("--db", help=_DB_HELP)] = None,
    ) -> None:
        """Revoke a token: it and its browser sessions stop working at once."""
        from chaintwin.store.access import revoke_token
        from chaintwin.store.engine import store_url
        from chaintwin.store.store import Store

        store = Store(store_url(db), create=False)
        try:
            info = revoke_token(store, name)
        finally:
            store.close()
        print(f"token '{safe(info.name)}' revoked at {info.revoked_at}")

    app.add_typer(token)
