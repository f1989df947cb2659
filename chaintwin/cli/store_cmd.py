"""``chaintwin ingest`` and ``export``: the results store from the command line."""

from __future__ import annotations

import csv
import io
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer
from rich.console import Console
from rich.progress import Progress

from chaintwin.cli.common import (
    ColumnsOption,
    DbOption,
    ProfilesOption,
    expand_recordings,
    json_option,
    load_profiles,
    print_json,
    print_refused,
    printable,
    safe,
)

if TYPE_CHECKING:
    pass

from chaintwin.errors import StoreError

__all__ = ["EXPORT_COLUMNS", "register"]

_PROFILE_HELP = "Profile of the one conveyor ingested."
_SCHED_HELP = (
    "Dask scheduler address (tcp://host:8786): run on that cluster instead of local processes."
)
_WORKERS_HELP = "Local worker processes (default: one per core)."
_JSON_HELP = "Print one JSON summary object."
_BASELINE_HELP = "Recordings in a baseline (new conveyors) [20]."
_GROUP_HELP = (
    "Most recordings stored in one transaction [64]; a kill loses at most the groups not yet "
    "written, one per conveyor being worked on (ingest again to finish them)."
)

EXPORT_COLUMNS: tuple[str, ...] = (
    "conveyor",
    "file",
    "recorded_at",
    "status",
    "alarm",
    "causes",
    "payload_kg",
    "uncertainty_kg",
    "tlf",
    "friction",
    "speed_loss",
    "residual_std",
    "tooth_pass",
    "unexplained_peak",
    "belt_bump",
    "warnings",
    "recording_id",
)
"""Columns of ``export --format csv`` (features as their own columns)."""


def _csv(rows: list[dict[str, Any]]) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(EXPORT_COLUMNS)
    for r in rows:
        feats = r.get("features") or {}
        out: list[Any] = []
        for col in EXPORT_COLUMNS:
            if col == "causes":
                out.append(";".join(f"{c['cause']}:{c['feature']}" for c in r.get("causes", [])))
            elif col == "warnings":
                out.append(";".join(w["code"] for w in r.get("warnings", [])))
            elif col in r:
                out.append("" if r[col] is None else r[col])
            else:
                v = feats.get(col)
                out.append("" if v is None else v)
        w.writerow([printable(c) if isinstance(c, str) else c for c in out])
    return buf.getvalue()


def register(app: typer.Typer) -> None:
    """Add the commands to the application."""

    @app.command("ingest")
    def ingest_cmd(
        paths: Annotated[list[Path], typer.Argument(help="Recordings (files or folders).")],
        profiles: ProfilesOption = None,
        profile: Annotated[Path | None, typer.Option("--profile", help=_PROFILE_HELP)] = None,
        db: DbOption = None,
        scheduler: Annotated[str | None, typer.Option("--scheduler", help=_SCHED_HELP)] = None,
        workers: Annotated[int | None, typer.Option("--workers", help=_WORKERS_HELP)] = None,
        baseline: Annotated[int | None, typer.Option("--baseline", help=_BASELINE_HELP)] = None,
        as_json: Annotated[bool, json_option(_JSON_HELP)] = False,
        columns: ColumnsOption = None,
        commit_group: Annotated[int, typer.Option("--commit-group", help=_GROUP_HELP)] = 64,
    ) -> None:
        """Read, validate, weigh and monitor recordings into the results store.

        Idempotent: a recording already stored is skipped. Refused files never
        stop the batch; the exit code is 0 when the batch ran.
        """
        from chaintwin.diagnose.records import SettingsGiven
        from chaintwin.ingest.pipeline import ingest
        from chaintwin.read.columns import load_column_map
        from chaintwin.store.engine import safe_url, store_url
        from chaintwin.store.store import Store

        profs = load_profiles(profile, profiles)
        if workers is not None and workers < 1:
            raise StoreError(f"--workers {workers} must be at least 1")
        if commit_group < 1:
            raise StoreError(f"--commit-group {commit_group} must be at least 1")
        settings = SettingsGiven(baseline_n=baseline).merged(None)
        cmap = load_column_map(columns) if columns is not None else None
        files = expand_recordings(paths)
        with (
            Store(store_url(db)) as store,
            Progress(transient=True, disable=as_json) as bar,
        ):
            task = bar.add_task("ingest", total=len(files))
            summary = ingest(
                files,
                profs,
                store,
                settings=settings,
                workers=workers,
                scheduler=scheduler,
                column_map=cmap,
                progress=lambda d, n: bar.update(task, completed=d, total=n),
                commit_group=commit_group,
            )
        if as_json:
            print_json(summary.to_dict())
            return
        console = Console()
        console.print(
            f"ingested into {safe(safe_url(store.url))}: {summary.processed} processed, "
            f"{summary.duplicates} duplicates skipped, {summary.refused} refused, "
            f"{summary.warnings} warnings, {summary.new_alarms} new alarms "
            f"({summary.seconds:.1f} s)",
            highlight=False,
        )
        if summary.waiting:
            console.print(
                f"{summary.waiting} recordings stored to wait for the calibration their "
                "conveyor learns from its first recordings (or give one with `calibrate "
                "--db`); the next ingest goes on from them",
                highlight=False,
            )
        for r in summary.refusals:
            print_refused(console, r["error"])

    @app.command("export")
    def export_cmd(
        db: DbOption = None,
        conveyor: Annotated[
            str | None, typer.Option("--conveyor", help="Only this conveyor (default all).")
        ] = None,
        fmt: Annotated[str, typer.Option("--format", help="csv or json.")] = "csv",
    ) -> None:
        """Write stored results (one row per recording) to standard output as CSV or JSON."""
        from chaintwin.store.engine import store_url
        from chaintwin.store.store import Store

        if fmt not in ("csv", "json"):
            raise StoreError(f"--format {fmt}: use csv or json")
        with Store(store_url(db), create=False, read_only=True) as store:
            if conveyor is not None and conveyor not in store.conveyors():
                raise StoreError(
                    f"the store holds no conveyor '{conveyor}' "
                    f"(it holds: {', '.join(store.conveyors()) or 'none'})"
                )
            rows = store.results(conveyor, with_ids=True)
        if fmt == "json":
            print_json(rows)
        else:
            sys.stdout.write(_csv(rows))
