"""Starting ``hevr serve``: open the stores, join or start the Dask cluster, run uvicorn.

The CLI (:mod:`hevr.cli.serve`) parses the arguments; this module does the work so that a Python
program can serve too (:func:`serve`). Nothing here reads a private key: the server has none.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable, Sequence
from typing import Any

from ..errors import MissingDependencyError, ParameterError
from ..remote.protocol import check_store_name
from ..store.reader import EncryptedVolume, open_volume

try:  # the 'serve' extra: Starlette and uvicorn (only their absence is a missing extra)
    import starlette
    import uvicorn
except ModuleNotFoundError:  # pragma: no cover - hevr serve says which extra
    starlette = uvicorn = None
if uvicorn is not None and starlette is not None:
    from .app import create_app
else:  # pragma: no cover
    create_app = None

log = logging.getLogger("hevr.serve")

__all__ = ["open_stores", "serve", "store_name"]


def store_name(spec: str) -> tuple[str, str]:
    """(name, path) of one ``hevr serve`` STORE argument: ``NAME=PATH``, where NAME is a store name
    (:func:`~hevr.remote.protocol.check_store_name`; a path whose first ``=`` follows a ``/`` or
    ``:`` is a path), or a path or URL, named after its last component without ``.zarr``.

    >>> store_name("/data/ct/vol.zarr/"), store_name("s3://bucket/b.zarr"), store_name("ct=/data/vol.zarr")
    (('vol', '/data/ct/vol.zarr/'), ('b', 's3://bucket/b.zarr'), ('ct', '/data/vol.zarr'))
    """
    if not isinstance(spec, str) or not spec:
        raise ParameterError(f"STORE: expected a path, a URL or NAME=PATH, got {str(spec)[:70]!r}")
    left, eq, right = spec.partition("=")
    if eq and left and not any(c in left for c in "/:\\"):
        if not right:
            raise ParameterError(f"STORE: expected NAME=PATH with a path, got {spec[:100]!r}")
        return check_store_name(left, f"STORE {spec[:100]!r}: NAME"), right
    last = spec.rstrip("/").rsplit("/", 1)[-1]
    name = last[:-len(".zarr")] if last.endswith(".zarr") else last
    try:
        return check_store_name(name, f"STORE {spec[:100]!r}: its name"), spec
    except ParameterError as exc:
        raise ParameterError(f"{exc}; name it explicitly with NAME=PATH") from None


def open_stores(specs: Sequence[str], storage_options: dict | None = None) -> dict[str, EncryptedVolume]:
    """Name -> opened store, for every ``hevr serve`` STORE argument (:func:`store_name`: a path or
    URL, or ``NAME=PATH``); two arguments of one name, or of one store, are refused before any is
    served. :func:`hevr.serve.app.create_app` takes the result as it is."""
    stores: dict[str, EncryptedVolume] = {}
    named = [store_name(spec) for spec in specs]  # every name checked before any store is opened
    seen: dict[str, str] = {}
    for name, path in named:
        if name in seen:
            raise ParameterError(f"STORE: expected distinct store names, got the name {name!r} twice ({seen[name]} "
                                 f"and {path}); name one of them with NAME=PATH")
        seen[name] = path
    ids: dict[str, str] = {}
    for name, path in named:
        ev = open_volume(path, storage_options=storage_options)
        sid = ev.meta.store_id
        if sid in ids:
            raise ParameterError(f"STORE: expected distinct stores, got the store {sid} twice ({stores[ids[sid]].path} "
                                 f"and {ev.path})")
        ids[sid] = name
        stores[name] = ev
    return stores


def serve(stores: dict[str, EncryptedVolume], *, host: str = "127.0.0.1", port: int = 8750, client: Any = None,
          tokens: Any = None, tls_cert: str | None = None, tls_key: str | None = None, max_concurrent: int = 4,
          backend: str | None = None, on_ready: Callable[[str], None] | None = None) -> None:
    """Serve ``stores`` (name or store id -> opened store: :func:`open_stores`,
    :func:`~hevr.serve.app.create_app`) until interrupted (uvicorn; TLS with ``tls_cert`` and ``tls_key``).
    ``on_ready(url)`` is called once the socket listens."""
    if uvicorn is None or create_app is None:
        raise MissingDependencyError("hevr serve needs the 'serve' extra (Starlette, uvicorn): pip install 'hevr[serve]'")
    if (tls_cert is None) != (tls_key is None):
        raise ParameterError("--tls-cert/--tls-key: expected both or neither, got one")
    app = create_app(stores, client=client, tokens=tokens, max_concurrent=max_concurrent, backend=backend)
    config = uvicorn.Config(app, host=host, port=port, log_level="warning", access_log=False,
                            ssl_certfile=tls_cert, ssl_keyfile=tls_key, timeout_keep_alive=5,
                            limit_concurrency=256, h11_max_incomplete_event_size=64 * 1024,
                            timeout_graceful_shutdown=3)  # Ctrl-C: open keep-alive connections get 3 s
    server = uvicorn.Server(config)
    if on_ready is not None:
        scheme = "https" if tls_cert else "http"

        async def startup() -> None:
            while not server.started:  # pragma: no branch - polled until the socket listens
                await asyncio.sleep(0.02)
            bound = port
            for s in getattr(server, "servers", []):
                for sock in getattr(s, "sockets", []):
                    bound = sock.getsockname()[1]
            on_ready(f"{scheme}://{host if ':' not in host else f'[{host}]'}:{bound}")

        async def main() -> None:
            task = asyncio.create_task(startup())
            await server.serve()
            task.cancel()

        asyncio.run(main())
    else:
        server.run()
