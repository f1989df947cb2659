"""``chaintwin verify``: the twin against its recordings, the published verification table."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer
from rich.console import Console
from rich.table import Table

from chaintwin.cli.common import (
    ColumnsOption,
    JsonListOption,
    error_message,
    expand_recordings,
    print_json,
    print_refused,
    print_warning,
    safe,
)
from chaintwin.cli.identify_cmd import _inspect
from chaintwin.errors import CalibrationError, ChaintwinError, EstimationError

if TYPE_CHECKING:
    from chaintwin.identify.verification import Residual


__all__ = ["register", "verify_rows"]


def _fmt(value: float | None) -> str:
    return "-" if value is None else f"{value:+.3f}"


def _cells(stats: dict[str, Any] | None) -> list[str]:
    if stats is None or stats.get("rep_mean_pct") is None:
        return ["-", "-", "-"]
    return [
        _fmt(stats["rep_mean_pct"]),
        f"{stats['rep_std_pct']:.3f}",
        f"{stats['rep_absmax_pct']:.3f}",
    ]


def verify_rows(result: dict[str, Any]) -> list[list[str]]:
    """Rows of the verification table of one file's ``verify --json`` object.

    One row for the whole movement, then one per moving phase: what, then the
    speed and torque REP (mean, std, max |.|, %).
    """
    rows = [[result["movement"], *_cells(result["speed"]), *_cells(result["torque"])]]
    for ph in result["phases"]:
        direction = "fwd" if ph["direction"] > 0 else "bwd"
        what = f"  {ph['kind']} {direction} {ph['start_s']:.2f}-{ph['end_s']:.2f} s"
        rows.append([what, *_cells(ph["speed"]), *_cells(ph["torque"])])
    return rows


def register(app: typer.Typer) -> None:
    """Add ``verify`` to the application."""

    @app.command("verify")
    def verify_cmd(
        files: Annotated[list[Path], typer.Argument(help="Recordings (files or folders).")],
        profile: Annotated[Path, typer.Option("--profile", help="Conveyor profile YAML.")],
        calibration: Annotated[
            Path | None,
            typer.Option(
                "--calibration",
                help="Calibration file; without one the profile's nominal model: values.",
            ),
        ] = None,
        residual: Annotated[
            str,
            typer.Option(
                "--residual",
                help="closed-loop: the controller replica driven by the recorded set points "
                "(the published method); inverse: the rigid model driven by the measured speed.",
            ),
        ] = "closed-loop",
        as_json: JsonListOption = False,
        columns: ColumnsOption = None,
    ) -> None:
        """Verify the twin: relative error (REP) of model against measured speed and torque.

        REP(t) = 100·(model − measured)/max|measured| per recording, with its
        mean, standard deviation and largest absolute value over the movement
        and per phase (%). Exit code 2 when a file was refused.
        """
        from chaintwin.identify.calibration import load_calibration
        from chaintwin.identify.verification import RESIDUALS, verify_recording
        from chaintwin.read.columns import load_column_map
        from chaintwin.read.profile import load_profile

        if residual not in RESIDUALS:
            raise EstimationError(f"--residual: '{residual}' is not one of {', '.join(RESIDUALS)}")
        mode: Residual = "inverse" if residual == "inverse" else "closed-loop"
        prof = load_profile(profile)
        cal = load_calibration(calibration) if calibration is not None else None
        if cal is not None and cal.profile.id != prof.id:
            raise CalibrationError(
                f"{calibration}: is a calibration of conveyor '{cal.profile.id}', not of "
                f"'{prof.id}'; give the matching profile or calibration"
            )
        cmap = load_column_map(columns) if columns is not None else None
        results: list[dict[str, Any]] = []
        for f in expand_recordings(files):
            try:
                rec = _inspect(f, prof, cmap).recording
                v = verify_recording(rec, prof, calibration=cal, residual=mode)
                out = v.to_dict()
                out["file"] = f
                results.append(out)
            except ChaintwinError as exc:
                message = error_message(exc)
                if not message.startswith(f):
                    message = f"{f}: {message}"
                results.append({"file": f, "error": message})
        if as_json:
            print_json(results)
        else:
            console = Console()
            source = "calibration" if cal is not None else "nominal profile values"
            if cal is None:
                console.print(
                    "no calibration given: the twin runs with the profile's nominal "
                    "model: values (give --calibration for the identified ones)",
                    highlight=False,
                )
            for r in results:
                if "error" in r:
                    print_refused(console, r["error"])
                    continue
                table = Table(
                    title=f"chaintwin verify: {safe(r['file'])} ({mode}, {source}, "
                    f"payload {r['payload_kg']:g} kg)",
                )
                table.add_column("movement / phase")
                for ch in ("speed", "torque"):
                    for s in ("mean %", "std %", "max|.| %"):
                        table.add_column(f"{ch} {s}", justify="right")
                for row in verify_rows(r):
                    table.add_row(*[safe(c) for c in row])
                console.print(table)
                if r["speed"].get("reason"):
                    console.print(f"speed: {safe(r['speed']['reason'])}", highlight=False)
                for w in r["warnings"]:
                    if w["code"] != "nominal_parameters":
                        print_warning(console, r["file"], w["code"], w["message"])
        if any("error" in r for r in results):
            raise typer.Exit(2)
