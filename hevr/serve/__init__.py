"""``hevr serve``: the render service beside the cluster (``pip install 'hevr[serve]'``).

The server side of the trust boundary (:mod:`hevr.remote` is the key holder's): a Starlette
application run by uvicorn that renders the stores it was given on its Dask cluster and answers
with data only. It never needs or accepts a private key, and no endpoint writes a store.

==============================  ==========================================================
:mod:`hevr.serve.app`           the ASGI application: routes, exception handlers, state
:mod:`hevr.serve.routes`        the endpoints, one module per resource (meta, stores, render)
:mod:`hevr.serve.service`       what the server holds: stores, client, tokens, limits; bodies
:mod:`hevr.serve.problems`      problem documents (RFC 9457), with no server internals
:mod:`hevr.serve.budget`        a cost bound for every request, from public parameters
:mod:`hevr.serve.jobs`          what a request runs: :func:`hevr.render`'s pipeline, cancellable
:mod:`hevr.serve.tokens`        bearer tokens per store (hashed, compared in constant time)
:mod:`hevr.serve.token_file`    the tokens file re-read when it changes; --new-token adds to it
:mod:`hevr.serve.store_watch`   a store re-encrypted under the server, noticed and opened again
:mod:`hevr.serve.file_watch`    one watched file: stat at most once a second, changed or not
:mod:`hevr.serve.openapi`       the protocol's OpenAPI document
:mod:`hevr.serve.guard`         deadlines for every byte: uvicorn's h11 protocol, guarded
:mod:`hevr.serve.connections`   the deadlines' settings; connections per address and in all
:mod:`hevr.serve.run`           opening the stores, the cluster and uvicorn (the CLI's)
==============================  ==========================================================
"""

from __future__ import annotations

__all__: list[str] = []  # the modules are the API: hevr.serve.app.create_app, hevr.serve.run.serve, ...
