"""The ``chaintwin`` Typer application and its entry point.

Every user mistake surfaces as a :class:`~chaintwin.errors.ChaintwinError`;
:func:`main` prints it on one line to standard error and exits with 2, so a
user never sees a traceback for bad input. A command asked for JSON
(``--json``, ``--format json``) also prints ``{"error": {"code", "message"}}``
on standard output, the shape the HTTP API uses. Output that cannot be
written (a full disk) is one line and exit 1; a closed pipe (``| head``)
ends the command quietly, as Unix tools do.
"""

from __future__ import annotations

import contextlib
import errno
import importlib
import io
import os
import signal
import sys
import threading
from typing import Annotated, Any, BinaryIO, TextIO, cast

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

__all__ = ["COMMAND_MODULES", "EXIT_ALARM", "EXIT_FAILURE", "EXIT_USAGE", "app", "main"]


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
    "chaintwin.cli.alarms_cmd",
    "chaintwin.cli.fleet_cmd",
    "chaintwin.cli.store_cmd",
    "chaintwin.cli.report_cmd",
    "chaintwin.cli.db_cmd",
    "chaintwin.cli.serve_cmd",
    "chaintwin.cli.drive_sim_cmd",
    "chaintwin.cli.refused_cmd",
    "chaintwin.cli.verify_cmd",
    "chaintwin.cli.opcua_cmd",
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
    stdout = sys.stdout
    sys.stdout = _whole_writes(stdout)
    try:
        app(args=argv, prog_name="chaintwin")  # standalone: always ends in SystemExit
    except SystemExit as exc:
        stop = _interrupt_behind(exc)  # typer turns Ctrl-C/SIGTERM into an exit of 130
        if stop is not None:
            return _stopped(stop)
        failed = _output_failure(exc)  # typer turns a closed pipe into an exit of 1
        if failed is not None:
            return _output_failed(failed)
        code = exc.code
        code = 0 if code is None else code if isinstance(code, int) else EXIT_USAGE
        try:
            sys.stdout.flush()  # what is still buffered: its failure too is the command's
        except OSError as flush_failed:
            if flush_failed.errno not in _OUTPUT_ERRNOS:
                raise
            return _output_failed(flush_failed)
        return code
    except OSError as exc:
        if exc.errno not in _OUTPUT_ERRNOS:
            raise
        return _output_failed(exc)
    except ChaintwinError as exc:
        message = error_message(exc)
        print(f"chaintwin: error: {printable(message)}", file=sys.stderr)
        if wants_json(sys.argv[1:] if argv is None else argv):
            print_json({"error": error_object(exc, message)})
        return EXIT_USAGE
    except KeyboardInterrupt as exc:
        return _stopped(exc)
    finally:
        if sys.stdout is not stdout:
            with contextlib.suppress(OSError, ValueError):
                sys.stdout.flush()
            sys.stdout = stdout
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
    return 0


EXIT_FAILURE = 1
"""Exit code when the output could not be written (a full disk)."""

_OUTPUT_ERRNOS = frozenset({errno.EPIPE, errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EIO})
"""Errors of writing the output: a closed pipe, a full disk or quota, a file too large."""


def _output_failure(exc: BaseException) -> OSError | None:
    """The failure to write the output an exit was raised in handling, if any."""
    cause = exc.__context__
    if isinstance(cause, OSError) and cause.errno in _OUTPUT_ERRNOS:
        return cause
    return None


def _output_failed(exc: OSError) -> int:
    """Say, in one line, that the output could not be written; the exit code.

    A closed pipe (``chaintwin export | head``) is no error: the reader has
    what it wanted, and the command ends quietly with 141 (128 + SIGPIPE),
    as Unix tools do. Anything else (a full disk) is: one line, exit 1. What
    is left in the output's buffer is dropped, so that Python does not fail
    again writing it at exit.
    """
    _drop_output()
    if exc.errno == errno.EPIPE:
        return 128 + int(signal.SIGPIPE)
    where = f" ({printable(str(exc.filename))})" if exc.filename else ""
    print(
        f"chaintwin: error: cannot write the output{where}: {exc.strerror or exc}; the output "
        "is incomplete: free some space (or write elsewhere) and run the command again",
        file=sys.stderr,
    )
    return EXIT_FAILURE


class _WholeWrites(io.BufferedIOBase):
    """A byte stream that passes each write on until all of it is taken.

    Python's text layer ignores a short write of its byte buffer: on a file
    system that fills part-way through a large write (an export of 44 kB
    into 16 kB left), the rest was dropped without an error and the command
    exited 0. Here the next write of the rest raises the file system's
    error (``ENOSPC``), which :func:`main` reports.
    """

    def __init__(self, inner: BinaryIO) -> None:
        super().__init__()
        self._inner = inner

    def write(self, data: Any) -> int:
        view = memoryview(data).cast("B")
        size = len(view)
        while view:
            taken = self._inner.write(view)
            if not taken:
                raise OSError(errno.EIO, "the output takes no more data")
            view = view[taken:]
        return size

    def flush(self) -> None:
        self._inner.flush()

    def fileno(self) -> int:
        return self._inner.fileno()

    def isatty(self) -> bool:
        return self._inner.isatty()

    def writable(self) -> bool:
        return True


def _whole_writes(stream: TextIO) -> TextIO:
    """Standard output as :class:`_WholeWrites` writes it (a file's stream only)."""
    inner = getattr(stream, "buffer", None)
    try:
        stream.fileno()
    except (AttributeError, OSError, ValueError):
        return stream  # not a file (captured): nothing is lost there
    if inner is None or not isinstance(stream, io.TextIOWrapper):
        return stream
    stream.flush()
    return io.TextIOWrapper(
        cast(BinaryIO, _WholeWrites(inner)),  # a buffered byte stream, as the text layer needs
        encoding=stream.encoding,
        errors=stream.errors,
        line_buffering=stream.line_buffering,
        write_through=stream.write_through,
    )


def _drop_output() -> None:
    """Send what standard output still holds, and will be given, to the null device."""
    try:
        fd = sys.stdout.fileno()
    except (AttributeError, OSError, ValueError):
        return  # not a file (captured): nothing is flushed at exit
    null = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(null, fd)
    finally:
        os.close(null)


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
