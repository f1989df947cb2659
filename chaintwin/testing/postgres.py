"""A throwaway PostgreSQL server of its own, for the tests and the benchmarks.

The store's PostgreSQL tests and the benchmarks that compare PostgreSQL with
SQLite need a server nobody else uses: :func:`throwaway_postgres` makes a
data folder with ``initdb``, starts ``pg_ctl`` on a free port bound to
127.0.0.1 (trust authentication, user ``postgres``), yields its URL and
stops and removes it afterwards. Run as root, the server runs as the
``postgres`` user (PostgreSQL refuses root). Nothing here is used by the
commands.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import socket
import subprocess
import tempfile
from collections.abc import Iterator
from pathlib import Path

__all__ = ["free_port", "postgres_binaries", "throwaway_postgres"]


def postgres_binaries() -> Path | None:
    """The folder holding ``initdb`` and ``pg_ctl`` (PATH first, then Debian's), or None."""
    found = shutil.which("initdb")
    if found:
        return Path(found).resolve().parent
    for cand in sorted(Path("/usr/lib/postgresql").glob("*/bin"), reverse=True):
        if (cand / "initdb").exists():
            return cand
    return None


def free_port() -> int:
    """A TCP port on 127.0.0.1 that was free a moment ago."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@contextlib.contextmanager
def throwaway_postgres(bindir: Path, *, prefix: str = "chaintwin-pg-") -> Iterator[str]:
    """Start a PostgreSQL server of our own; yield its URL; stop and remove it.

    Parameters
    ----------
    bindir : Path
        Where ``initdb`` and ``pg_ctl`` are (:func:`postgres_binaries`).
    prefix : str
        Name prefix of the temporary folder (data, socket, log).

    Yields
    ------
    str
        ``postgresql://postgres@127.0.0.1:<port>/postgres``.

    Raises
    ------
    subprocess.CalledProcessError
        When ``initdb`` or ``pg_ctl start`` fails (its output attached).
    """
    # not under a test's own folder: the server may run as another user, who must reach it
    root = Path(tempfile.mkdtemp(prefix=prefix))
    data, port = root / "data", free_port()
    as_user: list[str] = []
    if os.geteuid() == 0:  # the server refuses to run as root
        root.chmod(0o777)
        as_user = ["runuser", "-u", "postgres", "--"]
    try:
        subprocess.run(
            [*as_user, str(bindir / "initdb"), "-D", str(data), "-U", "postgres", "-A", "trust"],
            check=True,
            capture_output=True,
        )
        options = f"-p {port} -k {root} -c listen_addresses=127.0.0.1"
        log = str(root / "log")  # not a pipe: the server would hold it open
        start = ["-D", str(data), "-o", options, "-l", log, "-w", "start"]
        subprocess.run([*as_user, str(bindir / "pg_ctl"), *start], check=True, capture_output=True)
        yield f"postgresql://postgres@127.0.0.1:{port}/postgres"
    finally:
        subprocess.run(
            [*as_user, str(bindir / "pg_ctl"), "-D", str(data), "-m", "fast", "stop"],
            capture_output=True,
            check=False,
        )
        shutil.rmtree(root, ignore_errors=True)
