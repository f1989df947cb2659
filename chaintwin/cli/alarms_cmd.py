"""``chaintwin alarms list|acknowledge|shelve|unshelve|comment`` and ``out-of-service``.

Each works on a monitoring state file (``--state``) or a results store
(``--db``); on a store every change is written to the audit log.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any, TypeVar

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from chaintwin.cli.common import DbOption, EditStateOption, json_option, print_json
from chaintwin.diagnose.alarm_actions import (
    clear_out_of_service,
    comment_alarm,
    set_out_of_service,
    shelve_alarm,
    unshelve_alarm,
)
from chaintwin.diagnose.records import LIFECYCLES, Alarm
from chaintwin.diagnose.state import acknowledge_alarm, load_state
from chaintwin.errors import StoreError

__all__ = ["filter_alarms", "register"]

T = TypeVar("T")


def filter_alarms(
    alarms: list[Alarm], status: str | None = None, lifecycle: str | None = None
) -> list[Alarm]:
    """The alarms with ``status`` (``open``: not closed, or ``closed``) and ``lifecycle``.

    Raises
    ------
    StoreError
        For a status or lifecycle that is none of the known words.
    """
    if status is not None and status not in ("open", "closed"):
        raise StoreError(f"status '{status}' must be open or closed", field="status")
    if lifecycle is not None and lifecycle not in LIFECYCLES:
        raise StoreError(
            f"lifecycle '{lifecycle}' must be one of {', '.join(LIFECYCLES)}", field="lifecycle"
        )
    return [
        a
        for a in alarms
        if (status is None or a.is_open == (status == "open"))
        and (lifecycle is None or a.lifecycle() == lifecycle)
    ]


def _alarms(state: Path | None, db: str | None) -> list[Alarm]:
    """Every alarm of a state file or a store, oldest first."""
    if state is not None and db is not None:
        raise StoreError("give either --state (a state file) or --db (a results store), not both")
    if state is not None:
        data = load_state(state, missing_ok=False)
        out: list[Alarm] = []
        for conveyor, entry in data["conveyors"].items():
            try:
                out += [Alarm.from_dict(a) for a in entry["alarms"]]
            except (KeyError, TypeError, ValueError, AttributeError) as exc:
                raise StoreError(
                    f"{state}: the alarms of '{conveyor}' are damaged ({exc!r}); restore the "
                    "state from a backup or start a new one"
                ) from None
        return sorted(out, key=lambda a: (a.since or "", a.id))
    from chaintwin.store.engine import store_url
    from chaintwin.store.store import Store

    with Store(store_url(db), create=False) as store:
        return store.alarms()


def _change(
    state: Path | None,
    db: str | None,
    conveyor: str | None,
    edit: Callable[[dict[str, Any]], T],
    audit_as: tuple[str, str, dict[str, Any]],
    alarm: str | None = None,
) -> T:
    """Apply a change to a state file or a store; audit it on a store."""
    from chaintwin.cli.common import edit_state

    out = edit_state(state, db, conveyor, edit, alarm)
    if state is None:
        from chaintwin.store.engine import store_url
        from chaintwin.store.store import Store
        from chaintwin.web.access import audit

        with Store(store_url(db), create=False) as store:
            audit(store, *audit_as)
    return out


def _done(verb: str, a: Alarm) -> None:
    Console().print(
        f"{verb} alarm {a.id} ({escape(a.cause)}, {escape(a.feature)}) on {escape(a.conveyor)}: "
        f"{a.lifecycle()}",
        highlight=False,
    )


def _parse_until(text: str | None) -> Any:
    from chaintwin.cli.common import parse_at

    return parse_at(text, "--until")


def register(app: typer.Typer) -> None:
    """Add ``alarms`` and ``out-of-service`` to the command line."""
    group = typer.Typer(
        name="alarms",
        help="Alarms: list, acknowledge, shelve, unshelve, comment.",
        no_args_is_help=True,
    )

    @group.command("list")
    def list_cmd(
        status: Annotated[
            str | None, typer.Option("--status", help="open (not closed) or closed.")
        ] = None,
        lifecycle: Annotated[
            str | None, typer.Option("--lifecycle", help=f"One of {', '.join(LIFECYCLES)}.")
        ] = None,
        state: EditStateOption = None,
        db: DbOption = None,
        as_json: Annotated[bool, json_option("Print JSON.")] = False,
    ) -> None:
        """List alarms with their lifecycle, oldest first."""
        found = filter_alarms(_alarms(state, db), status, lifecycle)
        if as_json:
            print_json([a.to_dict() for a in found])
            return
        if not found:
            print("no alarms")
            return
        table = Table(title="chaintwin alarms")
        for col in ("id", "conveyor", "cause", "lifecycle", "since", "evidence"):
            table.add_column(col)
        for a in found:
            table.add_row(
                a.id,
                escape(a.conveyor),
                escape(a.cause),
                a.lifecycle(),
                a.since or "-",
                escape(", ".join(e.feature for e in a.evidence)),
            )
        Console().print(table)

    @group.command("acknowledge")
    def acknowledge_cmd(
        alarm: Annotated[str, typer.Argument(help="Alarm id.")],
        by: Annotated[str, typer.Option("--by", help="Who acknowledges.")],
        why: Annotated[str, typer.Option("--why", help="Why (e.g. work order).")] = "",
        state: EditStateOption = None,
        db: DbOption = None,
    ) -> None:
        """Acknowledge an alarm (as `chaintwin acknowledge`)."""
        a = _change(
            state,
            db,
            None,
            lambda d: acknowledge_alarm(d, alarm, by, why),
            (by, "acknowledge", {"alarm": alarm, "why": why}),
            alarm,
        )
        _done("acknowledged", a)

    @group.command("shelve")
    def shelve_cmd(
        alarm: Annotated[str, typer.Argument(help="Alarm id.")],
        by: Annotated[str, typer.Option("--by", help="Who shelves it.")],
        why: Annotated[str, typer.Option("--why", help="Why (required).")],
        minutes: Annotated[float, typer.Option("--minutes", help="For how long, minutes.")],
        state: EditStateOption = None,
        db: DbOption = None,
    ) -> None:
        """Shelve an alarm for a time: it neither counts nor notifies until it returns."""
        a = _change(
            state,
            db,
            None,
            lambda d: shelve_alarm(d, alarm, by, why, minutes),
            (by, "shelve", {"alarm": alarm, "why": why, "minutes": minutes}),
            alarm,
        )
        _done("shelved", a)
        print(f"until {a.shelved.until if a.shelved else '-'}")

    @group.command("unshelve")
    def unshelve_cmd(
        alarm: Annotated[str, typer.Argument(help="Alarm id.")],
        by: Annotated[str, typer.Option("--by", help="Who unshelves it.")],
        state: EditStateOption = None,
        db: DbOption = None,
    ) -> None:
        """End an alarm's shelf now."""
        a = _change(
            state,
            db,
            None,
            lambda d: unshelve_alarm(d, alarm, by),
            (by, "unshelve", {"alarm": alarm}),
            alarm,
        )
        _done("unshelved", a)

    @group.command("comment")
    def comment_cmd(
        alarm: Annotated[str, typer.Argument(help="Alarm id.")],
        text: Annotated[str, typer.Argument(help="The comment.")],
        by: Annotated[str, typer.Option("--by", help="Who writes it.")],
        state: EditStateOption = None,
        db: DbOption = None,
    ) -> None:
        """Add a comment to an alarm."""
        a = _change(
            state,
            db,
            None,
            lambda d: comment_alarm(d, alarm, by, text),
            (by, "comment", {"alarm": alarm, "text": text}),
            alarm,
        )
        _done("commented", a)

    app.add_typer(group)

    @app.command("out-of-service")
    def out_of_service_cmd(
        conveyor: Annotated[str, typer.Option("--conveyor", help="Conveyor id.")],
        by: Annotated[str, typer.Option("--by", help="Who.")],
        why: Annotated[str, typer.Option("--why", help="Why (e.g. work order).")] = "",
        until: Annotated[
            str | None,
            typer.Option("--until", help="Until when (ISO 8601); default until --end."),
        ] = None,
        end: Annotated[
            bool, typer.Option("--end", help="Put the conveyor back in service now.")
        ] = False,
        state: EditStateOption = None,
        db: DbOption = None,
    ) -> None:
        """Take a conveyor out of service: its recordings are kept, not judged, not learned."""
        if end:
            w = _change(
                state,
                db,
                conveyor,
                lambda d: clear_out_of_service(d, conveyor, by),
                (by, "in_service", {"conveyor": conveyor}),
            )
            print(f"{conveyor} is back in service (out of service from {w['from']})")
            return
        when = _parse_until(until)
        w = _change(
            state,
            db,
            conveyor,
            lambda d: set_out_of_service(d, conveyor, by, why, when),
            (by, "out_of_service", {"conveyor": conveyor, "why": why, "until": until}),
        )
        print(f"{conveyor} is out of service from {w['from']} until {w['until'] or '--end'}")
