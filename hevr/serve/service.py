"""What ``hevr serve`` holds while it runs: the served stores, the Dask client, the tokens and the
limits (:class:`Service`, on the application's ``state``), and the bounded reading of a request body.

* **Concurrent renders**: per token (its ``concurrent``), and for the whole server
  (``max_concurrent``): one more is a 429 with ``Retry-After``, so a client cannot queue
  unbounded work on the cluster (:class:`~hevr.serve.budget.Limits`).
* **Cost**: every render's modular products, its pixels, step and tile, checked before any work
  against the server's :class:`~hevr.serve.budget.Budget`; the products a token and the server
  have in flight; a render whose client left, or at the server's shutdown (:meth:`Service.close`),
  is cancelled on the cluster (:mod:`hevr.serve.budget`).
* **Tokens** (:mod:`hevr.serve.tokens`): a missing or unknown token is a 401; a store the token
  may not render is a 404, as an unknown one (ids are not disclosed).
* **A store changed on disk** (:mod:`hevr.serve.store_watch`): opened again on a thread of its
  own; a request naming it meanwhile is a 503 with ``Retry-After``.
* **Request size** (:data:`~hevr.remote.protocol.MAX_BODY`): a ``Content-Length`` above it is
  refused (413) before a byte of the body is read, and a body without one is read only that far
  (:func:`read_body`).
"""

from __future__ import annotations

from typing import Any

from starlette.requests import Request

from ..errors import ParameterError
from ..remote.protocol import MAX_BODY, check_store_name
from .budget import Budget, Limits
from .problems import Problem, private_locations
from .store_watch import RETRY_AFTER, StoreWatch
from .tokens import TokenTable

__all__ = ["Limits", "Service", "read_body", "served_stores"]


class Service:
    """The served stores (by id, and their names), the Dask client, the tokens and the limits."""

    def __init__(
        self,
        stores: dict,
        *,
        client: Any = None,
        tokens: TokenTable | None = None,
        max_concurrent: int = 4,
        backend: str | None = None,
        budget: Budget | None = None,
    ) -> None:
        self.stores, self.names, self.name_of = served_stores(stores)
        self.watch = StoreWatch(self.stores)  # a store rewritten on disk is opened again (re-encrypted)
        private_locations(ev.path for ev in self.stores.values())  # never in an answer (problems.public_text)
        self.client = client
        self.tokens = tokens
        self.budget = budget if budget is not None else Budget.from_config()
        self.limits = Limits(max_concurrent, self.budget)
        self.backend = backend

    def close(self, timeout: float = 5.0) -> bool:
        """The server stops: refuse new renders, cancel the running ones on the cluster and wait up
        to ``timeout`` seconds for them to end (the app's lifespan calls it); whether they did."""
        return self.limits.close(timeout)

    def who(self, request: Request) -> tuple[str, int, Any]:
        """(name, concurrent limit, token entry or None) of the request's bearer token."""
        if self.tokens is None:
            return "anonymous", self.limits.max_concurrent, None
        auth = request.headers.get("authorization", "")
        scheme, _, presented = auth.partition(" ")
        token = self.tokens.lookup(presented.strip()) if scheme.lower() == "bearer" else None
        if token is None:
            raise Problem(
                401,
                "unauthorised",
                "Authorization: expected 'Bearer <token>' with a token of this server",
                {"WWW-Authenticate": 'Bearer realm="hevr"'},
            )
        return token.name, token.concurrent, token

    def resolve(self, request: Request, token: Any) -> tuple[str, Any]:
        """(store id, opened store) of the request's ``{store}``: a store id or a served name."""
        key = request.path_params["store"]
        sid = key if key in self.stores else self.names.get(key)
        if sid is not None:
            self.watch.refresh(self, [sid])
            sid = key if key in self.stores else self.names.get(key)
        if sid is None or (token is not None and not token.may_render(sid)):
            raise Problem(404, "no such store", f"store: expected the id or name of a served store, got {key[:40]!r}")
        if self.watch.reopening(sid):  # changed on disk: the handle in force reads bricks no longer there
            raise Problem(
                503,
                "store being reopened",
                f"store: expected a store ready to render, got {key[:40]!r}, "
                "which changed on disk and is being opened again; retry in a moment",
                {"Retry-After": str(RETRY_AFTER)},
            )
        return sid, self.stores[sid]

    def store(self, request: Request, token: Any) -> Any:
        return self.resolve(request, token)[1]

    def visible(self, token: Any) -> list[str]:
        self.watch.refresh(self)
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
            raise ParameterError(
                f"stores: expected distinct stores, got the store {sid} twice ({by_id[sid].path} and {ev.path})"
            )
        by_id[sid] = ev
        if key != sid:
            names[check_store_name(key, "stores: a name")] = sid
            name_of[sid] = key
    return by_id, names, name_of


async def read_body(request: Request) -> bytes:
    """The request body, at most MAX_BODY bytes, refused from its Content-Length when that says more."""
    declared = request.headers.get("content-length")
    if declared is not None and (not declared.isdigit() or int(declared) > MAX_BODY):
        raise Problem(
            413, "request too large", f"body: expected at most {MAX_BODY} bytes, got Content-Length {declared[:20]}"
        )
    data = bytearray()
    async for chunk in request.stream():
        data += chunk
        if len(data) > MAX_BODY:
            raise Problem(413, "request too large", f"body: expected at most {MAX_BODY} bytes, got more")
    if request.headers.get("content-type", "").split(";")[0].strip() != "application/json":
        raise Problem(415, "unsupported media type", "Content-Type: expected application/json")
    return bytes(data)
