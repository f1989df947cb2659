"""The public API is small, sorted and importable (httpx's exported-members test)."""

from __future__ import annotations

import chaintwin
from chaintwin import errors


def test_all_is_sorted_and_complete() -> None:
    names = chaintwin.__all__
    assert names == sorted(names)
    for name in names:
        assert hasattr(chaintwin, name), name
    import pkgutil

    public = {n for n in dir(chaintwin) if not n.startswith("_")}
    submodules = {m.name for m in pkgutil.iter_modules(chaintwin.__path__)}
    assert public - submodules - {"__version__"} <= set(names)


def test_error_tree_has_one_root() -> None:
    for name in errors.__all__:
        cls = getattr(errors, name)
        if name == "ConvergenceWarning":
            assert issubclass(cls, UserWarning)
            continue
        assert issubclass(cls, errors.ChaintwinError)
    assert issubclass(errors.RecordingError, errors.DataError)
    assert issubclass(errors.NotFittedError, errors.EstimationError)


SUBPACKAGES = (
    "calibrating",
    "diagnose",
    "identify",
    "ingest",
    "model",
    "read",
    "report",
    "simulate",
    "store",
    "validate",
    "weigh",
)


def isort_key(name: str) -> tuple[int, str]:
    """The order ruff keeps ``__all__`` in: CONSTANTS, then Classes, then functions."""
    if name.isupper() and len(name) > 1:
        return 0, name
    return (1 if name[0].isupper() else 2), name


def test_every_subpackage_exports_a_sorted_existing_all() -> None:
    import importlib

    for name in SUBPACKAGES:
        module = importlib.import_module(f"chaintwin.{name}")
        exported = module.__all__
        assert exported, name
        assert list(exported) == sorted(exported, key=isort_key), name
        for item in exported:
            assert hasattr(module, item), f"chaintwin.{name}.{item}"


def test_the_workflow_is_importable_from_the_top() -> None:
    # read → validate → calibrate → weigh, each step one import away; ``weigh``
    # is the subpackage, its function is chaintwin.weigh.weigh
    for name in ("load_profile", "load_recording", "calibrate", "load_calibration"):
        assert callable(getattr(chaintwin, name)), name
    assert chaintwin.calibrate is chaintwin.calibrating.calibrate
    assert callable(chaintwin.weigh.weigh)
    assert chaintwin.WeighResult is chaintwin.weigh.WeighResult
    from chaintwin.diagnose.monitor import ConveyorMonitor
    from chaintwin.store.store import Store

    assert chaintwin.ConveyorMonitor is ConveyorMonitor
    assert chaintwin.Store is Store
