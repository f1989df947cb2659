"""What the API's handlers depend on: the service's state and the caller's role.

``Depends(require_role("viewer"))`` gives a handler the request's
:class:`~chaintwin.web.security.Principal` once it holds at least that role
(401 without a valid token, 403 with too low a role). The guard
(:mod:`chaintwin.web.guard`) has found the principal of a request with a body
already and kept it in the request's scope
(:data:`~chaintwin.web.security.PRINCIPAL`); a reading request's principal is
found here, once, and kept there too. A dependency made with
``changes=True`` also wants a browser session's CSRF nonce
(``X-CSRF-Token``).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from fastapi import Request

from chaintwin.web.security import Principal, require

__all__ = ["require_role", "web_of"]


def web_of(request: Request) -> Any:
    """The service's shared state (:class:`~chaintwin.web.app.WebState`)."""
    return request.app.state.web


def require_role(role: str, *, changes: bool = False) -> Callable[[Request], Principal]:
    """A dependency giving the request's principal if it holds ``role`` (ApiError 401/403).

    Parameters
    ----------
    role : str
        ``viewer``, ``maintainer`` or ``admin``: the least role that may call.
    changes : bool
        The request changes something: a browser session must send its CSRF
        nonce (header ``X-CSRF-Token``); bearer calls need none.
    """

    def principal(request: Request) -> Principal:
        csrf = request.headers.get("x-csrf-token") if changes else None
        found = web_of(request).principal(request)  # read from the scope once found
        return require(found, role, changes=changes, csrf=csrf)

    principal.__name__ = f"require_{role}{'_changes' if changes else ''}"
    return principal
