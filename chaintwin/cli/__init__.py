"""The ``chaintwin`` command line: thin wrappers over the library's stages."""

from __future__ import annotations

import os
import sys
from collections.abc import Sequence

__all__ = ["main"]


def starts_local_workers(args: Sequence[str]) -> bool:
    """Whether a command line runs an ingest (``ingest``, ``demo``) on local worker processes.

    Read off the arguments before the command line is parsed (a guess: a
    wrong one only starts the fork server for nothing, or late). The rule is
    the ingest's: local workers unless ``--scheduler`` is given or
    ``--workers`` is 1 (default: one per core).

    Parameters
    ----------
    args : sequence of str
        Arguments without the program name.
    """
    if not args or args[0] not in ("ingest", "demo") or "--help" in args:
        return False
    workers: str | None = None
    for k, arg in enumerate(args):
        if arg == "--scheduler" or arg.startswith("--scheduler="):
            return False
        if arg == "--workers" and k + 1 < len(args):
            workers = args[k + 1]
        elif arg.startswith("--workers="):
            workers = arg.partition("=")[2]
    if workers is None:
        return (os.cpu_count() or 1) > 1
    try:
        return int(workers) > 1
    except ValueError:
        return False


def main(argv: list[str] | None = None) -> int:
    """Run the command line; return the exit code (:func:`chaintwin.cli.app.main`).

    The ``chaintwin`` command's entry point. It imports the command line only
    when called, so that a process that imports the command's script without
    running it (the fork server of an ingest's workers) stays small. An
    ingest on local workers starts their fork server first: it imports the
    pipeline on another core while this process imports the command line.

    Parameters
    ----------
    argv : list of str, optional
        Arguments without the program name; default ``sys.argv[1:]``.
    """
    if starts_local_workers(sys.argv[1:] if argv is None else argv):
        from chaintwin.ingest import forkserver

        forkserver.start()
    from chaintwin.cli.app import main as run

    return run(argv)
