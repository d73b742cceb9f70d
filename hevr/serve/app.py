"""The ASGI application of ``hevr serve`` (Starlette, run by uvicorn): the endpoints of
:mod:`hevr.remote.protocol` over a set of opened stores and a Dask client.

What each limit answers:

* **Request size** (:data:`~hevr.remote.protocol.MAX_BODY`): a ``Content-Length`` above it is
  refused (413) before a byte of the body is read, and a body without one is read only that far;
  a client cannot make the server buffer more.
* **Strict JSON** (:func:`~hevr.remote.protocol.parse_json`, :class:`RenderRequest`): unknown
  fields, duplicate keys, NaN, 40-digit integers, deep nesting and out-of-range sizes are 400s
  before any work; the render's own planner (pixels, samples, overflow) is the second line.
* **Concurrent renders**: per token (its ``concurrent``), and for the whole server
  (``max_concurrent``): one more is a 429 with ``Retry-After``, so a client cannot queue
  unbounded work on the cluster.
* **Tokens** (:mod:`hevr.serve.tokens`): a missing or unknown token is a 401; a store the token
  may not render is a 404, as an unknown one (ids are not disclosed).
* **Errors** are RFC 9457 problem documents naming the parameter; an unexpected failure says
  only "internal error" (the server's log has the traceback), so the answer never carries the
  server's internals. The log holds method, path, status and the token's *name*, never a token.

Read-only: no endpoint writes a store; renders keep ray sums in memory (the render cache) only.
"""

from __future__ import annotations

import asyncio
import json
import logging
import re
import threading
import time
from contextlib import contextmanager
from typing import Any

import anyio
import numpy as np
from starlette.applications import Starlette
from starlette.requests import Request
from starlette.responses import JSONResponse, Response, StreamingResponse
from starlette.routing import Route

from .. import __version__
from ..errors import (
    HevrError,
    IntegrityError,
    MemoryLimitError,
    ParameterError,
    RenderPlanError,
    StoreError,
)
from ..remote.protocol import (
    API_VERSION,
    END,
    IMAGE_MEDIA,
    MAX_BODY,
    PROBLEM_MEDIA,
    UNITS_MEDIA,
    RenderRequest,
    VerifyRequest,
    check_store_name,
    pack_frame,
    parse_json,
)
from ..rendering.packed import PackedImage
from ..rendering.packed.colour import PackedColourImage
from ..rendering.packed.plane_image import PackedSlice
from .jobs import render_image, stats_header, verify_aggregate
from .openapi import openapi_document
from .tokens import TokenTable

log = logging.getLogger("hevr.serve")

__all__ = ["create_app", "problem"]


class Problem(Exception):
    """An answer that is an RFC 9457 problem document."""

    def __init__(self, status: int, title: str, detail: str, headers: dict | None = None) -> None:
        super().__init__(detail)
        self.status, self.title, self.detail, self.headers = status, title, detail, headers or {}


def problem(status: int, title: str, detail: str, headers: dict | None = None) -> JSONResponse:
    """A problem document (``application/problem+json``)."""
    body = {"type": "about:blank", "title": title, "status": status, "detail": detail}
    return JSONResponse(body, status_code=status, media_type=PROBLEM_MEDIA, headers=headers)


# An absolute path of the server's filesystem in a message: never sent (the log keeps it).
_SERVER_PATH = re.compile(r"(?<![\w.:/])/(?:[\w.@+~=-]+/)*[\w.@+~=-]+/?")


def public_text(text: str) -> str:
    """A message as a client may see it: the server's absolute file paths replaced by ``<server
    path>`` (relative fractions such as ``W/H`` or ``1/2`` stay; tests/serve/test_problems.py)."""
    return _SERVER_PATH.sub("<server path>", text)


def _as_problem(exc: BaseException) -> Problem:
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


class Limits:
    """Concurrent renders per token name and in all (thread-safe: released from render threads)."""

    def __init__(self, max_concurrent: int) -> None:
        self.max_concurrent = int(max_concurrent)
        self.lock = threading.Lock()
        self.running: dict[str, int] = {}
        self.total = 0

    @contextmanager
    def slot(self, name: str, per_token: int):
        with self.lock:
            if self.total >= self.max_concurrent or self.running.get(name, 0) >= per_token:
                raise Problem(429, "too many concurrent renders",
                              f"concurrent renders: expected at most {per_token} for this token and "
                              f"{self.max_concurrent} on this server, got one more; retry shortly",
                              {"Retry-After": "1"})
            self.running[name] = self.running.get(name, 0) + 1
            self.total += 1
        try:
            yield
        finally:
            with self.lock:
                self.running[name] -= 1
                self.total -= 1


