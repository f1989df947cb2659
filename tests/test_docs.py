"""The library page's examples run as written (docs/library.md)."""

from __future__ import annotations

import doctest
from pathlib import Path

DOCS = Path(__file__).resolve().parents[1] / "docs"


def test_library_page_runs(tmp_path: Path) -> None:
    result = doctest.testfile(
        str(DOCS / "library.md"),
        module_relative=False,
        globs={"tmp": tmp_path},
        optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE,
    )
    assert result.attempted > 10
    assert result.failed == 0
