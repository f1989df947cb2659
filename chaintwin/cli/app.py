"""The ``chaintwin`` Typer application and its entry point.

Every user mistake surfaces as a :class:`~chaintwin.errors.ChaintwinError`;
:func:`main` prints it on one line to standard error and exits with 2, so a
user never sees a traceback for bad input. A command asked for JSON
(``--json``, ``--format json``) also prints ``{"error": {"code", "message"}}``
on standard output, the shape the HTTP API uses.
"""

from __future__ import annotations

import os
import sys
from typing import Annotated

import typer

from chaintwin.cli.common import (
    EXIT_ALARM,
    EXIT_USAGE,
    error_message,
    error_object,
    print_json,
    printable,
    wants_json,
)
from chaintwin.errors import ChaintwinError
from chaintwin.read.files import MAX_FILE_MB_ENV

__all__ = ["EXIT_ALARM", "EXIT_USAGE", "app", "main"]


app = typer.Typer(
    name="chaintwin",
    help="Digital twin for condition monitoring of chain belt conveyors, "
    "from frequency-inverter scope recordings.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
)


@app.callback()
def _options(
    max_file_mb: Annotated[
        float | None,
        typer.Option(
            "--max-file-mb",
            help="Largest input file read, MB [64]; also CHAINTWIN_MAX_FILE_MB.",
            min=0.001,
        ),
    ] = None,
) -> None:
    """Options for every command."""
    if max_file_mb is not None:
        # through the environment, so that worker processes read with the same limit
        os.environ[MAX_FILE_MB_ENV] = repr(max_file_mb)


def _register() -> None:
    # imported here so that `chaintwin --help` stays fast and modules stay small
    from chaintwin.cli import (
        db_cmd,
        demo_cmd,
        identify_cmd,
        inspect_cmd,
        monitor_cmd,
        report_cmd,
        simulate_cmd,
        spectrum_cmd,
        store_cmd,
    )

    inspect_cmd.register(app)
    simulate_cmd.register(app)
    identify_cmd.register(app)
    demo_cmd.register(app)
    spectrum_cmd.register(app)
    monitor_cmd.register(app)
    store_cmd.register(app)
    report_cmd.register(app)
    db_cmd.register(app)


_register()


def main(argv: list[str] | None = None) -> int:
    """Run the command line; return the exit code.

    Parameters
    ----------
    argv : list of str, optional
        Arguments without the program name; default ``sys.argv[1:]``.
    """
    try:
        app(args=argv, prog_name="chaintwin")  # standalone: always ends in SystemExit
    except SystemExit as exc:
        code = exc.code
        if code is None:
            return 0
        return code if isinstance(code, int) else EXIT_USAGE
    except ChaintwinError as exc:
        message = error_message(exc)
        print(f"chaintwin: error: {printable(message)}", file=sys.stderr)
        if wants_json(sys.argv[1:] if argv is None else argv):
            print_json({"error": error_object(exc, message)})
        return EXIT_USAGE
    except KeyboardInterrupt:
        print("chaintwin: interrupted", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
