"""``chaintwin demo`` and ``chaintwin examples``: try everything with no data of one's own."""

from __future__ import annotations

import shutil
from importlib.resources import as_file, files
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console

from chaintwin.cli.inspect_cmd import _print_table, inspection_to_dict
from chaintwin.errors import RecordingError
from chaintwin.read.columns import ColumnMap, load_column_map
from chaintwin.read.profile import load_profiles
from chaintwin.read.reader import read_recording
from chaintwin.validate.checks import inspect_recording

__all__ = ["examples_dir", "register"]


def examples_dir() -> Path:
    """Folder of the bundled example profiles, recordings and column maps."""
    with as_file(files("chaintwin.examples")) as path:
        return Path(path)


def register(app: typer.Typer) -> None:
    """Add the ``demo`` and ``examples`` commands to the application."""

    @app.command("demo")
    def demo() -> None:
        """Run the main job on the bundled virtual conveyor's example recordings.

        For now: inspect every bundled recording against its conveyor's
        profile (matched by id) and show phases and warnings.
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
        Console().print(
            f"\n{len(results)} example recordings of {len(profiles)} conveyors "
            f"({', '.join(sorted(profiles))}); the vendor export is read with "
            "columns/vendor-de.yaml. Copy them with `chaintwin examples --out DIR`.",
            highlight=False,
            soft_wrap=True,
        )

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
