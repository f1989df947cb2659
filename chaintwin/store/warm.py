"""Warm-up of the fork server that starts ingest's local worker processes.

The fork server imports this module before it forks any worker
(``multiprocessing``'s preload). Importing it imports the pipeline and reads
and validates one bundled example recording, so that numba's compiled
parser is loaded from its cache here, once (about 0.1 s), and every forked
worker starts with it in memory instead of loading it on its first
recording.
"""

from __future__ import annotations

import warnings
from importlib import resources

from chaintwin.read.profile import load_profile
from chaintwin.store.ingest import prepare

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


warm_up()
