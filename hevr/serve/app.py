"""The ASGI application of ``hevr serve`` (Starlette, run by :mod:`hevr.serve.run`): the endpoints of
:mod:`hevr.remote.protocol` over a set of opened stores and a Dask client.

Laid out the Starlette way: the routes, one module per resource (:mod:`hevr.serve.routes`), the
exception handlers and problem documents (:mod:`hevr.serve.problems`), and the state on the
application (``app.state.service``, a :class:`~hevr.serve.service.Service`: stores, client, tokens,
limits). What each limit answers:

* **Request size**, **concurrent renders**, **tokens**: :mod:`hevr.serve.service`.
* **Strict JSON** (:func:`~hevr.remote.protocol.parse_json`, :class:`~hevr.remote.protocol.RenderRequest`):
  unknown fields, duplicate keys, NaN, 40-digit integers, deep nesting and out-of-range sizes are
  400s before any work; the render's own planner (pixels, samples, overflow) is the second line.
* **Cost**: every render's step, pixels, tile and modular products against the server's budget
  (422s before any work), the products a token and the server have in flight (429s); a render
  whose client left, or at shutdown (the lifespan), is cancelled on the cluster
  (:mod:`hevr.serve.budget`, :func:`hevr.serve.jobs.run_job`).
* **Errors** are RFC 9457 problem documents naming the parameter; an unexpected failure says only
  "internal error" (the server's log has the traceback), so the answer never carries the server's
  internals (:mod:`hevr.serve.problems`). The log holds method, path, status and the token's
  *name*, never a token.

Read-only: no endpoint writes a store; renders keep ray sums in memory (the render cache) only.
"""

from __future__ import annotations

import asyncio
import contextlib
import threading
from collections.abc import AsyncIterator
from typing import Any

from starlette.applications import Starlette

from .budget import Budget
from .jobs import SHUTDOWN
from .problems import Problem, as_problem, not_found, problem, public_text
from .routes import ROUTES
from .service import Service
from .tokens import TokenTable

__all__ = ["Problem", "as_problem", "create_app", "problem", "public_text"]


def create_app(
    stores: dict,
    *,
    client: Any = None,
    tokens: TokenTable | None = None,
    max_concurrent: int = 4,
    backend: str | None = None,
    budget: Budget | None = None,
) -> Starlette:
    """The application serving ``stores`` (name -> opened :class:`hevr.EncryptedVolume`, as
    :func:`hevr.serve.run.open_stores` gives them; a key that is its store's id serves that store
    without a name) on the Dask ``client`` (None: Dask's default scheduler in this process).
    ``budget``: what one render may cost (:class:`~hevr.serve.budget.Budget`; None: the Dask config's);
    at the app's shutdown (its lifespan) the running renders are cancelled (:meth:`Service.close`)."""
    svc = Service(stores, client=client, tokens=tokens, max_concurrent=max_concurrent, backend=backend, budget=budget)

    @contextlib.asynccontextmanager
    async def lifespan(app: Starlette) -> AsyncIterator[None]:
        svc.limits.open()
        try:
            yield
        finally:  # Ctrl-C: renders still running are cancelled on the cluster, their threads end
            await _stop(svc)

    app = Starlette(routes=ROUTES, exception_handlers={404: not_found, 405: not_found}, lifespan=lifespan)
    app.state.service = svc
    return app


def _settle(done: asyncio.Future[None]) -> None:
    """Mark ``done`` finished, unless it is already (cancelled while the thread waited)."""
    if not done.done():
        done.set_result(None)


async def _stop(svc: Service) -> None:
    """Cancel the running renders at once (no thread needed: each scope is cancelled from a thread of
    its own), then wait for them on a dedicated thread: never on anyio's pool, which renders may fill."""
    svc.limits.cancel_all(SHUTDOWN)
    loop = asyncio.get_running_loop()
    done: asyncio.Future[None] = loop.create_future()

    def wait() -> None:
        try:
            svc.close()
        finally:
            loop.call_soon_threadsafe(_settle, done)

    threading.Thread(target=wait, name="hevr-shutdown", daemon=True).start()
    await done
