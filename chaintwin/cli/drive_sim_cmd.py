"""``chaintwin drive-sim``: a simulated drive serving its scopes over OPC UA."""

from __future__ import annotations

import contextlib
import signal
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console

from chaintwin.cli.common import safe
from chaintwin.cli.simulate_cmd import FAULT_HELP, REALISM_SWITCHES, build_model, build_realism
from chaintwin.errors import ConnectorError

__all__ = ["register"]


def register(app: typer.Typer) -> None:
    """Add ``drive-sim`` to the application."""

    @app.command("drive-sim")
    def drive_sim_cmd(
        profile: Annotated[Path, typer.Option("--profile", help="Conveyor profile YAML.")],
        port: Annotated[
            int, typer.Option("--port", min=1, max=65535, help="TCP port to listen on.")
        ] = 4840,
        interval: Annotated[
            float, typer.Option("--interval", min=0.05, help="Seconds between two scopes.")
        ] = 2.0,
        fault: Annotated[list[str] | None, typer.Option("--fault", help=FAULT_HELP)] = None,
        onset: Annotated[
            int,
            typer.Option(
                "--onset", min=0, help="Scopes (0-based) before the faults start to grow."
            ),
        ] = 0,
        ramp: Annotated[
            int,
            typer.Option(
                "--ramp",
                min=0,
                help="Scopes over which a fault grows to its severity (0: at once).",
            ),
        ] = 0,
        host: Annotated[
            str, typer.Option("--host", help="Address to listen on (0.0.0.0: all).")
        ] = "0.0.0.0",
        sample_time: Annotated[
            float, typer.Option("--sample-time", help="Scope sample time, s.")
        ] = 0.006,
        payload_min: Annotated[float, typer.Option("--payload-min", help="kg")] = 10.0,
        payload_max: Annotated[float, typer.Option("--payload-max", help="kg")] = 40.0,
        drift: Annotated[
            float, typer.Option("--drift", help="Loss drift amplitude (0.05 = ±5 %).")
        ] = 0.05,
        seed: Annotated[int, typer.Option("--seed", min=0, help="Random seed.")] = 0,
        count: Annotated[
            int | None, typer.Option("--count", min=1, help="Stop after this many scopes.")
        ] = None,
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
        certificate: Annotated[
            Path | None,
            typer.Option(
                "--certificate",
                help="Server certificate (DER/PEM; created if missing): adds Basic256Sha256.",
            ),
        ] = None,
        private_key: Annotated[
            Path | None,
            typer.Option("--private-key", help="Server private key (PEM; created if missing)."),
        ] = None,
        user: Annotated[
            list[str] | None,
            typer.Option(
                "--user",
                help="NAME:PASSWORD of a user who may log in, repeatable; then no anonymous login.",
            ),
        ] = None,
        quiet: Annotated[bool, typer.Option("--quiet", help="No line per scope.")] = False,
    ) -> None:
        """Serve a virtual conveyor's scope recordings over OPC UA, as a drive would.

        A new recording every --interval seconds, in the node layout `serve
        --opcua` reads by default (docs/opcua.md); faults as for `generate`,
        their onset counted in scopes. Ctrl-C or SIGTERM stops it (exit 0).
        """
        import asyncio
        import logging

        from chaintwin.extras import require_extra

        require_extra("live", "asyncua", needed_by="chaintwin drive-sim")

        from chaintwin.live.drive_sim import DriveSim, Published
        from chaintwin.read.profile import load_profile
        from chaintwin.simulate.faults import parse_faults

        prof = load_profile(profile)
        model = build_model(prof, {}, calibration)
        faults = parse_faults(fault or [])
        realism = build_realism(ideal, without or [])
        if (certificate is None) != (private_key is None):
            raise ConnectorError("give both --certificate and --private-key, or neither")
        users: dict[str, str] = {}
        for given in user or []:
            name, sep, password = given.partition(":")
            if not sep or not name or not password:
                raise ConnectorError(
                    f"--user '{given}' must be NAME:PASSWORD, e.g. operator:s3cret"
                )
            users[name] = password
        sim = DriveSim(
            prof,
            port=port,
            host=host,
            interval_s=interval,
            faults=faults,
            onset=onset,
            ramp=ramp,
            seed=seed,
            sample_time_s=sample_time,
            payload_range_kg=(payload_min, payload_max),
            drift=drift,
            realism=realism,
            model=model,
            certificate=certificate,
            private_key=private_key,
            users=users,
            anonymous=not users,
        )
        sim.prepare()  # the first scope: refuses bad settings before the server starts
        # asyncua's start-up notes (no encrypting policy without a certificate, ...) are noise here
        logging.getLogger("asyncua").setLevel(logging.ERROR)
        console = Console(stderr=False, highlight=False, soft_wrap=True)

        def said(scope: Published) -> None:
            if quiet:
                return
            faults_now = ", ".join(f"{k}:{v:.3g}" for k, v in scope.faults.items()) or "none"
            when = scope.recording.metadata.recorded_at
            stamp = f" at {when:%H:%M:%S}" if when is not None else ""
            console.print(
                f"scope {scope.counter}{stamp}: payload {scope.truth['payload_kg']:.1f} kg, "
                f"faults: {faults_now}"
            )

        async def main() -> None:
            stop = asyncio.Event()
            loop = asyncio.get_running_loop()
            for sig in (signal.SIGINT, signal.SIGTERM):
                with contextlib.suppress(NotImplementedError, RuntimeError, ValueError):
                    loop.add_signal_handler(sig, stop.set)
            await sim.start()
            security = ", Basic256Sha256 Sign/SignAndEncrypt" if certificate else ""
            login = f"users {', '.join(sorted(users))}" if users else "anonymous"
            console.print(
                f"drive-sim {safe(prof.id)} on opc.tcp://{host}:{port} (security: None{security}; "
                f"login: {safe(login)}): "
                f"a scope every {interval:g} s; Ctrl-C or SIGTERM stops it"
            )
            await sim.run(stop, count=count, on_publish=said)

        asyncio.run(main())
