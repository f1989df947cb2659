"""``chaintwin demo`` and ``chaintwin examples``: try everything with no data of one's own."""

from __future__ import annotations

import shutil
from importlib.resources import as_file, files
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer
from rich.console import Console
from rich.table import Table

from chaintwin import __version__
from chaintwin.errors import StoreError

if TYPE_CHECKING:
    pass


__all__ = ["examples_dir", "register"]


def examples_dir() -> Path:
    """Folder of the bundled example profiles, recordings and column maps."""
    with as_file(files("chaintwin.examples")) as path:
        return Path(path)


DEMO_PLANT: tuple[tuple[str, str | None], ...] = (
    ("white-belt-01", None),
    ("incline-line-02", "friction:0.5"),
    ("short-fast-03", "rail_obstacle:1.5"),
)
"""The demo's virtual plant: conveyor (bundled profile) and the fault it develops."""

DEMO_MARKER = ".chaintwin-demo"
"""File that marks a folder as the demo's own (it may be emptied and rebuilt)."""


def _demo_folder(out: Path) -> None:
    """Make ``out`` the demo's folder: new, empty, or a previous demo's (emptied).

    Raises
    ------
    StoreError
        When ``out`` is a file, a link, or a folder that is not the demo's own.
    """
    if out.is_symlink() or (out.exists() and not out.is_dir()):
        raise StoreError(f"--out {out}: not a folder; give a new or empty folder")
    if out.exists() and any(out.iterdir()):
        if not (out / DEMO_MARKER).is_file():
            raise StoreError(
                f"--out {out}: the folder exists and is not a previous demo's; give a new "
                "or empty folder"
            )
        for sub in ("recordings", "reports"):
            target = out / sub
            if target.is_symlink() or (target.exists() and not target.is_dir()):
                raise StoreError(
                    f"--out {out}: '{sub}' is not the demo's own folder; remove it or give "
                    "another folder"
                )
            if target.exists():
                shutil.rmtree(target)
        for f in out.glob("plant.db*"):
            f.unlink()
    out.mkdir(parents=True, exist_ok=True)
    (out / DEMO_MARKER).write_text("made by `chaintwin demo`; it may empty this folder\n")


