"""Integers of a sane size in the files chaintwin reads (profiles, calibrations, states).

Python reads an integer of any length, and refuses to turn one of more than
4 300 digits into text (a ``ValueError`` while the file is parsed). No
number chaintwin reads needs more than a 64-bit integer: the parsers here
read a longer one as a :class:`HugeInteger` marker, and
:func:`refuse_huge_integers` refuses the document in one line naming the
field where it stands.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from typing import Any

from chaintwin.errors import ChaintwinError

__all__ = [
    "MAX_INTEGER",
    "HugeInteger",
    "bounded",
    "bounded_int",
    "huge_integer_at",
    "json_loads",
    "refuse_huge_integers",
]

MAX_INTEGER = 2**63 - 1
"""Largest integer (in size) a file may hold: a 64-bit count, 19 digits."""

_MAX_DIGITS = len(str(MAX_INTEGER))


class HugeInteger:
    """An integer too large for any field, as the parsers leave it (its digit count).

    Parameters
    ----------
    digits : int
        How many characters its text has (sign included).
    """

    __slots__ = ("digits",)

    def __init__(self, digits: int) -> None:
        self.digits = digits

    def __repr__(self) -> str:
        return f"<an integer of {self.digits} digits>"


def bounded_int(text: str) -> int | HugeInteger:
    """The integer of a JSON number's text, or a :class:`HugeInteger` beyond :data:`MAX_INTEGER`."""
    sign = "-" if text.startswith("-") else ""
    digits = text.lstrip("+-").lstrip("0") or "0"
    if len(digits) > _MAX_DIGITS:
        return HugeInteger(len(digits))
    value = int(sign + digits)
    return value if -MAX_INTEGER <= value <= MAX_INTEGER else HugeInteger(len(digits))


def bounded(value: int, text: str) -> int | HugeInteger:
    """``value`` (read from ``text``), or a :class:`HugeInteger` beyond :data:`MAX_INTEGER`."""
    return value if -MAX_INTEGER <= value <= MAX_INTEGER else HugeInteger(len(text))


def json_loads(text: str) -> Any:
    """Parse JSON text; an integer beyond :data:`MAX_INTEGER` becomes a :class:`HugeInteger`.

    Raises
    ------
    json.JSONDecodeError, RecursionError
        As :func:`json.loads`.
    """
    return json.loads(text, parse_int=bounded_int)


def huge_integer_at(data: Any) -> tuple[str, int] | None:
    """Where the first integer beyond :data:`MAX_INTEGER` stands (dotted path) and its digits.

    Both a :class:`HugeInteger` left by the parsers and a Python integer
    beyond the bound (a document built otherwise) are found.
    """
    stack: list[tuple[str, Any]] = [("", data)]
    while stack:
        path, node = stack.pop()
        if isinstance(node, HugeInteger):
            return path or "(top level)", node.digits
        if isinstance(node, int) and not isinstance(node, bool):
            if not -MAX_INTEGER <= node <= MAX_INTEGER:
                return path or "(top level)", int(abs(node).bit_length() * 0.30103) + 1
        elif isinstance(node, dict):
            items = [(f"{path}.{k}" if path else str(k), v) for k, v in node.items()]
            stack.extend(reversed(items))
        elif isinstance(node, list | tuple):
            items = [(f"{path}.{k}" if path else str(k), v) for k, v in enumerate(node)]
            stack.extend(reversed(items))
    return None


def refuse_huge_integers(
    data: Any, source: str, error: Callable[[str], ChaintwinError], what: str
) -> None:
    """Refuse a document holding an integer beyond :data:`MAX_INTEGER`, naming its field.

    Parameters
    ----------
    data : Any
        The parsed document.
    source : str
        Where it came from, for the message.
    error : callable
        Builds the error from its message (the document's kind of error).
    what : str
        What the document is ("profile", "calibration", "state").

    Raises
    ------
    ChaintwinError
        Built by ``error``.
    """
    found = huge_integer_at(data)
    if found is None:
        return
    path, digits = found
    shown = "".join(c if c.isprintable() else repr(c)[1:-1] for c in path)[:200]
    raise error(
        f"{source}: field '{shown}': an integer of about {digits} digits, more than a {what} "
        f"may hold (at most {_MAX_DIGITS} digits); correct it"
    )
