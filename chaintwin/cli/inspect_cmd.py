"""``chaintwin inspect``: what each recording holds and whether it is usable."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer
from rich.console import Console
from rich.table import Table

from chaintwin.cli.common import (
    ColumnsOption,
    error_message,
    expand_recordings,
    json_option,
    load_options,
    print_json,
    print_refused,
    print_warning,
    safe,
)
from chaintwin.errors import RecordingError

if TYPE_CHECKING:
    from chaintwin.read.columns import ColumnMap
    from chaintwin.read.profile import ConveyorProfile
    from chaintwin.validate.checks import Inspection


__all__ = ["inspect_files", "inspection_to_dict", "register"]

_ARROWS = {"standstill": "·", "accelerate": "↗", "constant": "→", "decelerate": "↘"}


def inspection_to_dict(
    file: str, ins: Inspection, profile: ConveyorProfile | None
) -> dict[str, Any]:
    """Return the ``inspect --json`` object of one accepted recording."""
    from chaintwin.validate.checks import tray_mass_kg

    rec = ins.recording
    meta = rec.metadata
    return {
        "file": file,
        "conveyor": meta.conveyor,
        "recorded_at": meta.recorded_at.isoformat() if meta.recorded_at else None,
        "samples": rec.samples,
        "sample_time_s": rec.sample_time_s,
        "duration_s": rec.duration_s,
        "channels": rec.si_units(),
        "complete_cycle": ins.complete_cycle,
        "phases": [p.to_dict() for p in ins.phases],
        "payload_kg": meta.payload_kg,
        "tray_kg": tray_mass_kg(rec, profile),
        "warnings": [w.to_dict() for w in rec.warnings],
    }


def inspect_files(
    files: list[str], profile: ConveyorProfile | None, column_map: ColumnMap | None
) -> list[dict[str, Any]]:
    """Inspect every file; a refused file gives ``{file, error}`` and the rest go on."""
    from chaintwin.validate.checks import load_recording

    results: list[dict[str, Any]] = []
    for f in files:
        try:
            ins = load_recording(f, profile=profile, column_map=column_map)
        except RecordingError as exc:
            results.append({"file": f, "error": error_message(exc)})
            continue
        results.append(inspection_to_dict(f, ins, profile))
    return results


def _print_table(results: list[dict[str, Any]]) -> None:
    console = Console()
    if not console.is_terminal:
        console = Console(width=max(console.width, 160))
    table = Table(title="chaintwin inspect", show_lines=False)
    for col in ("file", "conveyor", "samples", "Ts [ms]", "duration [s]", "cycle", "phases"):
        table.add_column(col, overflow="fold")
    for r in results:
        if "error" in r:
            table.add_row(safe(r["file"]), "", "", "", "", "[red]refused[/red]", "")
            continue
        phases = "".join(_ARROWS[p["kind"]] for p in r["phases"])
        table.add_row(
            safe(r["file"]),
            safe(r["conveyor"] or "?"),
            str(r["samples"]),
            f"{r['sample_time_s'] * 1e3:.4g}",
            f"{r['duration_s']:.3f}",
            "[green]complete[/green]" if r["complete_cycle"] else "[yellow]partial[/yellow]",
            phases,
        )
    console.print(table)
    for r in results:
        if "error" in r:
            print_refused(console, r["error"])
        for w in r.get("warnings", []):
            print_warning(console, r["file"], w["code"], w["message"])


def register(app: typer.Typer) -> None:
    """Add the ``inspect`` command to the application."""

    @app.command("inspect")
    def inspect(
        files: Annotated[list[Path], typer.Argument(help="Recording files (or folders of *.csv).")],
        profile: Annotated[
            Path | None,
            typer.Option(
                "--profile", help="Conveyor profile YAML: nominal torque, tray, torque limit."
            ),
        ] = None,
        columns: ColumnsOption = None,
        as_json: Annotated[bool, json_option("Print one JSON list instead of a table.")] = False,
    ) -> None:
        """Show what each recording holds and whether it is usable.

        Exit code 2 when any file was refused (the others are still shown).
        """
        prof, cmap = load_options(profile, columns)
        results = inspect_files(expand_recordings(files), prof, cmap)
        if as_json:
            print_json(results)
        else:
            _print_table(results)
        if any("error" in r for r in results):
            raise typer.Exit(2)
