"""Warm-up of the fork server that starts ingest's local worker processes.

The fork server imports this module before it forks any worker
(``multiprocessing``'s preload). Importing it

* imports the script that started the ingest, as each worker would
  otherwise do on its own (:func:`chaintwin.store.forkserver.import_main`);
* imports the pipeline and reads and validates one bundled example
  recording, so that numba's compiled parser is loaded from its cache here,
  once (about 0.1 s), and every forked worker starts with it in memory
  instead of loading it on its first recording;
* freezes the garbage collector's view of all that (:func:`gc.freeze`), so
  that a worker's collections do not write to the pages it shares with the
  fork server (each page written is copied first).
"""

from __future__ import annotations

import gc
import warnings
from importlib import resources

from chaintwin.store.forkserver import import_main, pin_threads

pin_threads()  # before numpy is loaded here: the workers inherit its BLAS

from chaintwin.read.profile import load_profile  # noqa: E402
from chaintwin.store.worker import prepare  # noqa: E402

__all__ = ["warm_up"]

EXAMPLE = "white-belt-01-40kg.csv"
"""The bundled recording read once."""

EXAMPLE_PROFILE = "white-belt-01.yaml"
"""Its bundled profile."""


def warm_up() -> bool:
    """Run the read, validation and packing steps once on a bundled recording.

    Returns
    -------
    bool
        True when it ran; False when the example could not be read (the
        workers then load the compiled code on their first recording, which
        is slower, not wrong).
    """
    try:
        examples = resources.files("chaintwin.examples")
        with (
            resources.as_file(examples / "recordings" / EXAMPLE) as rec,
            resources.as_file(examples / "profiles" / EXAMPLE_PROFILE) as prof,
            warnings.catch_warnings(),
        ):
            warnings.simplefilter("ignore")
            done = prepare(str(rec), load_profile(prof), None, None)
        return done.recording is not None
    except Exception:  # a warm-up must never stop the fork server
        return False


import_main()
warm_up()
# the fork server's objects are the workers' too: frozen, no collection in a
# worker traverses them, so their pages stay shared instead of being copied
# (gc.freeze's own advice for processes that fork)
gc.collect()
gc.freeze()
