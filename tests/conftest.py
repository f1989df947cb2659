"""Shared fixtures: hand-made recordings in the data-contract format, and a PostgreSQL
server with an empty store on it (or on SQLite)."""

from __future__ import annotations

import os
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from threadpoolctl import threadpool_limits

from chaintwin.read.profile import ConveyorProfile, load_profile
from chaintwin.testing.postgres import free_port, postgres_binaries, throwaway_postgres

# One BLAS thread: the machine's cores are shared with the processes the tests start
# (workers, servers), and a multi-threaded BLAS on small matrices only contends for them.
# The environment variables reach those processes; threadpoolctl pins this one, whose
# BLAS may already be loaded by the time this file is read.
for _variable in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_variable, "1")
threadpool_limits(limits=1)

EXAMPLES = Path(__file__).resolve().parents[1] / "chaintwin" / "examples"
REFERENCE_PROFILE = EXAMPLES / "profiles" / "white-belt-01.yaml"

HEADER = (
    "time [s],speed_setpoint [rpm],speed [rpm],position_setpoint [inc],position [inc],"
    "torque_setpoint [%],torque [%],digital_inputs [-]"
)


def trapezoid_rpm(
    n: int = 400,
    dt: float = 0.006,
    peak: float = 1415.0,
    ramp_s: float = 0.5,
    lead_s: float = 0.1,
    hold_s: float = 1.0,
    direction: int = 1,
) -> tuple[np.ndarray, np.ndarray]:
    """Return (time s, speed set point rpm) of a trapezoid move inside n samples."""
    t = np.arange(n) * dt
    up = np.clip((t - lead_s) / ramp_s, 0.0, 1.0)
    down = np.clip((t - lead_s - ramp_s - hold_s) / ramp_s, 0.0, 1.0)
    return t, direction * peak * (up - down)


def make_text(
    *,
    n: int = 400,
    dt: float = 0.006,
    seed: int = 1,
    direction: int = 1,
    meta: dict[str, str] | None = None,
    noise_rpm: float = 2.0,
    lead_s: float = 0.1,
    hold_s: float = 1.0,
) -> str:
    """A plausible recording: trapezoid set point, lagging speed, torque in %."""
    rng = np.random.default_rng(seed)
    t, wsp = trapezoid_rpm(n, dt, lead_s=lead_s, hold_s=hold_s, direction=direction)
    w = np.convolve(wsp, np.ones(3) / 3, mode="same") + rng.normal(0, noise_rpm, n)
    w[wsp == 0] = rng.normal(0, 0.2, int((wsp == 0).sum()))
    inc = 4096.0
    possp = np.round(np.cumsum(wsp) * dt / 60.0 * inc) + 1000
    pos = np.round(np.cumsum(w) * dt / 60.0 * inc) + 1000
    acc = np.gradient(wsp, t)
    tsp = 27.0 * np.sign(wsp) + 0.04 * acc * (wsp != 0)
    tq = tsp + rng.normal(0, 0.5, n)
    di = (np.abs(wsp) > 0).astype(int)
    head = {
        "conveyor": "white-belt-01",
        "recorded_at": "2026-11-21T10:15:00Z",
        "sample_time_s": f"{dt}",
        "nominal_torque_nm": "2.5",
        "increments_per_rev": "4096",
    }
    head.update(meta or {})
    lines = [f"# {k}: {v}" for k, v in head.items()]
    lines.append(HEADER)
    for row in zip(t, wsp, w, possp, pos, tsp, tq, di, strict=True):
        lines.append(
            f"{row[0]:.3f},{row[1]:.1f},{row[2]:.1f},{row[3]:.0f},{row[4]:.0f},"
            f"{row[5]:.2f},{row[6]:.2f},{row[7]}"
        )
    return "\n".join(lines) + "\n"


def to_semicolon(text: str) -> str:
    """Convert a ',' dialect text to the ';' dialect with ',' decimals (data lines only)."""
    out = []
    for line in text.split("\n"):
        if line.startswith("#") or "[" in line:
            out.append(line.replace(",", ";") if "[" in line else line)
        else:
            out.append(line.replace(",", ";").replace(".", ","))
    return "\n".join(out)


@pytest.fixture
def reference_profile() -> ConveyorProfile:
    """The published reference conveyor's profile."""
    return load_profile(REFERENCE_PROFILE)


@pytest.fixture
def rec_text() -> str:
    """A complete 400-sample recording at 6 ms in the ',' dialect."""
    return make_text()


@pytest.fixture
def write(tmp_path: Path):  # type: ignore[no-untyped-def]
    """Write text to a file in tmp_path and return its path."""

    def _write(text: str | bytes, name: str = "rec.csv") -> Path:
        p = tmp_path / name
        if isinstance(text, bytes):
            p.write_bytes(text)
        else:
            p.write_text(text, encoding="utf-8")
        return p

    return _write


# ---------------------------------------------------------------- servers
_free_port = free_port  # the name the tests import


@pytest.fixture(scope="session")
def postgres() -> Iterator[str]:
    """A PostgreSQL server of our own on a free port, one per test session (CI installs
    the binaries)."""
    bindir = postgres_binaries()
    if bindir is None:
        pytest.fail(
            "PostgreSQL server binaries (initdb, pg_ctl) not found: `.ci/run` installs them "
            "(apt-get install postgresql)"
        )
    with throwaway_postgres(bindir) as url:
        yield url


@pytest.fixture(params=["sqlite", "postgresql"])
def db(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[str]:
    """An empty store: a SQLite file, or a fresh database on the PostgreSQL server."""
    if request.param == "sqlite":
        yield f"sqlite:///{tmp_path / 'plant.db'}"
        return
    base: str = request.getfixturevalue("postgres")
    import psycopg

    name = f"t{os.getpid()}_{int(time.time() * 1e6) % 10**9}"
    with psycopg.connect(base.replace("postgresql://", "postgresql://", 1), autocommit=True) as c:
        c.execute(f"CREATE DATABASE {name}")
    yield base.rsplit("/", 1)[0] + "/" + name


# ---------------------------------------------------------------- markers
def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Mark every test that needs the PostgreSQL server ``postgres``: it asks for the
    ``postgres`` fixture (itself or through another fixture), or runs with a store
    fixture's ``postgresql`` parameter (``make test-fast`` leaves them out)."""
    for item in items:
        callspec = getattr(item, "callspec", None)
        params = callspec.params.values() if callspec is not None else ()
        on_postgresql = any(isinstance(v, str) and v == "postgresql" for v in params)
        if "postgres" in getattr(item, "fixturenames", ()) or on_postgresql:
            item.add_marker(pytest.mark.postgres)
