"""``chaintwin opcua nodeset``: the OPC UA server's namespace as NodeSet2 XML."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated

import typer

from chaintwin.cli.common import DbOption, safe

__all__ = ["register"]


def register(app: typer.Typer) -> None:
    """Add the ``opcua`` group (``nodeset``) to the application."""
    group = typer.Typer(
        name="opcua", help="The OPC UA server of the results.", no_args_is_help=True
    )

    @group.command("nodeset")
    def nodeset(
        out: Annotated[Path, typer.Option("--out", help="The NodeSet2 XML file to write.")],
        db: DbOption = None,
        no_values: Annotated[
            bool,
            typer.Option(
                "--no-values", help="Leave the variables' current values out (the nodes only)."
            ),
        ] = False,
    ) -> None:
        """Write the namespace `serve --opcua-endpoint` publishes for this store as NodeSet2 XML.

        Every conveyor of the store with its nodes, data types and engineering
        units, node ids as the server gives them (docs/opcua-server.md), for
        SCADA engineering tools to import.
        """
        import asyncio

        from chaintwin.extras import require_extra

        require_extra("live", "asyncua", needed_by="chaintwin opcua nodeset")
        from chaintwin.live.opcua_server import export_nodeset
        from chaintwin.store.engine import store_url
        from chaintwin.store.store import Store

        store = Store(store_url(db), create=False)
        try:
            count = asyncio.run(export_nodeset(store, out, values=not no_values))
        finally:
            store.close()
        print(
            f"{count} nodes of {len(store.conveyors())} conveyors written to {safe(str(out))}",
            file=sys.stderr,
        )

    app.add_typer(group)
