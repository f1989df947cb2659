"""``chaintwin identify``, ``calibrate`` and ``weigh``."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer
from rich.console import Console
from rich.table import Table

from chaintwin import __version__
from chaintwin.cli.common import (
    ColumnsOption,
    JsonListOption,
    JsonObjectOption,
    db_option,
    error_message,
    expand_recordings,
    json_option,
    print_json,
    print_refused,
    print_warning,
    safe,
)
from chaintwin.errors import CalibrationError, ChaintwinError, EstimationError, RecordingError
from chaintwin.identify.defaults import DEFAULT_FORGETTING, DEFAULT_HOLD_FIRST, LOSS_DRIFT_REL

if TYPE_CHECKING:
    from chaintwin.identify.calibration import Calibration
    from chaintwin.identify.zero_reference import ZeroReference
    from chaintwin.read.columns import ColumnMap
    from chaintwin.read.profile import ConveyorProfile
    from chaintwin.read.recording import Metadata, Recording
    from chaintwin.validate.checks import Inspection
    from chaintwin.weigh.weigh import WeighResult


__all__ = ["identify_dict", "register"]


def _load(file: str, profile: ConveyorProfile, column_map: ColumnMap | None) -> Recording:
    """Read and validate one recording of this conveyor (see :func:`_inspect`)."""
    return _inspect(file, profile, column_map).recording


def _inspect(file: str, profile: ConveyorProfile, column_map: ColumnMap | None) -> Inspection:
    """Read and validate one recording of this conveyor: the recording and its phases.

    Raises
    ------
    RecordingError
        When it cannot be read, or is a recording of another conveyor (profiles
        are matched to recordings by id).
    """
    from chaintwin.validate.checks import load_recording

    ins = load_recording(file, profile=profile, column_map=column_map)
    rec = ins.recording
    conveyor = rec.metadata.conveyor
    if conveyor is not None and conveyor != profile.id:
        raise RecordingError(
            file,
            f"is a recording of conveyor '{conveyor}', not of '{profile.id}'; "
            "give the matching profile or calibration",
        )
    return ins


def _none_usable(refused: list[dict[str, str]], what: str) -> EstimationError:
    """The error when no file is usable: each file and why, in one line."""
    reasons = "; ".join(r["error"] for r in refused) or "no recording was given"
    return EstimationError(f"no usable recording to {what} from: {reasons}")


def _read_all(
    files: list[str], profile: ConveyorProfile, column_map: ColumnMap | None, *, known: bool
) -> tuple[list[Recording], list[dict[str, str]]]:
    """Read and validate; refused files are collected, not fatal.

    With ``known``, recordings without ``payload_kg`` or without motion are
    refused here too, so that one bad file does not stop the others.
    """
    recs: list[Recording] = []
    refused: list[dict[str, str]] = []
    for f in files:
        try:
            rec = _load(f, profile, column_map)
            if known and rec.metadata.payload_kg is None:
                raise RecordingError(
                    f, "has no payload_kg in its metadata; add '# payload_kg: <kg>' (0 if empty)"
                )
            if rec.has_warning("no_motion"):
                raise RecordingError(f, "the conveyor does not move; nothing to identify")
            recs.append(rec)
        except ChaintwinError as exc:
            refused.append({"file": f, "error": error_message(exc)})
    return recs, refused


def _save(cal: Calibration, out: Path) -> None:
    try:
        cal.save(out)
    except OSError as exc:
        raise CalibrationError(
            f"{out}: cannot write the calibration ({exc.strerror or exc}); check the path"
        ) from None


def identify_dict(cal: Calibration) -> dict[str, Any]:
    """The ``identify --json`` object of a calibration's parameters."""
    from chaintwin.identify.losses import loss_verdict

    p = cal.parameters

    def pair(name: str, key: str) -> tuple[float | None, float | None]:
        if key in p.fixed:
            return p[key], None
        return p[key], p.stderr(key)

    out: dict[str, Any] = {}
    for name, key in (("mu", "mu"), ("BmA", "BmA"), ("BmB", "BmB"), ("BmC", "BmC")):
        value, err = pair(name, key)
        out[name] = value
        out[f"{name}_stderr"] = err
    verdict = loss_verdict(p, cal.plateau_speeds_rpm)
    if not verdict.separated:
        # a split the runs cannot make is not reported (the sum is, in "losses")
        for key in ("BmB", "BmC"):
            out[key] = out[f"{key}_stderr"] = None
    out["losses"] = verdict.to_dict()
    out["inertia_kgm2"] = cal.inertia_kgm2
    out["inertia_kgm2_stderr"] = p.stderr("J_d")
    out["torque_lag_s"] = cal.torque_lag_s
    out["torque_lag_s_stderr"] = cal.torque_lag_stderr_s
    out["warnings"] = [w.to_dict() for w in cal.warnings]
    out["drive_inertia_kgm2"] = p["J_d"]
    out["drive_inertia_kgm2_stderr"] = p.stderr("J_d")
    out["fixed"] = list(p.fixed)
    out["case"] = cal.case
    out["payload_sensitivity_nm_per_kg"] = cal.sensitivity_nm_per_kg
    out["payload_sensitivity_rel_uncertainty"] = cal.sensitivity_rel_uncertainty
    out["residual_rms_nm"] = cal.residual_rms_nm
    out["recordings"] = [
        {
            "file": r["file"],
            "payload_kg": r["payload_kg"],
            "plateau_speed_rpm": r["plateau_speed_rpm"],
        }
        for r in cal.recordings
    ]
    return out


