"""The web dashboard and HTTP API over a results store (``chaintwin serve``)."""

from chaintwin.web.app import create_app

__all__ = ["create_app"]
