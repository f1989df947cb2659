"""Reading an input file safely: regular files only, and none larger than the limit.

Every loader (recordings, profiles, column maps, calibrations, state files)
and the live service's watched folders read through :func:`read_limited`, so
that a named pipe, a device or a socket given as a file is refused instead of
blocking forever, and an oversized file is refused before it is read, or
once reading passes the limit should it grow (memory stays bounded by the
limit). What decides is the opened descriptor (``fstat``), not the name.
Symbolic links are followed to the file they name; a loop of links is
refused.

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
from typing import Any, BinaryIO

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

    The one way bytes of a file come in (the command line, the watched
    folders, the live service's re-reads). What is read is decided on the
    opened descriptor, not on the name: the file is opened without waiting
    (``O_NONBLOCK``: a pipe without a writer does not block) and without
    becoming a terminal (``O_NOCTTY``), and ``fstat`` of the descriptor must
    show a regular file no larger than the limit; a look at the name before
    opening keeps devices, pipes and sockets from being opened at all. The
    limit is enforced while reading too: a file that grows past it while
    being read (or reports a size of 0 but yields more, as ``/proc`` files
    do) is refused once the limit is passed, having held at most the limit
    in memory.

    Parameters
    ----------
    path : str or Path
        The file (a symbolic link is followed; it must lead to a regular file).
    what : str
        What the file should be, for messages (``"recording"``, ``"profile"``).
    error : callable
        Makes the loader's own error from ``(source, message)``.

    Raises
    ------
    ChaintwinError
        Of the loader's type: the file is missing or unreadable (its cause the
        ``OSError``), a folder, not a regular file, or larger than the limit,
        or grew past it while being read (``field`` ``max_file_mb``).
    """
    source = str(path)
    limit = max_file_bytes()
    try:
        # a first look by name: a device, pipe or socket is not even opened
        # (opening some devices does something); the descriptor decides below
        named = os.stat(path)  # follows links; a loop raises ELOOP
    except OSError as exc:
        raise error(source, f"cannot be read ({exc.strerror or exc}); check the path") from exc
    _check_kind(named, source, what, limit, error)
    try:
        fd = os.open(path, os.O_RDONLY | _NONBLOCK | _NOCTTY | _CLOEXEC)
    except OSError as exc:
        raise error(source, f"cannot be read ({exc.strerror or exc}); check the path") from exc
    with os.fdopen(fd, "rb") as handle:
        opened = os.fstat(handle.fileno())  # what was opened, whatever the name now is
        _check_kind(opened, source, what, limit, error)
        try:
            return _read_at_most(handle, opened.st_size, limit, source, what, error)
        except OSError as exc:
            raise error(source, f"cannot be read ({exc.strerror or exc}); check the path") from exc


_NONBLOCK = getattr(os, "O_NONBLOCK", 0)
_NOCTTY = getattr(os, "O_NOCTTY", 0)
_CLOEXEC = getattr(os, "O_CLOEXEC", 0)

_CHUNK = 1 << 20
"""What is read at a time beyond the size ``fstat`` gave, bytes."""


def _check_kind(
    info: os.stat_result,
    source: str,
    what: str,
    limit: int,
    error: Callable[[str, str], ChaintwinError],
) -> None:
    """Refuse what is not a regular file no larger than ``limit`` (from its stat)."""
    if stat.S_ISDIR(info.st_mode):
        raise error(source, f"is a folder, not a {what} file")
    if not stat.S_ISREG(info.st_mode):
        raise error(
            source,
            f"is not a regular file (a pipe, device or socket); give a {what} file",
        )
    if info.st_size > limit:
        raise _too_large(error, source, info.st_size, limit, what)


def _read_at_most(
    handle: BinaryIO,
    size: int,
    limit: int,
    source: str,
    what: str,
    error: Callable[[str, str], ChaintwinError],
) -> bytes:
    """Read an opened regular file of ``size`` bytes (``fstat``), refusing it past ``limit``.

    One read of the size ``fstat`` gave (one allocation, as large as the
    file); should more come (it grows, or its size was not told), the rest
    in chunks of :data:`_CHUNK` until the end or until the limit is passed.
    """
    data: bytes = handle.read(size + 1) or b""
    if len(data) <= size:
        return data
    parts = [data]
    total = len(data)
    while total <= limit:
        chunk: bytes = handle.read(min(_CHUNK, limit + 1 - total)) or b""
        if not chunk:
            break
        parts.append(chunk)
        total += len(chunk)
    if total > limit:
        del parts
        exc = error(
            source,
            f"grew past {limit / _MB:g} MB while being read (max_file_mb {limit / _MB:g} MB); "
            f"a {what} file is read once complete: check what writes it",
        )
        exc.field = "max_file_mb"
        raise exc
    return b"".join(parts)


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
