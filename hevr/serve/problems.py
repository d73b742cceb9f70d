"""Problem documents (RFC 9457) of ``hevr serve``: what a failed request answers, and nothing more.

Every failure becomes ``application/problem+json`` with a title, a status and a detail naming the
parameter (:class:`Problem`, :func:`as_problem`). hevr's own errors keep their message, less the
server's absolute file paths, URLs and the served stores' locations as given (:func:`public_text`;
the whole message goes to the server's log); an
unexpected failure says only "internal error" and its traceback stays in the log, so an answer never
carries the server's internals.
"""

from __future__ import annotations

import contextlib
import logging
import os
import re
from collections.abc import Iterable

from starlette.requests import Request
from starlette.responses import JSONResponse, Response

from ..errors import HevrError, IntegrityError, MemoryLimitError, ParameterError, RenderPlanError, StoreError
from ..remote.protocol import PROBLEM_MEDIA

log = logging.getLogger("hevr.serve")

__all__ = ["Problem", "as_problem", "not_found", "problem", "private_locations", "public_text"]


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
# A URL (s3://bucket/key, gs://..., http(s)://..., file://...): where a store lives, never sent either.
_URL = re.compile(r"\b[A-Za-z][A-Za-z0-9+.-]{0,15}://[^\s'\"<>()\[\]{},;]*[^\s'\"<>()\[\]{},;:.]")
_PART = r"[\w.@+~=-]+"
_PRIVATE: set[str] = set()  # the served stores' locations as given (private_locations)
_private: tuple[frozenset, re.Pattern | None] = (frozenset(), None)


def private_locations(paths: Iterable[str]) -> None:
    """Add the locations of served stores (``ev.path``: a local path or a URL) to what
    :func:`public_text` replaces, with the forms a message may hold them in: a URL without its
    scheme (``bucket/key``: fsspec's), a local path relative to the working folder
    (``data/ct.zarr``: as the operator typed it). The service registers its own stores."""
    for p in map(str, paths):
        forms = {p.rstrip("/")}
        if "://" in p:
            forms.add(p.split("://", 1)[1].rstrip("/"))
        elif os.path.isabs(p):
            with contextlib.suppress(ValueError):
                rel = os.path.relpath(p)
                if not rel.startswith(".."):
                    forms.add(rel)
        _PRIVATE.update(f for f in forms if f and f != ".")


def _private_pattern() -> re.Pattern | None:
    global _private
    names = frozenset(_PRIVATE)
    if names != _private[0]:
        # a one-word location (``ct``) only with a part after it (``ct/scalar/c/0``): alone, it is a word
        alts = [
            re.escape(n) + (f"(?:/{_PART})*/?" if "/" in n or "." in n else f"(?:/{_PART})+/?")
            for n in sorted(names, key=len, reverse=True)
        ]
        _private = names, (re.compile(rf"(?<![\w.@+~=/-])(?:{'|'.join(alts)})(?![\w.@+~=-])") if alts else None)
    return _private[1]


def public_text(text: str) -> str:
    """A message as a client may see it: the served stores' locations (:func:`private_locations`),
    URLs and the server's absolute file paths replaced by ``<server path>`` (relative fractions
    such as ``W/H`` or ``1/2`` stay).

    >>> public_text("brick at s3://bucket/ct.zarr/scalar/c/0: gone (W/H 1/2, see /data/x)")
    'brick at <server path>: gone (W/H 1/2, see <server path>)'
    """
    private = _private_pattern()
    if private is not None:
        text = private.sub("<server path>", text)
    return _SERVER_PATH.sub("<server path>", _URL.sub("<server path>", text))


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
    return problem(
        status,
        "not found" if status == 404 else "method not allowed",
        f"{request.method} {request.url.path}: expected one of the /v1 endpoints (/v1/openapi.json lists them)",
    )
