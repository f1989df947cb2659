"""The serving benchmark's fault fleet at full size: really ingested, then grown.

Ingesting 200 conveyors x 10 000 recordings one by one would take days here
(an ingest costs 0.4 to 1 s a recording on this 2-core machine, a calibration
40 s a conveyor), so the fleet is made in two steps:

1. **Template** (:func:`build_template`, cached in a SQLite file): ``kinds``
   virtual conveyors (``faulty-000`` ...) are simulated, their rail friction
   rising from day ``onset_day`` to 0.8 more on the last day, each with its
   own seed, and their recordings really ingested
   (:func:`chaintwin.ingest.pipeline.ingest`, the forecasts refitted after
   it): results, health models, alarms opened, outbox rows, stored forecasts
   are what ingest wrote. One calibration is learned (from the first
   conveyor's simulated calibration runs, :func:`~chaintwin.calibrating.procedure.calibrate`)
   and stored for each of them (the conveyors share one profile but their id).
2. **Fleet** (:func:`grow`): conveyor ``k`` of the ``conveyors`` is template
   conveyor ``k % kinds`` under its own id: its profile and calibration,
   health model, alarms (new ids), outbox, results and recordings (samples
   included) copied with every id and content hash renamed, so that each is
   a conveyor of its own. Its history is grown to ``results`` results by
   replicating its results from before the fault's onset (its first
   ``onset_day x per_day``, the baseline) backwards in time, one copy of
   that stretch per ``onset_day`` days before it, each copy a recording
   and a result row of its own (own content hash, file name and time);
   these older recordings keep no samples (as if retention had dropped
   them). Rows are written with the store's own table definitions,
   statements and JSON serializer (``insert(RecordingRow)``,
   ``insert(ResultRow)`` as :meth:`~chaintwin.store.store.Store.commit_recordings`
   writes them), the older copies first, so that ids grow in recorded order
   as ingest writes them, with the same indexes. Then each conveyor's
   forecasts are refitted and stored (:func:`chaintwin.report.trend_series.refit_with_trends`)
   as ingest does after it.

What is not as a real 10 000-recording ingest: the health model (baseline,
alarm windows, the history its forecasts are fitted on) is the one the real
ingest left, so it knows the real recordings only, not the replicated older
ones; and the replicated history repeats the real baseline's values.
"""

from __future__ import annotations

import dataclasses
import hashlib
import time
from datetime import datetime, timedelta
from pathlib import Path
from typing import Any

import orjson
from sqlalchemy import func, insert, select

from chaintwin.calibrating.procedure import calibrate
from chaintwin.diagnose.records import MonitorSettings
from chaintwin.identify.calibration import identification_profile
from chaintwin.ingest.pipeline import ingest
from chaintwin.read.profile import ConveyorProfile, load_profile
from chaintwin.report.trend_series import refit_with_trends as refit
from chaintwin.simulate.faults import Fault
from chaintwin.simulate.fleet import generate
from chaintwin.store.engine import _to_json as to_json
from chaintwin.store.schema import (
    AlarmAliasRow,
    AlarmRow,
    CalibrationRow,
    ConveyorRow,
    DerivedHealthRow,
    EventRow,
    MonitorStateRow,
    OutboxRow,
    RecordingRow,
    ResultRow,
)
from chaintwin.store.store import Store
from chaintwin.validate import load_recording

PROFILE = Path(__file__).resolve().parents[1] / "chaintwin/examples/profiles/white-belt-01.yaml"

SETTINGS = MonitorSettings(baseline_n=10)
"""The fault fleet's monitoring: a baseline of 10 recordings, then alarms."""

ONSET_DAY = 2
"""The day (from 0) the friction starts rising."""


def fault_id(k: int) -> str:
    """The id of the fault fleet's conveyor ``k``."""
    return f"faulty-{k:03d}"


