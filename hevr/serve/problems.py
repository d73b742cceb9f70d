"""Problem documents (RFC 9457) of ``hevr serve``: what a failed request answers, and nothing more.

Every failure becomes ``application/problem+json`` with a title, a status and a detail naming the
parameter (:class:`Problem`, :func:`as_problem`). hevr's own errors keep their message, less the
server's absolute file paths (:func:`public_text`; the whole message goes to the server's log); an
unexpected failure says only "internal error" and its traceback stays in the log, so an answer never
carries the server's internals.
"""

from __future__ import annotations

import logging
import re

from starlette.requests import Request
from starlette.responses import JSONResponse, Response

from ..errors import HevrError, IntegrityError, MemoryLimitError, ParameterError, RenderPlanError, StoreError
from ..remote.protocol import PROBLEM_MEDIA

log = logging.getLogger("hevr.serve")

__all__ = ["Problem", "as_problem", "not_found", "problem", "public_text"]


class Problem(Exception):
    """An answer that is an RFC 9457 problem document."""

    def __init__(self, status: int, title: str, detail: str, headers: dict | None = None) -> None:
        super().__init__(detail)
        self.status, self.title, self.detail, self.headers = status, title, detail, headers or {}

    def document(self) -> dict:
        """The problem document's JSON object."""
        return {"type": "about:blank", "title": self.title, "status": self.status, "detail": self.detail}

    def response(self) -> JSONResponse:
        """The answer: the document with its status and headers."""
        return JSONResponse(self.document(), status_code=self.status, media_type=PROBLEM_MEDIA, headers=self.headers)


def problem(status: int, title: str, detail: str, headers: dict | None = None) -> JSONResponse:
    """A problem document (``application/problem+json``)."""
    return Problem(status, title, detail, headers).response()


# An absolute path of the server's filesystem in a message: never sent (the log keeps it).
_SERVER_PATH = re.compile(r"(?<![\w.:/])/(?:[\w.@+~=-]+/)*[\w.@+~=-]+/?")


def public_text(text: str) -> str:
    """A message as a client may see it: the server's absolute file paths replaced by ``<server
    path>`` (relative fractions such as ``W/H`` or ``1/2`` stay; tests/serve/test_problems.py)."""
    return _SERVER_PATH.sub("<server path>", text)


def as_problem(exc: BaseException) -> Problem:
    """The problem document of a failed request: hevr's own errors with their message, less the
    server's file paths (:func:`public_text`; the whole message in the log), anything else as an
    internal error (logged here with its traceback, never sent)."""
    if isinstance(exc, Problem):
        return exc
    text = public_text(str(exc))
    if isinstance(exc, RenderPlanError):
        return Problem(422, "render refused by the planner", text)
    if isinstance(exc, ParameterError):
        return Problem(400, "bad request", text)
    if isinstance(exc, MemoryLimitError):
        return Problem(503, "server out of memory for this render", text, {"Retry-After": "5"})
    if isinstance(exc, (StoreError, IntegrityError)):
        log.error("store failed a check: %s", exc)
        return Problem(500, "store failed a check", text)
    if isinstance(exc, HevrError):
        log.error("render failed: %s", exc)
        return Problem(500, "render failed", text)
    log.error("internal error", exc_info=exc)
    return Problem(500, "internal error", "the server failed to render; its log has the details")


async def not_found(request: Request, exc: Exception) -> Response:
    """Starlette's 404 and 405 as problem documents (the app's exception handlers)."""
    status = getattr(exc, "status_code", 404)
    return problem(status, "not found" if status == 404 else "method not allowed",
                   f"{request.method} {request.url.path}: expected one of the /v1 endpoints "
                   "(/v1/openapi.json lists them)")
