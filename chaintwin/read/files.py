"""Reading an input file safely: regular files only, and none larger than the limit.

Every loader (recordings, profiles, column maps, calibrations, state files)
reads through :func:`read_limited`, so that a named pipe, a device or a
socket given as a file is refused instead of blocking forever, and an
oversized file is refused before it is read (memory stays bounded by the
limit). Symbolic links are followed to the file they name; a loop of links
is refused.

The limit is :data:`DEFAULT_MAX_FILE_MB` (64 MB) unless the environment
variable ``CHAINTWIN_MAX_FILE_MB`` says otherwise (the command line's
``--max-file-mb`` sets it, so worker processes see the same limit).
"""

from __future__ import annotations

import contextlib
import math
import os
import re
import stat
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import yaml

from chaintwin.errors import ChaintwinError

from .integers import HugeInteger, bounded

__all__ = [
    "DEFAULT_MAX_FILE_MB",
    "MAX_FILE_MB_ENV",
    "max_file_bytes",
    "read_limited",
    "write_atomic",
    "yaml_load",
]

DEFAULT_MAX_FILE_MB = 64.0
"""Largest input file read, MB (10⁶ bytes), unless set otherwise."""

MAX_FILE_MB_ENV = "CHAINTWIN_MAX_FILE_MB"
"""The environment variable that sets the limit, MB."""

_MB = 1_000_000

_UMASK = os.umask(0)
os.umask(_UMASK)  # read once: the mode new files get (0o666 less the umask)


def max_file_bytes() -> int:
    """The largest input file read, bytes (``CHAINTWIN_MAX_FILE_MB``, else 64 MB).

    Raises
    ------
    ChaintwinError
        When the environment variable is not a positive number.
    """
    given = os.environ.get(MAX_FILE_MB_ENV)
    if given is None or given.strip() == "":
        return int(DEFAULT_MAX_FILE_MB * _MB)
    try:
        mb = float(given)
    except ValueError:
        mb = math.nan
    if not (math.isfinite(mb) and mb > 0.0):
        raise ChaintwinError(
            f"max_file_mb {given!r} (from {MAX_FILE_MB_ENV}) must be a positive number of MB",
            field="max_file_mb",
        )
    return int(mb * _MB)


def read_limited(
    path: str | Path, *, what: str, error: Callable[[str, str], ChaintwinError]
) -> bytes:
    """The bytes of a regular file no larger than :func:`max_file_bytes`.

    Parameters
    ----------
    path : str or Path
        The file (a symbolic link is followed).
    what : str
        What the file should be, for messages (``"recording"``, ``"profile"``).
    error : callable
        Makes the loader's own error from ``(source, message)``.

    Raises
    ------
    ChaintwinError
        Of the loader's type: the file is missing or unreadable, a folder, not
        a regular file, or larger than the limit (``field`` ``max_file_mb``).
    """
    source = str(path)
    limit = max_file_bytes()
    try:
        info = os.stat(path)  # follows links; a loop raises ELOOP
    except OSError as exc:
        raise error(source, f"cannot be read ({exc.strerror or exc}); check the path") from None
    if stat.S_ISDIR(info.st_mode):
        raise error(source, f"is a folder, not a {what} file")
    if not stat.S_ISREG(info.st_mode):
        raise error(
            source,
            f"is not a regular file (a pipe, device or socket); give a {what} file",
        )
    if info.st_size > limit:
        raise _too_large(error, source, info.st_size, limit, what)
    try:
        # O_NONBLOCK: should the path have become a pipe since the check, open
        # must not wait for a writer
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    except OSError as exc:
        raise error(source, f"cannot be read ({exc.strerror or exc}); check the path") from None
    with os.fdopen(fd, "rb") as handle:
        info = os.fstat(handle.fileno())
        if not stat.S_ISREG(info.st_mode):
            raise error(source, f"is not a regular file; give a {what} file")
        # read(n) allocates n bytes first: ask for the file's size, not the limit
        data = handle.read(min(info.st_size, limit) + 1)
        if len(data) > info.st_size:  # it grows while being read
            data += handle.read(limit + 1 - len(data))
    if len(data) > limit:  # it grew while being read
        raise _too_large(error, source, len(data), limit, what)
    return data


