"""Local workers: the fork server imports the main script once, and the entry point stays small."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from chaintwin.cli import starts_local_workers

SCRIPT = textwrap.dedent(
    """
    import argparse
    import os
    import sys
    from concurrent.futures import ProcessPoolExecutor

    # arguments read at import (argparse exits without them): the fork server
    # and the workers see the ingest's own
    parser = argparse.ArgumentParser()
    parser.add_argument("log")
    ARGS = parser.parse_args()

    # one line per import of this script, and by whom
    with open(ARGS.log, "a") as f:
        f.write(f"{__name__} {os.getpid()}\\n")


    def task(k):
        import sys

        return os.getpid(), "chaintwin.ingest.worker" in sys.modules


    if __name__ == "__main__":
        from chaintwin.ingest import forkserver

        with ProcessPoolExecutor(2, mp_context=forkserver.context()) as ex:
            out = list(ex.map(task, range(8)))
        print(len({pid for pid, _ in out}), all(warm for _, warm in out))
    """
)


def test_workers_do_not_import_the_main_script_again(tmp_path: Path) -> None:
    script = tmp_path / "ingest_script.py"
    script.write_text(SCRIPT)
    log = tmp_path / "imports.log"
    done = subprocess.run(
        [sys.executable, str(script), str(log)],
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
    )
    workers, warm = done.stdout.split()
    lines = log.read_text().splitlines()
    # the script itself, then the fork server once (as __mp_main__); workers
    # forked from it have it already and import nothing at start
    assert [line.split()[0] for line in lines] == ["__main__", "__mp_main__"], lines
    assert warm == "True"  # the pipeline was preloaded in the fork server
    assert int(workers) >= 1


def test_a_main_script_that_fails_in_the_fork_server_changes_nothing(tmp_path: Path) -> None:
    """import_main keeps the fork server alive when the script raises or exits at import."""
    import json
    import os

    from chaintwin.ingest.forkserver import MAIN_ENV, import_main

    bodies = (
        "raise SystemExit(2)",
        "raise RuntimeError('no')",
        "import argparse\nargparse.ArgumentParser().parse_args(['--nope'])",
    )
    for body in bodies:
        script = tmp_path / "bad_script.py"
        script.write_text(body + "\n")
        main, argv = sys.modules["__main__"], list(sys.argv)
        os.environ[MAIN_ENV] = json.dumps(
            {"init_main_from_path": str(script), "sys_argv": [str(script), "--x"]}
        )
        assert import_main() is False
        assert MAIN_ENV not in os.environ  # taken, not left for the workers
        assert sys.modules["__main__"] is main and sys.argv == argv
        assert "__mp_main__" not in sys.modules


@pytest.mark.parametrize(
    ("args", "expected"),
    [
        (["ingest", "recs/", "--profiles", "p/"], None),  # one per core
        (["ingest", "recs/", "--workers", "2"], True),
        (["ingest", "recs/", "--workers=3"], True),
        (["ingest", "recs/", "--workers", "1"], False),
        (["ingest", "recs/", "--workers=1"], False),
        (["ingest", "recs/", "--scheduler", "tcp://h:8786", "--workers", "4"], False),
        (["ingest", "recs/", "--scheduler=tcp://h:8786"], False),
        (["ingest", "--help"], False),
        (["ingest", "recs/", "--workers", "two"], False),
        (["report", "--fleet"], False),
        (["demo"], None),
        (["demo", "--workers", "1"], False),
        ([], False),
    ],
)
def test_the_entry_point_reads_whether_an_ingest_starts_local_workers(
    args: list[str], expected: bool | None, monkeypatch: pytest.MonkeyPatch
) -> None:
    for cores in (1, 2):
        monkeypatch.setattr("os.cpu_count", lambda cores=cores: cores)
        want = (cores > 1) if expected is None else expected
        assert starts_local_workers(args) is want


def test_the_package_s_parts_are_reachable_as_attributes() -> None:
    code = (
        "import chaintwin; print(chaintwin.read.load_profile.__name__, "
        "chaintwin.simulate.simulate.__name__, chaintwin.load_recording.__name__)"
    )
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True
    )
    assert done.stdout.split() == ["load_profile", "simulate", "load_recording"]


def test_the_entry_point_and_the_error_tree_import_nothing_heavy() -> None:
    code = (
        "import sys, chaintwin.cli, chaintwin.errors; "
        "print(sorted(m for m in ('numba', 'scipy', 'sqlalchemy', 'statsmodels', 'typer') "
        "if m in sys.modules))"
    )
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True
    )
    assert done.stdout.strip() == "[]"


@pytest.mark.slow
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="pipe sizes are Linux's")
def test_the_ingest_pool_s_results_pipe_holds_a_whole_task_s_results(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    import fcntl
    import os

    from chaintwin.ingest import forkserver
    from chaintwin.ingest.pipeline import executor

    def pipe_size(ex: object) -> int:
        reader = ex._result_queue._reader  # type: ignore[attr-defined]
        size: int = fcntl.fcntl(reader.fileno(), fcntl.F_GETPIPE_SZ)
        return size

    r, w = os.pipe()
    default = fcntl.fcntl(r, fcntl.F_GETPIPE_SZ)
    os.close(r)
    os.close(w)
    limit = int(Path("/proc/sys/fs/pipe-max-size").read_text())
    wanted = max(default, min(forkserver.RESULT_PIPE_BYTES, limit))
    with executor(2, None) as ex:  # the pool an ingest uses
        assert pipe_size(ex) >= wanted
        assert ex.submit(divmod, 7, 2).result() == (3, 1)  # and it works
    monkeypatch.setattr(forkserver, "RESULT_PIPE_BYTES", 0)  # 0: left as the system makes it
    with executor(2, None) as ex:
        assert pipe_size(ex) == default


def test_the_fork_server_s_warm_up_runs_a_worker_s_whole_part() -> None:
    # in a new interpreter: importing the warm-up freezes the garbage collector
    done = subprocess.run(
        [sys.executable, "-c", "import chaintwin.ingest.warm as w; print(w.warm_up())"],
        capture_output=True,
        text=True,
        check=True,
        timeout=300,
    )
    assert done.stdout.split() == ["True"]  # calibrated, and features computed
