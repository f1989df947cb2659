"""The optional parts of an install (``pip install 'chaintwin[web]'``) and their check.

``pip install chaintwin`` gives the library and the batch command line. The
extras add the rest:

========== =============================================================
extra      what it adds
========== =============================================================
web        the dashboard and JSON API (``chaintwin serve``)
live       watched folders, OPC UA drives, alarm notifications (and web)
postgres   PostgreSQL stores (``--db postgresql://...``)
dask       a Dask cluster for the ingest (``ingest --scheduler``)
all        everything above
========== =============================================================

A command or option that needs an extra calls :func:`require_extra` before it
imports it: a missing one is a one-line error naming the extra to install
(exit 2 on the command line), not a traceback.
"""

from __future__ import annotations

import importlib

from chaintwin.errors import ChaintwinError

__all__ = ["EXTRAS", "EXTRA_MODULES", "require_extra"]

EXTRA_MODULES: dict[str, tuple[str, ...]] = {
    "web": ("fastapi", "uvicorn", "fastapi_offline", "plotly", "prometheus_client"),
    "live": ("asyncua", "watchfiles", "httpx"),
    "postgres": ("psycopg",),
    "dask": ("distributed",),
}
"""What each extra installs that chaintwin imports (the web service serves ``/metrics``)."""

EXTRAS: tuple[str, ...] = (*EXTRA_MODULES, "all")
"""The extras ``pyproject.toml`` declares."""


def require_extra(extra: str, *modules: str, needed_by: str = "") -> None:
    """Check that the modules an extra installs can be imported.

    Parameters
    ----------
    extra : str
        The extra that installs them (one of :data:`EXTRAS`).
    *modules : str
        Importable names, e.g. ``"asyncua"``; default: all the extra installs
        (:data:`EXTRA_MODULES`).
    needed_by : str, optional
        What needs them, for the message (``"chaintwin serve"``, ``"--opcua"``);
        default: the extra's name.

    Raises
    ------
    ChaintwinError
        When one of them cannot be imported; the message names the extra and
        the command that installs it.

    Examples
    --------
    >>> require_extra("web", "json")  # installed: nothing happens
    >>> require_extra("web", "no_such_module_here", needed_by="chaintwin serve")
    Traceback (most recent call last):
    ...
    chaintwin.errors.ChaintwinError: chaintwin serve needs the 'web' extra \
(no_such_module_here is not installed): pip install 'chaintwin[web]'
    """
    if extra not in EXTRAS:
        raise ValueError(f"unknown extra {extra!r}; one of {', '.join(EXTRAS)}")
    for module in modules or EXTRA_MODULES.get(extra, ()):
        try:
            importlib.import_module(module)
        except ImportError:
            what = needed_by or f"the {extra} part of chaintwin"
            raise ChaintwinError(
                f"{what} needs the '{extra}' extra ({module} is not installed): "
                f"pip install 'chaintwin[{extra}]'"
            ) from None