def write_atomic(
    path: str | Path,
    content: str | bytes | Callable[[Path], None],
    *,
    what: str,
    error: Callable[[str, str], ChaintwinError],
) -> Path:
    """Write a file so that a reader sees the old one or the whole new one, never half.

    The content goes to a temporary file of a unique name beside the target
    (``.<name>.<random>.tmp``), which is then renamed over it. On any failure
    the temporary file is removed and the target left as it was; the error
    names the target and the system's reason.

    Parameters
    ----------
    path : str or Path
        The file to write.
    content : str, bytes or callable
        Text (UTF-8), bytes, or a function that writes the file at the path
        it is given (e.g. a figure's ``savefig``).
    what : str
        What the file is, for messages (``"calibration"``, ``"report"``).
    error : callable
        Makes the caller's own error from ``(target, message)``.

    Raises
    ------
    ChaintwinError
        Of the caller's type, when the file cannot be written.
    """
    target = Path(path)
    tmp: Path | None = None
    try:
        fd, name = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
        tmp = Path(name)
        with os.fdopen(fd, "wb") as handle:
            if isinstance(content, str):
                handle.write(content.encode("utf-8"))
            elif isinstance(content, bytes):
                handle.write(content)
        if callable(content):
            content(tmp)
        os.chmod(tmp, 0o666 & ~_UMASK)  # mkstemp makes it private; give it the usual mode
        os.replace(tmp, target)
        tmp = None
    except OSError as exc:
        raise error(
            str(target), f"cannot write the {what} ({exc.strerror or exc}); check the folder"
        ) from None
    finally:
        if tmp is not None:
            with contextlib.suppress(OSError):  # never masks the error above
                tmp.unlink()
    return target


def _too_large(
    error: Callable[[str, str], ChaintwinError], source: str, size: int, limit: int, what: str
) -> ChaintwinError:
    exc = error(
        source,
        f"{size / _MB:.1f} MB is more than a {what} file may hold (max_file_mb "
        f"{limit / _MB:g} MB); raise the limit if the file is right",
    )
    exc.field = "max_file_mb"
    return exc


class _Loader(yaml.SafeLoader):
    """YAML's safe loader that reads ``2.7e9`` as a number, as YAML 1.2 does.

    PyYAML follows YAML 1.1, where an exponent needs a sign (``2.7e+9``) and
    ``2.7e9`` is a string; profile fields are strict numbers, so it would be
    refused.
    """


_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(
        r"""^(?:[-+]?(?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+]?[0-9]+)?
        |[-+]?(?:[0-9][0-9_]*)(?:[eE][-+]?[0-9]+)
        |\.[0-9_]+(?:[eE][-+]?[0-9]+)?
        |[-+]?\.(?:inf|Inf|INF)
        |\.(?:nan|NaN|NAN))$""",
        re.X,
    ),
    list("-+0123456789."),
)


def _bounded_yaml_int(loader: yaml.SafeLoader, node: yaml.ScalarNode) -> int | HugeInteger:
    """A YAML integer; one beyond :data:`~.integers.MAX_INTEGER` as a :class:`HugeInteger`."""
    text = str(node.value)
    if len(text.replace("_", "").lstrip("+-0")) > 4000:  # past Python's int-to-text limit
        return HugeInteger(len(text))
    return bounded(yaml.SafeLoader.construct_yaml_int(loader, node), text)


_Loader.add_constructor("tag:yaml.org,2002:int", _bounded_yaml_int)


def yaml_load(text: str) -> Any:
    """Parse YAML text with :class:`_Loader` (safe; numbers with any exponent).

    An integer beyond :data:`~.integers.MAX_INTEGER` is read as a
    :class:`~.integers.HugeInteger` (:func:`~.integers.refuse_huge_integers`
    names its field).
    """
    return yaml.load(text, Loader=_Loader)
