"""A light start and the extras: what `--help` imports, and a missing extra said in one line.

Each check runs the command line in a fresh interpreter (a subprocess), so
that what this test process imported does not count.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from chaintwin.cli.demo_cmd import examples_dir
from chaintwin.extras import EXTRA_MODULES, EXTRAS

ROOT = Path(__file__).resolve().parents[1]

HEAVY = ("numba", "scipy", "sqlalchemy", "matplotlib", "fastapi", "dask", "asyncua")
"""What `chaintwin --help` and `chaintwin <command> --help` must not import."""

_HELP_RUNNER = """
import contextlib, io, json, sys
import click, typer
from chaintwin.cli import main

def commands(group, ctx, prefix):
    for name in group.list_commands(ctx):
        cmd = group.get_command(ctx, name)
        yield [*prefix, name]
        if isinstance(cmd, click.Group):
            yield from commands(cmd, click.Context(cmd, parent=ctx), [*prefix, name])

codes = {}
with contextlib.redirect_stdout(io.StringIO()):
    codes["--help"] = main(["--help"])
    from chaintwin.cli.app import app
    group = typer.main.get_command(app)
    for words in commands(group, click.Context(group), []):
        codes[" ".join(words)] = main([*words, "--help"])
print(json.dumps({"codes": codes, "modules": sorted(m.split(".")[0] for m in sys.modules)}))
"""


def _run(code: str, *args: str) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run(
        [sys.executable, "-c", code, *args],
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
        check=False,
    )


@pytest.mark.slow
def test_help_of_every_command_imports_nothing_heavy() -> None:
    """`--help`, and `--help` of every command and subcommand, load none of HEAVY."""
    done = _run(_HELP_RUNNER)
    assert done.returncode == 0, done.stderr
    out = json.loads(done.stdout)
    codes: dict[str, int] = out["codes"]
    assert {"--help", "identify", "weigh", "monitor", "ingest", "serve"} <= set(codes)
    assert set(codes.values()) == {0}, codes
    assert [m for m in HEAVY if m in out["modules"]] == []


_BLOCKED_RUNNER = """
import sys
for name in sys.argv[1].split(","):
    sys.modules[name] = None  # as if not installed: importing it raises ImportError
from chaintwin.cli import main
sys.exit(main(sys.argv[2:]))
"""


@pytest.mark.parametrize(
    ("blocked", "args", "extra", "needed_by"),
    [
        ("fastapi", ["serve", "--db", "sqlite:///{tmp}/plant.db"], "web", "chaintwin serve"),
        ("uvicorn", ["serve", "--db", "sqlite:///{tmp}/plant.db"], "web", "chaintwin serve"),
        ("asyncua", ["serve", "--opcua", "{tmp}/opcua.yaml"], "live", "--opcua"),
        ("watchfiles", ["serve", "--watch", "{tmp}"], "live", "--watch"),
        ("asyncua", ["drive-sim", "--profile", "{tmp}/p.yaml"], "live", "chaintwin drive-sim"),
        (
            "psycopg",
            ["db", "upgrade", "--db", "postgresql://u@127.0.0.1/x"],
            "postgres",
            "a PostgreSQL store",
        ),
        (
            "distributed",
            [
                "ingest",
                "{examples}/recordings",
                "--profiles",
                "{examples}/profiles",
                "--db",
                "sqlite:///{tmp}/plant.db",
                "--scheduler",
                "tcp://127.0.0.1:1",
            ],
            "dask",
            "a Dask scheduler (tcp://127.0.0.1:1)",
        ),
    ],
)
@pytest.mark.slow
def test_a_missing_extra_is_named_in_one_line_with_exit_2(
    tmp_path: Path, blocked: str, args: list[str], extra: str, needed_by: str
) -> None:
    examples = examples_dir()
    done = _run(
        _BLOCKED_RUNNER, blocked, *(a.format(tmp=tmp_path, examples=examples) for a in args)
    )
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1, done.stderr
    assert lines[0].startswith(f"chaintwin: error: {needed_by}")
    assert lines[0].endswith(
        f"needs the '{extra}' extra ({blocked} is not installed): pip install 'chaintwin[{extra}]'"
    )


def test_the_extras_checked_are_the_ones_declared() -> None:
    """Every extra :func:`require_extra` names is declared in pyproject.toml; dev has all."""
    declared = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"][
        "optional-dependencies"
    ]
    assert set(EXTRAS) <= set(declared)
    assert set(EXTRA_MODULES) < set(EXTRAS)
    assert "chaintwin[all]" in declared["dev"]
    assert "chaintwin[web]" in declared["live"]