def build_template(path: Path, kinds: int, days: int, per_day: int, work: Path) -> dict[str, Any]:
    """Simulate ``kinds`` conveyors with friction rising and ingest them into ``path``.

    Returns what it did (seconds of simulation and ingest, recordings).
    """
    base = load_profile(PROFILE)
    profiles: dict[str, ConveyorProfile] = {}
    files: list[str] = []
    t0 = time.perf_counter()
    for k in range(kinds):
        prof = base.model_copy(update={"id": fault_id(k)})
        out = work / prof.id
        generate(
            prof,
            out,
            days=days,
            per_day=per_day,
            faults=[Fault("friction", 0.8)],
            onset_day=ONSET_DAY,
            seed=100 + k,
            calibration=k == 0,
        )
        profiles[prof.id] = prof
        files += sorted(str(f) for f in out.glob("*.csv"))
    simulated = time.perf_counter() - t0
    first = profiles[fault_id(0)]
    runs = sorted((work / first.id / "calibration").glob("*.csv"))
    t0 = time.perf_counter()
    cal = calibrate([load_recording(f, profile=first).recording for f in runs], first)
    calibrated = time.perf_counter() - t0
    tmp = path.with_suffix(".part")
    tmp.unlink(missing_ok=True)
    with Store(f"sqlite:///{tmp}") as store:
        for prof in profiles.values():
            store.put_calibration(dataclasses.replace(cal, profile=prof))
        t0 = time.perf_counter()
        summary = ingest(files, profiles, store, settings=SETTINGS, workers=1, refit=True)
        ingested = time.perf_counter() - t0
    if summary.refused:
        raise SystemExit(f"fault fleet template: {summary.refused} refused: {summary.refusals[:3]}")
    tmp.rename(path)
    return {
        "simulated_s": simulated,
        "calibrated_s": calibrated,
        "ingested_s": ingested,
        "recordings": summary.processed,
    }


def _hash(*parts: str) -> str:
    return hashlib.sha256(":".join(parts).encode()).hexdigest()


def _renamed(value: Any, pairs: list[tuple[str, str]]) -> Any:
    """``value`` (JSON-like) with every text ``old`` replaced by ``new``."""
    raw = orjson.dumps(value).decode()
    for old, new in pairs:
        raw = raw.replace(old, new)
    return orjson.loads(raw)


def _rows(store: Store, table: Any, conveyor: str, order: Any = None) -> list[dict[str, Any]]:
    """A template conveyor's rows of ``table`` as dicts of column values."""
    cols = table.__table__.c
    q = select(table.__table__).where(cols.conveyor_id == conveyor)
    if order is not None:
        q = q.order_by(order)
    with store.engine.connect() as c:
        return [dict(r._mapping) for r in c.execute(q)]