def _print_refused(console: Console, refused: list[dict[str, str]]) -> None:
    for r in refused:
        print_refused(console, r["error"])


def register(app: typer.Typer) -> None:
    """Add ``identify``, ``calibrate`` and ``weigh`` to the application."""

    @app.command("identify")
    def identify_cmd(
        files: Annotated[list[Path], typer.Argument(help="Recordings with payload_kg metadata.")],
        profile: Annotated[Path, typer.Option("--profile", help="Conveyor profile YAML.")],
        as_json: JsonObjectOption = False,
        columns: ColumnsOption = None,
        method: Annotated[
            str,
            typer.Option(
                "--method",
                help="ls: windowed batch least squares (default); rls: recursive least "
                "squares over the recordings in time order, tracking BmA and BmB; oe: "
                "output-error fit of the closed loop.",
            ),
        ] = "ls",
        forgetting: Annotated[
            float,
            typer.Option(
                "--forgetting",
                min=0.5,
                max=1.0,
                help=f"rls: forgetting factor λ [{DEFAULT_FORGETTING}].",
            ),
        ] = DEFAULT_FORGETTING,
        hold_first: Annotated[
            int,
            typer.Option(
                "--hold-first",
                min=1,
                help="rls: J_d, mu and BmC are held at the batch fit of this many first "
                f"recordings [{DEFAULT_HOLD_FIRST}].",
            ),
        ] = DEFAULT_HOLD_FIRST,
    ) -> None:
        """Identify friction, gear losses, inertia and torque lag from known-load recordings.

        The profile's model: section is never read. With one load only,
        friction and the constant loss BmA cannot be separated (a warning says
        what was assumed). Exit code 2 when a file was refused.
        """
        from chaintwin.calibrating.methods import METHODS, identify_oe, identify_rls, in_time_order
        from chaintwin.calibrating.procedure import calibrate
        from chaintwin.read.columns import load_column_map
        from chaintwin.read.profile import load_profile

        if method not in METHODS:
            raise EstimationError(f"--method: '{method}' is not one of {', '.join(METHODS)}")
        prof = load_profile(profile)
        cmap = load_column_map(columns) if columns is not None else None
        recs, refused = _read_all(expand_recordings(files), prof, cmap, known=True)
        if not recs:
            raise _none_usable(refused, "identify")
        extra: dict[str, Any] = {}
        if method == "rls":
            cal, track = identify_rls(
                in_time_order(recs),
                prof,
                forgetting=forgetting,
                hold_first=hold_first,
                version=__version__,
            )
            extra["forgetting"] = forgetting
            extra["track"] = [p.to_dict() for p in track]
        elif method == "oe":
            cal, details = identify_oe(recs, prof, version=__version__)
            extra["output_error"] = details
        else:
            cal = calibrate(recs, prof, version=__version__)
        out = identify_dict(cal)
        out["method"] = method
        out["method_description"] = cal.method
        out.update(extra)
        out["refused"] = refused
        if as_json:
            print_json(out)
        else:
            console = Console()
            table = Table(title=f"chaintwin identify ({method}): {safe(prof.id)}")
            for col in ("parameter", "value", "std. error", "unit"):
                table.add_column(col)
            units = {"mu": "-", "BmA": "Nm", "BmB": "Nm·s/rad", "BmC": "Nm·s²/rad²"}
            for key, unit in [*units.items(), ("inertia_kgm2", "kg·m²"), ("torque_lag_s", "s")]:
                value, err = out[key], out[f"{key}_stderr"]
                if key in ("BmB", "BmC") and out["losses"]["verdict"] == "not_separable":
                    table.add_row(key, "not separable", "-", unit)
                    continue
                table.add_row(
                    key,
                    "-" if value is None else f"{value:.5g}",
                    "fixed" if key in out["fixed"] else ("-" if err is None else f"{err:.2g}"),
                    unit,
                )
            console.print(table)
            console.print(f"losses: {safe(out['losses']['message'])}", highlight=False)
            for w in out["warnings"]:
                print_warning(console, "", w["code"], w["message"])
            _print_refused(console, refused)
        if refused:
            raise typer.Exit(2)

    @app.command("calibrate")
    def calibrate_cmd(
        files: Annotated[list[Path], typer.Argument(help="Recordings with payload_kg metadata.")],
        profile: Annotated[Path, typer.Option("--profile", help="Conveyor profile YAML.")],
        out: Annotated[
            Path | None, typer.Option("--out", help="Calibration file to write (JSON).")
        ] = None,
        db: Annotated[
            str | None,
            db_option("Keep the calibration in this results store (URL)."),
        ] = None,
        as_json: Annotated[bool, json_option("Print the calibration file's content.")] = False,
        columns: ColumnsOption = None,
        friction_drift: Annotated[
            float,
            typer.Option(
                "--friction-drift",
                min=0.0,
                max=1.0,
                help="Standard uncertainty of the rail friction relative to the calibration's, "
                "stored in the calibration: weigh, ingest and the live service carry it into "
                "the uncertainty (default 0: trusted). E.g. 0.1 where the calibration warns "
                "`friction_unchecked`.",
            ),
        ] = 0.0,
    ) -> None:
        """Calibrate a conveyor for weighing and write a versioned calibration file.

        With --db the calibration is kept in the results store (where ingest
        uses it); --out and --db may be given together. One of them is needed.

        Accepts any mix of empty-tray runs, reference-load runs and runs at
        several speeds, and says how well the payload sensitivity is known and
        which run would improve it.
        """
        from chaintwin.calibrating.procedure import calibrate
        from chaintwin.read.columns import load_column_map
        from chaintwin.read.profile import load_profile

        if out is None and db is None:
            raise CalibrationError("give --out FILE, --db URL or both: where the calibration goes")
        prof = load_profile(profile)
        cmap = load_column_map(columns) if columns is not None else None
        recs, refused = _read_all(expand_recordings(files), prof, cmap, known=True)
        if not recs:
            raise _none_usable(refused, "calibrate")
        cal = calibrate(recs, prof, version=__version__, friction_drift=friction_drift)
        if out is not None:
            _save(cal, out)
        if db is not None:
            from chaintwin.store.engine import store_url
            from chaintwin.store.store import Store

            with Store(store_url(db)) as store:
                store.put_calibration(cal)
        if as_json:
            print_json(cal.to_dict())
        else:
            console = Console()
            console.print(
                f"wrote {safe(str(out) if out is not None else 'the store')}: "
                f"{len(recs)} recordings, case "
                f"[bold]{cal.case}[/bold], mu = {cal.parameters['mu']:.4f}, payload "
                f"sensitivity {cal.sensitivity_nm_per_kg * 1e3:.3f} mNm/kg "
                f"± {cal.sensitivity_rel_uncertainty:.2%}",
                highlight=False,
                soft_wrap=True,
            )
            for w in cal.warnings:
                print_warning(console, "", w.code, w.message)
            _print_refused(console, refused)
        if refused:
            raise typer.Exit(2)

    @app.command("weigh")
    def weigh_cmd(
        files: Annotated[list[Path], typer.Argument(help="Recordings to weigh.")],
        calibration: Annotated[
            Path, typer.Option("--calibration", help="Calibration file from `calibrate`.")
        ],
        as_json: JsonListOption = False,
        columns: ColumnsOption = None,
        loss_drift: Annotated[
            float,
            typer.Option(
                "--loss-drift",
                min=0.0,
                max=0.5,
                help="Standard uncertainty of the gear losses relative to the calibration's "
                "(0.06: a drift within ±10 %, the default; 0 trusts the calibration's losses).",
            ),
        ] = LOSS_DRIFT_REL,
        friction_drift: Annotated[
            float | None,
            typer.Option(
                "--friction-drift",
                min=0.0,
                max=1.0,
                help="Standard uncertainty of the rail friction relative to the calibration's, "
                "carried into the uncertainty; overrides the calibration's own (`calibrate "
                "--friction-drift`, 0 unless given there: trusted). Use it where the "
                "calibration warns `friction_unchecked` (e.g. 0.1).",
            ),
        ] = None,
        zero_tracking: Annotated[
            bool | None,
            typer.Option(
                "--zero-tracking/--no-zero-tracking",
                help="Experimental: track the loss drift over the files in recorded order: a "
                "recording with a known payload (metadata payload_kg, e.g. an empty run at "
                "shift start) measures it, the others are weighed with what it can have moved "
                "since (loss_drift, since_known_run_s); it then replaces --loss-drift. Off by "
                "default: on simulated fleets its weights were not yet as honest as the "
                "blanket allowance's.",
            ),
        ] = None,
    ) -> None:
        """Weigh the payload of each recording from torque alone, with an uncertainty.

        A recording that cannot be weighed gets payload null and the warning
        `unweighable` with its reason (exit code 0). Exit code 2 after the
        others are done when a file was refused.
        """
        from chaintwin.identify.calibration import load_calibration
        from chaintwin.read.columns import load_column_map
        from chaintwin.weigh.drift import LossDrift
        from chaintwin.weigh.weigh import weigh

        cal = load_calibration(calibration)
        drift = LossDrift(0.0, loss_drift)
        cmap = load_column_map(columns) if columns is not None else None
        results: list[dict[str, Any]] = []
        weighed: dict[int, tuple[WeighResult, Metadata]] = {}
        for f in expand_recordings(files):
            try:
                ins = _inspect(f, cal.profile, cmap)
                res = weigh(ins, cal, source=f, loss_drift=drift, friction_drift=friction_drift)
                weighed[len(results)] = (res, ins.recording.metadata)
                results.append(res.to_dict())
            except EstimationError as exc:
                message = error_message(exc)
                if not message.startswith(f):
                    message = f"{f}: {message}"
                results.append({"file": f, "error": message})
            except ChaintwinError as exc:
                results.append({"file": f, "error": error_message(exc)})
        if zero_tracking:
            for k, res in track_in_order(weighed, cal.zero_reference).items():
                results[k] = res.to_dict()
        if as_json:
            print_json(results)
            # the summary beside the JSON, so that the list stays one document
            typer.echo(_weigh_summary(results), err=True)
        else:
            console = Console()
            table = Table(title=f"chaintwin weigh: {safe(cal.profile.id)}")
            for col in ("file", "payload [kg]", "± [kg]", "friction", "inertia", "ok", "TLF"):
                table.add_column(col)
            for r in results:
                if "error" in r:
                    table.add_row(safe(r["file"]), "[red]refused[/red]", "", "", "", "", "")
                    continue
                if r["payload_kg"] is None:
                    table.add_row(safe(r["file"]), "[yellow]unweighable[/yellow]", *[""] * 5)
                    continue
                inertia = r["payload_inertia_kg"]
                table.add_row(
                    safe(r["file"]),
                    f"{r['payload_kg']:.2f}",
                    f"{r['uncertainty_kg']:.2f}",
                    f"{r['payload_friction_kg']:.2f}",
                    "-" if inertia is None else f"{inertia:.2f}",
                    "yes" if r["consistent"] else "[red]NO[/red]",
                    "-" if r["tlf"] is None else f"{r['tlf']:.3f}",
                )
            console.print(table)
            for r in results:
                if "error" in r:
                    _print_refused(console, [r])
                for w in r.get("warnings", []):
                    print_warning(console, r["file"], w["code"], w["message"])
            console.print(_weigh_summary(results), highlight=False)
        if any("error" in r for r in results):
            raise typer.Exit(2)


def track_in_order(
    weighed: dict[int, tuple[WeighResult, Metadata]],
    reference: ZeroReference | None,
) -> dict[int, WeighResult]:
    """Each weighing combined with the zero-tracked loss drift, fed in recorded order.

    Recordings without a time keep their place among the given order; known
    runs are read relative to the calibration's ``reference`` zero.
    """
    from chaintwin.weigh.zero_tracking import ZeroTracker

    tracker = ZeroTracker()
    order = sorted(weighed)
    if all(weighed[k][1].recorded_at is not None for k in order):
        order.sort(key=lambda k: (weighed[k][1].recorded_at, k))
    return {
        k: tracker.track(
            weighed[k][0],
            weighed[k][1].recorded_at,
            weighed[k][1].payload_kg,
            reference,
            known_runs=True,
        )
        for k in order
    }


def _weigh_summary(results: list[dict[str, Any]]) -> str:
    """``N weighed, M unweighable, K refused`` for the end of ``weigh``'s table."""
    refused = sum(1 for r in results if "error" in r)
    unweighable = sum(1 for r in results if "error" not in r and r["payload_kg"] is None)
    weighed = len(results) - refused - unweighable
    return f"{weighed} weighed, {unweighable} unweighable, {refused} refused"
