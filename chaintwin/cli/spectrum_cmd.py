"""``chaintwin spectrum``: the torque spectrum of one recording, lines marked."""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer
from rich.console import Console
from rich.table import Table

from chaintwin.cli.common import (
    ColumnsOption,
    json_option,
    load_options,
    print_json,
    print_warning,
    safe,
)

if TYPE_CHECKING:
    from chaintwin.diagnose.spectra import Spectrum
    from chaintwin.read.profile import ConveyorProfile

from chaintwin.errors import EstimationError, RecordingError

__all__ = ["line_rows", "register", "spectrum_dict"]

FILE_HELP = "Recording file."
PROFILE_HELP = "Conveyor profile YAML: needed for the characteristic lines."
ORDERS_HELP = "Order spectrum (torque resampled to equal motor angle) instead of Welch."
PNG_HELP = "Write the spectrum as a PNG, characteristic lines marked."
JSON_HELP = "Print one JSON object instead of tables."

PEAKS = 5
"""How many of the strongest peaks are listed."""

LOW_BINS = 6
"""Peaks in the lowest bins (three true resolution cells) are trend leakage: not listed."""


def line_rows(
    spectrum: Spectrum,
    profile: ConveyorProfile | None,
    sample_time_s: float,
    *,
    payload_kg: float = 0.0,
) -> list[dict[str, Any]]:
    """The characteristic lines: where the scope shows them and the amplitude there.

    One row per line of :func:`~chaintwin.model.frequencies.line_orders` (the
    speed-locked lines) and per structural mode of
    :func:`~chaintwin.model.frequencies.characteristic_lines` (longitudinal
    belt modes, two-mass mode, lateral modes), with ``name``, ``order`` (None
    for a structural mode, which does not scale with speed), ``frequency_hz``
    (at the spectrum's mean speed), ``apparent`` (folded; Hz for a frequency
    spectrum, orders for an order spectrum), ``amplitude`` (Nm, ±2 bins),
    ``aliased`` and ``resolvable``. A line the spectrum cannot resolve (below
    one bin, or less than one bin from another line) has amplitude None and a
    ``reason``: the amplitude there would be another line's or the trend's.
    None without a profile.

    Raises
    ------
    EstimationError
        When the motor turns slower than 1 rpm on the analysed part.
    """
    from chaintwin.diagnose.lines import band_amplitude
    from chaintwin.diagnose.spectra import MIN_SPEED_RPM
    from chaintwin.model.frequencies import (
        apparent_order,
        characteristic_lines,
        fold_frequency,
        line_orders,
    )

    if profile is None:
        return []
    if spectrum.speed_rpm < MIN_SPEED_RPM:
        raise EstimationError(
            f"the motor turns at {spectrum.speed_rpm:.2g} rpm on the analysed part: no "
            "speed-locked lines to show; leave out --profile for the spectrum alone"
        )
    rot_hz = spectrum.speed_rpm / 60.0
    rows: list[dict[str, Any]] = []
    for name, order in line_orders(profile).items():
        frequency = order * rot_hz
        folded = apparent_order(order, spectrum.speed_rpm, sample_time_s)
        apparent = folded if spectrum.kind == "order" else folded * rot_hz
        rows.append({"name": name, "order": order, "frequency_hz": frequency, "apparent": apparent})
    for line in characteristic_lines(profile, spectrum.speed_rpm, payload_kg=payload_kg):
        if line.order is not None:
            continue
        folded_hz = fold_frequency(line.frequency_hz, sample_time_s)
        apparent = folded_hz if spectrum.kind == "frequency" else folded_hz / rot_hz
        rows.append(
            {
                "name": line.name,
                "order": None,
                "frequency_hz": line.frequency_hz,
                "apparent": apparent,
            }
        )
    bin_width = spectrum.resolution
    for row in rows:
        row["aliased"] = row["frequency_hz"] > 0.5 / sample_time_s
        reason = _unresolvable(row, rows, bin_width)
        row["resolvable"] = reason is None
        row["amplitude"] = None if reason is not None else band_amplitude(spectrum, row["apparent"])
        if reason is not None:
            row["reason"] = reason
    return rows


def _unresolvable(row: dict[str, Any], rows: list[dict[str, Any]], bin_width: float) -> str | None:
    """Why a line's amplitude cannot be read from a spectrum of this bin width, or None."""
    x = row["apparent"]
    if x < bin_width:
        return f"at {x:.3g}, below one bin ({bin_width:.3g}): not resolved from the trend"
    close = [
        r["name"]
        for r in rows
        if r is not row
        and abs(r["apparent"] - x) < bin_width
        and not math.isclose(r["frequency_hz"], row["frequency_hz"], rel_tol=1e-9)
    ]
    if close:
        return f"less than one bin ({bin_width:.3g}) from {', '.join(close)}: not told apart"
    return None


