"""The ``chaintwin`` Typer application and its entry point.

Every user mistake surfaces as a :class:`~chaintwin.errors.ChaintwinError`;
:func:`main` prints it on one line to standard error and exits with 2, so a
user never sees a traceback for bad input. A command asked for JSON
(``--json``, ``--format json``) also prints ``{"error": {"code", "message"}}``
on standard output, the shape the HTTP API uses.
"""

from __future__ import annotations

import importlib
import os
import signal
import sys
import threading
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

__all__ = ["COMMAND_MODULES", "EXIT_ALARM", "EXIT_USAGE", "app", "main"]


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


COMMAND_MODULES: tuple[str, ...] = (
    "chaintwin.cli.inspect_cmd",
    "chaintwin.cli.simulate_cmd",
    "chaintwin.cli.identify_cmd",
    "chaintwin.cli.demo_cmd",
    "chaintwin.cli.spectrum_cmd",
    "chaintwin.cli.monitor_cmd",
    "chaintwin.cli.store_cmd",
    "chaintwin.cli.report_cmd",
    "chaintwin.cli.db_cmd",
    "chaintwin.cli.serve_cmd",
    "chaintwin.cli.drive_sim_cmd",
    "chaintwin.cli.refused_cmd",
    "chaintwin.cli.verify_cmd",
)
"""The modules whose ``register(app)`` adds their commands, in the order ``--help`` lists them.

A new command is one line here. Its module stays light at the top: the
standard library, typer, rich, :mod:`chaintwin.cli.common`,
:mod:`chaintwin.errors` and small modules of constants only; what the
command runs (NumPy, SciPy, SQLAlchemy, FastAPI, ...) it imports inside the
command's function, and an optional part it checks first with
:func:`chaintwin.extras.require_extra`.
"""


def _register() -> None:
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(app)


_register()


def main(argv: list[str] | None = None) -> int:
    """Run the command line; return the exit code.

    Parameters
    ----------
    argv : list of str, optional
        Arguments without the program name; default ``sys.argv[1:]``.
    """
    if argv is None:
        from chaintwin.cli.serve_cmd import system_malloc_command

        again = system_malloc_command(sys.argv[1:], os.environ, sys.orig_argv)
        if again is not None:
            # the same process (pid, open files), Python's objects in glibc's heap
            os.execve(sys.executable, *again)
    previous = None
    if threading.current_thread() is threading.main_thread():
        previous = signal.signal(signal.SIGTERM, _terminate)
    try:
        app(args=argv, prog_name="chaintwin")  # standalone: always ends in SystemExit
    except SystemExit as exc:
        stop = _interrupt_behind(exc)  # typer turns Ctrl-C/SIGTERM into an exit of 130
        if stop is not None:
            return _stopped(stop)
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
    except KeyboardInterrupt as exc:
        return _stopped(exc)
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
    return 0


class Terminated(KeyboardInterrupt):
    """SIGTERM, turned into an exception so that a command stops as on Ctrl-C.

    Work in hand unwinds: stores commit nothing half-done, local workers are
    shut down, and the command says what it had done.
    """

    def __init__(self, signum: int) -> None:
        super().__init__(signum)
        self.signum = signum


def _terminate(signum: int, _frame: object) -> None:
    raise Terminated(signum)


def _interrupt_behind(exc: BaseException) -> KeyboardInterrupt | None:
    """The Ctrl-C or SIGTERM an exception was raised in handling, if any."""
    seen: set[int] = set()
    cause: BaseException | None = exc
    while cause is not None and id(cause) not in seen:
        if isinstance(cause, KeyboardInterrupt):
            return cause
        seen.add(id(cause))
        cause = cause.__cause__ or cause.__context__
    return None


def _stopped(exc: KeyboardInterrupt) -> int:
    """Say that the command was stopped and what it had done; the exit code 128 + signal."""
    signum = exc.signum if isinstance(exc, Terminated) else int(signal.SIGINT)
    print(f"chaintwin: stopped by {signal.Signals(signum).name}", file=sys.stderr)
    for note in getattr(exc, "__notes__", ()):
        print(f"chaintwin: {printable(note)}", file=sys.stderr)
    return 128 + signum


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