def grow(
    template: Path,
    url: str,
    conveyors: int,
    results: int,
    onset: int,
    days_back: int = ONSET_DAY,
    chunk: int = 5_000,
) -> dict[str, Any]:
    """Fill the empty store ``url`` with ``conveyors`` fault conveyors of ``results`` results.

    ``onset``: the template's results before the fault's onset (replicated
    backwards, one copy per ``days_back`` days). Returns what it did.
    """
    base = load_profile(PROFILE)
    t_start = time.perf_counter()
    with Store(f"sqlite:///{template}", read_only=True) as tpl:
        kinds = len(tpl.conveyors())
        source = {cid: _template(tpl, cid) for cid in tpl.conveyors()}
    refit_s = 0.0
    with Store(url) as store:
        with store.engine.connect() as c:  # after what the store holds (the synthetic rows)
            rec_id = int(c.execute(select(func.max(RecordingRow.id))).scalar() or 0)
            res_id = int(c.execute(select(func.max(ResultRow.id))).scalar() or 0)
        first_res = res_id
        for k in range(conveyors):
            cid = fault_id(k)
            src_id = fault_id(k % kinds)
            src = source[src_id]
            prof = base.model_copy(update={"id": cid})
            pairs = [
                (src["profile_sha256"], prof.content_hash()),
                (src["id_profile_sha256"], identification_profile(prof).content_hash()),
            ]
            if cid != src_id:
                pairs += [(sha, _hash(cid, sha)) for sha in src["shas"]]
                pairs += [(a, _hash(cid, a)[:8]) for a in src["alarm_ids"]]
                pairs += [(e, _hash(cid, e)[:16]) for e in src["event_ids"]]
                pairs.append((src_id, cid))
            real = [_renamed(r, pairs) for r in src["results"]]
            recs = [  # the samples (bytes) as they are, the rest renamed
                _renamed({k: v for k, v in r.items() if k != "samples"}, pairs)
                | {"samples": r["samples"]}
                for r in src["recordings"]
            ]
            with store.engine.begin() as c:
                c.execute(
                    insert(ConveyorRow),
                    [
                        {
                            "id": cid,
                            "profile": prof.model_dump(mode="json"),
                            "profile_sha256": prof.content_hash(),
                        }
                    ],
                )
                for cal in src["calibrations"]:
                    row = _renamed(cal, pairs)
                    row.pop("id")
                    c.execute(insert(CalibrationRow), [row])
            # the older history first: ids grow in recorded order, as ingest writes them
            older = results - len(real)
            first_at = datetime.fromisoformat(str(real[0]["recorded_at"]))
            stretch = real[:onset]
            rows_rec: list[dict[str, Any]] = []
            rows_res: list[dict[str, Any]] = []
            old_rec: list[tuple[Any, ...]] = []
            old_res: list[tuple[Any, ...]] = []
            warnings = [to_json(r["warnings"]) for r in recs]
            stems = [Path(str(r["file"])).stem for r in recs]
            times = [datetime.fromisoformat(str(r["recorded_at"])) for r in stretch]

            copies = -(-older // onset)
            n = 0
            newest_at = ""
            for copy in range(copies, 0, -1):  # the oldest copy first
                shift = timedelta(days=days_back * copy)
                for j, res in enumerate(stretch):
                    if n >= older:
                        break
                    if copy * onset - j > older:  # the oldest copy is partial: its newest part
                        continue
                    rec = recs[j]
                    at = (times[j] - shift).isoformat()
                    name = f"{stems[j]}-r{copy}.csv"
                    sha = _hash(cid, str(rec["sha256"]), str(copy))
                    rec_id += 1
                    res_id += 1
                    n += 1
                    meta = dict(rec["meta"]) | {"recorded_at": at}
                    old_rec.append(
                        (rec_id, sha, cid, name, at, to_json(meta), warnings[j], b"")
                    )  # older: retention dropped its samples
                    newest_at = at
                    content = dict(res["content"]) | {"file": name, "recorded_at": at}
                    old_res.append(
                        (res_id, rec_id, cid, at, res["status"], res["alarm"],
                         res["payload_kg"], res["tlf"], to_json(content), res["stored_at"])
                    )  # fmt: skip
                    if len(old_rec) >= chunk:
                        _flush_raw(store, old_rec, old_res)
            if n != older or (older and first_at <= datetime.fromisoformat(newest_at)):
                raise AssertionError(f"{cid}: the grown history is not older than the real one")
            _flush_raw(store, old_rec, old_res)
            # the real ones, as ingest wrote them (renamed)
            ids: dict[int, int] = {}
            for rec in recs:
                rec_id += 1
                ids[int(rec["id"])] = rec_id
                rows_rec.append(rec | {"id": rec_id, "superseded_by": None})
            for res in real:
                res_id += 1
                rows_res.append(res | {"id": res_id, "recording_id": ids[int(res["recording_id"])]})
            _flush(store, rows_rec, rows_res)
            with store.engine.begin() as c:
                state = _renamed(src["state"], pairs)
                c.execute(insert(MonitorStateRow), [state])
                for table, rows in (
                    (AlarmRow, src["alarms"]),
                    (EventRow, src["events"]),
                    (OutboxRow, src["outbox"]),
                    (AlarmAliasRow, src["aliases"]),
                    (DerivedHealthRow, src["derived"]),  # the forecasts the real ingest stored
                ):
                    if rows:
                        c.execute(insert(table), [_renamed(r, pairs) for r in rows])
            t0 = time.perf_counter()
            refit(store, cid)  # as ingest does after it: nothing when they are current

            refit_s += time.perf_counter() - t0
        if store.engine.dialect.name == "postgresql":  # ids given: move the sequences
            with store.engine.begin() as c:
                for seq_table, last in (("recordings", rec_id), ("results", res_id)):
                    c.exec_driver_sql(
                        f"SELECT setval(pg_get_serial_sequence('{seq_table}', 'id'), {last})"
                    )
                c.exec_driver_sql("ANALYZE")  # as autovacuum does; SQLite: none, as ingest
    return {
        "seconds": time.perf_counter() - t_start,
        "refit_s": refit_s,
        "conveyors": conveyors,
        "results": res_id - first_res,
        "kinds": kinds,
    }


_SQL = {
    "recordings": "id, sha256, conveyor_id, file, recorded_at, meta, warnings, samples",
    "results": "id, recording_id, conveyor_id, recorded_at, status, alarm, payload_kg, tlf, "
    "content, stored_at",
}


def _flush_raw(store: Store, recs: list[tuple[Any, ...]], results: list[tuple[Any, ...]]) -> None:
    """Write the older copies' rows in one transaction, straight to the driver.

    Their JSON columns are already text from the engine's own serializer
    (:func:`chaintwin.store.engine._to_json`, what the columns write);
    SQLAlchemy's per-row processing would take most of the fill's time.
    """
    if not recs:
        return
    if store.engine.dialect.name == "postgresql":  # COPY: executemany is 10 times slower
        with store.engine.begin() as c:
            cursor = c.connection.dbapi_connection.cursor()  # type: ignore[union-attr]
            for table, rows in (("recordings", recs), ("results", results)):
                with cursor.copy(f"COPY {table} ({_SQL[table]}) FROM STDIN") as copy:
                    for row in rows:
                        copy.write_row(row)
        recs.clear()
        results.clear()
        return
    mark = "?" if store.engine.dialect.paramstyle == "qmark" else "%s"
    with store.engine.begin() as c:
        for table, rows in (("recordings", recs), ("results", results)):
            cols = _SQL[table]
            marks = ", ".join([mark] * len(cols.split(",")))
            c.exec_driver_sql(f"INSERT INTO {table} ({cols}) VALUES ({marks})", rows)
    recs.clear()
    results.clear()


def _flush(store: Store, recs: list[dict[str, Any]], results: list[dict[str, Any]]) -> None:
    """Write recordings and their results in one transaction (as ingest: a group at once)."""
    if recs:
        with store.engine.begin() as c:
            c.execute(insert(RecordingRow), recs)
            c.execute(insert(ResultRow), results)
    recs.clear()
    results.clear()


def _template(tpl: Store, cid: str) -> dict[str, Any]:
    """Everything a template conveyor has in the store."""
    recordings = _rows(tpl, RecordingRow, cid, RecordingRow.id)
    results = _rows(tpl, ResultRow, cid, ResultRow.id)
    by_id = {int(r["id"]): r for r in recordings}
    # recordings in the order of their results (those without one: none in the template)
    ordered = [by_id[int(r["recording_id"])] for r in results]
    assert len(ordered) == len(recordings), f"{cid}: recordings without a result"
    prof = tpl.profile(cid)
    assert prof is not None
    with tpl.engine.connect() as c:
        aliases = [
            dict(r._mapping)
            for r in c.execute(
                select(AlarmAliasRow.__table__).where(
                    AlarmAliasRow.alarm_id.in_(
                        select(AlarmRow.id).where(AlarmRow.conveyor_id == cid)
                    )
                )
            )
        ]
    alarms = _rows(tpl, AlarmRow, cid)
    events = _rows(tpl, EventRow, cid)
    states = _rows(tpl, MonitorStateRow, cid)
    derived = _rows(tpl, DerivedHealthRow, cid)
    assert states and derived, f"{cid}: no health model or forecasts in the template"
    return {
        "profile_sha256": prof.content_hash(),
        "id_profile_sha256": identification_profile(prof).content_hash(),
        "recordings": ordered,
        "results": results,
        "shas": [str(r["sha256"]) for r in recordings],
        "alarm_ids": [str(a["id"]) for a in alarms] + [str(a["old_id"]) for a in aliases],
        "event_ids": [str(e["id"]) for e in events],
        "calibrations": _rows(tpl, CalibrationRow, cid, CalibrationRow.id),
        "state": states[0],
        "alarms": alarms,
        "events": events,
        "outbox": _rows(tpl, OutboxRow, cid),
        "derived": derived,
        "aliases": aliases,
    }
