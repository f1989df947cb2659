"""The web dashboard and HTTP API over a results store (``chaintwin serve``).

:func:`create_app` is imported on first use (PEP 562): the tokens and the
audit log (:mod:`chaintwin.web.access`) serve ``chaintwin token`` on an
install without the ``web`` extra.
"""

import typing as _typing

from chaintwin._lazy import lazy_getattr

if _typing.TYPE_CHECKING:
    from chaintwin.web.app import create_app

_LAZY: dict[str, str] = {"create_app": "chaintwin.web.app"}

__all__ = ["create_app"]


__getattr__ = lazy_getattr(__name__, _LAZY)
