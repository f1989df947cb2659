"""``chaintwin refused list`` and ``retry``: the files the live service refused."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console
from rich.table import Table

from chaintwin.cli.common import DbOption, JsonListOption, print_json, printable, safe
from chaintwin.errors import StoreError

__all__ = ["register", "retry_refusals"]


def retry_refusals(
    store: Any, profiles: dict[str, Any], files: list[str] | None = None
) -> list[dict[str, Any]]:
    """Read refused files again, as the live service would; each file's outcome.

    Parameters
    ----------
    store : Store
        The results store.
    profiles : dict
        Profiles by id (``--profiles``); the store's serve the other conveyors.
    files : list of str, optional
        The refused files to retry (as ``refused list`` names them, or their
        paths); default all of them.

    Returns
    -------
    list of dict
        ``{"path", "status", "reason"}`` per refused file: ``stored``,
        ``waiting``, ``already_stored``, ``refused`` (again, with the new
        reason), ``gone`` (the file is no longer there: its refusal stays)
        or ``not_kept`` (a drive's scope, which was not kept).

    Raises
    ------
    StoreError
        When a file given is not among the refused files.
    """
    from chaintwin.live.ledger import forget_refusal, refusals
    from chaintwin.live.sources import Ingestor, Job

    rows = refusals(store)
    if files:
        by_path: dict[str, Any] = {}
        for r in rows:
            by_path.setdefault(r.path, r)
            if not r.path.startswith("opcua://"):
                by_path.setdefault(os.path.realpath(r.path), r)
        chosen = []
        for f in files:
            row = by_path.get(f) or by_path.get(os.path.realpath(f))
            if row is None:
                raise StoreError(
                    f"{f}: not among the refused files; `chaintwin refused list` names them"
                )
            if row not in chosen:
                chosen.append(row)
        rows = chosen
    out: list[dict[str, Any]] = []
    ingestor = Ingestor(store, profiles)
    try:
        for r in rows:
            if r.path.startswith("opcua://"):
                out.append(
                    {
                        "path": r.path,
                        "status": "not_kept",
                        "reason": "a drive's scope is not kept; it cannot be read again",
                    }
                )
                continue
            if not os.path.isfile(r.path):
                out.append({"path": r.path, "status": "gone", "reason": "no such file any more"})
                continue
            if not forget_refusal(store, r.sha256):
                continue  # retried meanwhile by a service
            outcome = ingestor.ingest_one(Job(r.path, r.source))
            status = "already_stored" if outcome.status == "already_stored" else outcome.status
            out.append({"path": r.path, "status": status, "reason": outcome.reason})
    finally:
        ingestor.close()
    return out


def register(app: typer.Typer) -> None:
    """Add the ``refused`` command group to the application."""
    group = typer.Typer(
        name="refused",
        help="The files the live service refused: list them, read them again.",
        no_args_is_help=True,
    )

    @group.command("list")
    def list_cmd(
        db: DbOption = None,
        as_json: JsonListOption = False,
    ) -> None:
        """List the refused files: when, why (cause: profile or recording), the reason."""
        from chaintwin.live.ledger import refusals
        from chaintwin.store.engine import store_url
        from chaintwin.store.store import Store

        with Store(store_url(db), create=False) as store:
            rows = refusals(store)
        if as_json:
            print_json([r.to_dict() for r in rows])
            return
        table = Table(title=f"chaintwin refused files ({len(rows)})")
        for col in ("refused at", "cause", "conveyor", "file", "reason"):
            table.add_column(col, overflow="fold")
        for r in rows:
            table.add_row(
                r.refused_at[:19], r.cause, safe(r.conveyor or ""), safe(r.path), safe(r.reason)
            )
        Console().print(table)

    @group.command("retry")
    def retry_cmd(
        files: Annotated[
            list[str] | None,
            typer.Argument(help="Refused files to read again (default: all of them)."),
        ] = None,
        db: DbOption = None,
        profiles: Annotated[
            Path | None,
            typer.Option("--profiles", help="Folder of profiles (the store's serve the rest)."),
        ] = None,
        as_json: JsonListOption = False,
    ) -> None:
        """Read refused files again (after their profile was added or fixed).

        A file refused again keeps its refusal with the new reason; one that
        is gone keeps its refusal.
        """
        from chaintwin.cli.common import load_profiles
        from chaintwin.store.engine import store_url
        from chaintwin.store.store import Store

        profs = load_profiles(None, profiles) if profiles is not None else {}
        with Store(store_url(db), create=False) as store:
            done = retry_refusals(store, profs, files or None)
        if as_json:
            print_json(done)
            return
        if not done:
            print("no refused files")
        for d in done:
            tail = f": {d['reason']}" if d["status"] in ("refused", "gone", "not_kept") else ""
            print(printable(f"{d['status']:<15} {d['path']}{tail}"))

    app.add_typer(group)
