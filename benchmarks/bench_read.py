"""Benchmark: read + validate one 2048-sample, 8-channel recording.

Prints a table with the time per file of chaintwin's reader (parse only, and
parse + validation as every pipeline does it) against ``pandas.read_csv``
on the same text, measured in the same run. Target (issue 2): about 2 ms or
less for read + validate.

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

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from conftest import make_text, to_semicolon

from chaintwin import inspect_recording, parse_recording


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


if __name__ == "__main__":
    main()
