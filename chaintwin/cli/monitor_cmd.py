"""``chaintwin monitor``, ``maintenance`` and ``acknowledge``."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer
from rich.console import Console
from rich.table import Table

from chaintwin.cli.common import (
    EXIT_ALARM,
    ColumnsOption,
    EditStateOption,
    ProfilesOption,
    db_option,
    edit_state,
    expand_recordings,
    json_option,
    load_profiles,
    parse_at,
    print_json,
    print_refused,
    print_warning,
    safe,
)
from chaintwin.diagnose.state import MAINTENANCE_KINDS

if TYPE_CHECKING:
    from chaintwin.diagnose.monitor import ConveyorMonitor
    from chaintwin.diagnose.records import RecordingResult, SettingsGiven
    from chaintwin.identify.calibration import Calibration
    from chaintwin.read.columns import ColumnMap
    from chaintwin.read.profile import ConveyorProfile

from chaintwin.errors import (
    ChaintwinError,
    MonitorError,
    StoreError,
)

__all__ = ["register", "run_monitor"]

_PROFILE_HELP = "Profile of the one conveyor monitored."
_CAL_HELP = (
    "Calibration file (repeat for several conveyors). A calibration of another conveyor "
    "serves as a sibling's starting point when one --profile is given."
)
_STATE_HELP = "State file: monitoring continues from it and is saved back (created if missing)."
_BASELINE_HELP = "Recordings in a baseline (and in a learned calibration) [20]."
_EDIT_DB_HELP = (
    "Or the results store (of `ingest --db`); without --state the store is used: this URL, "
    "else CHAINTWIN_DB, else sqlite:///chaintwin.db."
)
_RULE_HELP = "Alarm rule X/Y: X exceedances of one feature in the last Y recordings [3/10]."
_Z_HELP = "A feature exceeds above this many robust baseline scales [5]."
_JSON_HELP = "Print one JSON object: recordings and conveyors."
_FAIL_HELP = (
    "Exit with 3 when an alarm stands: open, acknowledged or not (shelved ones and those of a "
    "conveyor out of service aside)."
)
_FILES_HELP = "Recordings (files or folders), in any order: they are sorted by recorded_at."


def run_monitor(
    files: list[str],
    profiles: dict[str, ConveyorProfile],
    calibrations: Sequence[Calibration],
    settings: SettingsGiven,
    state: dict[str, Any] | None,
    column_map: ColumnMap | None,
) -> tuple[list[RecordingResult], list[ConveyorMonitor]]:
    """Monitor recordings of one or several conveyors (the ``monitor`` command's core).

    Parameters
    ----------
    files : list of str
        Recording files, any order.
    profiles : dict
        Profiles by id.
    calibrations : sequence of Calibration
        Calibrations; one of another conveyor serves a single profile as a sibling's.
    settings : SettingsGiven
        Baseline size and alarm rule as given (the rest from the state, else defaults).
    state : dict, optional
        A state (:mod:`chaintwin.diagnose.state`); updated in place.
    column_map : ColumnMap, optional
        For exports named otherwise.

    Returns
    -------
    (list of RecordingResult, list of ConveyorMonitor)
        Results in processing order (refused files first), and the monitors.
    """
    from chaintwin.diagnose.monitor import ConveyorMonitor
    from chaintwin.diagnose.records import RecordingResult
    from chaintwin.diagnose.session import resume, undated
    from chaintwin.read.batch import group_by_conveyor, order_recordings
    from chaintwin.validate.checks import load_recording

    cal_by_id: dict[str, Calibration] = {}
    for cal in calibrations:
        cid = cal.profile.id
        if cid not in profiles:
            if len(profiles) == 1 and len(calibrations) == 1:
                cid = next(iter(profiles))
            else:
                raise StoreError(
                    f"calibration of '{cal.profile.id}' matches none of the profiles "
                    f"({', '.join(sorted(profiles))})"
                )
        cal_by_id[cid] = cal
    groups, refused = group_by_conveyor(files, profiles)
    results = [RecordingResult(f, "", None, "refused", error=e) for f, e in refused]
    monitors: list[ConveyorMonitor] = []
    stored = state["conveyors"] if state is not None else {}
    for cid, items in groups.items():
        prof = profiles[cid]

        def loader(name: str, prof: ConveyorProfile = prof) -> Any:
            return load_recording(name, profile=prof, column_map=column_map).recording

        saved = (
            ConveyorMonitor.from_state(stored[cid], prof, loader=loader, source="--state")
            if cid in stored
            else None
        )
        merged = settings.merged(None if saved is None else saved.settings)
        mon, flushed = resume(
            saved, prof, merged, cal_by_id.get(cid), loader=loader, source="--state"
        )
        results += flushed
        sha = {item.path: item.sha256 for item in items}
        order, missing = order_recordings([(item.path, item.recorded_at) for item in items])
        for f in order:
            try:
                ins = load_recording(f, profile=prof, column_map=column_map)
            except ChaintwinError as exc:
                results.append(RecordingResult(f, cid, None, "refused", error=str(exc)))
                continue
            if f in missing:
                ins = dataclasses.replace(ins, recording=undated(ins.recording))
            results += mon.process(ins, sha[f])  # the inspection: its phases are reused
        results += mon.finish()
        monitors.append(mon)
        if state is not None:
            state["conveyors"][cid] = mon.to_state().to_dict()
    return results, monitors


def standing_alarm(state: dict[str, Any] | None, monitors: list[ConveyorMonitor]) -> bool:
    """Whether any conveyor (of this run, or of the state) has a standing alarm.

    Every alarm that is not closed counts, acknowledged or not (an acknowledged
    alarm is still active); shelved alarms and those of a conveyor out of
    service do not.
    """
    from chaintwin.diagnose.monitor_state import MonitorState

    alarms = [a for m in monitors for a in m.open_alarms()]
    ran = {m.profile.id for m in monitors}
    if state is not None:  # the conveyors of the state this run did not monitor
        for cid, conveyor in state["conveyors"].items():
            if cid not in ran:
                alarms += [a for a in MonitorState.from_dict(conveyor).alarms if a.is_open]
    return any(a.counts() for a in alarms)


def _print_table(results: list[RecordingResult], monitors: list[ConveyorMonitor]) -> None:
    console = Console()
    table = Table(title="chaintwin monitor")
    for col in ("file", "conveyor", "status", "payload [kg]", "TLF", "alarm", "causes"):
        table.add_column(col)
    for r in results:
        if r.error is not None:
            table.add_row(safe(r.file), "", "[red]refused[/red]", "", "", "", "")
            continue
        causes = ", ".join(f"{c['cause']} ({c['feature']} {_pct(c['change'])})" for c in r.causes)
        table.add_row(
            safe(r.file),
            safe(r.conveyor),
            r.status,
            "-" if r.payload_kg is None else f"{r.payload_kg:.1f}",
            "-" if r.tlf is None else f"{r.tlf:.3f}",
            "[red]ALARM[/red]" if r.alarm else "",
            safe(causes),
        )
    console.print(table)
    for r in results:
        if r.error is not None:
            print_refused(console, r.error)
    for mon in monitors:
        s = mon.summary()
        base = s["baseline"]
        console.print(
            f"[bold]{safe(s['conveyor'])}[/bold]: calibration {s['calibration']}, "
            f"{s['recordings']} recordings, baseline "
            f"{'complete' if base['complete'] else 'learning'} ({base['recordings']})",
            highlight=False,
        )
        since = f" since {s['health_since'][:16]}" if s["health_since"] else ""
        console.print(
            f"  health {s['health']}{since} (NE 107 {s['ne107']}), health index "
            f"{'-' if s['health_index'] is None else format(s['health_index'], '.2f')}",
            highlight=False,
        )
        for a in s["open_alarms"]:
            ack = " (acknowledged)" if a["acknowledged"] else ""
            console.print(
                f"  [red]alarm {safe(a['id'])}[/red]{ack}: {safe(a['cause'])} - "
                f"{safe(a['feature'])} {_pct(a['change'])} since {safe(a['since'])}",
                highlight=False,
            )
        for fc in s["forecasts"]:
            if fc.get("crossed"):
                console.print(
                    f"  forecast: {fc['feature']} ({fc['cause']}) crossed {fc['limit']:.4g} "
                    f"since {fc['crosses_at'][:16]}, remaining life 0",
                    highlight=False,
                )
                continue
            console.print(
                f"  forecast ({safe(fc.get('model', 'line'))}): {safe(fc['feature'])} "
                f"({safe(fc['cause'])}) crosses "
                f"{fc['limit']:.4g} about {fc['crosses_at'][:10]} (90 %: {fc['earliest'][:10]} "
                f"to {(fc['latest'] or 'beyond a year')[:10]})",
                highlight=False,
            )
        for n in s["notes"]:
            print_warning(console, s["conveyor"], n["code"], n["message"])


def _pct(change: float | None) -> str:
    return "-" if change is None else f"{change:+.0%}"


def _parse_rule(rule: str) -> tuple[int, int]:
    x, sep, y = rule.partition("/")
    try:
        if not sep:
            raise ValueError
        return int(x), int(y)
    except ValueError:
        raise MonitorError(f"--alarm-rule '{rule}' must be X/Y, e.g. 3/10") from None


def register(app: typer.Typer) -> None:
    """Add the commands to the application."""

    @app.command("monitor")
    def monitor_cmd(
        files: Annotated[list[Path], typer.Argument(help=_FILES_HELP)],
        profile: Annotated[Path | None, typer.Option("--profile", help=_PROFILE_HELP)] = None,
        profiles: ProfilesOption = None,
        calibration: Annotated[
            list[Path] | None, typer.Option("--calibration", help=_CAL_HELP)
        ] = None,
        state: Annotated[Path | None, typer.Option("--state", help=_STATE_HELP)] = None,
        baseline: Annotated[int | None, typer.Option("--baseline", help=_BASELINE_HELP)] = None,
        alarm_rule: Annotated[str | None, typer.Option("--alarm-rule", help=_RULE_HELP)] = None,
        z_limit: Annotated[float | None, typer.Option("--z-limit", help=_Z_HELP)] = None,
        as_json: Annotated[bool, json_option(_JSON_HELP)] = False,
        fail_on_alarm: Annotated[bool, typer.Option("--fail-on-alarm", help=_FAIL_HELP)] = False,
        columns: ColumnsOption = None,
        residual: Annotated[
            str | None,
            typer.Option(
                "--residual",
                help="Residual features against the inverse model (measured speed) or the "
                "closed loop (recorded set points) [inverse; a state keeps its own].",
            ),
        ] = None,
    ) -> None:
        """Follow conveyors' health over their recordings: baselines, alarms, causes, forecasts.

        Exit code 3 with --fail-on-alarm when an alarm stands (open, neither shelved
        nor of a conveyor out of service),
        else 2 when a file was refused (after the others are done).
        """
        from chaintwin.diagnose.records import SettingsGiven
        from chaintwin.diagnose.state import load_state, save_state
        from chaintwin.identify.calibration import load_calibration
        from chaintwin.read.columns import load_column_map

        profs = load_profiles(profile, profiles)
        cals = [load_calibration(c) for c in calibration or []]
        x, y = _parse_rule(alarm_rule) if alarm_rule is not None else (None, None)
        settings = SettingsGiven(baseline_n=baseline, x=x, y=y, z_limit=z_limit, residual=residual)
        settings.merged(None)  # checks the values before anything is read
        data = load_state(state) if state is not None else None
        cmap = load_column_map(columns) if columns is not None else None
        results, monitors = run_monitor(expand_recordings(files), profs, cals, settings, data, cmap)
        if state is not None and data is not None:
            save_state(state, data)
        if as_json:
            print_json(
                {
                    "recordings": [r.to_dict() for r in results],
                    "conveyors": [m.summary() for m in monitors],
                }
            )
        else:
            _print_table(results, monitors)
        if fail_on_alarm and standing_alarm(data, monitors):
            raise typer.Exit(EXIT_ALARM)
        if any(r.error is not None for r in results):
            raise typer.Exit(2)

    @app.command("maintenance")
    def maintenance_cmd(
        conveyor: Annotated[str, typer.Option("--conveyor", help="Conveyor id.")],
        kind: Annotated[
            str, typer.Option("--kind", help=f"One of {', '.join(MAINTENANCE_KINDS)}.")
        ],
        by: Annotated[str, typer.Option("--by", help="Who did it.")],
        why: Annotated[str, typer.Option("--why", help="What was done and why.")] = "",
        at: Annotated[
            str | None, typer.Option("--at", help="When (ISO 8601); default now.")
        ] = None,
        state: EditStateOption = None,
        db: Annotated[str | None, db_option(_EDIT_DB_HELP)] = None,
    ) -> None:
        """Record a maintenance event: the conveyor's baseline restarts after it."""
        from chaintwin.diagnose.state import add_maintenance

        when = parse_at(at)
        event = edit_state(
            state, db, conveyor, lambda data: add_maintenance(data, conveyor, kind, by, why, when)
        )
        Console().print(
            f"recorded maintenance {event.id} ({kind}) on {safe(conveyor)} at {event.at}; "
            "the baseline restarts with the recordings after it",
            highlight=False,
        )

    @app.command("acknowledge")
    def acknowledge_cmd(
        alarm: Annotated[str, typer.Argument(help="Alarm id (from monitor).")],
        by: Annotated[str, typer.Option("--by", help="Who acknowledges.")],
        why: Annotated[str, typer.Option("--why", help="Why (e.g. work order).")] = "",
        state: EditStateOption = None,
        db: Annotated[str | None, db_option(_EDIT_DB_HELP)] = None,
    ) -> None:
        """Acknowledge an alarm: someone has seen it; it stays open until it closes."""
        from chaintwin.diagnose.state import acknowledge_alarm

        a = edit_state(state, db, None, lambda data: acknowledge_alarm(data, alarm, by, why), alarm)
        Console().print(
            f"acknowledged alarm {safe(a.id)} ({safe(a.cause)}, {safe(a.feature)}) on "
            f"{safe(a.conveyor)}",
            highlight=False,
        )
