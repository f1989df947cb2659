"""``chaintwin simulate`` and ``chaintwin generate``: the virtual conveyor."""

from __future__ import annotations

import math
from dataclasses import replace
from datetime import datetime
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from chaintwin.simulate.faults import fault_names

if TYPE_CHECKING:
    from chaintwin.read.profile import ConveyorProfile, ModelSpec
    from chaintwin.simulate import setpoints as sp
    from chaintwin.simulate.fleet import GenerateSummary
    from chaintwin.simulate.virtual import Realism

from rich.console import Console
from rich.progress import Progress

from chaintwin.cli.common import json_option, print_json
from chaintwin.diagnose.records import date_out_of_span
from chaintwin.errors import CalibrationError, ModelError, RecordingError
from chaintwin.units import RPM_TO_RAD_S

__all__ = ["build_model", "build_realism", "register"]

REALISM_SWITCHES = ("noise", "quantisation", "elastic", "stick_slip", "polygon", "gear_mesh")
MOVES = ("trapezoid", "trapezoid2", "ramp", "stairs")
FAULT_HELP = f"NAME:SEVERITY, repeatable; names: {', '.join(fault_names())}."


def build_model(
    profile: ConveyorProfile,
    overrides: dict[str, float | None],
    calibration: Path | None = None,
) -> ModelSpec:
    """The plant parameters for a simulation.

    Precedence: command-line overrides, then a calibration file's identified
    friction and losses (``--calibration``), then the profile's ``model:``
    section, then typical values. Identified losses below zero (a fit's
    scatter around a small value) are simulated as zero.

    Raises
    ------
    ModelError
        When an override is out of range (naming the option).
    CalibrationError
        When the calibration file cannot be used, or belongs to another conveyor.
    """
    from pydantic import ValidationError

    from chaintwin.read.profile import ModelSpec
    from chaintwin.simulate.plant import calibrated_model

    model = profile.model or ModelSpec()
    if calibration is not None:
        from chaintwin.identify.calibration import load_calibration

        cal = load_calibration(calibration)
        if cal.profile.id != profile.id:
            raise CalibrationError(
                f"{calibration}: calibration of conveyor '{cal.profile.id}', not of "
                f"'{profile.id}'; give the matching calibration"
            )
        model = calibrated_model(model, cal.parameters)
    base = model.model_dump()
    base.update({k: v for k, v in overrides.items() if v is not None})
    try:
        return ModelSpec.model_validate(base)
    except ValidationError as exc:
        err = exc.errors()[0]
        options = {
            "friction": "--friction",
            "static_friction_ratio": "--static-friction-ratio",
            "loss_constant_nm": "--loss-constant",
            "loss_viscous_nm_s_rad": "--loss-viscous",
            "loss_quadratic_nm_s2_rad2": "--loss-quadratic",
            "belt_stiffness_n_m": "--stiffness",
            "belt_damping_n_s_m": "--damping",
        }
        field = str(err["loc"][0]) if err["loc"] else ""
        name = options.get(field, f"model field '{field}'")
        raise ModelError(f"option {name}: {err['msg']}") from None


def _generate_or_refuse(out: Path, *args: Any, **kwargs: Any) -> GenerateSummary:
    """Run :func:`generate`, turning file-system errors into a one-line refusal."""
    from chaintwin.simulate.fleet import generate

    try:
        return generate(*args, **kwargs)
    except OSError as exc:
        where = exc.filename or out
        raise RecordingError(
            str(where), f"cannot be written ({exc.strerror or exc}); give a writable folder"
        ) from None


def build_realism(ideal: bool, without: list[str]) -> Realism:
    """Realism switches from ``--ideal`` and ``--without NAME`` options."""
    from chaintwin.simulate.virtual import Realism

    realism = Realism.off() if ideal else Realism()
    for name in without:
        if name not in REALISM_SWITCHES:
            raise ModelError(f"--without '{name}': use one of {', '.join(REALISM_SWITCHES)}")
        realism = replace(realism, **{name: False})
    return realism


