"""Ingest of many recordings into a results store, on local processes or a Dask cluster.

:func:`ingest` reads, checks, weighs and monitors each recording
(:mod:`chaintwin.ingest.worker`, in worker processes started by
:mod:`chaintwin.ingest.forkserver` and warmed up by :mod:`chaintwin.ingest.warm`;
the pools in :mod:`chaintwin.ingest.executors`) and stores the results in
conveyor order (:mod:`chaintwin.ingest.pipeline`).

The names below are imported on first use (PEP 562): the worker processes
import ``chaintwin.ingest.worker`` without the store's database code.
"""

import typing as _typing

from chaintwin._lazy import lazy_getattr

if _typing.TYPE_CHECKING:
    from chaintwin.ingest.pipeline import IngestSummary, ingest

_LAZY: dict[str, str] = {
    "IngestSummary": "chaintwin.ingest.pipeline",
    "ingest": "chaintwin.ingest.pipeline",
}

__all__ = ["IngestSummary", "ingest"]


__getattr__ = lazy_getattr(__name__, _LAZY)
