"""The trace lines of ``chaintwin serve``: a maintainers' tool, off unless asked for.

With ``CHAINTWIN_TRACE_SLOW_MS=N`` in the environment the serving process
writes one line per event to stderr (``trace <unix time> ...``): the web
server's slow requests, collections and loop stalls
(:mod:`chaintwin.web.trace`) and the live service's ``malloc_trim``
(:func:`trace_trim`). This module holds the switch and the line; the web
server's probes sit above it.
"""

from __future__ import annotations

import os
import sys
import time

__all__ = ["slow_ms", "trace_line", "trace_trim"]


def slow_ms() -> float | None:
    """The threshold of ``CHAINTWIN_TRACE_SLOW_MS``, ms (None: tracing off)."""
    text = os.environ.get("CHAINTWIN_TRACE_SLOW_MS", "")
    try:
        value = float(text)
    except ValueError:
        return None
    return value if value > 0 else None


def trace_line(text: str) -> None:
    """Write ``trace <unix time, s> <text>`` to stderr at once."""
    sys.stderr.write(f"trace {time.time():.3f} {text}\n")
    sys.stderr.flush()


def trace_trim(seconds: float) -> None:
    """Report a ``malloc_trim`` that took ``seconds``, s (when tracing)."""
    if slow_ms() is not None:
        trace_line(f"malloc_trim ms={1e3 * seconds:.1f}")
