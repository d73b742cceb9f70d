"""What every endpoint of ``hevr serve`` shares: who is asking (the bearer token), the request log
line, and every failure turned into a problem document (:func:`endpoint`).

The request log: one line per request, at INFO on the logger ``hevr.serve``, written once the
answer's last byte was handed to the server (a stream's at its end)::

    10.0.0.7 POST /v1/stores/ct/render 200 48213 radiology 2.315
    10.0.0.7 POST /v1/stores/ct/stream 499 12288 radiology 9.870 client left

The fields, space-separated (``docs/operator/logs.md``): the client's address (the
TCP peer: a reverse proxy's own address behind one; ``X-Forwarded-For`` is not read here), the
method, the path (percent-encoded as sent, no query string, at most 200 characters), the status,
the body bytes sent, the token's *name* (``-``: none asked, as on ``/v1/health``; ``anonymous``:
a server without tokens; never a token), the seconds from the request to its last byte, and an
optional note: ``client left`` when the client went away before the whole answer (status 499,
as nginx logs it; the bytes are those sent until then), ``failed`` when the server broke the
answer off (status 500; an ERROR line says why).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Awaitable, Callable
from typing import Any, NamedTuple

import anyio
from starlette.requests import ClientDisconnect, Request
from starlette.responses import Response
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from ...errors import CorruptStoreError
from ..problems import as_problem
from ..service import Service

log = logging.getLogger("hevr.serve")

__all__ = ["CLIENT_LEFT", "Caller", "ClientLeft", "endpoint", "log_line", "service"]

CLIENT_LEFT = 499  # the status logged for a client that went away (nginx's); never sent
_MAX_PATH = 200


class ClientLeft(Exception):
    """Raised by an endpoint that noticed its client went away (its work is dropped): logged with
    status :data:`CLIENT_LEFT` and the note ``client left``, answered with nothing."""


class Caller(NamedTuple):
    """Who asks: the token's name, its concurrent renders and its entry (None without tokens)."""

    name: str
    per_token: int
    token: Any


def service(request: Request) -> Service:
    """The application's :class:`~hevr.serve.service.Service` (its ``state``)."""
    return request.app.state.service


def log_line(request: Request, status: int, sent: int, name: str, seconds: float, note: str = "") -> None:
    """Log one request (the module docstring's format) at INFO on ``hevr.serve``."""
    client = request.client.host if request.client else "-"
    raw = request.scope.get("raw_path") or request.url.path.encode()
    path = raw.decode("ascii", "backslashreplace")[:_MAX_PATH]
    log.info(
        "%s %s %s %d %d %s %.3f%s",
        client,
        request.method,
        path,
        status,
        sent,
        name,
        seconds,
        f" {note}" if note else "",
    )


class _Logged:
    """An answer that logs its request once it is sent (or once its client left)."""

    def __init__(self, response: Any, request: Request, name: str, t0: float) -> None:
        self.response, self.request, self.name, self.t0 = response, request, name, t0

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        status, sent, done = getattr(self.response, "status_code", 200), 0, False

        async def counted(message: Message) -> None:
            nonlocal status, sent, done
            if message["type"] == "http.response.start":
                status = message["status"]
            elif message["type"] == "http.response.body":
                sent += len(message.get("body", b""))
                done = done or not message.get("more_body", False)
            await send(message)

        failed: BaseException | None = None
        try:
            await self.response(scope, receive, counted)
        except BaseException as exc:
            failed = exc
            raise
        finally:  # cut short by a client that went away (a failed send included), or by the server's own failure
            left = failed is None or isinstance(failed, (ClientDisconnect, OSError, anyio.get_cancelled_exc_class()))
            if self.request.method == "HEAD":
                sent = 0
            code, note = (status, "") if done else (CLIENT_LEFT, "client left") if left else (500, "failed")
            log_line(self.request, code, sent, self.name, time.perf_counter() - self.t0, note)


def endpoint(
    fn: Callable[[Request, Caller], Awaitable[ASGIApp]], *, public: bool = False
) -> Callable[[Request], Awaitable[Any]]:
    """A Starlette endpoint of ``fn(request, caller)``: the token checked first (unless ``public``),
    every failure a problem document, one log line per request (the module docstring)."""

    async def handler(request: Request) -> Any:
        t0 = time.perf_counter()
        name = "-"
        try:
            caller = Caller("-", 0, None) if public else Caller(*service(request).who(request))
            name = caller.name
            response = await fn(request, caller)
        except (ClientLeft, ClientDisconnect):  # nobody to answer: logged as such
            log_line(request, CLIENT_LEFT, 0, name, time.perf_counter() - t0, "client left")
            return Response(status_code=CLIENT_LEFT)
        except Exception as exc:  # every failure is a problem document
            if isinstance(exc, CorruptStoreError):  # rewritten under the server? looked at by the next request
                service(request).watch.soon()
            response = as_problem(exc).response()
        return _Logged(response, request, name, t0)

    handler.__name__ = handler.__qualname__ = fn.__name__
    return handler
