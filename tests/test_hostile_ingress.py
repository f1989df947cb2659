"""Hostile files in a watched folder: each refused in one line, unread, and the service goes on.

One ``chaintwin serve --watch`` subprocess (the file limit set to 1 MB) is
given, one after the other, what an adversarial review dropped into a watched
folder: a symbolic link to ``/dev/zero``, a named pipe, a socket, a sparse
2 GB file, a header of 10^5 columns, a file that says it holds nothing and
yields more than the limit when read, and a file that grows past the limit
while it is watched. For each: the refusal stored is the exact one line the
reader gives, a good file dropped after it is stored, nothing else is
written (the store's recordings and refusals, the folder), and the service's
peak resident size stays below its size once started plus the file limit
plus 100 MB (``VmHWM`` in ``/proc``). SIGTERM then stops it.

Beside it, the reader's own checks: the opened descriptor decides (not the
name), a file is refused while it is read once past the limit, the header
column cap, and a wide but allowed header parsed.
"""

from __future__ import annotations

import os
import socket
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from conftest import EXAMPLES, make_text
from sqlalchemy import select
from sqlalchemy.orm import Session
from test_live import PROFILES, Service, wait_for

from chaintwin.errors import RecordingError
from chaintwin.read import files
from chaintwin.read.files import MAX_FILE_MB_ENV, read_limited
from chaintwin.read.formats import read_recording
from chaintwin.read.reader import MAX_COLUMNS, parse_recording
from chaintwin.store.engine import engine_for
from chaintwin.store.schema import RecordingRow, RefusedFileRow
from chaintwin.store.store import Store

LIMIT_MB = 1.0
"""The service's file limit in these tests, MB (a good recording is about 0.12 MB)."""

HEADROOM = 100_000_000
"""What the service may grow by beyond its started size and the file limit, bytes."""

GOOD = EXAMPLES / "recordings" / "white-belt-01-40kg.csv"

PAD_VARS = 12
"""Environment variables of 120 kB given the service: its ``/proc/self/environ``
says it holds 0 bytes and yields 1.44 MB."""


