"""``chaintwin demo`` and ``chaintwin examples``: try everything with no data of one's own."""

from __future__ import annotations

import shutil
from importlib.resources import as_file, files
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.table import Table

from chaintwin.cli.inspect_cmd import _print_table, inspection_to_dict
from chaintwin.errors import RecordingError
from chaintwin.read.columns import ColumnMap, load_column_map
from chaintwin.read.profile import ConveyorProfile, load_profiles
from chaintwin.read.reader import read_recording
from chaintwin.validate.checks import inspect_recording, load_recording

__all__ = ["examples_dir", "register"]


def examples_dir() -> Path:
    """Folder of the bundled example profiles, recordings and column maps."""
    with as_file(files("chaintwin.examples")) as path:
        return Path(path)


def _demo_weighing(
    root: Path, profile: ConveyorProfile, vendor_map: ColumnMap, console: Console
) -> None:
    """Calibrate the reference conveyor and weigh its example recordings."""
    from chaintwin.identify.calibration import calibrate
    from chaintwin.weigh.weigh import weigh

    rec_dir = root / "recordings"
    cal_recs = [
        load_recording(rec_dir / name, profile=profile).recording
        for name in ("white-belt-01-cal-empty.csv", "white-belt-01-cal-50kg.csv")
    ]
    cal = calibrate(cal_recs, profile)
    console.print(
        f"calibrated {profile.id} ({cal.case}): mu = {cal.parameters['mu']:.4f} "
        f"± {cal.parameters.stderr('mu'):.4f}, payload sensitivity "
        f"{cal.sensitivity_nm_per_kg * 1e3:.3f} mNm/kg ± {cal.sensitivity_rel_uncertainty:.2%}",
        highlight=False,
        soft_wrap=True,
    )
    table = Table(title=f"weighing {profile.id} (true payloads: 40, 20 and 30 kg)")
    for col in ("recording", "payload [kg]", "± [kg]", "friction", "inertia", "ok", "TLF"):
        table.add_column(col)
    for path, cmap in (
        (rec_dir / "white-belt-01-40kg.csv", None),
        (rec_dir / "white-belt-01-1ms.csv", None),
        (root / "vendor" / "white-belt-01-vendor-export.csv", vendor_map),
    ):
        rec = load_recording(path, profile=profile, column_map=cmap).recording
        res = weigh(rec, cal, source=path.name)
        inertia = res.payload_inertia_kg
        table.add_row(
            path.name,
            f"{res.payload_kg:.2f}",
            f"{res.uncertainty_kg:.2f}",
            f"{res.payload_friction_kg:.2f}",
            "-" if inertia is None else f"{inertia:.2f}",
            "yes" if res.consistent else "NO",
            "-" if res.tlf is None else f"{res.tlf:.3f}",
        )
    console.print(table)


def register(app: typer.Typer) -> None:
    """Add the ``demo`` and ``examples`` commands to the application."""

    @app.command("demo")
    def demo() -> None:
        """Run the main job on the bundled virtual conveyor's example recordings.

        Inspects every bundled recording against its conveyor's profile
        (matched by id), calibrates the reference conveyor from its two
        calibration recordings (empty tray and a 50 kg reference load) and
        weighs its other recordings, the vendor export included.
        """
        root = examples_dir()
        profiles = load_profiles(root / "profiles")
        vendor_map = load_column_map(root / "columns" / "vendor-de.yaml")
        files: list[tuple[Path, ColumnMap | None]] = [
            (f, None) for f in sorted((root / "recordings").glob("*.csv"))
        ]
        files += [(f, vendor_map) for f in sorted((root / "vendor").glob("*.csv"))]
        results = []
        for f, cmap in files:
            shown = f"examples/{f.parent.name}/{f.name}"
            try:
                rec = read_recording(f, column_map=cmap)
                profile = profiles.get(rec.metadata.conveyor or "")
                if profile is not None:  # re-read: the profile may supply % nominal torque
                    rec = read_recording(f, profile=profile, column_map=cmap)
                results.append(inspection_to_dict(shown, inspect_recording(rec, profile), profile))
            except RecordingError as exc:
                results.append({"file": shown, "error": str(exc)})
        _print_table(results)
        console = Console()
        console.print(
            f"\n{len(results)} example recordings of {len(profiles)} conveyors "
            f"({', '.join(sorted(profiles))}); the vendor export is read with "
            "columns/vendor-de.yaml. Copy them with `chaintwin examples --out DIR`.\n",
            highlight=False,
            soft_wrap=True,
        )
        _demo_weighing(root, profiles["white-belt-01"], vendor_map, console)

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
