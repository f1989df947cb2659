"""``chaintwin report``: self-contained HTML pages from the results store."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console

from chaintwin.cli.common import DbOption, safe
from chaintwin.errors import StoreError

__all__ = ["register"]

_CONVEYOR_HELP = "The conveyor whose page is made."
_FLEET_HELP = "Make the fleet page (conveyors ranked by health and by TLF)."
_ALL_HELP = "Make every conveyor's page and the fleet page (fleet.html) in the --out folder."
_OUT_HELP = (
    "The page to write (default <conveyor>.html, or fleet.html); with --all, the folder "
    "(default reports/)."
)


def register(app: typer.Typer) -> None:
    """Add the command to the application."""

    @app.command("report")
    def report_cmd(
        db: DbOption = None,
        conveyor: Annotated[str | None, typer.Option("--conveyor", help=_CONVEYOR_HELP)] = None,
        fleet: Annotated[bool, typer.Option("--fleet", help=_FLEET_HELP)] = False,
        every: Annotated[bool, typer.Option("--all", help=_ALL_HELP)] = False,
        out: Annotated[Path | None, typer.Option("--out", help=_OUT_HELP)] = None,
    ) -> None:
        """Write HTML reports that open offline: per conveyor, or for the fleet.

        A conveyor's page: status and forecasts, alarms and maintenance,
        parameter trends with control limits, payload and TLF over time,
        residual statistics, spectrum and order waterfall, the latest recording
        against the model.
        """
        from chaintwin.report.html import (
            conveyor_page,
            fleet_page,
            report_file_name,
            write_folder,
            write_page,
        )
        from chaintwin.store.engine import store_url
        from chaintwin.store.store import Store

        if sum((conveyor is not None, fleet, every)) != 1:
            raise StoreError("give one of --conveyor ID, --fleet or --all")
        console = Console()
        with Store(store_url(db), create=False, read_only=True) as store:
            if conveyor is not None:
                html, _d = conveyor_page(store, conveyor)
                target = write_page(html, out or Path(report_file_name(conveyor)))
                console.print(f"wrote {safe(str(target))}", highlight=False)
            elif fleet:
                target = write_page(fleet_page(store), out or Path("fleet.html"))
                console.print(f"wrote {safe(str(target))}", highlight=False)
            else:
                folder = out or Path("reports")
                written = write_folder(store, folder)
                console.print(
                    f"wrote {len(written)} pages into {safe(str(folder))} "
                    f"(start with {safe(str(written[-1]))})",
                    highlight=False,
                )
