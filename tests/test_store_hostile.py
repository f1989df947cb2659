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

import pytest
from conftest import EXAMPLES, REFERENCE_PROFILE

from chaintwin.cli.app import main
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