def peak_resident(pid: int) -> int:
    """A process's peak resident size so far (``VmHWM``), bytes."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) * 1024
    raise AssertionError("no VmHWM in /proc")


class Watched:
    """The service, its folder and store, and what the cases have put there."""

    def __init__(self, root: Path) -> None:
        self.folder = root / "drop"
        self.folder.mkdir()
        self.url = f"sqlite:///{root / 'plant.db'}"
        Store(self.url).close()
        self.engine = engine_for(self.url)
        self.placed: set[str] = set()
        self.goods = 0
        with pytest.MonkeyPatch.context() as env:
            env.setenv(MAX_FILE_MB_ENV, str(LIMIT_MB))
            for k in range(PAD_VARS):
                env.setenv(f"CHAINTWIN_TEST_PAD_{k}", "x" * 120_000)
            self.service = Service(
                [
                    "--db", self.url, "--watch", str(self.folder), "--profiles", str(PROFILES),
                    "--settle-s", "0.5", "--no-web",
                ],
                root / "serve.log",
            )  # fmt: skip
        self.drop_good()  # started, and the pipeline warm: its size now is the start
        self.started = peak_resident(self.service.proc.pid)

    def rows(self) -> tuple[dict[str, str], dict[str, str]]:
        """The stored recordings (file → sha256) and refusals (path → reason)."""
        with Session(self.engine) as s:
            stored = {r.file: r.sha256 for r in s.scalars(select(RecordingRow))}
            refused = {r.path: r.reason for r in s.scalars(select(RefusedFileRow))}
        return stored, refused

    def drop_good(self) -> str:
        """Drop a good recording of its own content; wait until it is stored."""
        self.goods += 1
        path = self.folder / f"good-{self.goods}.csv"
        tmp = self.folder / f"good-{self.goods}.csv.part"  # renamed in: complete at once
        tmp.write_text(f"# case: {self.goods}\n" + GOOD.read_text())
        tmp.rename(path)
        self.placed.add(path.name)
        wait_for(lambda: str(path) in self.rows()[0], 60, f"{path.name} stored", self.service)
        return str(path)

    def refused(self, path: Path) -> str:
        """Wait for the refusal of ``path``; its reason."""
        wait_for(lambda: str(path) in self.rows()[1], 60, f"{path.name} refused", self.service)
        return self.rows()[1][str(path)]

    def close(self) -> None:
        if self.service.proc.poll() is None:
            self.service.kill()
        self.engine.dispose()


@pytest.fixture(scope="module")
def watched(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Watched]:
    w = Watched(tmp_path_factory.mktemp("hostile"))
    try:
        yield w
    finally:
        w.close()


def _sparse(path: Path, size: int) -> None:
    with path.open("wb") as f:  # on paper only: nothing on disk
        f.truncate(size)


def _wide_header(path: Path, ncols: int) -> None:
    cells = ["time [s]", "speed [rpm]", "torque [Nm]"]
    cells += [f"{k:x}[]" for k in range(ncols - len(cells))]
    path.write_text("# conveyor: white-belt-01\n" + ",".join(cells) + "\n")


NOT_REGULAR = "is not a regular file (a pipe, device or socket); give a recording file"
TOO_LARGE = (
    "MB is more than a recording file may hold (max_file_mb 1 MB); raise the limit if the file "
    "is right"
)
GREW = (
    "grew past 1 MB while being read (max_file_mb 1 MB); a recording file is read once complete: "
    "check what writes it"
)


def _case_zero(path: Path) -> str:
    path.symlink_to("/dev/zero")
    return f"{path}: {NOT_REGULAR}"


def _case_fifo(path: Path) -> str:
    os.mkfifo(path)
    return f"{path}: {NOT_REGULAR}"


def _case_socket(path: Path) -> str:
    sock = socket.socket(socket.AF_UNIX)
    sock.bind(str(path))  # the socket file stays after the socket is closed
    sock.close()
    return f"{path}: {NOT_REGULAR}"


def _case_sparse(path: Path) -> str:
    _sparse(path, 2_000_000_000)
    return f"{path}: 2000.0 {TOO_LARGE}"


def _case_columns(path: Path) -> str:
    _wide_header(path, 100_000)
    assert path.stat().st_size < LIMIT_MB * 1e6  # refused for its columns, not its size
    return (
        f"{path}, line 2: header row has 100000 columns, more than the 256 a recording may "
        "have; is this a drive recording?"
    )


def _case_proc(path: Path) -> str:
    # fstat says 0 bytes; reading yields the service's environment, 1.44 MB: as a file
    # that grows between fstat and read, it must be refused once the limit is passed
    path.symlink_to("/proc/self/environ")
    return f"{path}: {GREW}"


CASES = {
    "zero.csv": _case_zero,
    "fifo.csv": _case_fifo,
    "socket.csv": _case_socket,
    "sparse-2gb.csv": _case_sparse,
    "columns-1e5.csv": _case_columns,
    "says-empty.csv": _case_proc,
}


def _after(watched: Watched, before: tuple[dict[str, str], dict[str, str]], hostile: str) -> None:
    """A good file is stored after the hostile one; nothing else written; memory bounded."""
    good = watched.drop_good()
    stored, refused = watched.rows()
    assert set(stored) == set(before[0]) | {good}
    assert set(refused) == set(before[1]) | {hostile}
    assert {p.name for p in watched.folder.iterdir()} == watched.placed
    peak = peak_resident(watched.service.proc.pid)
    bound = watched.started + LIMIT_MB * 1e6 + HEADROOM
    print(f"{hostile}: peak {peak / 1e6:.1f} MB, started {watched.started / 1e6:.1f} MB")
    assert peak <= bound, f"peak {peak / 1e6:.0f} MB, bound {bound / 1e6:.0f} MB"


@pytest.mark.slow
@pytest.mark.parametrize("name", list(CASES))
def test_a_hostile_file_is_refused_in_one_line_and_the_next_good_file_stored(
    watched: Watched, name: str
) -> None:
    before = watched.rows()
    path = watched.folder / name
    expected = CASES[name](path)
    watched.placed.add(name)
    reason = watched.refused(path)
    assert reason == expected
    assert sum(expected in line for line in watched.service.lines()) == 1  # said once
    _after(watched, before, str(path))


def test_a_file_growing_past_the_limit_is_not_read_until_it_stops_then_refused(
    watched: Watched,
) -> None:
    """A file being written is left alone (the folder waits until it settles); the ingest
    goes on meanwhile; once it stops, past the limit, it is refused by its size unread."""
    before = watched.rows()
    path = watched.folder / "growing.csv"
    watched.placed.add(path.name)
    started = threading.Event()

    def grow() -> None:
        with path.open("wb") as f:
            for _ in range(24):  # 24 x 50 kB = 1.2 MB, a write every 0.05 s
                f.write(b"0" * 50_000)
                f.flush()
                started.set()
                time.sleep(0.05)

    writer = threading.Thread(target=grow)
    writer.start()
    try:
        assert started.wait(10)
        good = watched.drop_good()  # stored while the other grows
        assert str(path) not in watched.rows()[1] or not writer.is_alive()
    finally:
        writer.join()
    reason = watched.refused(path)
    assert reason == f"{path}: 1.2 {TOO_LARGE}"
    stored, refused = watched.rows()
    assert set(stored) == set(before[0]) | {good}
    assert set(refused) == set(before[1]) | {str(path)}
    _after(watched, (stored, refused), str(path))


def test_sigterm_stops_the_service_after_the_hostile_files(watched: Watched) -> None:
    assert watched.service.stop(timeout=20) == 0, watched.service.lines()[-5:]


# ---------------------------------------------------------------- the reader's own checks
def _refuse(source: str, message: str) -> RecordingError:
    return RecordingError(source, message)


def test_the_opened_descriptor_decides_not_the_name(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A name that looked like a regular file and is a pipe when opened: refused, no wait."""
    pipe = tmp_path / "pipe.csv"
    os.mkfifo(pipe)
    regular = os.stat(GOOD)
    monkeypatch.setattr(files.os, "stat", lambda *a, **k: regular)  # the look by name is fooled
    outcome: list[BaseException | bytes] = []

    def read() -> None:
        try:
            outcome.append(read_limited(pipe, what="recording", error=_refuse))
        except BaseException as exc:  # handed to the test's thread
            outcome.append(exc)

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    reader.join(20)
    if reader.is_alive():  # blocked in open(): let it go before failing
        with open(pipe, "wb"):
            pass
        pytest.fail("read_limited waited for a writer on a pipe")
    (result,) = outcome
    assert isinstance(result, RecordingError)
    assert str(result) == f"{pipe}: {NOT_REGULAR}"