def run_demo(out: Path, *, days: int, per_day: int, workers: int | None, console: Console) -> int:
    """The demo: a virtual plant, calibration, ingest into the embedded store, reports.

    Returns
    -------
    int
        Open alarms at the end.
    """
    import time

    from rich.progress import Progress

    from chaintwin.calibrating.procedure import calibrate
    from chaintwin.ingest.pipeline import ingest
    from chaintwin.read.profile import load_profiles
    from chaintwin.report.data import conveyor_data
    from chaintwin.report.html import write_folder
    from chaintwin.simulate.faults import parse_fault
    from chaintwin.simulate.fleet import generate
    from chaintwin.store.store import Store
    from chaintwin.validate.checks import load_recording

    started = time.perf_counter()
    _demo_folder(out)
    profiles = load_profiles(examples_dir() / "profiles")
    plant = {cid: profiles[cid] for cid, _f in DEMO_PLANT}
    onset = days // 3
    console.print(
        f"[bold]1. virtual plant[/]: {len(plant)} conveyors, {days} days x {per_day} recordings "
        f"each at 6 ms, payload 10-40 kg, every realism effect on; from day {onset + 1} "
        "incline-line-02 develops a friction rise (to +50 %) and short-fast-03 a rail obstacle "
        "that one tray hits once per belt revolution",
        highlight=False,
    )
    files: list[str] = []
    with Progress(transient=True, console=console) as bar:
        task = bar.add_task("simulate", total=len(plant) * days * per_day)
        for k, (cid, fault) in enumerate(DEMO_PLANT):

            def tick(d: int, _n: int, before: int = k * days * per_day) -> None:
                bar.update(task, completed=before + d)

            summary = generate(
                plant[cid],
                out / "recordings" / cid,
                days=days,
                per_day=per_day,
                faults=[parse_fault(fault)] if fault else [],
                onset_day=onset,
                seed=11 + k,
                progress=tick,
            )
            files += sorted(str(f) for f in summary.folder.glob("*.csv"))
    with Store(f"sqlite:///{out / 'plant.db'}") as store:
        console.print(
            "[bold]2. calibration[/] from each conveyor's empty runs at several speeds "
            "(one_load_several_speeds, the recommended protocol):"
        )
        for cid, prof in plant.items():
            cal_files = sorted((out / "recordings" / cid / "calibration").glob("*.csv"))
            recs = [load_recording(f, profile=prof).recording for f in cal_files]
            recs = [r for r in recs if r.metadata.payload_kg == 0.0]
            cal = calibrate(recs, prof, version=__version__)
            store.put_calibration(cal)
            speeds = ", ".join(f"{x:.0f}" for x in cal.plateau_speeds_rpm)
            console.print(
                f"   {cid}: {len(recs)} empty runs at {speeds} rpm ({cal.case}), "
                f"mu = {cal.parameters['mu']:.4f} ± {cal.parameters.stderr('mu'):.4f}, payload "
                f"sensitivity ± {cal.sensitivity_rel_uncertainty:.2%}",
                highlight=False,
            )
        console.print(
            f"[bold]3. ingest[/] {len(files)} recordings into {out / 'plant.db'} "
            "(read, validate, weigh, monitor):",
            highlight=False,
        )
        with Progress(transient=True, console=console) as bar:
            task = bar.add_task("ingest", total=len(files))
            result = ingest(
                files,
                plant,
                store,
                workers=workers,
                progress=lambda d, n: bar.update(task, completed=d, total=n),
            )
        console.print(
            f"   {result.processed} processed, {result.duplicates} duplicates, "
            f"{result.refused} refused, {result.warnings} warnings, {result.new_alarms} new "
            f"alarms ({result.seconds:.1f} s)",
            highlight=False,
        )
        console.print("[bold]4. reports[/]:")
        pages = write_folder(store, out / "reports")
        table = Table(title="the plant after the demo")
        for col, justify in (
            ("conveyor", "left"),
            ("rec.", "right"),
            ("health (NE 107)", "left"),
            ("open alarm: cause (since)", "left"),
            ("payload kg", "right"),
            ("weights right", "right"),
            ("TLF", "right"),
            ("health index", "right"),
        ):
            table.add_column(col, justify=justify, no_wrap=col == "conveyor")  # type: ignore[arg-type]
        open_alarms = 0
        for cid in plant:
            d = conveyor_data(store, cid, waterfall=0)
            opened = d.open_alarms()
            open_alarms += len(opened)
            table.add_row(
                cid,
                str(len(d.results)),
                f"{d.verdict.health} ({d.verdict.ne107})",
                "; ".join(f"{a.cause} ({(a.since or '')[5:10]})" for a in opened) or "-",
                f"{d.recent_payload():.1f}",
                _weights_right(d.results, out / "recordings" / cid / "truth.jsonl"),
                f"{d.recent_tlf():.2f}",
                "-" if d.verdict.health_index is None else f"{d.verdict.health_index:.2f}",
            )
        console.print(table)
    console.print(
        "payload and TLF: medians of the latest recordings; weights right: share of the "
        "weighed recordings within 2 standard uncertainties of the simulated payload, median "
        "error, and how many weights carry friction_changed (taken while monitoring saw the "
        "rail friction move); health: worst feature, 0 = baseline, 1 = alarm limit",
        style="dim",
        highlight=False,
    )
    console.print(
        f"reports: {', '.join(str(p) for p in pages)}\nopen [bold]{pages[-1]}[/] in a browser "
        f"(works offline); the store is {out / 'plant.db'}, e.g. `chaintwin export --db "
        f"sqlite:///{out / 'plant.db'}`. The demo took {time.perf_counter() - started:.0f} s.",
        highlight=False,
        soft_wrap=True,
    )
    return open_alarms


def demo_token(out: Path) -> str:
    """A new viewer token on the demo's store (a new one each run: tokens are shown once)."""
    from chaintwin.store.store import Store
    from chaintwin.web.access import create_token, list_tokens

    with Store(f"sqlite:///{out / 'plant.db'}") as store:
        n = len(list_tokens(store))
        return create_token(store, f"demo-viewer-{n + 1}", "viewer")


