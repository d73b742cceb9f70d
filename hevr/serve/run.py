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

__all__ = ["open_stores", "serve"]


def open_stores(paths: Sequence[str], storage_options: dict | None = None) -> dict[str, EncryptedVolume]:
    """Store id -> opened store, for every path or URL (two paths of one store are refused)."""
    stores: dict[str, EncryptedVolume] = {}
    for path in paths:
        ev = open_volume(path, storage_options=storage_options)
        sid = ev.meta.store_id
        if sid in stores:
            raise ParameterError(f"STORE: expected distinct stores, got the store {sid} twice ({stores[sid].path} and "
                                 f"{ev.path})")
        stores[sid] = ev
    return stores


def serve(stores: dict[str, EncryptedVolume], *, host: str = "127.0.0.1", port: int = 8750, client: Any = None,
          tokens: Any = None, tls_cert: str | None = None, tls_key: str | None = None, max_concurrent: int = 4,
          backend: str | None = None, on_ready: Callable[[str], None] | None = None) -> None:
    """Serve ``stores`` until interrupted (uvicorn; TLS with ``tls_cert`` and ``tls_key``).
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
