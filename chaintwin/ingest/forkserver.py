"""The fork server that starts an ingest's local worker processes.

Local workers are forked from a fork server (``multiprocessing``'s
``forkserver`` start method), not from the ingest's own process: a worker
forked from it would inherit the store's open database connections and,
outliving a killed ingest, hold its transaction open. The fork server
imports :data:`PRELOAD` once and runs a warm-up (:mod:`chaintwin.ingest.warm`)
before it forks, so that no worker pays for the imports or for loading
numba's compiled code.

Starting it takes most of a second (a new interpreter importing the
pipeline). :func:`start` lets a command start it first thing, so that this
runs on another core while the command's own process imports and opens the
store; :func:`context` is what the ingest's process pool uses, and finds it
running. This module imports nothing of the pipeline itself.
"""

from __future__ import annotations

import json
import multiprocessing
import os
import select
import sys
import threading
import time
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import forkserver, process, spawn
from multiprocessing.context import ForkServerContext
from pathlib import Path
from typing import Any

__all__ = [
    "MAIN_ENV",
    "PRELOAD",
    "RESULT_PIPE_BYTES",
    "context",
    "import_main",
    "pin_threads",
    "pool",
    "start",
]

PRELOAD = ("chaintwin.ingest.warm",)
"""Module the fork server imports (and so runs) before it forks workers.

It imports the main script (:func:`import_main`), then warms the pipeline
up. ``"__main__"`` is not in the list: Python 3.11 to 3.13.7 ignore it (the
fork server's start-up looks for the key ``main_path`` among preparation
data that name it ``init_main_from_path``), and the releases that honour it
let an error of the script stop the fork server, and with it the ingest.
"""

MAIN_ENV = "CHAINTWIN_FORKSERVER_MAIN"
"""Environment variable that hands the fork server the main script, while it starts.

A worker process imports the script that started the ingest (``__main__``:
the ``chaintwin`` command, or a user's script) before its first task, unless
its fork server has imported it already: 0.15 s a worker for a script that
imports the store. The variable holds what each worker would be told (JSON:
the script's path or module name, and ``sys.argv``), so that the fork
server imports it once, the same way (:func:`import_main`). It is set only
while the fork server starts, and the fork server removes it.
"""

RESULT_PIPE_BYTES = 1 << 20
"""Room asked for in the pipe that carries the workers' results, bytes (Linux).

A task's results (16 recordings with their packed samples, about 0.7 MB)
do not fit the default pipe (64 kB): a worker would stay in its write until
this process' reader thread, which needs the interpreter lock, had drained
the pipe a dozen times, and the other worker, which shares the pipe, behind
it. Measured on 400 recordings with 2 workers: 115 ms of the workers' time
spent in sending with the default pipe, 42 ms with 1 MiB. Capped by the
system's ``/proc/sys/fs/pipe-max-size``; 0 leaves the pipe as it is.
"""

BLAS_THREADS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


def pin_threads() -> None:
    """One BLAS thread per worker process (docs/design.md, section 4: small matrices oversubscribe).

    Effective in a process that has not loaded numpy yet (the fork server,
    before its warm-up); a worker initializer calls it too, for Dask's and
    for workers of a fork server started by someone else.
    """
    for var in BLAS_THREADS:
        os.environ.setdefault(var, "1")


def _main() -> dict[str, Any] | None:
    """How a worker would be told to import the main script (None: nothing to import)."""
    data = spawn.get_preparation_data("chaintwin")
    found = {k: data[k] for k in ("init_main_from_path", "init_main_from_name") if k in data}
    return found | {"sys_argv": list(data.get("sys_argv", []))} if found else None


def context() -> ForkServerContext:
    """The ``forkserver`` context of ingest's local workers, its fork server running.

    Returns
    -------
    multiprocessing.context.ForkServerContext
    """
    ctx = multiprocessing.get_context("forkserver")
    assert isinstance(ctx, ForkServerContext)
    ctx.set_forkserver_preload(list(PRELOAD))
    main = _main()
    before = os.environ.pop(MAIN_ENV, None)
    if main is not None:
        os.environ[MAIN_ENV] = json.dumps(main)
    try:
        forkserver.ensure_running()  # one per process: a running one is kept
    finally:
        os.environ.pop(MAIN_ENV, None)
        if before is not None:
            os.environ[MAIN_ENV] = before
    return ctx


