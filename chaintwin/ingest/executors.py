"""Where an ingest's work runs: this process, a local process pool, or a Dask cluster.

:func:`executor` hands out a ``concurrent.futures`` executor for each; the
ingest's code path is the same on all three.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
from collections.abc import Callable, Iterator
from concurrent.futures import Executor, Future
from contextlib import contextmanager
from typing import Any

from chaintwin.errors import StoreError

from . import forkserver

__all__ = [
    "SWITCH_INTERVAL_S",
    "ClusterExecutor",
    "InlineExecutor",
    "executor",
    "lanes",
    "runs_inline",
    "shared",
    "signals_deferred",
]


class InlineExecutor(Executor):
    """A ``concurrent.futures`` executor that runs each task in this process at once.

    One worker needs no pool: the pipeline then runs on one core with
    nothing sent between processes and no worker to start, by the same code
    path as on a pool or a cluster (the futures are done when returned).
    """

    def submit(self, fn: Callable[..., Any], /, *args: Any, **kwargs: Any) -> Future[Any]:
        """Run ``fn(*args, **kwargs)`` now; its result (or exception) in a done future."""
        fut: Future[Any] = Future()
        try:
            fut.set_result(fn(*args, **kwargs))
        except Exception as exc:  # handed to the caller through the future
            fut.set_exception(exc)
        return fut


class ClusterExecutor(Executor):
    """A Dask cluster as a ``concurrent.futures`` executor that sends shared inputs once.

    Tasks are submitted as not pure (``pure=False``): a task reads files,
    which may change, so two equal submissions are two tasks, and nothing
    is hashed (``dask.base.tokenize``) per task. What many tasks share (a
    conveyor's profile and calibration) goes to every worker once
    (:meth:`share`, ``Client.scatter(..., broadcast=True)``) and the tasks
    carry a reference to it, not a copy through the scheduler.

    Parameters
    ----------
    client : distributed.Client
        A connected client; closed by whoever opened it.
    """

    def __init__(self, client: Any) -> None:
        self.client = client
        self._ex = client.get_executor(pure=False)
        self._shared: dict[int, tuple[object, Any]] = {}

    def submit(self, fn: Callable[..., Any], /, *args: Any, **kwargs: Any) -> Future[Any]:
        """Run ``fn(*args, **kwargs)`` on the cluster; a future of its result."""
        fut: Future[Any] = self._ex.submit(fn, *args, **kwargs)
        return fut

    def shutdown(self, wait: bool = True, *, cancel_futures: bool = False) -> None:
        """Stop taking tasks (``wait``: until those submitted are done)."""
        self._ex.shutdown(wait=wait)

    def share(self, value: object) -> Any:
        """``value`` on every worker: a Dask future to pass to tasks in its place.

        Scattered once per object (kept by identity for the executor's life,
        so that a changed calibration, a new object, is sent anew).
        """
        hit = self._shared.get(id(value))
        if hit is None or hit[0] is not value:
            (fut,) = self.client.scatter([value], broadcast=True, hash=False)
            hit = self._shared[id(value)] = (value, fut)
        return hit[1]

    def threads(self) -> int:
        """Threads of the cluster's workers now (0 while it has none)."""
        workers = self.client.scheduler_info()["workers"].values()
        return int(sum(w.get("nthreads", 1) for w in workers))


def shared(ex: Executor, value: object) -> Any:
    """What to pass to the executor's tasks for ``value``, which many of them share.

    A Dask cluster's reference to it on every worker (:meth:`ClusterExecutor.share`);
    the value itself for a local pool (pickled with each task: a few kB) and
    in this process. None stays None.
    """
    if value is None or not isinstance(ex, ClusterExecutor):
        return value
    return ex.share(value)


def lanes(ex: Executor, workers: int | None) -> int:
    """How many tasks the executor runs at once.

    Parameters
    ----------
    ex : Executor
        From :func:`executor`.
    workers : int, optional
        The local worker processes asked for (default: the machine's cores).

    Returns
    -------
    int
        A Dask cluster's worker threads (asked of its scheduler; 0 while it
        has none), else the local workers.
    """
    if isinstance(ex, ClusterExecutor):
        return ex.threads()
    if isinstance(ex, InlineExecutor):
        return 1
    return workers or os.cpu_count() or 1


def runs_inline(workers: int | None, scheduler: str | None) -> bool:
    """Whether the pipeline runs in this process: one local worker (given, or one core)."""
    return scheduler is None and (workers or os.cpu_count() or 1) == 1


SWITCH_INTERVAL_S = 0.0002
"""The interpreter's thread switch interval while local workers run, s (default 0.005)."""

_responsive_lock = threading.Lock()
_responsive_users = 0
_responsive_before = 0.005


@contextmanager
def _responsive() -> Iterator[None]:
    """A shorter thread switch interval for the time of the block.

    The process pool's own threads in this process (one reads the workers'
    results from a pipe, another hands them their tasks;
    a Dask client's event loop likewise) need the interpreter lock, which
    the health model and the store hold while they work: at the default
    interval (5 ms) a worker can wait that long to hand over each piece of
    its results or to get its next task.
    """
    global _responsive_users, _responsive_before
    with _responsive_lock:  # ingests may run in threads: the first sets, the last restores
        if _responsive_users == 0:
            _responsive_before = sys.getswitchinterval()
            sys.setswitchinterval(min(_responsive_before, SWITCH_INTERVAL_S))
        _responsive_users += 1
    try:
        yield
    finally:
        with _responsive_lock:
            _responsive_users -= 1
            if _responsive_users == 0:
                sys.setswitchinterval(_responsive_before)


@contextmanager
def executor(workers: int | None, scheduler: str | None) -> Iterator[Executor]:
    """A ``concurrent.futures`` executor: this process, a local process pool, or a Dask cluster.

    Parameters
    ----------
    workers : int, optional
        Local worker processes (default: the machine's cores); 1 runs the
        pipeline in this process (:class:`InlineExecutor`).
    scheduler : str, optional
        Address of a Dask scheduler (``tcp://host:8786``); the cluster's
        workers are used instead of local processes.

    Raises
    ------
    StoreError
        When the scheduler cannot be reached.
    """
    if runs_inline(workers, scheduler):
        yield InlineExecutor()
        return
    with _responsive():
        if scheduler is None:
            # forked from the fork server (forkserver.py says why), which may
            # have been started already by the command (forkserver.start)
            ex = forkserver.pool(workers)
            try:
                yield ex
            except BaseException:
                # stopped (an error, Ctrl-C, SIGTERM): tasks not started are dropped
                ex.shutdown(wait=True, cancel_futures=True)
                raise
            ex.shutdown(wait=True)
            return
        from chaintwin.extras import require_extra

        require_extra("dask", "distributed", needed_by=f"a Dask scheduler ({scheduler})")
        from distributed import Client

        try:
            client = Client(scheduler, timeout="10s")  # type: ignore[no-untyped-call]
        except (OSError, TimeoutError) as exc:
            raise StoreError(
                f"scheduler {scheduler}: cannot reach the Dask scheduler ({exc})",
                field="scheduler",
            ) from None
        try:
            yield ClusterExecutor(client)
        finally:
            client.close()  # type: ignore[no-untyped-call]


@contextmanager
def signals_deferred() -> Iterator[None]:
    """Hold SIGTERM and SIGINT back while a group is committed and counted.

    The stop message counts what is stored; a signal handled between the
    commit and the count would make it say less than the store holds. In
    the main thread (where Python handles signals) they are blocked, and
    their Python handlers replaced by one that notes them: a signal that
    arrived just before the block has its handler run by the interpreter
    later, at any point inside it. Right after, with the handlers back, a
    noted signal's Python handler is called in this thread (a default
    action is raised again). Elsewhere nothing changes.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    noted: list[int] = []

    def note(signum: int, _frame: object) -> None:
        noted.append(signum)

    held = (signal.SIGTERM, signal.SIGINT)
    old = signal.pthread_sigmask(signal.SIG_BLOCK, set(held))
    # a handler not set from Python (None) cannot be put back: left as it is
    handlers = {s: h for s in held if (h := signal.getsignal(s)) is not None}
    for sig in handlers:
        signal.signal(sig, note)
    try:
        yield
    finally:
        # a signal sent during the block waits, blocked: taken here and raised
        # below, where its handler runs at once (``raise_signal`` handles it
        # before returning); unblocked, the interpreter would run the handler
        # at its next check, a few instructions later, wherever that falls
        ours = set(held) - set(old)  # blocked here, not by the caller
        pending = ours & signal.sigpending()
        while pending:
            info = signal.sigtimedwait(pending, 0)
            if info is None:
                break
            noted.append(info.si_signo)
            pending = ours & signal.sigpending()
        for sig, handler in handlers.items():
            signal.signal(sig, handler)
        signal.pthread_sigmask(signal.SIG_SETMASK, old)
        for signum in dict.fromkeys(noted):
            put_back = handlers.get(signal.Signals(signum))
            if callable(put_back):
                # run here, in this thread: re-raising it could land on another
                # thread, or wait behind a mask the caller keeps (a test run
                # failed so: the handler never ran)
                put_back(signum, None)
            elif put_back != signal.SIG_IGN:
                signal.raise_signal(signum)
