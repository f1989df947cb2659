"""The fork server that starts an ingest's local worker processes.

Local workers are forked from a fork server (``multiprocessing``'s
``forkserver`` start method), not from the ingest's own process: a worker
forked from it would inherit the store's open database connections and,
outliving a killed ingest, hold its transaction open. The fork server
imports :data:`PRELOAD` once and runs a warm-up (:mod:`chaintwin.store.warm`)
before it forks, so that no worker pays for the imports or for loading
numba's compiled code.

Starting it takes most of a second (a new interpreter importing the
pipeline). :func:`start` lets a command start it first thing, so that this
runs on another core while the command's own process imports and opens the
store; :func:`context` is what the ingest's process pool uses, and finds it
running. This module imports nothing of the pipeline itself.
"""

from __future__ import annotations

import multiprocessing
import os
from multiprocessing import forkserver, process, spawn
from multiprocessing.context import ForkServerContext
from typing import Any

__all__ = ["MAIN_ENV", "PRELOAD", "context", "import_main", "start"]

PRELOAD = ("__main__", "chaintwin.store.warm")
"""Modules the fork server imports (and so runs) before it forks workers."""

MAIN_ENV = "CHAINTWIN_FORKSERVER_MAIN"
"""Environment variable that tells the fork server the main script's path.

A worker process imports the script that started the ingest (``__main__``:
the ``chaintwin`` command, or a user's script) before its first task, unless
its fork server has imported it already. ``"__main__"`` in the preload list
is meant to do that, but Python 3.11 to 3.13 never pass the script's path to
the fork server (its start-up looks for the key ``main_path`` among
preparation data that name it ``init_main_from_path``), so every worker
imports the script on its own: 0.15 s for a script that imports the store.
:func:`import_main` does it in the fork server instead, from this variable.
"""


def context() -> ForkServerContext:
    """The ``forkserver`` context of ingest's local workers, its preload set.

    Returns
    -------
    multiprocessing.context.ForkServerContext
    """
    ctx = multiprocessing.get_context("forkserver")
    assert isinstance(ctx, ForkServerContext)
    ctx.set_forkserver_preload(list(PRELOAD))
    # the path exactly as each worker will be told it (and compare it)
    main_path = spawn.get_preparation_data("chaintwin").get("init_main_from_path")
    if main_path is not None:
        os.environ[MAIN_ENV] = str(main_path)
    else:  # run as a module (python -m ...): workers do not import it again
        os.environ.pop(MAIN_ENV, None)
    return ctx


def import_main() -> bool:
    """In the fork server: import the main script as multiprocessing's workers would.

    Returns
    -------
    bool
        True when a script was imported; False without one, or when its
        import failed (each worker then imports it, and says why).
    """
    path = os.environ.get(MAIN_ENV)
    if not path:
        return False
    proc: Any = process.current_process()
    proc._inheriting = True  # as multiprocessing's own preload of __main__ does
    try:
        spawn.import_main_path(path)
    except Exception:  # the workers import it again, with its error
        return False
    finally:
        del proc._inheriting
    return True


def start() -> None:
    """Start the fork server now, in the background (it is started once per process).

    It imports and warms up the pipeline while this process goes on; the
    first worker started afterwards waits for it to be ready.
    """
    context()
    forkserver.ensure_running()