def test_a_file_is_refused_once_reading_passes_the_limit(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``/proc/self/status`` says 0 bytes and holds about 1.4 kB: read whole within the
    limit, refused once past it, holding no more than the limit."""
    status = Path("/proc/self/status")
    assert status.stat().st_size == 0
    whole = read_limited(status, what="recording", error=_refuse)
    assert whole.startswith(b"Name:") and f"\nPid:\t{os.getpid()}\n".encode() in whole
    assert len(whole) > 1000  # not cut at the 0 bytes fstat gave
    monkeypatch.setenv(MAX_FILE_MB_ENV, "0.0005")  # 500 bytes
    with pytest.raises(RecordingError) as info:
        read_limited(status, what="recording", error=_refuse)
    assert str(info.value) == (
        f"{status}: grew past 0.0005 MB while being read (max_file_mb 0.0005 MB); "
        "a recording file is read once complete: check what writes it"
    )
    assert info.value.field == "max_file_mb"


def test_a_header_beyond_256_columns_is_refused_and_one_of_256_parsed(tmp_path: Path) -> None:
    assert MAX_COLUMNS == 256
    text = make_text(n=64)
    head, _, rest = text.partition("time [s]")
    header, _, body = ("time [s]" + rest).partition("\n")
    ncols = header.count(",") + 1
    extra = MAX_COLUMNS - ncols

    def widen(k: int) -> str:
        cells = header + "".join(f",extra_{j} [-]" for j in range(k))
        rows = "\n".join(line + ",0.5" * k for line in body.strip().split("\n"))
        return head + cells + "\n" + rows + "\n"

    wide = tmp_path / "wide.csv"
    wide.write_text(widen(extra))
    rec = read_recording(wide)
    assert len(rec.channels) == MAX_COLUMNS
    assert rec.samples == 64
    np.testing.assert_array_equal(rec.channels[f"extra_{extra - 1}"], np.full(64, 0.5))
    line = head.count("\n") + 1
    with pytest.raises(RecordingError) as info:
        parse_recording(widen(extra + 1), "too-wide.csv")
    assert str(info.value) == (
        f"too-wide.csv, line {line}: header row has 257 columns, more than the 256 a "
        "recording may have; is this a drive recording?"
    )


def test_blank_lines_do_not_size_the_table(tmp_path: Path) -> None:
    """10^5 blank lines between two rows: parsed by lines, the table sized by its values."""
    import tracemalloc

    text = make_text(n=64)
    head, _, rest = text.partition("time [s]")
    header, _, body = ("time [s]" + rest).partition("\n")
    first, _, others = body.partition("\n")
    padded = head + header + "\n" + first + "\n" * 100_000 + others
    tracemalloc.start()
    try:
        rec = parse_recording(padded, "blank.csv")
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert rec.samples == 64
    np.testing.assert_array_equal(rec.time, parse_recording(text, "x").time)
    # the text (0.13 MB) is copied a few times; a list of its 10^5 lines would add
    # 0.8 MB, a grid of 10^5 rows 6.4 MB
    assert peak < 8 * len(padded), peak


def _dense(rows: int) -> str:
    """A valid recording of ``rows`` samples and 8 columns, values as short as they come."""
    head = "# conveyor: white-belt-01\n# nominal_torque_nm: 2.5\n"
    header = "time [s],speed [rpm],torque [Nm]," + ",".join(f"x{k} [-]" for k in range(5))
    body = "\n".join(f"{k * 0.001:.3f},0,0,0,0,0,0,0" for k in range(rows))
    return head + header + "\n" + body + "\n"


def test_more_values_than_a_recording_may_hold_is_refused_before_parsing() -> None:
    from chaintwin.read.reader import MAX_VALUES

    assert MAX_VALUES == 8_000_000
    rows = MAX_VALUES // 8 + 1
    text = "# conveyor: white-belt-01\ntime [s],speed [rpm],torque [Nm]," + ",".join(
        f"x{k} [-]" for k in range(5)
    )
    text += "\n" + "0,0,0,0,0,0,0,0\n" * rows
    with pytest.raises(RecordingError) as info:
        parse_recording(text.encode(), "many.csv")
    assert str(info.value) == (
        f"many.csv, line 3: holds {rows} lines of 8 columns, more than the 8000000 values a "
        "recording may hold; cut it into shorter recordings"
    )


def test_parsing_the_largest_recording_holds_its_bytes_and_its_samples_only(
    tmp_path: Path,
) -> None:
    """10^6 samples x 8 columns (the most a recording may hold, 24 MB of text): the
    parse's peak resident growth stays within the file, its samples (64 MB) and 20 MB."""
    import subprocess
    import sys

    path = tmp_path / "dense.csv"
    path.write_text(_dense(1_000_000))
    size = path.stat().st_size
    warm = tmp_path / "warm.csv"
    warm.write_text(_dense(64))
    script = (
        "from chaintwin.read.formats import read_recording\n"
        # the same call on a small file first: what it imports (lazily) is not the parse's
        f"read_recording({str(warm)!r})\n"
        "def kb(key):\n"
        "    for line in open('/proc/self/status'):\n"
        "        if line.startswith(key):\n"
        "            return int(line.split()[1]) * 1024\n"
        "before = kb('VmRSS')\n"
        f"rec = read_recording({str(path)!r})\n"
        "print(rec.samples, kb('VmHWM') - before)\n"
    )
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[1]))
    # the default file limit (64 MB), whatever an earlier test's --max-file-mb left set
    env.pop("CHAINTWIN_MAX_FILE_MB", None)
    out = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, env=env, check=True
    ).stdout.split()
    samples, grown = int(out[0]), int(out[1])
    assert samples == 1_000_000
    values = 1_000_000 * 8 * 8
    assert grown <= size + values + 20_000_000, f"grew {grown / 1e6:.0f} MB, file {size / 1e6:.0f}"
    print(
        f"file {size / 1e6:.1f} MB, samples {values / 1e6:.0f} MB, peak growth {grown / 1e6:.1f} MB"
    )


