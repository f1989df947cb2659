"""Hostile stores and outputs: foreign, damaged and read-only stores; full disks, closed pipes."""

from __future__ import annotations

import errno
import json
import os
import shutil
import sqlite3
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from conftest import EXAMPLES, REFERENCE_PROFILE
from hypothesis import given
from hypothesis import strategies as st
from test_loader_fuzz import FUZZ, JSON_VALUE, _paths, mutated

from chaintwin.cli.app import main
from chaintwin.diagnose.alarms import close_quiet_alarms, judge
from chaintwin.diagnose.impacts import background_hits_per_m
from chaintwin.diagnose.monitor_state import MonitorState, read_health
from chaintwin.diagnose.state import STATE_FORMAT, STATE_VERSION
from chaintwin.diagnose.verdict import verdict
from chaintwin.errors import StoreError
from chaintwin.read.profile import load_profile
from chaintwin.store.store import Store

PROFILE = load_profile(REFERENCE_PROFILE)
RECORDING = EXAMPLES / "recordings" / "white-belt-01-40kg.csv"
CALIBRATION_RUNS = [
    EXAMPLES / "recordings" / "white-belt-01-cal-empty.csv",
    EXAMPLES / "recordings" / "white-belt-01-cal-50kg.csv",
]


def _commands(url: str, tmp: Path) -> dict[str, list[str]]:
    """Every command that opens a results store, with ``--db url``."""
    return {
        "ingest": ["ingest", str(RECORDING), "--profile", str(REFERENCE_PROFILE), "--db", url],
        "db upgrade": ["db", "upgrade", "--db", url],
        "token create": ["token", "create", "--name", "someone", "--db", url],
        "token list": ["token", "list", "--db", url],
        "token revoke": ["token", "revoke", "someone", "--db", url],
        "refused list": ["refused", "list", "--db", url],
        "refused retry": ["refused", "retry", "--db", url],
        "export": ["export", "--db", url],
        "report": ["report", "--fleet", "--db", url, "--out", str(tmp / "fleet.html")],
        "maintenance": [
            *("maintenance", "--conveyor", PROFILE.id, "--kind", "chain_replaced"),
            *("--by", "me", "--db", url),
        ],
        "acknowledge": ["acknowledge", "a1b2c3d4", "--by", "me", "--db", url],
        "calibrate": [
            "calibrate",
            *map(str, CALIBRATION_RUNS),
            *("--profile", str(REFERENCE_PROFILE), "--db", url),
        ],
        "serve": ["serve", "--db", url, "--no-web"],
    }


def _listing(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.is_file()}


