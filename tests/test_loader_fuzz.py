"""Property tests of every loader but the recording reader's (test_reader_fuzz.py).

Whatever a profile, column map, calibration, state file or store URL holds,
loading it ends in a result or in the project's own error, within a time
bound (hypothesis' deadline: a hang fails) and a memory bound (tracemalloc:
an input of a few kB must not cost tens of MB).
"""

from __future__ import annotations

import json
import tracemalloc
from collections.abc import Callable, Iterator
from contextlib import contextmanager, nullcontext
from datetime import timedelta
from pathlib import Path
from typing import Any

import pytest
from conftest import REFERENCE_PROFILE
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from chaintwin.diagnose.monitor_state import MonitorState
from chaintwin.diagnose.state import load_state
from chaintwin.errors import ChaintwinError
from chaintwin.identify.calibration import Calibration, load_calibration
from chaintwin.read.columns import load_column_map
from chaintwin.read.files import yaml_load
from chaintwin.read.profile import load_profile, parse_profile
from chaintwin.store.store import Store
from chaintwin.weigh.zero_tracking import ZeroTracker

FUZZ = settings(
    max_examples=150,
    deadline=timedelta(seconds=5),  # a hang guard, not a speed target
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)
MEMORY_BOUND = 32 * 2**20
"""Most memory (bytes) one loader may take for an input of a few kB."""

JSON_LEAF = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(min_value=-(2**70), max_value=2**70),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=20),
)
JSON_VALUE = st.recursive(
    JSON_LEAF,
    lambda inner: st.one_of(
        st.lists(inner, max_size=4), st.dictionaries(st.text(max_size=10), inner, max_size=4)
    ),
    max_leaves=20,
)


@contextmanager
def bounded() -> Iterator[None]:
    """Fail when the block allocates more than :data:`MEMORY_BOUND` at its peak."""
    tracemalloc.start()
    try:
        yield
        _now, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < MEMORY_BOUND, f"peak {peak / 2**20:.0f} MB"


def ends_cleanly(load: Callable[[], Any]) -> None:
    """A result, or the project's error in one line; the second run within the memory bound.

    The first run is not measured: it may import modules and fill caches.
    """
    for measure in (False, True):
        with bounded() if measure else nullcontext():
            try:
                load()
            except ChaintwinError as exc:
                assert "\n" not in str(exc)


def mutated(base: Any, path: list[Any], value: Any) -> Any:
    """``base`` with the item at ``path`` (followed as far as it leads) replaced by ``value``."""
    copy = json.loads(json.dumps(base))
    node = copy
    for key in path[:-1]:
        listed = isinstance(node, list) and isinstance(key, int) and 0 <= key < len(node)
        if not (listed or (isinstance(node, dict) and key in node)):
            break
        node = node[key]
    last = path[-1] if path else None
    if isinstance(node, dict):
        node[last if last in node else next(iter(node), "x")] = value
    elif isinstance(node, list) and node:
        node[0] = value
    return copy


def _paths(base: Any, prefix: list[Any] | None = None) -> list[list[Any]]:
    """Every path to an item of a JSON value."""
    prefix = prefix or []
    out = [prefix] if prefix else []
    if isinstance(base, dict):
        for k, v in base.items():
            out += _paths(v, [*prefix, k])
    elif isinstance(base, list):
        for k, v in enumerate(base[:3]):
            out += _paths(v, [*prefix, k])
    return out


PROFILE_DICT = yaml_load(REFERENCE_PROFILE.read_text())
PROFILE_PATHS = _paths(PROFILE_DICT)


@FUZZ
@given(st.binary(max_size=3000))
def test_profile_files_of_any_bytes(tmp_path_factory: pytest.TempPathFactory, data: bytes) -> None:
    path = tmp_path_factory.mktemp("p") / "fuzz.yaml"
    path.write_bytes(data)
    ends_cleanly(lambda: load_profile(path))


@pytest.mark.slow
@FUZZ
@given(st.sampled_from(PROFILE_PATHS), JSON_VALUE)
def test_profiles_with_any_value_anywhere(path: list[Any], value: Any) -> None:
    ends_cleanly(lambda: parse_profile(mutated(PROFILE_DICT, path, value), "fuzz.yaml"))


@FUZZ
@given(st.one_of(st.binary(max_size=2000), JSON_VALUE.map(json.dumps).map(str.encode)))
def test_column_maps_of_any_content(tmp_path_factory: pytest.TempPathFactory, data: bytes) -> None:
    path = tmp_path_factory.mktemp("c") / "fuzz.yaml"
    path.write_bytes(data)
    ends_cleanly(lambda: load_column_map(path))


CALIBRATION_SHAPE = {
    "format": "chaintwin.calibration",
    "format_version": 1,
    "chaintwin_version": "0.1.0",
    "profile": PROFILE_DICT,
    "profile_sha256": "0" * 64,
    "parameters": {"mu": 0.1, "BmA": 0.2, "J_d": 1e-3, "gain": 1.0},
    "recordings": 3,
}


@FUZZ
@given(st.one_of(st.binary(max_size=2000), JSON_VALUE.map(json.dumps).map(str.encode)))
def test_calibration_files_of_any_content(
    tmp_path_factory: pytest.TempPathFactory, data: bytes
) -> None:
    path = tmp_path_factory.mktemp("k") / "fuzz.json"
    path.write_bytes(data)
    ends_cleanly(lambda: load_calibration(path))


