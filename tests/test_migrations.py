"""Schema migrations: the store of chaintwin 0.1.0 upgraded on SQLite and PostgreSQL.

``tests/fixtures/store-c909904.sqlite`` was written by chaintwin 0.1.0 (commit
c909904, before migrations): 36 recordings of white-belt-01 with a friction
rise, a calibration, a maintenance event and the alarm it closed.
``store-c909904.export.json`` is what that chaintwin's ``export --format json``
printed for it. On PostgreSQL the same store is rebuilt from the baseline
revision and the fixture's rows.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from conftest import EXAMPLES
from sqlalchemy import MetaData, inspect, select, text

from chaintwin.cli.app import main
from chaintwin.errors import StoreError
from chaintwin.store import migrate
from chaintwin.store.engine import engine_for
from chaintwin.store.schema import Base
from chaintwin.store.store import Store

FIXTURES = Path(__file__).parent / "fixtures"
LEGACY = FIXTURES / "store-c909904.sqlite"
LEGACY_EXPORT = json.loads((FIXTURES / "store-c909904.export.json").read_text())


def _legacy_store(url: str, tmp_path: Path) -> None:
    """Put the 0.1.0 store at ``url``: the file itself on SQLite, its rows on PostgreSQL."""
    if url.startswith("sqlite:///"):
        shutil.copyfile(LEGACY, url[len("sqlite:///") :])
        return
    source = engine_for(f"sqlite:///{LEGACY}")
    target = engine_for(url)
    from alembic import command

    with target.begin() as connection:
        command.upgrade(migrate._config(connection), migrate.BASELINE_REVISION)
        connection.execute(text("DROP TABLE alembic_version"))  # 0.1.0 had no Alembic
    tables = MetaData()
    tables.reflect(source)
    with source.connect() as read, target.begin() as write:
        write.execute(text("DELETE FROM schema"))
        for table in tables.sorted_tables:
            rows = [dict(r._mapping) for r in read.execute(select(table))]
            if rows:
                write.execute(Base.metadata.tables[table.name].insert(), rows)
    source.dispose()
    target.dispose()


def _run(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    code = main(args)
    out, err = capsys.readouterr()
    return code, out, err


def test_head_revision_is_the_scripts_head() -> None:
    assert migrate.head_from_scripts() == migrate.HEAD_REVISION
    assert migrate._order()[0] == migrate.BASELINE_REVISION
    assert migrate._order()[-1] == migrate.HEAD_REVISION


def test_a_new_store_is_created_at_the_head_with_the_models_tables(db: str) -> None:
    from alembic.autogenerate import compare_metadata
    from alembic.migration import MigrationContext

    Store(db).close()
    engine = engine_for(db)
    with engine.connect() as connection:
        assert migrate.revision_of(connection) == migrate.HEAD_REVISION
        differences = compare_metadata(MigrationContext.configure(connection), Base.metadata)
        assert connection.execute(text("SELECT version FROM schema")).scalar() == 2
    engine.dispose()
    assert differences == []


def test_the_store_of_0_1_0_is_refused_then_upgraded_and_reads_the_same(
    db: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    _legacy_store(db, tmp_path)
    before = LEGACY.read_bytes() if db.startswith("sqlite") else None
    code, out, err = _run(["export", "--db", db, "--format", "json"], capsys)
    assert code == 2
    assert json.loads(out)["error"]["code"] == "store_error"  # --format json: JSON too
    assert len(err.strip().splitlines()) == 1
    assert "revision 0001" in err and f"needs {migrate.HEAD_REVISION}" in err
    assert f"run `chaintwin db upgrade --db {db}`" in err
    if before is not None:  # refused untouched
        assert Path(db[len("sqlite:///") :]).read_bytes() == before

    code, out, _ = _run(["db", "upgrade", "--db", db], capsys)
    assert code == 0
    assert f"from revision 0001 to revision {migrate.HEAD_REVISION}" in out
    code, out, _ = _run(["db", "upgrade", "--db", db, "--json"], capsys)
    assert code == 0
    assert json.loads(out) == {
        "store": db,
        "from": migrate.HEAD_REVISION,
        "to": migrate.HEAD_REVISION,
    }

    code, out, _ = _run(["export", "--db", db, "--format", "json"], capsys)
    assert code == 0
    rows = json.loads(out)
    # what 0.1.0 exported, plus each recording's content hash; no write time
    # for results stored before revision 0003
    assert all(len(r.pop("recording_id")) == 64 for r in rows)
    assert all(r.pop("stored_at") is None for r in rows)
    assert rows == LEGACY_EXPORT
    # and the upgraded store takes new work: a maintenance event
    code, _, _ = _run(
        [
            "maintenance",
            "--db",
            db,
            "--conveyor",
            "white-belt-01",
            "--kind",
            "cleaning",
            "--by",
            "A",
        ],
        capsys,
    )
    assert code == 0


def test_the_fixture_store_at_0004_with_refusals_upgrades_and_sorts_their_causes(
    db: str, tmp_path: Path
) -> None:
    """0005: the refusals a 0004 store kept get their cause and conveyor from their reason."""
    from alembic import command

    _legacy_store(db, tmp_path)
    engine = engine_for(db)
    with engine.begin() as connection:
        command.stamp(migrate._config(connection), migrate.BASELINE_REVISION)
        command.upgrade(migrate._config(connection), "0004")
    reasons = {
        "a.csv": "a.csv: is a recording of conveyor 'white-belt-01', for which no profile was "
        "given (profiles: short-fast-03)",
        "b.csv": "sqlite:///x.db: conveyor 'incline-line-02' is monitored with another "
        "profile; ...",
        "c.csv": "c.csv: has no 'conveyor' in its metadata; add '# conveyor: <profile id>'",
    }
    with engine.begin() as connection:
        for k, (name, reason) in enumerate(reasons.items()):
            connection.execute(
                text(
                    "INSERT INTO refused_files (sha256, path, source, reason, refused_at) "
                    "VALUES (:sha, :path, 'folder:/in', :reason, '2026-11-25T00:00:00+00:00')"
                ),
                {"sha": f"{k}" * 64, "path": name, "reason": reason},
            )
    before, after = migrate.upgrade(engine)
    assert (before, after) == ("0004", migrate.HEAD_REVISION)
    with engine.connect() as connection:
        rows = connection.execute(
            text("SELECT path, cause, conveyor, reason FROM refused_files ORDER BY path")
        ).all()
    assert [tuple(r[:3]) for r in rows] == [
        ("a.csv", "profile", "white-belt-01"),
        ("b.csv", "profile", "incline-line-02"),
        ("c.csv", "recording", None),
    ]
    assert [r[3] for r in rows] == list(reasons.values())  # kept as written
    # and the store reads them, and the old exports, as before
    store = Store(db)
    from chaintwin.live.ledger import refusals

    assert [r.path for r in refusals(store, cause="profile", conveyors={"white-belt-01"})] == [
        "a.csv"
    ]
    assert len(store.results()) == len(LEGACY_EXPORT)
    store.close()
    engine.dispose()


def test_a_store_newer_than_the_code_is_refused(tmp_path: Path) -> None:
    url = f"sqlite:///{tmp_path / 'new.db'}"
    Store(url).close()
    engine = engine_for(url)
    with engine.begin() as connection:
        connection.execute(text("UPDATE alembic_version SET version_num = '9999'"))
    with pytest.raises(StoreError, match="revision 9999, which this chaintwin does not know"):
        Store(url)
    with pytest.raises(StoreError, match="newer than this chaintwin knows"):
        migrate.upgrade(engine)
    engine.dispose()


def test_another_programs_database_is_refused_and_left_alone(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "other.db"
    engine = engine_for(f"sqlite:///{path}")
    with engine.begin() as connection:
        connection.execute(text("CREATE TABLE users (id INTEGER PRIMARY KEY, name TEXT)"))
    engine.dispose()
    before = path.read_bytes()
    recordings = tmp_path / "recordings"
    recordings.mkdir()
    shutil.copy(EXAMPLES / "recordings" / "white-belt-01-40kg.csv", recordings)
    ingest = ["ingest", str(recordings), "--profiles", str(EXAMPLES / "profiles"), "--workers", "1"]
    for args in (["export"], ["db", "upgrade"], ingest):
        code, _, err = _run([*args, "--db", f"sqlite:///{path}"], capsys)
        assert code == 2, args
        assert "other tables than a chaintwin store's (users)" in err
    assert path.read_bytes() == before
    engine = engine_for(f"sqlite:///{path}")
    assert inspect(engine).get_table_names() == ["users"]
    engine.dispose()


def test_a_0005_store_groups_open_alarms_of_one_cause_and_old_ids_still_resolve(
    db: str, tmp_path: Path
) -> None:
    """0006: two open friction alarms become one with both features; old ids resolve."""
    from alembic import command
    from sqlalchemy.orm import Session

    from chaintwin.diagnose.state import acknowledge_alarm
    from chaintwin.store.schema import AlarmRow, MonitorStateRow

    _legacy_store(db, tmp_path)
    engine = engine_for(db)
    with engine.begin() as connection:
        command.stamp(migrate._config(connection), migrate.BASELINE_REVISION)
        command.upgrade(migrate._config(connection), "0005")

    def old_alarm(aid: str, feature: str, since: str, ack: dict[str, str] | None) -> dict:
        return {
            "id": aid,
            "conveyor": "white-belt-01",
            "feature": feature,
            "cause": "friction",
            "change": 0.3,
            "since": since,
            "opened_at": since,
            "last_seen": since,
            "status": "open",
            "acknowledged": ack,
            "rule": "x_of_y",
            "kind": "statistical",
        }

    ack = {"by": "ann", "why": "seen", "at": "2026-02-01T10:00:00+00:00"}
    first = old_alarm("aaaa0001", "friction", "2026-02-01T08:00:00+00:00", None)
    second = old_alarm("aaaa0002", "residual_rms", "2026-02-01T09:00:00+00:00", ack)
    with Session(engine) as s, s.begin():
        row = s.get(MonitorStateRow, "white-belt-01")
        assert row is not None
        closed = [a for a in row.state["alarms"] if a["status"] == "closed"]
        row.state = dict(row.state, alarms=[*closed, first, second])
        for a in (first, second):
            s.add(
                AlarmRow(
                    id=a["id"],
                    conveyor_id="white-belt-01",
                    feature=a["feature"],
                    cause="friction",
                    status="open",
                    since=a["since"],
                    content=a,
                )
            )
    before, after = migrate.upgrade(engine)
    assert (before, after) == ("0005", migrate.HEAD_REVISION)
    store = Store(db)
    opened = [a for a in store.alarms() if a.is_open]
    assert [a.id for a in opened] == ["aaaa0001"]
    grouped = opened[0]
    assert [e.feature for e in grouped.evidence] == ["friction", "residual_rms"]
    assert grouped.merged == ["aaaa0002"]
    assert grouped.acknowledged is not None and grouped.acknowledged.by == "ann"
    assert grouped.lifecycle() == "acknowledged"
    assert len([a for a in store.alarms() if not a.is_open]) == len(closed)
    # the old id names the grouped alarm: its conveyor, and its acknowledgement
    assert store.alarm_conveyor("aaaa0002") == "white-belt-01"
    with pytest.raises(StoreError, match="was acknowledged by ann"):
        store.edit_state(
            "white-belt-01", lambda d: acknowledge_alarm(d, "aaaa0002", "bob", "again")
        )
    state = store.state("white-belt-01")
    assert state is not None
    assert [a.id for a in state.alarms if a.is_open] == ["aaaa0001"]
    store.close()
    engine.dispose()