def _move(
    kind: str, profile: ConveyorProfile, speed_rpm: float | None, direction: int, duration: float
) -> sp.Setpoints:
    from chaintwin.simulate import setpoints as sp
    from chaintwin.simulate.virtual import default_setpoints

    if kind == "trapezoid":
        return default_setpoints(
            profile, duration_s=duration, speed_rpm=speed_rpm, direction=direction
        )
    rpm = speed_rpm or profile.motor.nominal_speed_rpm or 1400.0
    w = rpm * RPM_TO_RAD_S
    cycle = profile.controller.cycle_s
    tail = max(0.5, duration - 9.5)
    if kind == "trapezoid2":
        return sp.trapezoid2(
            speed_rad_s=w,
            accel1_rad_s2=w / 0.3,
            accel2_rad_s2=w / 1.2,
            hold_s=6.0,
            direction=direction,
            lead_s=0.2,
            tail_s=tail,
            cycle_s=cycle,
        )
    if kind == "ramp":
        return sp.ramp(
            speed_rad_s=w,
            ramp_s=2.0,
            hold_s=4.0,
            direction=direction,
            lead_s=0.2,
            tail_s=tail,
            cycle_s=cycle,
        )
    if kind == "stairs":
        return sp.stairs(
            speeds_rad_s=[w / 3, 2 * w / 3, w],
            step_s=2.0,
            accel_rad_s2=w / 0.5,
            direction=direction,
            lead_s=0.2,
            tail_s=tail,
            cycle_s=cycle,
        )
    raise ModelError(f"--move '{kind}': use one of {', '.join(MOVES)}")


def _with_incline(profile: ConveyorProfile, incline_deg: float | None) -> ConveyorProfile:
    if incline_deg is None:
        return profile
    if not -90.0 <= incline_deg <= 90.0:
        raise ModelError(f"--incline-deg {incline_deg} must be between -90 and 90")
    belt = profile.belt.model_copy(update={"incline_deg": incline_deg})
    return profile.model_copy(update={"belt": belt})