class Service:
    """The served stores (by id, and their names), the Dask client, the tokens and the limits."""

    def __init__(self, stores: dict, *, client: Any = None, tokens: TokenTable | None = None,
                 max_concurrent: int = 4, backend: str | None = None) -> None:
        self.stores, self.names, self.name_of = served_stores(stores)
        self.client = client
        self.tokens = tokens
        self.limits = Limits(max_concurrent)
        self.backend = backend

    def who(self, request: Request) -> tuple[str, int, Any]:
        """(name, concurrent limit, token entry or None) of the request's bearer token."""
        if self.tokens is None:
            return "anonymous", self.limits.max_concurrent, None
        auth = request.headers.get("authorization", "")
        scheme, _, presented = auth.partition(" ")
        token = self.tokens.lookup(presented.strip()) if scheme.lower() == "bearer" else None
        if token is None:
            raise Problem(401, "unauthorised", "Authorization: expected 'Bearer <token>' with a token of this server",
                          {"WWW-Authenticate": 'Bearer realm="hevr"'})
        return token.name, token.concurrent, token

    def resolve(self, request: Request, token: Any) -> tuple[str, Any]:
        """(store id, opened store) of the request's ``{store}``: a store id or a served name."""
        key = request.path_params["store"]
        sid = key if key in self.stores else self.names.get(key)
        if sid is None or (token is not None and not token.may_render(sid)):
            raise Problem(404, "no such store", f"store: expected the id or name of a served store, got {key[:40]!r}")
        return sid, self.stores[sid]

    def store(self, request: Request, token: Any) -> Any:
        return self.resolve(request, token)[1]

    def visible(self, token: Any) -> list[str]:
        return [sid for sid in self.stores if token is None or token.may_render(sid)]

    def description(self, sid: str) -> dict:
        """What ``/v1/stores`` says of a store: its id, its name (None: served by id only) and its
        public metadata."""
        return {"id": sid, "name": self.name_of.get(sid), "metadata": self.stores[sid].meta.to_dict()}


def served_stores(stores: dict) -> tuple[dict, dict, dict]:
    """(store id -> store, name -> store id, store id -> name) of ``create_app``'s ``stores``: a
    key that is its store's id serves it without a name; any other key is its name
    (:func:`~hevr.remote.protocol.check_store_name`). Names and stores are unique."""
    by_id: dict = {}
    names: dict = {}
    name_of: dict = {}
    for key, ev in stores.items():
        sid = ev.meta.store_id
        if sid in by_id:
            raise ParameterError(f"stores: expected distinct stores, got the store {sid} twice ({by_id[sid].path} "
                                 f"and {ev.path})")
        by_id[sid] = ev
        if key != sid:
            names[check_store_name(key, "stores: a name")] = sid
            name_of[sid] = key
    return by_id, names, name_of


async def _body(request: Request) -> bytes:
    """The request body, at most MAX_BODY bytes, refused from its Content-Length when that says more."""
    declared = request.headers.get("content-length")
    if declared is not None and (not declared.isdigit() or int(declared) > MAX_BODY):
        raise Problem(413, "request too large", f"body: expected at most {MAX_BODY} bytes, got "
                                                f"Content-Length {declared[:20]}")
    data = bytearray()
    async for chunk in request.stream():
        data += chunk
        if len(data) > MAX_BODY:
            raise Problem(413, "request too large", f"body: expected at most {MAX_BODY} bytes, got more")
    if request.headers.get("content-type", "").split(";")[0].strip() != "application/json":
        raise Problem(415, "unsupported media type", "Content-Type: expected application/json")
    return bytes(data)


