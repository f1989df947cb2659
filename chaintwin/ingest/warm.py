"""Warm-up of the fork server that starts ingest's local worker processes.

The fork server imports this module before it forks any worker
(``multiprocessing``'s preload). Importing it

* imports the script that started the ingest, as each worker would
  otherwise do on its own (:func:`chaintwin.ingest.forkserver.import_main`);
* imports the pipeline, calibrates from the two bundled calibration
  recordings and runs the whole worker part (read, validate, weigh,
  features) on one bundled example recording, so that numba's compiled
  parser is loaded from its cache here, once (about 0.1 s), and the
  filters' and fits' first-use caches are filled here (a worker's first
  recording took 4 ms more without them); every forked worker starts with
  all that in memory;
* freezes the garbage collector's view of all that (:func:`gc.freeze`), so
  that a worker's collections do not write to the pages it shares with the
  fork server (each page written is copied first).
"""

from __future__ import annotations

import gc
import warnings
from importlib import resources

from chaintwin.ingest.forkserver import import_main, pin_threads

pin_threads()  # before numpy is loaded here: the workers inherit its BLAS

from chaintwin.calibrating.procedure import calibrate  # noqa: E402
from chaintwin.ingest.worker import prepare  # noqa: E402
from chaintwin.read.profile import load_profile  # noqa: E402
from chaintwin.validate.checks import load_recording  # noqa: E402

__all__ = ["warm_up"]

EXAMPLE = "white-belt-01-40kg.csv"
"""The bundled recording read once."""

EXAMPLE_PROFILE = "white-belt-01.yaml"
"""Its bundled profile."""

EXAMPLE_CALIBRATION = ("white-belt-01-cal-empty.csv", "white-belt-01-cal-50kg.csv")
"""The bundled calibration recordings of that conveyor (an empty tray and 50 kg)."""


def warm_up() -> bool:
    """Run a worker's part once on a bundled recording, with a calibration.

    Returns
    -------
    bool
        True when it ran to the features; False when the examples could not
        be read or calibrated (the workers then load the compiled code and
        fill the caches on their first recording, which is slower, not
        wrong).
    """
    try:
        recordings = resources.files("chaintwin.examples") / "recordings"
        profiles = resources.files("chaintwin.examples") / "profiles"
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            with resources.as_file(profiles / EXAMPLE_PROFILE) as path:
                profile = load_profile(path)
            runs = []
            for name in EXAMPLE_CALIBRATION:
                with resources.as_file(recordings / name) as path:
                    runs.append(load_recording(path, profile=profile).recording)
            calibration = calibrate(runs, profile)
            with resources.as_file(recordings / EXAMPLE) as path:
                done = prepare(str(path), profile, None, calibration)
        return done.features is not None
    except Exception:  # a warm-up must never stop the fork server
        return False


import_main()
warm_up()
# the fork server's objects are the workers' too: frozen, no collection in a
# worker traverses them, so their pages stay shared instead of being copied
# (gc.freeze's own advice for processes that fork)
gc.collect()
gc.freeze()