@FUZZ
@given(st.sampled_from(_paths(CALIBRATION_SHAPE)), JSON_VALUE)
def test_calibrations_with_any_value_anywhere(path: list[Any], value: Any) -> None:
    ends_cleanly(lambda: Calibration.from_dict(mutated(CALIBRATION_SHAPE, path, value), "f"))


STATE_SHAPE = {
    "conveyor": "c",
    "profile_sha256": "0" * 64,
    "settings": {"baseline_n": 20, "x": 3, "y": 10, "z_limit": 5.0, "residual": "inverse"},
    "calibration": None,
    "calibration_source": "none",
    "pending": [{"path": "a.csv", "file": "a.csv", "sha256": "0", "warnings": []}],
    "baseline_rows": [],
    "late_rows": [],
    "baseline_spectra": [[[0.0, 1.0], [0.1, 0.2], 1400.0]],
    "baselines": None,
    "baseline_spectrum": None,
    "baseline_since": None,
    "belt_last": [],
    "belt_prev": [],
    "windows": {"friction": [True, False]},
    "window_times": {"friction": [None, None]},
    "alarms": [
        {
            "id": "a1",
            "conveyor": "c",
            "feature": "friction",
            "cause": "friction",
            "change": 0.5,
            "since": None,
            "opened_at": None,
            "last_seen": None,
            "status": "open",
            "acknowledged": {"by": "x", "why": "y", "at": "2026-01-01T00:00:00+00:00"},
            "rule": "x_of_y",
            "kind": "statistical",
            "lifecycle": "acknowledged",
            "evidence": [
                {
                    "feature": "friction",
                    "kind": "statistical",
                    "value": None,
                    "z": None,
                    "since": None,
                }
            ],
            "active": True,
            "shelved_until": None,
            "shelved": None,
            "out_of_service": False,
            "out_of_service_until": None,
            "comments": [],
        }
    ],
    "events": [
        {
            "id": "e1",
            "kind": "repair",
            "at": "2026-01-01T00:00:00+00:00",
            "by": "x",
            "why": "y",
            "recorded": "2026-01-01T00:00:00+00:00",
            "applied": False,
        }
    ],
    "history": [],
    "notes": [],
    "last_recorded_at": None,
    "out_of_service": None,
    "zero_tracking": {
        "version": 2,
        "at": "2026-01-01T06:00:00+00:00",
        "state": [0.01, 1e-8],
        "covariance": [[1e-4, 0.0], [0.0, 1e-12]],
        "innovations": [0.5],
        "warm": [[0.9, 0.3, 0.002, -0.01, 0.002]],
        "history": [[0.02, 0.003, 0.4, 0.002]],
        "reference_var": 1e-5,
    },
    "zero_tracking_undo": {
        "sha256": "ab" * 32,
        "before": {
            "version": 2,
            "at": None,
            "state": [0.0, 0.0],
            "covariance": [[0.0, 0.0], [0.0, 0.0]],
            "innovations": [],
            "warm": [],
            "history": [],
            "reference_var": 0.0,
        },
    },
}


def test_the_state_shape_is_a_valid_state() -> None:
    assert MonitorState.from_dict(STATE_SHAPE).to_dict() == STATE_SHAPE
    # a state written before the residual setting, the alarms' rule and their lifecycle
    # existed
    old = json.loads(json.dumps(STATE_SHAPE))
    del old["settings"]["residual"]
    del old["out_of_service"]
    del old["zero_tracking"], old["zero_tracking_undo"]
    lifecycle = ("lifecycle", "evidence", "active", "shelved_until", "shelved")
    for key in ("rule", "kind", *lifecycle, "out_of_service", "out_of_service_until", "comments"):
        del old["alarms"][0][key]
    assert MonitorState.from_dict(old).to_dict() == STATE_SHAPE | {
        "zero_tracking": ZeroTracker().to_dict(),
        "zero_tracking_undo": None,
    }


@FUZZ
@given(st.sampled_from(_paths(STATE_SHAPE)), JSON_VALUE)
def test_states_with_any_value_anywhere(path: list[Any], value: Any) -> None:
    ends_cleanly(lambda: MonitorState.from_dict(mutated(STATE_SHAPE, path, value)))


@FUZZ
@given(st.one_of(st.binary(max_size=2000), JSON_VALUE.map(json.dumps).map(str.encode)))
def test_state_files_of_any_content(tmp_path_factory: pytest.TempPathFactory, data: bytes) -> None:
    path = tmp_path_factory.mktemp("s") / "state.json"
    path.write_bytes(data)
    ends_cleanly(lambda: load_state(path))


URL = st.one_of(
    st.text(max_size=60),
    st.builds(
        "{}://{}".format,
        st.sampled_from(["sqlite", "sqlite+pysqlite", "mysql", "nosuchdb", "http", "file"]),
        st.text(max_size=40),
    ),
)


@pytest.mark.slow
@FUZZ
@given(URL)
def test_store_urls_of_any_text(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, url: str) -> None:
    monkeypatch.chdir(tmp_path)  # whatever a URL creates stays here

    def open_and_close() -> None:
        Store(url, create=False).close()

    ends_cleanly(open_and_close)
