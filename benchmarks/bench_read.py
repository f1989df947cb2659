"""Benchmark: read + validate one 2048-sample, 8-channel recording; parse time against size.

Prints a table with the time per file of chaintwin's reader (parse only, and
parse + validation as every pipeline does it) against ``pandas.read_csv``
on the same text, measured in the same run. Target: about 2 ms or
less for read + validate.

Then the parse time of inputs ten times larger than each other (header
columns, metadata lines, blank lines, data rows), measured in the same run:
a ratio near 10 is linear time, near 100 quadratic. The header columns are
parsed cell by cell with the column cap lifted (as if it were not there), and
refused with it.

Run: ``.venv/bin/python benchmarks/bench_read.py``
"""

from __future__ import annotations

import io
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pandas as pd

import chaintwin.read.reader as reader

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from conftest import make_text, to_semicolon

from chaintwin import inspect_recording, parse_recording
from chaintwin.errors import RecordingError


def best_of(fn: Callable[[], object], repeat: int = 7, number: int = 50) -> float:
    """Best mean time per call over ``repeat`` rounds of ``number`` calls, s."""
    fn()  # warm up (numba compile / caches)
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        for _ in range(number):
            fn()
        times.append((time.perf_counter() - t0) / number)
    return min(times)


def main() -> None:
    text = make_text(n=2048)
    semi = to_semicolon(text)
    data = text.encode()
    assert parse_recording(text, "b").samples == 2048

    def pandas_comma() -> object:
        return pd.read_csv(io.BytesIO(data), comment="#")

    def pandas_semi() -> object:
        return pd.read_csv(io.BytesIO(semi.encode()), comment="#", sep=";", decimal=",")

    ref = best_of(pandas_comma)
    rows = [
        ("pandas.read_csv, ',' dialect (reference)", ref),
        ("pandas.read_csv, ';' dialect", best_of(pandas_semi)),
        ("chaintwin parse, ',' dialect", best_of(lambda: parse_recording(data, "b"))),
        ("chaintwin parse, ';' dialect", best_of(lambda: parse_recording(semi, "b"))),
        (
            "chaintwin parse + validate (segment, warnings)",
            best_of(lambda: inspect_recording(parse_recording(data, "b"))),
        ),
    ]
    print(f"2048 samples x 8 channels, {len(data) / 1024:.0f} KiB, best of 7 x 50 calls")
    print(f"{'what':50s} {'ms/file':>9s} {'ratio':>7s}")
    for name, t in rows:
        print(f"{name:50s} {t * 1e3:9.3f} {t / ref:7.2f}")
    check = pd.read_csv(io.BytesIO(data), comment="#").to_numpy()
    rec = parse_recording(data, "b")
    assert np.allclose(check[:, 6] * 2.5 / 100, rec.torque)


def wide_header(ncols: int) -> str:
    """A header-only recording of ``ncols`` columns (the required ones first)."""
    cells = ["time [s]", "speed [rpm]", "torque [Nm]"]
    cells += [f"c{k} [-]" for k in range(ncols - len(cells))]
    return "# conveyor: white-belt-01\n" + ",".join(cells) + "\n"


def refusal_time(text: str, needle: str, repeat: int = 5) -> float:
    """Best time to parse ``text`` into the refusal naming ``needle``, s."""
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        try:
            parse_recording(text, "b")
        except RecordingError as exc:
            assert needle in str(exc), exc
        else:
            raise AssertionError("not refused")
        best = min(best, time.perf_counter() - t0)
    return best


def parse_time(text: str, repeat: int = 5) -> float:
    """Best time to parse ``text``, s."""
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        parse_recording(text, "b")
        best = min(best, time.perf_counter() - t0)
    return best


def scaling() -> None:
    """Parse time of inputs 10x apart (same run): ratio ~10 linear, ~100 quadratic."""
    head, _, body = make_text(n=64).partition("time [s]")
    body = "time [s]" + body
    header, _, rows = body.partition("\n")

    def with_meta(k: int) -> str:
        return "".join(f"# extra_{j}: {j}\n" for j in range(k)) + make_text(n=64)

    def with_blanks(k: int) -> str:
        first, _, rest = rows.partition("\n")
        return head + header + "\n" + first + "\n" * k + "\n" + rest

    def with_rows(k: int) -> str:
        return make_text(n=k)

    cases: list[tuple[str, Callable[[int], float], int]] = [
        (
            "header columns, parsed cell by cell (cap lifted)",
            lambda k: refusal_time(wide_header(k), "holds 0 samples"),
            10_000,
        ),
        (
            "header columns, refused by the 256 cap",
            lambda k: refusal_time(wide_header(k), "more than the 256"),
            10_000,
        ),
        ("metadata lines", lambda k: parse_time(with_meta(k)), 10_000),
        (
            "blank lines in the body (line-by-line parser)",
            lambda k: parse_time(with_blanks(k)),
            10_000,  # 10^6 blank lines: refused, lines x columns over the values cap
        ),
        ("data rows (compiled parser)", lambda k: parse_time(with_rows(k)), 100_000),
    ]
    print()
    print(f"{'input':50s} {'n':>8s} {'s (n)':>9s} {'s (10 n)':>9s} {'ratio':>7s}")
    for name, timed, n in cases:
        lifted = name.endswith("(cap lifted)")
        saved = reader.MAX_COLUMNS
        if lifted:
            reader.MAX_COLUMNS = 10**9
        try:
            timed(n // 10)  # warm up
            small, large = timed(n), timed(10 * n)
        finally:
            reader.MAX_COLUMNS = saved
        print(f"{name:50s} {n:8d} {small:9.4f} {large:9.4f} {large / small:7.1f}")


if __name__ == "__main__":
    main()
    scaling()
