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
