"""``chaintwin db upgrade``: bring a results store's schema to this chaintwin's."""

from __future__ import annotations

import typer

from chaintwin.cli.common import DbOption, JsonObjectOption, print_json
from chaintwin.errors import StoreError

__all__ = ["register"]


def register(app: typer.Typer) -> None:
    """Add the ``db`` command group to the application."""
    db = typer.Typer(
        name="db",
        help="The results store's schema: upgrade it to this chaintwin's.",
        no_args_is_help=True,
    )

    @db.command("upgrade")
    def upgrade(
        url: DbOption = None,
        as_json: JsonObjectOption = False,
    ) -> None:
        """Upgrade a store's tables to this chaintwin's revision (creates an empty store).

        Back up the store first (SQLite: copy the file while nothing writes to
        it; PostgreSQL: pg_dump). Running it again on an upgraded store
        changes nothing. A SQLite store is checked whole first (``PRAGMA
        quick_check``, read-only): a damaged store, or another program's
        database, is refused and left as it was.
        """
        from sqlalchemy.exc import OperationalError

        from chaintwin.store import migrate
        from chaintwin.store.engine import engine_for, hide_password, safe_url, store_url
        from chaintwin.store.recognise import recognise

        given = store_url(url)
        recognise(given, safe_url(given), check_all=True)  # refused before anything is written
        engine = engine_for(given)
        try:
            before, after = migrate.upgrade(engine, safe_url(given))
        except OperationalError as exc:
            raise StoreError(
                f"url {safe_url(given)}: cannot open the store "
                f"({hide_password(str(exc.orig), given)}); check the path "
                "or server",
                field="url",
            ) from None
        finally:
            engine.dispose()
        if as_json:
            print_json({"store": safe_url(given), "from": before, "to": after})
        elif before == after:
            typer.echo(f"{safe_url(given)}: schema at revision {after} already; nothing to do")
        else:
            typer.echo(
                f"{safe_url(given)}: schema upgraded from "
                f"{'an empty database' if before is None else 'revision ' + before} "
                f"to revision {after}"
            )

    app.add_typer(db)