def import_main() -> bool:
    """In the fork server: import the main script as each worker would.

    The script runs as ``__mp_main__`` with the ingest's ``sys.argv``
    (``multiprocessing.spawn.prepare``, what a worker runs at start). Like
    any script that starts worker processes, it must keep its work under
    ``if __name__ == "__main__":``; what its top does (a database
    connection, a thread) is done once here and inherited by every worker.

    Returns
    -------
    bool
        True when a script was imported; False without one, or when its
        import failed or exited (each worker then imports it itself, and
        says why).
    """
    raw = os.environ.pop(MAIN_ENV, None)  # not for the workers
    if not raw:
        return False
    try:
        data = json.loads(raw)
    except ValueError:
        return False
    proc: Any = process.current_process()
    main, argv = sys.modules["__main__"], sys.argv
    proc._inheriting = True  # as multiprocessing's own preload of __main__ does
    try:
        spawn.prepare(data)
    except BaseException:  # a script may raise anything at import, or exit (argparse)
        sys.modules["__main__"] = main
        sys.modules.pop("__mp_main__", None)
        sys.argv = argv
        return False
    finally:
        del proc._inheriting
    return True


def pool(workers: int | None) -> ProcessPoolExecutor:
    """A process pool of ``workers`` processes started by the fork server.

    Parameters
    ----------
    workers : int, optional
        Worker processes (default: the machine's cores).

    Returns
    -------
    concurrent.futures.ProcessPoolExecutor
        Its results pipe widened to :data:`RESULT_PIPE_BYTES` where the
        system allows it.
    """
    ex = ProcessPoolExecutor(
        max_workers=workers,
        mp_context=context(),
        initializer=init_worker,
        initargs=(os.getpid(),),
    )
    _widen_results(ex)
    return ex


def init_worker(parent: int) -> None:
    """A local worker's set-up: one BLAS thread, and exit when ``parent`` (the ingest) dies.

    A worker forked by the fork server is the fork server's child and holds
    the pipes that keep the fork server and the resource tracker alive; it
    would wait for tasks for good after a ``kill -9`` of the ingest. A
    daemon thread waits for the ingest to end (a pidfd on Linux, else a
    check every second) and ends the worker; the fork server and the
    resource tracker then see their pipes close and end too.
    """
    pin_threads()
    threading.Thread(target=_exit_with, args=(parent,), name="parent-watch", daemon=True).start()


def _exit_with(parent: int) -> None:
    """Wait until process ``parent`` has ended, then end this process at once."""
    try:
        fd = os.pidfd_open(parent)
    except (AttributeError, OSError):  # no pidfd: poll
        fd = None
    if fd is not None:
        poller = select.poll()
        poller.register(fd, select.POLLIN)
        poller.poll()  # readable once the process has ended
    else:  # pragma: no cover - Linux before 5.3, other systems
        while True:
            time.sleep(1.0)
            try:
                os.kill(parent, 0)
            except ProcessLookupError:
                break
            except PermissionError:
                continue
    os._exit(1)  # the task in hand is abandoned: its ingest is gone


def _widen_results(ex: ProcessPoolExecutor) -> int | None:
    """Widen the pool's results pipe; its new size in bytes, or None where it cannot be."""
    try:
        import fcntl  # not on Windows
    except ImportError:
        return None
    setsize = getattr(fcntl, "F_SETPIPE_SZ", None)  # Linux only
    getsize = getattr(fcntl, "F_GETPIPE_SZ", None)
    reader = getattr(getattr(ex, "_result_queue", None), "_reader", None)  # CPython's pool
    if setsize is None or getsize is None or reader is None or RESULT_PIPE_BYTES <= 0:
        return None
    try:
        wanted = min(RESULT_PIPE_BYTES, int(Path("/proc/sys/fs/pipe-max-size").read_text()))
    except (OSError, ValueError):
        wanted = RESULT_PIPE_BYTES
    try:
        fd = reader.fileno()
        size: int = fcntl.fcntl(fd, getsize)
        if size < wanted:  # only ever grown
            size = fcntl.fcntl(fd, setsize, wanted)
    except (OSError, AttributeError):  # over a per-user limit of pipe memory, or no pipe
        return None
    return size


def start() -> None:
    """Start the fork server now, in the background (it is started once per process).

    It imports and warms up the pipeline while this process goes on; the
    first worker started afterwards waits for it to be ready.
    """
    context()
