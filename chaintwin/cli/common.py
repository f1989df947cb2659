"""Helpers shared by the command modules: file lists, profiles, output."""

from __future__ import annotations

import itertools
import json
import re
import sys
from collections.abc import Callable, Iterable
from datetime import datetime
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, TypeVar

import typer
from rich.console import Console
from rich.markup import escape

from chaintwin.errors import ChaintwinError, ProfileError, RecordingError, StoreError

if TYPE_CHECKING:
    from chaintwin.read.columns import ColumnMap
    from chaintwin.read.profile import ConveyorProfile


__all__ = [
    "DB_HELP",
    "EDIT_STATE_HELP",
    "EXIT_ALARM",
    "EXIT_USAGE",
    "OPTION_OF_FIELD",
    "PROFILES_HELP",
    "ColumnsOption",
    "DbOption",
    "EditStateOption",
    "JsonListOption",
    "JsonObjectOption",
    "ProfilesOption",
    "db_option",
    "edit_state",
    "error_message",
    "error_object",
    "expand_recordings",
    "json_option",
    "load_options",
    "load_profiles",
    "parse_at",
    "print_json",
    "print_refused",
    "print_warning",
    "printable",
    "safe",
    "wants_json",
]

T = TypeVar("T")

EXIT_USAGE = 2
"""Exit code for bad input or usage."""
EXIT_ALARM = 3
"""Exit code for ``--fail-on-alarm`` when an alarm is open."""

OPTION_OF_FIELD: dict[str, str] = {
    "alarm_rule": "--alarm-rule",
    "baseline_n": "--baseline",
    "by": "--by",
    "column_map": "--columns",
    "days": "--days",
    "max_file_mb": "--max-file-mb",
    "drift": "--drift",
    "onset_day": "--onset",
    "out": "--out",
    "per_day": "--per-day",
    "png": "--png",
    "residual": "--residual",
    "scheduler": "--scheduler",
    "state": "--state",
    "url": "--db",
    "z_limit": "--z-limit",
}
"""The command-line option that sets each library field an error may name."""


def error_message(exc: ChaintwinError) -> str:
    """A library error in the command line's words: its field's name becomes the option's.

    An error about one setting names it (:attr:`ChaintwinError.field`); where
    an option sets it, the first mention of the field becomes the option
    (``days 0: ...`` → ``--days 0: ...``; ``a column map (column_map)`` →
    ``a column map (--columns)``).
    """
    message = str(exc)
    option = OPTION_OF_FIELD.get(exc.field or "")
    if option is None or exc.field is None:
        return message
    word = re.compile(rf"(?<![\w-]){re.escape(exc.field)}(?![\w-])")
    return word.sub(option, message, count=1)


#: The ``--columns`` option every command that reads recordings takes.
ColumnsOption = Annotated[
    Path | None,
    typer.Option("--columns", help="Column map YAML for exports named otherwise."),
]

DB_HELP = (
    "Results store URL (sqlite:///file.db, postgresql://...); default CHAINTWIN_DB, "
    "else sqlite:///chaintwin.db."
)
"""The help of ``--db`` where it names the results store."""

PROFILES_HELP = "Folder of profiles (*.yaml); recordings are matched to them by conveyor id."
"""The help of ``--profiles`` where recordings are matched to profiles."""

EDIT_STATE_HELP = "The monitoring state file (of `monitor --state`)."
"""The help of ``--state`` for the commands that change a monitoring state."""


def db_option(help: str = DB_HELP) -> Any:
    """The ``--db`` option (a results store URL), with its help."""
    return typer.Option("--db", help=help)


def json_option(help: str) -> Any:
    """The ``--json`` option (print JSON instead of text), with its help."""
    return typer.Option("--json", help=help)


#: ``--db``: the results store's URL (default CHAINTWIN_DB, else sqlite:///chaintwin.db).
DbOption = Annotated[str | None, db_option()]

#: ``--json`` of a command that prints a list.
JsonListOption = Annotated[bool, json_option("Print one JSON list.")]

#: ``--json`` of a command that prints one object.
JsonObjectOption = Annotated[bool, json_option("Print one JSON object.")]

#: ``--profiles``: a folder of profiles matched to recordings by conveyor id.
ProfilesOption = Annotated[Path | None, typer.Option("--profiles", help=PROFILES_HELP)]

#: ``--state`` of the commands that change a monitoring state file.
EditStateOption = Annotated[Path | None, typer.Option("--state", help=EDIT_STATE_HELP)]


def wants_json(args: Iterable[str]) -> bool:
    """Whether a command line asks for JSON output (``--json``, ``--format json``)."""
    words = list(args)
    if "--json" in words or "--format=json" in words:
        return True
    return any(a == "--format" and b == "json" for a, b in itertools.pairwise(words))


def error_object(exc: ChaintwinError, message: str | None = None) -> dict[str, str]:
    """A command-level error as JSON: ``{"code": ..., "message": ...}`` (and ``field``).

    ``code`` is the error's kind in snake case (``store_error``,
    ``recording_error``), stable for scripts; ``message`` the one line.
    """
    kind = re.sub(r"(?<!^)(?=[A-Z])", "_", type(exc).__name__).lower()
    out = {"code": kind, "message": error_message(exc) if message is None else message}
    if exc.field is not None:
        out["field"] = exc.field
    return out