def create_app(stores: dict, *, client: Any = None, tokens: TokenTable | None = None, max_concurrent: int = 4,
               backend: str | None = None) -> Starlette:
    """The application serving ``stores`` (name -> opened :class:`hevr.EncryptedVolume`, as
    :func:`hevr.serve.run.open_stores` gives them; a key that is its store's id serves that store
    without a name) on the Dask ``client`` (None: Dask's default scheduler in this process)."""
    svc = Service(stores, client=client, tokens=tokens, max_concurrent=max_concurrent, backend=backend)

    def endpoint(fn):
        async def handler(request: Request) -> Response:
            t0 = time.perf_counter()
            name = "-"
            try:
                name, per_token, token = svc.who(request)
                response = await fn(request, token, per_token, name)
            except Exception as exc:  # every failure is a problem document
                p = _as_problem(exc)
                response = problem(p.status, p.title, p.detail, p.headers)
            log.info("%s %s %d %s %.3f s", request.method, request.url.path, response.status_code, name,
                     time.perf_counter() - t0)
            return response
        return handler

    async def version(request: Request, token: Any, per_token: int, name: str) -> Response:
        return JSONResponse({"api": API_VERSION, "hevr": __version__})

    async def openapi(request: Request, token: Any, per_token: int, name: str) -> Response:
        return JSONResponse(openapi_document())

    async def list_stores(request: Request, token: Any, per_token: int, name: str) -> Response:
        return JSONResponse({"stores": [svc.description(sid) for sid in svc.visible(token)]})

    async def one_store(request: Request, token: Any, per_token: int, name: str) -> Response:
        sid, _ = svc.resolve(request, token)
        return JSONResponse(svc.description(sid))

    async def render(request: Request, token: Any, per_token: int, name: str) -> Response:
        ev = svc.store(request, token)
        req = RenderRequest.from_dict(parse_json(await _body(request), "body"))

        def run() -> tuple[bytes, str, str]:
            with svc.limits.slot(name, per_token):
                img = render_image(ev, req, client=svc.client, backend=svc.backend)
                if isinstance(img, (PackedImage, PackedColourImage, PackedSlice)):  # tiles as frames, then the end
                    end = json.dumps({"ok": True, "stats": stats_header(img.stats)}).encode()
                    tiles = [t for c in getattr(img, "components", [img]) for t in c.ciphertexts]
                    blob = b"".join(pack_frame(i, np.ascontiguousarray(t).tobytes())
                                    for i, t in enumerate(tiles)) + pack_frame(END, end)
                    return blob, stats_header(img.stats), UNITS_MEDIA
                return img.to_bytes(), stats_header(img.stats), IMAGE_MEDIA

        blob, stats, media = await anyio.to_thread.run_sync(run)
        return Response(blob, media_type=media, headers={"X-Hevr-Stats": stats})

    async def stream(request: Request, token: Any, per_token: int, name: str) -> Response:
        ev = svc.store(request, token)
        req = RenderRequest.from_dict(parse_json(await _body(request), "body"))
        if ev.meta.packing is not None:
            raise Problem(400, "bad request", f"stream: expected a per-voxel store, got the packed store "
                                              f"{ev.meta.store_id} (its frame comes whole from /render)")
        loop = asyncio.get_running_loop()
        queue: asyncio.Queue = asyncio.Queue()
        slot = svc.limits.slot(name, per_token)
        slot.__enter__()  # a 429 now, before the stream starts

        class Sink:
            def start(self, finish: Any, fields: dict) -> None:
                pass

            def unit(self, i: int, packed: Any) -> None:
                loop.call_soon_threadsafe(queue.put_nowait, pack_frame(i, packed.tobytes()))

        def run() -> None:
            try:
                img = render_image(ev, req, client=svc.client, backend=svc.backend, stream=Sink())
                end = {"ok": True, "stats": stats_header(img.stats)}
            except Exception as exc:
                p = _as_problem(exc)
                end = {"type": "about:blank", "title": p.title, "status": p.status, "detail": p.detail}
            finally:
                slot.__exit__(None, None, None)
            loop.call_soon_threadsafe(queue.put_nowait, pack_frame(END, json.dumps(end).encode()))

        loop.run_in_executor(None, run)  # runs to its end even if the client leaves (its slot is freed then)

        async def frames():
            while True:
                frame = await queue.get()
                yield frame
                if int.from_bytes(frame[:4], "little") == END:
                    return

        return StreamingResponse(frames(), media_type=UNITS_MEDIA)

    async def verify(request: Request, token: Any, per_token: int, name: str) -> Response:
        ev = svc.store(request, token)
        vr = VerifyRequest.from_dict(parse_json(await _body(request), "body"))

        def run() -> int:
            with svc.limits.slot(name, per_token):
                return verify_aggregate(ev, vr.render, vr.seed, client=svc.client, backend=svc.backend)

        aggregate = await anyio.to_thread.run_sync(run)
        return JSONResponse({"aggregate": str(aggregate)})

    routes = [
        Route("/v1", endpoint(version), methods=["GET"]),
        Route("/v1/openapi.json", endpoint(openapi), methods=["GET"]),
        Route("/v1/stores", endpoint(list_stores), methods=["GET"]),
        Route("/v1/stores/{store}", endpoint(one_store), methods=["GET"]),
        Route("/v1/stores/{store}/render", endpoint(render), methods=["POST"]),
        Route("/v1/stores/{store}/stream", endpoint(stream), methods=["POST"]),
        Route("/v1/stores/{store}/verify", endpoint(verify), methods=["POST"]),
    ]

    async def not_found(request: Request, exc: Exception) -> Response:
        status = getattr(exc, "status_code", 404)
        return problem(status, "not found" if status == 404 else "method not allowed",
                       f"{request.method} {request.url.path}: expected one of the /v1 endpoints "
                       "(/v1/openapi.json lists them)")

    return Starlette(routes=routes, exception_handlers={404: not_found, 405: not_found})