@pytest.mark.slow
def test_every_command_refuses_a_foreign_sqlite_file_leaving_its_bytes_as_they_were(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    folder = tmp_path / "db"
    folder.mkdir()
    foreign = folder / "crm.db"
    con = sqlite3.connect(foreign)
    con.execute("CREATE TABLE customers (id INTEGER PRIMARY KEY, name TEXT)")
    con.execute("INSERT INTO customers (name) VALUES ('ACME')")
    con.commit()
    con.close()
    before = _listing(folder)
    assert before["crm.db"][:16] == b"SQLite format 3\x00"
    for name, argv in _commands(f"sqlite:///{foreign}", tmp_path).items():
        capsys.readouterr()
        assert main(argv) == 2, name
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1, (name, err)
        assert "other tables than a chaintwin store's (customers)" in err, (name, err)
        assert _listing(folder) == before, name  # no byte changed, no WAL or journal left


def _store(path: Path) -> Path:
    store = Store(f"sqlite:///{path}")
    store.put_profile(PROFILE)
    store.close()
    return path


def _damaged(good: bytes) -> dict[str, bytes]:
    page = 4096
    header = bytearray(good)
    header[:16] = b"SQLite format 2\x00"
    odd_page = bytearray(good)
    odd_page[16:18] = (1000).to_bytes(2, "big")
    return {
        "truncated": good[: len(good) // 2],
        "corrupt header": bytes(header),
        "corrupt page size": bytes(odd_page),
        "text file": b"conveyor,payload\nwhite-belt-01,40\n" * 200,
        "overwritten pages": good[: 2 * page]
        + bytes(range(256)) * (page // 256)
        + good[3 * page :],
    }


def test_db_upgrade_refuses_a_damaged_store_in_one_line_and_changes_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    good = _store(tmp_path / "good.db").read_bytes()
    for name, content in _damaged(good).items():
        path = tmp_path / f"{name.replace(' ', '-')}.db"
        path.write_bytes(content)
        capsys.readouterr()
        assert main(["db", "upgrade", "--db", f"sqlite:///{path}"]) == 2, name
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and "Traceback" not in err, (name, err)
        assert "damaged" in err or "not a usable SQLite database" in err, (name, err)
        assert path.read_bytes() == content, name
    # the good one: checked, then nothing to do
    path = tmp_path / "good.db"
    assert main(["db", "upgrade", "--db", f"sqlite:///{path}"]) == 0
    assert "already; nothing to do" in capsys.readouterr().out


@pytest.fixture
def read_only_mount(tmp_path: Path) -> Iterator[Path]:
    """A small tmpfs, mounted read-only after a store was copied onto it (root only)."""
    if os.geteuid() != 0 or shutil.which("mount") is None:
        pytest.skip("mounting a file system needs root")
    mnt = tmp_path / "mnt"
    mnt.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=4m", "tmpfs", str(mnt)]).returncode:
        pytest.skip("cannot mount a tmpfs here")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", str(mnt)], check=True)


def test_a_store_on_a_read_only_file_system_is_exported_and_reported(
    tmp_path: Path, read_only_mount: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    src = _store(tmp_path / "plant.db")
    shutil.copy(src, read_only_mount / "plant.db")
    subprocess.run(["mount", "-o", "remount,ro", str(read_only_mount)], check=True)
    url = f"sqlite:///{read_only_mount / 'plant.db'}"
    capsys.readouterr()
    assert main(["export", "--db", url, "--format", "json"]) == 0
    assert capsys.readouterr().out.strip() == "[]"
    out = tmp_path / "fleet.html"
    assert main(["report", "--fleet", "--db", url, "--out", str(out)]) == 0
    assert PROFILE.id in out.read_text(encoding="utf-8")
    # a command that writes says why it cannot, in one line
    assert main(["token", "create", "--name", "x", "--db", url]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err


# ---------------------------------------------------------------- outputs
def _run(argv: list[str], **kw: object) -> subprocess.Popen[bytes]:
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[1]))
    return subprocess.Popen(
        [sys.executable, "-m", "chaintwin", *argv],
        stderr=subprocess.PIPE,
        env=env,
        **kw,  # type: ignore[call-overload]
    )


@pytest.mark.slow
def test_output_to_a_full_disk_is_one_line_and_exit_1(tmp_path: Path) -> None:
    url = f"sqlite:///{_store(tmp_path / 'plant.db')}"
    for argv in (
        ["export", "--db", url, "--format", "json"],
        ["inspect", "--json", str(RECORDING)],
    ):
        with open("/dev/full", "wb") as full:
            proc = _run(argv, stdout=full)
            _, err = proc.communicate(timeout=300)
        text = err.decode().strip()
        assert proc.returncode == 1, (argv[0], text)
        assert len(text.splitlines()) == 1 and "No space left on device" in text, text


@pytest.mark.slow
def test_a_closed_pipe_ends_the_command_quietly(tmp_path: Path) -> None:
    url = f"sqlite:///{_store(tmp_path / 'plant.db')}"
    proc = _run(["export", "--db", url, "--format", "json"], stdout=subprocess.PIPE)
    assert proc.stdout is not None
    proc.stdout.close()  # the reader is gone before anything is written (`| head -0`)
    _, err = proc.communicate(timeout=300)
    assert proc.returncode in (0, 141), err.decode()
    assert err.decode() == ""


class _FullDisk:
    """A standard output on a full disk."""

    def write(self, _text: str) -> int:
        raise OSError(errno.ENOSPC, "No space left on device")

    def flush(self) -> None:
        pass


def test_a_full_disk_met_inside_a_command_is_one_line(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    url = f"sqlite:///{_store(tmp_path / 'plant.db')}"
    capsys.readouterr()
    monkeypatch.setattr(sys, "stdout", _FullDisk())
    assert main(["export", "--db", url, "--format", "csv"]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith("chaintwin: error: cannot write the output: No space left on device")
    assert len(err.splitlines()) == 1


def test_store_strings_are_printed_without_their_control_characters(
    capsys: pytest.CaptureFixture[str],
) -> None:
    from chaintwin.cli.common import print_json
    from chaintwin.cli.store_cmd import _csv

    hostile = "belt\x1b]0;owned\x07\x9b2J\r"
    text = _csv([{"conveyor": hostile, "file": hostile, "features": {}}])
    assert not any(c in text for c in "\x1b\x07\x9b\r")
    assert "belt\ufffd]0;owned\ufffd\ufffd2J\ufffd" in text
    print_json({"conveyor": hostile})
    out = capsys.readouterr().out
    assert not any(c in out for c in "\x1b\x07\x9b\r")
    assert json.loads(out) == {"conveyor": hostile}  # escaped, not lost


# ---------------------------------------------------------------- bounded numbers
FIXTURE_STORE = Path(__file__).parent / "fixtures" / "store-c909904.sqlite"


def _fixture_state() -> dict[str, Any]:
    """A real health model (baselines, windows, alarms, history) from the fixture store."""
    con = sqlite3.connect(f"file:{FIXTURE_STORE}?immutable=1", uri=True)  # leaves no -wal
    try:
        (text,) = con.execute("SELECT state FROM monitor_states ORDER BY conveyor_id").fetchone()
    finally:
        con.close()
    state: dict[str, Any] = json.loads(text)
    return state


STATE = _fixture_state()


def test_a_huge_integer_in_a_profile_calibration_or_state_is_one_line_naming_its_field(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    huge = "9" * 5000
    profile = tmp_path / "huge.yaml"
    profile.write_text(
        REFERENCE_PROFILE.read_text().replace("  teeth: 10", f"  teeth: {huge}"), encoding="utf-8"
    )
    calibration = tmp_path / "cal.json"
    calibration.write_text(
        json.dumps({"format": "chaintwin-calibration", "format_version": "HUGE"}).replace(
            '"HUGE"', huge
        )
    )
    state = tmp_path / "state.json"
    state.write_text(
        json.dumps(
            {"format": STATE_FORMAT, "format_version": 1, "conveyors": {"a": {"x": [1, "HUGE"]}}}
        ).replace('"HUGE"', "-" + huge)
    )
    cases = {
        "sprocket.teeth": ["monitor", str(RECORDING), "--profile", str(profile)],
        "format_version": [
            *("monitor", str(RECORDING), "--profile", str(REFERENCE_PROFILE)),
            *("--calibration", str(calibration)),
        ],
        "conveyors.a.x.1": [
            *("monitor", str(RECORDING), "--profile", str(REFERENCE_PROFILE)),
            *("--state", str(state)),
        ],
    }
    for field, argv in cases.items():
        capsys.readouterr()
        assert main(argv) == 2, field
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1, err
        assert f"field '{field}': an integer of about 500" in err, err
        assert "at most 19 digits" in err


@pytest.mark.parametrize(
    ("key", "value", "field"),
    [
        ("baseline_rows", "x", "baseline_rows"),
        ("windows", {"comb_rotor": "abc"}, "windows.comb_rotor"),
        ("window_times", {"comb_rotor": [1]}, "window_times.comb_rotor.0"),
        ("belt_last", [0.1, "0.2"], "belt_last.1"),
        ("settings", {"baseline_n": 10**30, "x": 3, "y": 10, "z_limit": 5.0}, "baseline_n"),
        ("history", [{"file": "a.csv", "features": {"tlf": "high"}}], "history.0.features.tlf"),
    ],
)
def test_a_tampered_state_field_is_refused_in_one_line_naming_it(
    key: str, value: Any, field: str
) -> None:
    tampered = json.loads(json.dumps(STATE))
    tampered[key] = value
    with pytest.raises(StoreError) as caught:
        MonitorState.from_dict(tampered, source="state.json")
    message = str(caught.value)
    assert "\n" not in message and message.startswith("state.json: monitoring state of")
    assert field in message, message


def test_a_tampered_state_file_is_refused_by_monitor_before_any_recording(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    entry = json.loads(json.dumps(STATE)) | {"windows": {"comb_rotor": "abc"}}
    entry["conveyor"] = PROFILE.id
    state = tmp_path / "state.json"
    state.write_text(
        json.dumps(
            {
                "format": STATE_FORMAT,
                "format_version": STATE_VERSION,
                "conveyors": {PROFILE.id: entry},
            }
        )
    )
    before = state.read_bytes()
    capsys.readouterr()
    argv = ["monitor", str(RECORDING), "--profile", str(REFERENCE_PROFILE), "--state", str(state)]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "field 'windows.comb_rotor'" in err, err
    assert state.read_bytes() == before


STATE_PATHS = _paths(STATE)


@pytest.mark.slow
@FUZZ
@given(st.sampled_from(STATE_PATHS), JSON_VALUE)
def test_a_tampered_state_is_refused_in_one_line_or_works_everywhere_it_is_used(
    path: list[Any], value: Any
) -> None:
    """Fuzz-ish: any value anywhere in a real state; what is accepted must be usable."""
    tampered = mutated(STATE, path, value)
    try:
        state = MonitorState.from_dict(tampered, source="state.json")
    except StoreError as exc:
        assert "\n" not in str(exc)
        return
    read_health(state, bands=True)
    verdict(state)
    background_hits_per_m(state.baseline_rows + state.late_rows)
    close_quiet_alarms(state.alarms, state.windows, state.settings.y, None)
    if state.baselines and state.baseline_rows:
        values = {k: v for k, v in state.baseline_rows[-1].items() if v is not None}
        judge(state.baselines, values, state.windows, state.window_times, state.settings, None)


# ---------------------------------------------------------------- dates
OUT_OF_SPAN = ["0001-01-01T00:00:00", "9999-12-31T23:59:59-05:00", "1969-12-31T23:59:59+00:00"]


def _monitored_store(tmp_path: Path) -> tuple[str, str]:
    """A store with a health model (the fixture store, upgraded): its URL and a conveyor."""
    path = tmp_path / "monitored.db"
    shutil.copy(FIXTURE_STORE, path)
    url = f"sqlite:///{path}"
    assert main(["db", "upgrade", "--db", url]) == 0
    with Store(url) as store:
        conveyor = store.conveyors()[0]
    return url, conveyor


@pytest.mark.slow
def test_maintenance_dated_outside_1970_2200_is_refused_by_the_api_with_422(
    tmp_path: Path,
) -> None:
    import httpx
    from test_web import start_server

    from chaintwin.web.access import create_token
    from chaintwin.web.app import create_app

    url, conveyor = _monitored_store(tmp_path)
    store = Store(url)
    base, server, thread = start_server(create_app(store, {}))
    try:
        token = create_token(store, "fitter", "maintainer")
        path = f"/api/v1/conveyors/{conveyor}/maintenance"
        headers = {"Authorization": f"Bearer {token}"}
        with httpx.Client(base_url=base, headers=headers, timeout=30) as client:
            for at in OUT_OF_SPAN:
                body = {"kind": "cleaning", "why": "rails cleaned", "at": at}
                response = client.post(path, json=body)
                assert response.status_code == 422, (at, response.text)
                error = response.json()["error"]
                assert error["code"] == "invalid"
                assert "outside 1970-01-01..2200-01-01" in error["message"], error
            body = {"kind": "cleaning", "why": "rails cleaned", "at": "2199-12-31T00:00:00Z"}
            response = client.post(path, json=body)
            assert response.status_code == 200, response.text
    finally:
        server.should_exit = True
        thread.join(10)
        store.close()
    # the report reads every stored date
    out = tmp_path / "report"
    assert main(["report", "--all", "--db", url, "--out", str(out)]) == 0


def test_dates_outside_1970_2200_are_refused_by_cli_options(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    url, conveyor = _monitored_store(tmp_path)
    for at in OUT_OF_SPAN:
        argv = [
            *("maintenance", "--conveyor", conveyor, "--kind", "cleaning", "--by", "me"),
            *("--at", at, "--db", url),
        ]
        capsys.readouterr()
        assert main(argv) == 2, at
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and "--at" in err and "outside 1970" in err, err
        argv = [
            *("simulate", "--profile", str(REFERENCE_PROFILE), "--recorded-at", at),
            *("--out", str(tmp_path / "sim.csv")),
        ]
        assert main(argv) == 2, at
        err = capsys.readouterr().err.strip()
        assert "--recorded-at" in err and "outside 1970" in err, err
    assert not (tmp_path / "sim.csv").exists()
    argv = [
        *("maintenance", "--conveyor", conveyor, "--kind", "cleaning", "--by", "me"),
        *("--at", "2026-11-21T10:15:00Z", "--db", url),
    ]
    assert main(argv) == 0


@pytest.mark.slow
def test_export_to_a_full_tmpfs_is_one_line_and_exit_1(
    tmp_path: Path, read_only_mount: Path
) -> None:
    """A small file system that fills part-way through (the fixture's export is larger)."""
    url, _conveyor = _monitored_store(tmp_path)
    subprocess.run(["mount", "-o", "remount,size=16k", str(read_only_mount)], check=True)
    target = read_only_mount / "results.json"
    with open(target, "wb") as out:
        proc = _run(["export", "--db", url, "--format", "json"], stdout=out)
        _, err = proc.communicate(timeout=300)
    text = err.decode().strip()
    assert proc.returncode == 1, text
    assert len(text.splitlines()) == 1 and "No space left on device" in text, text
    assert 0 < target.stat().st_size <= 16 * 1024