def spectrum_dict(file: str, spectrum: Spectrum, rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Return the ``spectrum --json`` object.

    ``{file, kind, speed_rpm, resolution, lines: [{name, order, apparent,
    amplitude, resolvable, reason?}], peaks: [{x, amplitude}]}`` with ``rows``
    from :func:`line_rows`; the peaks leave out the lowest bins, which hold
    trend leakage.
    """
    from chaintwin.diagnose.peaks import strongest_peaks

    peaks = strongest_peaks(spectrum, top=PEAKS, min_x=LOW_BINS * spectrum.resolution)
    return {
        "file": file,
        "kind": spectrum.kind,
        "speed_rpm": spectrum.speed_rpm,
        "resolution": spectrum.resolution,
        "lines": [
            {k: r[k] for k in ("name", "order", "apparent", "amplitude", "resolvable")}
            | ({"reason": r["reason"]} if "reason" in r else {})
            for r in rows
        ],
        "peaks": [{"x": x, "amplitude": a} for x, a in peaks],
    }


def _print_tables(out: dict[str, Any], rows: list[dict[str, Any]], sample_time_s: float) -> None:
    console = Console()
    if not console.is_terminal:
        console = Console(width=max(console.width, 120))
    unit = "Hz" if out["kind"] == "frequency" else "order"
    console.print(
        f"{safe(out['file'])}: {out['kind']} spectrum at {out['speed_rpm']:.1f} rpm, "
        f"Ts {sample_time_s * 1e3:.4g} ms, bin {out['resolution']:.4g} {unit}",
        highlight=False,
        soft_wrap=True,
    )
    if rows:
        table = Table(title="characteristic lines")
        for col in ("line", "order", "frequency [Hz]", f"apparent [{unit}]", "amplitude [Nm]"):
            table.add_column(safe(col), justify="left" if col == "line" else "right")
        table.add_column("aliased")
        for r in rows:
            table.add_row(
                r["name"],
                "-" if r["order"] is None else f"{r['order']:.4g}",
                f"{r['frequency_hz']:.4g}",
                f"{r['apparent']:.4g}",
                "unresolvable" if r["amplitude"] is None else f"{r['amplitude']:.3g}",
                "[yellow]yes[/yellow]" if r["aliased"] else "no",
            )
        console.print(table)
    else:
        console.print("no --profile: characteristic lines not shown", highlight=False)
    peaks = Table(title=f"{PEAKS} strongest peaks")
    for col in (f"x [{unit}]", "amplitude [Nm]", "near line"):
        peaks.add_column(safe(col), justify="left" if col == "near line" else "right")
    tolerance = 2.0 * out["resolution"]
    for p in out["peaks"]:
        near = [r["name"] for r in rows if abs(r["apparent"] - p["x"]) <= tolerance]
        peaks.add_row(f"{p['x']:.4g}", f"{p['amplitude']:.3g}", ", ".join(near))
    console.print(peaks)


def register(app: typer.Typer) -> None:
    """Add the ``spectrum`` command to the application."""

    @app.command("spectrum")
    def spectrum(
        file: Annotated[Path, typer.Argument(help=FILE_HELP)],
        profile: Annotated[Path | None, typer.Option("--profile", help=PROFILE_HELP)] = None,
        orders: Annotated[bool, typer.Option("--orders", help=ORDERS_HELP)] = False,
        png: Annotated[Path | None, typer.Option("--png", help=PNG_HELP)] = None,
        as_json: Annotated[bool, json_option(JSON_HELP)] = False,
        columns: ColumnsOption = None,
    ) -> None:
        """Show the torque spectrum of a recording with its characteristic lines.

        Without --orders a Welch spectrum of the constant-speed plateau (lines
        above the Nyquist frequency are looked for where they fold: drive
        scopes have no anti-alias filter); with --orders an order spectrum of
        the run above 30 % of peak speed. Amplitudes in Nm.
        """
        from chaintwin.diagnose.spectra import order_spectrum, welch_spectrum
        from chaintwin.model.frequencies import lateral_modes_note
        from chaintwin.report.spectrum_plot import plot_spectrum
        from chaintwin.validate.checks import load_recording

        prof, cmap = load_options(profile, columns)
        rec = load_recording(str(file), profile=prof, column_map=cmap).recording
        conveyor = rec.metadata.conveyor
        if prof is not None and conveyor is not None and conveyor != prof.id:
            raise RecordingError(
                str(file),
                f"is a recording of conveyor '{conveyor}', not of '{prof.id}'; give its profile",
            )
        spec = order_spectrum(rec) if orders else welch_spectrum(rec)
        ts = rec.sample_time_s
        try:
            rows = line_rows(spec, prof, ts, payload_kg=rec.metadata.payload_kg or 0.0)
        except EstimationError as exc:
            raise EstimationError(f"{file}: {exc}") from None
        out = spectrum_dict(str(file), spec, rows)
        note = lateral_modes_note(prof) if prof is not None else None
        if note is not None:
            out["notes"] = [note]
        if png is not None:
            kind = "order" if orders else "Welch"
            marks = {r["name"]: r["apparent"] for r in rows}
            plot_spectrum(spec, png, lines=marks, title=f"{file.name}: {kind} spectrum of torque")
        if as_json:
            print_json(out)
        else:
            _print_tables(out, rows, ts)
            if note is not None:
                Console().print(f"note: {safe(note)}", highlight=False, soft_wrap=True)
            for w in rec.warnings:
                print_warning(Console(), str(file), w.code, w.message)
