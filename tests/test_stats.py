"""The lean medians give numpy's numbers bit for bit (chaintwin._stats)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from chaintwin._stats import (
    column_medians,
    median,
    phase_bins,
    subtract_bin_medians,
    subtract_binned_medians,
)

floats = st.floats(allow_nan=True, allow_infinity=True, width=64)


@settings(max_examples=300, deadline=None)
@given(arrays(np.float64, st.integers(1, 60), elements=floats))
def test_median_is_numpys(x: np.ndarray) -> None:
    with np.errstate(all="ignore"):
        want = np.median(x)
        got = median(x)
    assert (np.isnan(want) and np.isnan(got)) or got == want
    assert np.signbit(got) == np.signbit(want) or np.isnan(want)


def test_median_of_a_strided_view_and_of_nothing() -> None:
    x = np.arange(20.0)[::3]
    assert median(x) == np.median(x)
    with pytest.warns(RuntimeWarning):
        assert np.isnan(median(np.array([], dtype=np.float64)))


@settings(max_examples=200, deadline=None)
@given(
    arrays(np.float64, st.integers(1, 80), elements=floats),
    st.integers(1, 9),
    st.randoms(use_true_random=False),
)
def test_bin_medians_are_numpys(x: np.ndarray, bins: int, rnd: object) -> None:
    idx = np.array([rnd.randrange(bins) for _ in range(x.shape[0])], dtype=np.intp)  # type: ignore[attr-defined]
    members = np.argsort(idx, kind="stable")
    bounds = np.searchsorted(idx[members], np.arange(bins + 1))
    want = x.copy()
    with np.errstate(all="ignore"):  # inf - inf, huge + huge: the same NaN and inf both ways
        for b in range(bins):
            m = members[bounds[b] : bounds[b + 1]]
            if m.size:
                want[m] -= np.median(want[m])
    got = x.copy()
    subtract_bin_medians(got, members, bounds)
    assert np.array_equal(got, want, equal_nan=True)


@pytest.mark.parametrize("seed", range(20))
def test_binned_medians_group_as_a_stable_argsort(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n, bins = int(rng.integers(1, 3000)), int(rng.integers(1, 64))
    idx = rng.integers(0, bins, size=n)
    x = rng.normal(size=n)
    x[rng.random(n) < 0.01] = np.nan
    want, got = x.copy(), x.copy()
    members = np.argsort(idx, kind="stable")
    subtract_bin_medians(want, members, np.searchsorted(idx[members], np.arange(bins + 1)))
    subtract_binned_medians(got, idx, bins)
    np.testing.assert_array_equal(got, want)
    # out of range (as a NaN angle gives): numpy's grouping
    idx[0] = -5
    want, got = x.copy(), x.copy()
    members = np.argsort(idx, kind="stable")
    subtract_bin_medians(want, members, np.searchsorted(idx[members], np.arange(bins + 1)))
    subtract_binned_medians(got, idx, bins)
    np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("seed", range(20))
def test_column_medians_are_numpys(seed: int) -> None:
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(int(rng.integers(1, 12)), int(rng.integers(1, 300))))
    x[rng.random(x.shape) < 0.02] = np.nan
    x[rng.random(x.shape) < 0.05] = -0.0
    x[rng.random(x.shape) < 0.05] = 0.0
    want = np.median(x, axis=0)
    got = column_medians(x)
    np.testing.assert_array_equal(got, want)
    assert np.array_equal(np.signbit(got), np.signbit(want))


@pytest.mark.parametrize("seed", range(30))
def test_phase_bins_are_numpys(seed: int) -> None:
    rng = np.random.default_rng(seed)
    step = rng.choice([1e-3, 1e-2, 0.1, 1.0]) * rng.choice([1.0, -1.0])
    turned = np.cumsum(rng.normal(1.0, 0.3, size=int(rng.integers(1, 5000)))) * step
    order = float(rng.choice([0.0322683949675943, 0.3226839496759436, 1.0, rng.random() * 5]))
    bins = int(rng.integers(4, 65))
    phase = np.mod(order * turned, 2.0 * np.pi)
    want = np.minimum((phase / (2.0 * np.pi) * bins).astype(np.intp), bins - 1)
    np.testing.assert_array_equal(phase_bins(turned, order, bins), want)


def test_phase_bins_on_whole_turns() -> None:
    turned = np.arange(-1000, 1000) * (2.0 * np.pi / 7.0)
    for order in (1.0, 7.0, 0.5):
        phase = np.mod(order * turned, 2.0 * np.pi)
        want = np.minimum((phase / (2.0 * np.pi) * 16).astype(np.intp), 15)
        np.testing.assert_array_equal(phase_bins(turned, order, 16), want)


@pytest.mark.parametrize("seed", range(10))
def test_running_integrals_are_numpys_cumsum(seed: int) -> None:
    from chaintwin.model.windows import _running_integrals

    rng = np.random.default_rng(seed)
    n, m = int(rng.integers(1, 3000)), int(rng.integers(1, 11))
    t = np.cumsum(rng.random(n))
    w, gf = rng.normal(size=n), rng.normal(size=n)
    f = rng.normal(size=(n, m))
    f[rng.random((n, m)) < 0.05] = -0.0
    w[rng.random(n) < 0.05] = -0.0
    h = np.diff(t)
    steps = np.empty((h.shape[0], m + 2))
    np.multiply(0.5 * (f[1:] + f[:-1]), h[:, None], out=steps[:, :m])
    steps[:, m] = 0.5 * (gf[1:] + gf[:-1]) * np.diff(w)
    steps[:, m + 1] = np.abs(0.5 * (w[1:] + w[:-1])) * h
    want = np.empty((n, m + 4))
    want[:, 0], want[:, 1], want[0, 2:] = t, w, 0.0
    np.cumsum(steps, axis=0, out=want[1:, 2:])
    got = _running_integrals(np.ascontiguousarray(f.T), t, w, gf, h)
    np.testing.assert_array_equal(got, want)
    assert np.array_equal(np.signbit(got), np.signbit(want))


@pytest.mark.parametrize("seed", range(10))
def test_near_any_is_numpys(seed: int) -> None:
    from chaintwin.diagnose.peaks import _near_any

    rng = np.random.default_rng(seed)
    x = np.linspace(0.0, 83.3, int(rng.integers(1, 600)))
    centres = rng.random(int(rng.integers(0, 80))) * 90.0
    centres[: min(3, centres.shape[0])] = x[rng.integers(0, x.shape[0], min(3, centres.shape[0]))]
    width = float(rng.integers(1, 4)) * (x[1] - x[0] if x.shape[0] > 1 else 0.1)
    want = (np.abs(x[:, None] - centres[None, :]) <= width).any(axis=1)
    np.testing.assert_array_equal(_near_any(x, centres, width), want)