def register(app: typer.Typer) -> None:
    """Add ``simulate`` and ``generate`` to the application."""

    @app.command("simulate")
    def simulate_cmd(
        profile: Annotated[Path, typer.Option("--profile", help="Conveyor profile YAML.")],
        out: Annotated[Path, typer.Option("--out", help="Recording file to write.")],
        payload: Annotated[float, typer.Option("--payload", help="Payload, kg.")] = 0.0,
        sample_time: Annotated[
            float, typer.Option("--sample-time", help="Scope sample time, s.")
        ] = 0.006,
        fault: Annotated[list[str] | None, typer.Option("--fault", help=FAULT_HELP)] = None,
        seed: Annotated[int | None, typer.Option("--seed", min=0, help="Random seed.")] = None,
        speed_rpm: Annotated[
            float | None, typer.Option("--speed-rpm", help="Plateau motor speed, rpm.")
        ] = None,
        move: Annotated[
            str, typer.Option("--move", help=f"Set point profile: {', '.join(MOVES)}.")
        ] = "trapezoid",
        backward: Annotated[bool, typer.Option("--backward", help="Run backward.")] = False,
        setpoints_from: Annotated[
            Path | None,
            typer.Option("--setpoints-from", help="Drive with the set points of a recording."),
        ] = None,
        known_load: Annotated[
            bool,
            typer.Option("--known-load", help="Write payload_kg to the metadata (calibration)."),
        ] = False,
        ideal: Annotated[
            bool, typer.Option("--ideal", help="Rigid model, no noise or quantisation.")
        ] = False,
        without: Annotated[
            list[str] | None,
            typer.Option("--without", help=f"Switch off: {', '.join(REALISM_SWITCHES)}."),
        ] = None,
        recorded_at: Annotated[
            str | None, typer.Option("--recorded-at", help="ISO 8601 time for the metadata.")
        ] = None,
        friction: Annotated[float | None, typer.Option("--friction", help="Rail μ.")] = None,
        static_friction_ratio: Annotated[
            float | None, typer.Option("--static-friction-ratio")
        ] = None,
        loss_constant: Annotated[
            float | None, typer.Option("--loss-constant", help="BmA, Nm.")
        ] = None,
        loss_viscous: Annotated[
            float | None, typer.Option("--loss-viscous", help="BmB, Nm/(rad/s).")
        ] = None,
        loss_quadratic: Annotated[
            float | None, typer.Option("--loss-quadratic", help="BmC, Nm/(rad/s)².")
        ] = None,
        stiffness: Annotated[
            float | None, typer.Option("--stiffness", help="Belt stiffness, N/m.")
        ] = None,
        damping: Annotated[
            float | None, typer.Option("--damping", help="Belt damping, N·s/m.")
        ] = None,
        incline_deg: Annotated[float | None, typer.Option("--incline-deg")] = None,
        calibration: Annotated[
            Path | None,
            typer.Option(
                "--calibration", help="Simulate with the friction and losses of a calibration."
            ),
        ] = None,
        as_json: Annotated[bool, json_option("Print the ground truth as JSON.")] = False,
    ) -> None:
        """Simulate one drive recording of the virtual conveyor (what-if runs).

        Plant parameters come from the command line, else --calibration (the
        identified friction and losses), else the profile's model: section,
        else typical values (friction 0.23, the reference losses).
        """
        from chaintwin.read.formats import read_recording
        from chaintwin.read.profile import load_profile
        from chaintwin.read.writer import write_recording
        from chaintwin.simulate import setpoints as sp
        from chaintwin.simulate.faults import parse_faults
        from chaintwin.simulate.virtual import run_virtual

        prof = _with_incline(load_profile(profile), incline_deg)
        model = build_model(
            prof,
            {
                "friction": friction,
                "static_friction_ratio": static_friction_ratio,
                "loss_constant_nm": loss_constant,
                "loss_viscous_nm_s_rad": loss_viscous,
                "loss_quadratic_nm_s2_rad2": loss_quadratic,
                "belt_stiffness_n_m": stiffness,
                "belt_damping_n_s_m": damping,
            },
            calibration,
        )
        realism = build_realism(ideal, without or [])
        faults = parse_faults(fault or [])
        if not (math.isfinite(sample_time) and sample_time > 0):
            raise ModelError(f"--sample-time {sample_time} must be a positive number of seconds")
        direction = -1 if backward else 1
        if setpoints_from is not None:
            src = read_recording(setpoints_from, profile=prof)
            if src.speed_setpoint is None:
                raise ModelError(f"{setpoints_from}: has no speed_setpoint column to drive with")
            setpoints = sp.from_arrays(
                src.time - src.time[0],
                src.speed_setpoint * direction,
                None if src.position_setpoint is None else src.position_setpoint * direction,
                cycle_s=prof.controller.cycle_s,
            )
        else:
            setpoints = _move(move, prof, speed_rpm, direction, realism.max_samples * sample_time)
        when = None
        if recorded_at is not None:
            try:
                when = datetime.fromisoformat(recorded_at)
            except ValueError:
                raise ModelError(f"--recorded-at '{recorded_at}' is not an ISO 8601 time") from None
            refused = date_out_of_span(when)
            if refused is not None:
                raise ModelError(f"--recorded-at {refused}")
        run = run_virtual(
            prof,
            payload_kg=payload,
            sample_time_s=sample_time,
            faults=faults,
            realism=realism,
            seed=seed,
            setpoints=setpoints,
            speed_rpm=speed_rpm,
            model=model,
            recorded_at=when,
            calibration=known_load,
            source=str(out),
        )
        try:
            out.parent.mkdir(parents=True, exist_ok=True)
            write_recording(run.recording, out)
        except OSError as exc:
            raise RecordingError(
                str(out), f"cannot be written ({exc.strerror or exc}); check the path"
            ) from None
        if as_json:
            print_json({"file": str(out), **run.truth})
        else:
            rec = run.recording
            Console().print(
                f"wrote {out}: {rec.samples} samples at {sample_time * 1e3:g} ms, "
                f"payload {payload:g} kg, faults: {', '.join(map(str, faults)) or 'none'}",
                highlight=False,
                soft_wrap=True,
            )

    @app.command("generate")
    def generate_cmd(
        profile: Annotated[Path, typer.Option("--profile", help="Conveyor profile YAML.")],
        out: Annotated[Path, typer.Option("--out", help="Folder to write into.")],
        days: Annotated[int, typer.Option("--days", help="Simulated days.")] = 30,
        per_day: Annotated[int, typer.Option("--per-day", help="Recordings per day.")] = 4,
        fault: Annotated[list[str] | None, typer.Option("--fault", help=FAULT_HELP)] = None,
        onset: Annotated[
            int, typer.Option("--onset", help="Day (0-based) from which faults grow.")
        ] = 0,
        sample_time: Annotated[
            float, typer.Option("--sample-time", help="Scope sample time, s.")
        ] = 0.006,
        payload_min: Annotated[float, typer.Option("--payload-min", help="kg")] = 10.0,
        payload_max: Annotated[float, typer.Option("--payload-max", help="kg")] = 40.0,
        drift: Annotated[
            float, typer.Option("--drift", help="Loss drift amplitude (0.05 = ±5 %).")
        ] = 0.05,
        seed: Annotated[int, typer.Option("--seed", min=0, help="Random seed.")] = 0,
        no_calibration: Annotated[
            bool, typer.Option("--no-calibration", help="Skip the calibration recordings.")
        ] = False,
        ideal: Annotated[bool, typer.Option("--ideal", help="Rigid model, exact export.")] = False,
        without: Annotated[
            list[str] | None,
            typer.Option("--without", help=f"Switch off: {', '.join(REALISM_SWITCHES)}."),
        ] = None,
        calibration: Annotated[
            Path | None,
            typer.Option(
                "--calibration", help="Simulate with the friction and losses of a calibration."
            ),
        ] = None,
    ) -> None:
        """Write a conveyor's recordings over simulated days, with growing faults.

        Beside them: truth.jsonl (payload, every fault's severity per file) and,
        unless --no-calibration, calibration/ recordings with a known payload_kg.
        """
        from chaintwin.read.profile import load_profile
        from chaintwin.simulate.faults import parse_faults

        prof = load_profile(profile)
        model = build_model(prof, {}, calibration)
        faults = parse_faults(fault or [])
        realism = build_realism(ideal, without or [])
        with Progress(transient=True) as bar:
            task = bar.add_task("simulating", total=None)

            def progress(done: int, total: int) -> None:
                bar.update(task, completed=done, total=total)

            summary = _generate_or_refuse(
                out,
                prof,
                out,
                days=days,
                per_day=per_day,
                faults=faults,
                onset_day=onset,
                sample_time_s=sample_time,
                payload_range_kg=(payload_min, payload_max),
                drift=drift,
                realism=realism,
                seed=seed,
                calibration=not no_calibration,
                model=model,
                progress=progress,
            )
        info: dict[str, Any] = {
            "folder": str(summary.folder),
            "recordings": summary.recordings,
            "calibration_recordings": summary.calibration_recordings,
            "truth": str(summary.truth_file),
        }
        Console().print(
            f"wrote {info['recordings']} recordings and {info['calibration_recordings']} "
            f"calibration recordings to {info['folder']}; ground truth in {info['truth']}",
            highlight=False,
            soft_wrap=True,
        )