def test_a_file_that_cannot_be_read_now_fails_and_is_tried_again_not_refused(
    tmp_path: Path,
) -> None:
    """An OS error (here a loop of links) is not the file's content: the ingest fails (the
    folder hands it again later) and no refusal is kept; a pipe is refused and kept."""
    from chaintwin.live.sources import Ingestor, Job

    a, b = tmp_path / "a.csv", tmp_path / "b.csv"
    a.symlink_to(b)
    b.symlink_to(a)
    pipe = tmp_path / "pipe.csv"
    os.mkfifo(pipe)
    url = f"sqlite:///{tmp_path / 'plant.db'}"
    with Store(url) as store:
        ingestor = Ingestor(store, {})
        with pytest.raises(RecordingError, match="cannot be read") as info:
            ingestor.ingest_one(Job(str(a), "folder:x"))
        assert isinstance(info.value.__cause__, OSError)
        refused = ingestor.ingest_one(Job(str(pipe), "folder:x"))
        assert (refused.status, refused.reason) == ("refused", f"{pipe}: {NOT_REGULAR}")
        gone = ingestor.ingest_one(Job(str(tmp_path / "gone.csv"), "folder:x"))
        assert gone.status == "gone"
        with Session(store.engine) as s:
            rows = [(r.path, r.reason) for r in s.scalars(select(RefusedFileRow))]
        assert rows == [(str(pipe), f"{pipe}: {NOT_REGULAR}")]
        ingestor.close()