_CONTROL = re.compile(r"[\x00-\x08\x0a-\x1f\x7f-\x9f]")
"""Control characters (C0 but the tab, DEL, C1): a file's text must not steer the terminal."""


def printable(text: str) -> str:
    """Text a file supplied, with its control characters (ESC, CR, ...) shown as U+FFFD.

    Names, metadata and messages come from files: an ``ESC ]0;...`` or
    ``ESC [2J`` in them would retitle or clear the user's terminal.
    """
    return _CONTROL.sub("\ufffd", text)


def safe(text: str) -> str:
    """:func:`printable` text with Rich markup escaped, for ``console.print``."""
    return escape(printable(text))


def print_refused(console: Console, error: str) -> None:
    """Print a refusal on one line (markup escaped, control characters replaced)."""
    console.print(f"[red]refused[/red] {safe(error)}", highlight=False, soft_wrap=True)


def print_warning(console: Console, where: str, code: str, message: str) -> None:
    """Print a warning on one line: ``warning <where>: <code>: <message>``."""
    prefix = f"{safe(where)}: " if where else ""
    console.print(
        f"[yellow]warning[/yellow] {prefix}[bold]{code}[/bold]: {safe(message)}",
        highlight=False,
        soft_wrap=True,
    )


def expand_recordings(paths: Iterable[Path]) -> list[str]:
    """Expand folders into their recording files (sorted); keep files as given.

    A folder's recording files are those matching a registered format's
    pattern (:func:`~chaintwin.read.formats.recording_patterns`: ``*.csv``
    and those of the formats added).

    Raises
    ------
    RecordingError
        When a folder holds no recording file.
    """
    from chaintwin.read.formats import recording_patterns

    patterns = recording_patterns()
    out: list[str] = []
    for p in paths:
        if p.is_dir():
            found = sorted({str(f) for pattern in patterns for f in p.rglob(pattern)})
            if not found:
                raise RecordingError(str(p), f"folder holds no {' or '.join(patterns)} recording")
            out.extend(found)
        else:
            out.append(str(p))
    return out


def load_options(
    profile: Path | None, columns: Path | None
) -> tuple[ConveyorProfile | None, ColumnMap | None]:
    """Load the optional ``--profile`` and ``--columns`` files."""
    from chaintwin.read.columns import load_column_map
    from chaintwin.read.profile import load_profile

    prof = load_profile(profile) if profile is not None else None
    cmap = load_column_map(columns) if columns is not None else None
    return prof, cmap


def load_profiles(profile: Path | None, profiles: Path | None) -> dict[str, ConveyorProfile]:
    """The profiles of ``--profile`` or ``--profiles``, by id (one loader: the library's).

    Raises
    ------
    ProfileError
        When neither or both are given, a folder holds none, or two share an id.
    """
    from chaintwin.read.profile import load_profile
    from chaintwin.read.profile import load_profiles as read_profiles

    if (profile is None) == (profiles is None):
        raise ProfileError("give either --profile FILE (one conveyor) or --profiles DIR")
    if profile is not None:
        p = load_profile(profile)
        return {p.id: p}
    assert profiles is not None
    return read_profiles(profiles)


def edit_state(
    state: Path | None,
    db: str | None,
    conveyor: str | None,
    edit: Callable[[dict[str, Any]], T],
    alarm: str | None = None,
) -> T:
    """Apply a change to a state file, or to the health model in a results store."""
    from chaintwin.diagnose.state import load_state, save_state

    if state is not None and db is not None:
        raise StoreError("give either --state (a state file) or --db (a results store), not both")
    if state is not None:
        data = load_state(state, missing_ok=False)
        out = edit(data)
        save_state(state, data)
        return out
    from chaintwin.store.engine import store_url
    from chaintwin.store.store import Store

    with Store(store_url(db), create=False) as store:
        if conveyor is None:
            conveyor = store.alarm_conveyor(alarm or "")
        return store.edit_state(conveyor, edit)


def parse_at(text: str | None, option: str = "--at") -> datetime | None:
    """A CLI option's ISO 8601 time, within the span of dates chaintwin accepts."""
    if text is None:
        return None
    try:
        at = datetime.fromisoformat(text)
    except ValueError:
        raise StoreError(
            f"{option} '{text}' is not an ISO 8601 time (e.g. 2026-11-21T10:15:00Z)",
            field=option.lstrip("-"),
        ) from None
    from chaintwin.diagnose.records import date_out_of_span

    refused = date_out_of_span(at)
    if refused is not None:
        raise StoreError(f"{option} {refused}", field=option.lstrip("-"))
    return at


def print_json(data: Any) -> None:
    """Print JSON to standard output (NaN/inf become null).

    Control characters in strings are written as JSON escapes (``\\u001b``),
    the C1 ones too, which JSON leaves as they are: a file's text cannot
    steer the terminal, and the data read back is the same.
    """
    text = json.dumps(_finite(data), indent=2, ensure_ascii=False)
    sys.stdout.write(_C1.sub(lambda m: f"\\u{ord(m.group()):04x}", text) + "\n")


_C1 = re.compile(r"[\x7f-\x9f]")
"""DEL and the C1 controls: not escaped by JSON, yet some terminals obey them."""


def _finite(obj: Any) -> Any:
    if isinstance(obj, float):
        return obj if obj == obj and obj not in (float("inf"), float("-inf")) else None
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_finite(v) for v in obj]
    return obj
