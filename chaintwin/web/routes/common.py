"""What the API's routers share: their error answers, the orjson answer, the prefix."""

from __future__ import annotations

from typing import Any

import orjson
from fastapi import APIRouter, Response
from fastapi.encoders import jsonable_encoder

from chaintwin.web.models import ErrorBody

__all__ = ["ERRORS", "PREFIX", "fast_json", "make_router"]

PREFIX = "/api/v1"
"""Where the API's operations live."""

ERRORS: dict[int | str, dict[str, Any]] = {
    status: {"model": ErrorBody, "description": text}
    for status, text in (
        (400, "Bad input (the message says what to do)"),
        (401, "No or an unknown token"),
        (403, "The token's role is too low, or a browser change lacks its CSRF token"),
        (404, "No such conveyor, alarm, feature or recording"),
        (409, "A token of that name exists"),
        (413, "The upload is too large"),
        (422, "The request does not match its schema"),
    )
}
"""Every operation's error answers (``{"error": {"code", "message"}}``)."""


def make_router(tag: str) -> APIRouter:
    """A router of the API for one resource (its operations grouped under ``tag``)."""
    return APIRouter(prefix=PREFIX, tags=[tag], responses=ERRORS)


def fast_json(content: Any) -> Response:
    """A JSON response encoded by orjson at once (no generic encoder, no validation).

    For the answers that are large or polled; their operations declare their
    model for the document (``response_model``), and the tests check that
    the answers match it.
    """
    try:
        body = orjson.dumps(content, option=orjson.OPT_SERIALIZE_NUMPY)
    except TypeError:  # a value orjson does not know: FastAPI's encoder first
        body = orjson.dumps(jsonable_encoder(content), option=orjson.OPT_SERIALIZE_NUMPY)
    return Response(body, media_type="application/json")
