"""Plumbing declared once: the shared command-line options, the store as a context."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from chaintwin.cli.common import DB_HELP
from chaintwin.errors import StoreError
from chaintwin.store.store import Store

CLI = Path(__file__).resolve().parents[1] / "chaintwin" / "cli"


def test_db_and_json_are_declared_once_in_common() -> None:
    declared = {
        p.name: re.findall(r'Option\(\s*"--(db|json)"', p.read_text(encoding="utf-8"))
        for p in sorted(CLI.glob("*.py"))
    }
    assert {name: found for name, found in declared.items() if found} == {
        "common.py": ["db", "json"]
    }
    # the store's help text is written once too
    assert (
        sum(
            p.read_text(encoding="utf-8").count("(sqlite:///file.db, postgresql://...)")
            for p in CLI.glob("*.py")
        )
        == 1
    )


def test_every_store_option_of_the_commands_names_the_default(
    capsys: pytest.CaptureFixture[str],
) -> None:
    from chaintwin.cli.app import main

    for command in (["ingest"], ["export"], ["report"], ["db", "upgrade"], ["refused", "list"]):
        assert main([*command, "--help"]) == 0
        text = " ".join(capsys.readouterr().out.replace("│", " ").split())
        assert "--db" in text and " ".join(DB_HELP.split()[:4]) in text, command


def test_a_store_closes_when_its_block_ends_however_it_ends(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    closed: list[str] = []
    close = Store.close

    def counting(self: Store) -> None:
        closed.append(self.url)
        close(self)

    monkeypatch.setattr(Store, "close", counting)
    url = f"sqlite:///{tmp_path / 'plant.db'}"
    with Store(url) as store:
        assert store.conveyors() == []
    assert closed == [url]
    with pytest.raises(StoreError, match="no such conveyor"), Store(url) as store:
        raise StoreError("no such conveyor")
    assert closed == [url, url]
