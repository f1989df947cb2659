"""The estimator contract, checked over every estimator (docs/design.md, section 4).

* ``__init__`` takes keyword-only settings, stores each under its own name
  and does nothing else (no validation, no state): a setting's check
  happens in ``fit``.
* ``fit`` returns ``self``.
* Fitted values are public names ending in ``_``; before ``fit`` they raise
  :class:`~chaintwin.errors.NotFittedError`, after it they have values.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest
from conftest import REFERENCE_PROFILE

from chaintwin.errors import NotFittedError
from chaintwin.identify import (
    OutputErrorFit,
    RecursiveLeastSquares,
    RigidModelRegression,
    TorqueLagEstimator,
    simulate_torque_lag,
)
from chaintwin.read.profile import load_profile
from chaintwin.simulate import Realism, run_virtual

PROFILE = load_profile(REFERENCE_PROFILE)


def _fit_rigid(est: Any) -> Any:
    recs = [
        run_virtual(
            PROFILE, payload_kg=load, seed=900 + k, sample_time_s=0.006, calibration=True
        ).recording
        for k, load in enumerate((0.0, 50.0))
    ]
    return est.fit(recs, PROFILE)


def _fit_rls(est: Any) -> Any:
    rng = np.random.default_rng(3)
    x = rng.normal(size=(50, 2))
    return est.fit(x, x @ np.array([1.5, -0.5]) + rng.normal(0, 0.01, 50))


def _fit_lag(est: Any) -> Any:
    t = np.arange(40) * 1e-3
    sp = np.where(t >= 0.01, 2.0, 0.0)
    return est.fit(t, sp, simulate_torque_lag(sp, tau_s=0.98e-3, cycle_s=1e-3))


def _fit_oe(est: Any) -> Any:
    run = run_virtual(PROFILE, payload_kg=20.0, seed=7, realism=Realism.off(), sample_time_s=0.006)
    return est.fit(run.recording, PROFILE, payload_kg=20.0)


ESTIMATORS: dict[type, Callable[[Any], Any]] = {
    RigidModelRegression: _fit_rigid,
    RecursiveLeastSquares: _fit_rls,
    TorqueLagEstimator: _fit_lag,
    OutputErrorFit: _fit_oe,
}


def _settings(cls: type) -> list[inspect.Parameter]:
    return [p for p in inspect.signature(cls.__init__).parameters.values() if p.name != "self"]


def _fitted_names(cls: type) -> list[str]:
    return sorted(
        name
        for name in dir(cls)
        if name.endswith("_") and not name.startswith("_") and not name.endswith("__")
    )


@pytest.mark.parametrize("cls", list(ESTIMATORS), ids=lambda c: c.__name__)
def test_init_only_stores_keyword_only_settings(cls: type) -> None:
    settings = _settings(cls)
    assert settings, f"{cls.__name__} has no settings"
    for p in settings:
        assert p.kind is inspect.Parameter.KEYWORD_ONLY, p.name
        assert p.default is not inspect.Parameter.empty, p.name
    est = cls()
    assert vars(est) == {p.name: p.default for p in settings}
    # no validation in __init__: an absurd value is stored as it is
    odd = object()
    for p in settings:
        assert getattr(cls(**{p.name: odd}), p.name) is odd


@pytest.mark.parametrize("cls", list(ESTIMATORS), ids=lambda c: c.__name__)
def test_fitted_values_end_in_underscore_and_need_fit(cls: type) -> None:
    names = _fitted_names(cls)
    assert names, f"{cls.__name__} declares no fitted values"
    unfitted = cls()
    for name in names:
        with pytest.raises(NotFittedError):
            getattr(unfitted, name)
    est = cls()
    assert ESTIMATORS[cls](est) is est
    settings = {p.name for p in _settings(cls)}
    added = {k for k in vars(est) if not k.startswith("_")} - settings
    assert all(k.endswith("_") for k in added), f"fit set public names without '_': {added}"
    for name in [*names, *added]:
        assert getattr(est, name) is not None, name