def _weights_right(results: list[dict[str, Any]], truth_file: Path) -> str:
    """Share of weighed recordings within 2 uncertainties of the truth, and the median error.

    The virtual plant's ground truth (``truth.jsonl``, never in the
    recordings) against what the store holds: the demo checks itself.
    """
    import json

    import numpy as np

    truth = {
        Path(t["file"]).name: float(t["payload_kg"])
        for t in map(json.loads, truth_file.read_text().splitlines())
    }
    z, err = [], []
    for r in results:
        true = truth.get(Path(str(r.get("file", ""))).name)
        p, u = r.get("payload_kg"), r.get("uncertainty_kg")
        if true is None or p is None or not u:
            continue
        err.append(abs(p - true))
        z.append(abs(p - true) / u)
    # weights taken while monitoring saw the rail friction move (friction_changed)
    changed = sum(
        1
        for r in results
        if any(
            (w.get("code") if isinstance(w, dict) else w) == "friction_changed"
            for w in r.get("warnings") or []
        )
    )
    note = f", {changed} friction_changed" if changed else ""
    if not z:
        return "-" + note
    return f"{np.mean(np.array(z) <= 2):.0%}, {np.median(err):.1f} kg{note}"


def register(app: typer.Typer) -> None:
    """Add the ``demo`` and ``examples`` commands to the application."""

    @app.command("demo")
    def demo(
        out: Annotated[
            Path, typer.Option("--out", help="Folder for the plant's data, store and reports.")
        ] = Path("chaintwin-demo"),
        days: Annotated[int, typer.Option("--days", min=4, help="Simulated days.")] = 12,
        per_day: Annotated[int, typer.Option("--per-day", min=1, help="Recordings per day.")] = 6,
        workers: Annotated[
            int | None, typer.Option("--workers", help="Worker processes (default: one per core).")
        ] = None,
        serve: Annotated[
            bool, typer.Option("--serve", help="Then serve the store's dashboard (Ctrl-C stops).")
        ] = False,
        port: Annotated[int, typer.Option("--port", help="Port for --serve or --live.")] = 8000,
        live: Annotated[
            bool,
            typer.Option(
                "--live",
                help="Then run the plant as drives over OPC UA, followed live with the "
                "dashboard and a webhook receiver (Ctrl-C stops).",
            ),
        ] = False,
    ) -> None:
        """The main job on a virtual plant: simulate, calibrate, ingest, monitor, report.

        Three conveyors (the bundled profiles) are simulated over days with
        every realism effect on, one of them developing a fault; each is
        calibrated from its calibration runs, all recordings are ingested into
        an embedded SQLite store (weighed and monitored), and HTML reports are
        written. Prints a summary table, where the reports are, and the
        command that serves the dashboard with a new token (--serve runs it).
        --live then turns the plant into simulated drives publishing over OPC
        UA, which the live service follows into the same store, with the
        dashboard and signed alarm notifications to a webhook receiver.
        """
        console = Console()
        run_demo(out, days=days, per_day=per_day, workers=workers, console=console)
        if live:
            from chaintwin.cli.demo_live import run_live

            run_live(out, port=port, console=console)
            return
        token = demo_token(out)
        db = f"sqlite:///{out / 'plant.db'}"
        console.print(
            f"dashboard: [bold]chaintwin serve --db {db} --port {port}[/], then open "
            f"http://127.0.0.1:{port}/ and log in with this viewer token (new on each run):"
            f"\n{token}\nTo acknowledge alarms and upload: chaintwin token create --db {db} "
            "--name me --role maintainer",
            highlight=False,
            soft_wrap=True,
        )
        if serve:
            from chaintwin.cli.serve_cmd import serve as run_service

            run_service(db, examples_dir() / "profiles", "127.0.0.1", port, 20.0)

    @app.command("examples")
    def examples(
        out: Annotated[Path, typer.Option("--out", help="Folder to copy the examples into.")],
    ) -> None:
        """Copy the bundled example profiles, recordings and column maps to a folder."""
        root = examples_dir()
        for sub in ("profiles", "recordings", "columns", "vendor"):
            target = out / sub
            target.mkdir(parents=True, exist_ok=True)
            for f in sorted((root / sub).iterdir()):
                if f.suffix in (".yaml", ".csv"):
                    shutil.copy2(f, target / f.name)
        Console().print(f"examples copied to {out}")
