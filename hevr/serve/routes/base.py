"""What every endpoint of ``hevr serve`` shares: who is asking (the bearer token), the request log
line, and every failure turned into a problem document (:func:`endpoint`).

The log holds method, path, status, the token's *name* (never a token) and the seconds taken.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Awaitable, Callable
from typing import Any, NamedTuple

from starlette.requests import Request
from starlette.responses import Response

from ..problems import as_problem
from ..service import Service

log = logging.getLogger("hevr.serve")

__all__ = ["Caller", "endpoint", "service"]


class Caller(NamedTuple):
    """Who asks: the token's name, its concurrent renders and its entry (None without tokens)."""

    name: str
    per_token: int
    token: Any


def service(request: Request) -> Service:
    """The application's :class:`~hevr.serve.service.Service` (its ``state``)."""
    return request.app.state.service


def endpoint(fn: Callable[[Request, Caller], Awaitable[Response]], *, public: bool = False) -> Callable:
    """A Starlette endpoint of ``fn(request, caller)``: the token checked first (unless ``public``),
    every failure a problem document, one log line per request."""
    async def handler(request: Request) -> Response:
        t0 = time.perf_counter()
        name = "-"
        try:
            caller = Caller("-", 0, None) if public else Caller(*service(request).who(request))
            name = caller.name
            response = await fn(request, caller)
        except Exception as exc:  # every failure is a problem document
            response = as_problem(exc).response()
        log.info("%s %s %d %s %.3f s", request.method, request.url.path, response.status_code, name,
                 time.perf_counter() - t0)
        return response
    handler.__name__ = handler.__qualname__ = fn.__name__
    return handler
