"""``chaintwin fleet``: the fleet's health in the terminal, redrawn as the store changes.

Per conveyor: its verdict (health, NE 107, as the dashboard and the API give
it), open alarms, latest payload and TLF, and its stored forecasts (the
remaining life of the feature to reach its limit first, and the features
that crossed it), read as the dashboard reads them: computed after ingest
(:mod:`chaintwin.store.derived`), never refitted here, with the newest
recording they were computed from.
"""

from __future__ import annotations

import math
import time
from typing import Annotated, Any

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from chaintwin.cli.common import DbOption, json_option, print_json

__all__ = ["fleet_rows", "forecast_text", "register"]


def _life(days: Any) -> float | None:
    """A remaining life (days) when it is a finite number, else None."""
    if isinstance(days, int | float) and math.isfinite(days):
        return float(days)
    return None


def _first(forecasts: list[dict[str, Any]]) -> dict[str, Any] | None:
    """The forecast not yet crossed that reaches its limit first (by its expected life)."""
    ahead = [
        f
        for f in forecasts
        if not f.get("crossed")
        and isinstance(f.get("remaining_life_days"), dict)
        and _life(f["remaining_life_days"].get("expected")) is not None
    ]
    return min(ahead, key=lambda f: float(f["remaining_life_days"]["expected"]), default=None)


def forecast_text(forecasts: list[dict[str, Any]] | None) -> str:
    """What a conveyor's stored forecasts say, in a line.

    The features that crossed their limit (``crossed``, with since when),
    then the one to reach it first with its expected remaining life and
    90 % interval, in days; "no forecast stored yet" when none was computed.
    """
    if forecasts is None:
        return "no forecast stored yet"
    parts = [
        f"{f['feature']} crossed {f['limit']:.4g} since {str(f.get('crosses_at') or '-')[:16]}"
        for f in forecasts
        if f.get("crossed")
    ]
    first = _first(forecasts)
    if first is not None:
        life = first["remaining_life_days"]
        late = _life(life.get("latest"))
        parts.append(
            f"{first['feature']} ({first.get('cause', '-')}) reaches {first['limit']:.4g} in "
            f"{float(life['expected']):.1f} d (90 %: {float(life.get('earliest') or 0.0):.1f} "
            f"to {'beyond a year' if late is None else f'{late:.1f}'} d)"
        )
    return "; ".join(parts) or "no feature is forecast to reach its limit"


def fleet_rows(store: Any) -> list[dict[str, Any]]:
    """Per conveyor: the fleet's row (:class:`~chaintwin.web.fleet.FleetHealth`) with its
    stored ``forecasts`` (None: never computed) and ``forecasts_latest`` (the newest
    recording's time they were computed from)."""
    from sqlalchemy import select

    from chaintwin.store.schema import DerivedHealthRow
    from chaintwin.web.fleet import FleetHealth

    with store.session() as s:
        rows = FleetHealth().rows(store)
        derived = {
            str(cid): (dict(content or {}), latest)
            for cid, content, latest in s.execute(
                select(
                    DerivedHealthRow.conveyor_id,
                    DerivedHealthRow.content,
                    DerivedHealthRow.latest,
                )
            )
        }
    for row in rows:
        content, latest = derived.get(row["id"], (None, None))
        row["forecasts"] = None if content is None else list(content.get("forecasts") or [])
        row["forecasts_latest"] = latest
    return rows


def _table(rows: list[dict[str, Any]]) -> Table:
    table = Table(title="chaintwin fleet")
    for col in ("conveyor", "health", "alarms", "payload [kg]", "TLF", "latest", "forecast"):
        table.add_column(col)
    for r in rows:
        alarms = ", ".join(f"{a['cause']} ({a['feature']})" for a in r["open_alarms"])
        as_of = f" (as of {r['forecasts_latest'][:16]})" if r["forecasts_latest"] else ""
        table.add_row(
            escape(r["id"]),
            f"{r['health']} ({r['ne107']})",
            escape(alarms) or "-",
            "-" if r["payload_kg"] is None else f"{r['payload_kg']:.1f}",
            "-" if r["tlf"] is None else f"{r['tlf']:.3f}",
            (r["last_recorded_at"] or "-")[:16],
            escape(forecast_text(r["forecasts"]) + as_of),
        )
    return table


def register(app: typer.Typer) -> None:
    """Add ``fleet`` to the command line."""

    @app.command("fleet")
    def fleet_cmd(
        db: DbOption = None,
        every: Annotated[
            float, typer.Option("--every", min=0.5, help="Look for changes this often, s.")
        ] = 10.0,
        once: Annotated[bool, typer.Option("--once", help="Show the fleet once and exit.")] = False,
        as_json: Annotated[bool, json_option("Print the rows once as JSON and exit.")] = False,
    ) -> None:
        """The fleet's health, alarms and stored forecasts; redrawn as the store changes."""
        from chaintwin.store.engine import store_url
        from chaintwin.store.queries import store_signature
        from chaintwin.store.store import Store

        console = Console()
        with Store(store_url(db), create=False, read_only=True) as store:
            if as_json:
                print_json(fleet_rows(store))
                return
            shown: tuple[str, str] | None = None
            while True:
                # forecasts are stored after the results they come from: both tell a change
                key = (store_signature(store).id, _forecasts_stamp(store))
                if key != shown:
                    if shown is not None:
                        console.clear()
                    console.print(_table(fleet_rows(store)))
                    shown = key
                if once:
                    return
                try:
                    time.sleep(every)
                except KeyboardInterrupt:
                    return


def _forecasts_stamp(store: Any) -> str:
    """When the store's forecasts were last computed (empty: never)."""
    from sqlalchemy import func, select

    from chaintwin.store.schema import DerivedHealthRow

    with store.session() as s:
        return str(s.scalar(select(func.max(DerivedHealthRow.computed_at))) or "")
