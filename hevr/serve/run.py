"""Starting ``hevr serve``: open the stores, join or start the Dask cluster, run uvicorn.

The CLI (:mod:`hevr.cli.serve`) parses the arguments; this module does the work so that a Python
program can serve too (:func:`serve`). Nothing here reads a private key: the server has none.

* **Before anything starts** the TLS files are loaded once (:func:`check_tls`: missing, not PEM,
  swapped, encrypted, or a key of another certificate) and the sockets are bound (:func:`bind`: a
  host that does not resolve or is not this machine's, a port out of range, in use or privileged);
  each failure is one :class:`~hevr.errors.ParameterError` naming the option (``hevr serve`` exit 2),
  never uvicorn's own line, ``[SSL] PEM lib`` or exit 3.
* **Every connection** keeps the deadlines of :mod:`hevr.serve.guard` (idle, head, body, send,
  TLS handshake; connections per address and in all).
* **Ctrl-C** (or SIGTERM): the sockets stop listening, idle connections close, and the
  application's shutdown runs at once (renders cancelled there, their requests answer 503), for at
  most :data:`LIFESPAN_STOP` (5 s); a request still running :data:`GRACE` (1 s) after that is
  cancelled (:class:`_Server`). Measured with a render in flight: 0.5-1.5 s to exit (1.2-1.4 s with
  a 2-worker cluster), the render's client answered 503; before, 3.9-6.2 s and no answer.
"""

from __future__ import annotations

import asyncio
import dataclasses
import errno
import logging
import os
import socket
import ssl
import sys
from collections.abc import Callable, Sequence
from typing import Any

from ..errors import MissingDependencyError, MissingFileError, ParameterError
from ..remote.protocol import check_store_name
from ..store.reader import EncryptedVolume, open_volume
from .connections import Deadlines

if sys.platform != "win32":  # no open-files limit to raise on Windows
    import resource
try:  # the 'serve' extra: Starlette and uvicorn (only their absence is a missing extra)
    import starlette  # noqa: F401  (the application's)
    import uvicorn

    SERVE_EXTRA = True
except ModuleNotFoundError:  # pragma: no cover - hevr serve says which extra
    SERVE_EXTRA = False
if SERVE_EXTRA:
    from .app import create_app
    from .guard import GuardedH11Protocol, guarded_protocol, over_tls

log = logging.getLogger("hevr.serve")

#: Ctrl-C: at most LIFESPAN_STOP seconds for the application's shutdown (it cancels the running renders
#: and waits for their threads), and GRACE seconds more for the answers in flight before their requests
#: are cancelled (an answer being written takes milliseconds) (:class:`_Server`).
GRACE, LIFESPAN_STOP = 1.0, 5.0

__all__ = ["bind", "check_listen", "check_tls", "open_stores", "serve", "store_name"]


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
    name = last[: -len(".zarr")] if last.endswith(".zarr") else last
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
            raise ParameterError(
                f"STORE: expected distinct store names, got the name {name!r} twice ({seen[name]} "
                f"and {path}); name one of them with NAME=PATH"
            )
        seen[name] = path
    ids: dict[str, str] = {}
    for name, path in named:
        ev = open_volume(path, storage_options=storage_options)
        sid = ev.meta.store_id
        if sid in ids:
            raise ParameterError(
                f"STORE: expected distinct stores, got the store {sid} twice ({stores[ids[sid]].path} and {ev.path})"
            )
        ids[sid] = name
        stores[name] = ev
    return stores


def check_tls(cert: str | None, key: str | None) -> None:
    """Refuse TLS files uvicorn could not load, in one line naming the option (``--tls-cert``,
    ``--tls-key``): one without the other, missing, not PEM, swapped, encrypted, or a key of another
    certificate. Neither given: nothing to check.

    >>> check_tls(None, None)
    >>> check_tls("cert.pem", None)
    Traceback (most recent call last):
    hevr.errors.ParameterError: --tls-cert/--tls-key: expected both or neither, got one
    """
    if (cert is None) != (key is None):
        raise ParameterError("--tls-cert/--tls-key: expected both or neither, got one")
    if cert is None or key is None:  # neither (one without the other was refused above)
        return
    texts = {}
    for option, path in (("--tls-cert", cert), ("--tls-key", key)):
        if not os.path.isfile(path):
            raise MissingFileError(option, "a PEM file", path)
        try:
            with open(path, "rb") as f:
                texts[option] = f.read(1 << 20).decode("ascii", "replace")
        except OSError as exc:
            raise ParameterError(f"{option}: expected a readable PEM file, got {path} ({exc.strerror})") from None
    c, k = texts["--tls-cert"], texts["--tls-key"]
    if "-----BEGIN CERTIFICATE-----" not in c or "PRIVATE KEY-----" not in k:
        swapped = "PRIVATE KEY-----" in c and "-----BEGIN CERTIFICATE-----" in k
        which = (
            ("--tls-cert", cert, "a certificate")
            if "-----BEGIN CERTIFICATE-----" not in c
            else ("--tls-key", key, "a private key")
        )
        hint = "; --tls-cert and --tls-key look swapped" if swapped else ""
        raise ParameterError(f"{which[0]}: expected {which[2]} in PEM, got {which[1]} without one{hint}")
    if "ENCRYPTED" in k:
        raise ParameterError(
            f"--tls-key: expected an unencrypted private key (hevr serve asks for no "
            f"password), got an encrypted one in {key}"
        )

    def no_password() -> bytes:
        raise ValueError("encrypted")

    try:
        ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER).load_cert_chain(cert, key, password=no_password)
    except (ssl.SSLError, ValueError) as exc:
        reason = getattr(exc, "reason", None) or str(exc)[:80]
        raise ParameterError(
            f"--tls-cert/--tls-key: expected a certificate chain and its own private key in PEM, "
            f"got {cert} and {key} ({str(reason).lower().replace('_', ' ')})"
        ) from None


def bind(host: str, port: int) -> list[socket.socket]:
    """Sockets bound to every address ``host`` resolves to, at ``port`` (0: one free port for all),
    not yet listening; a bad host or a port in use is one :class:`ParameterError` naming the option."""
    if isinstance(port, bool) or not isinstance(port, int) or not 0 <= port <= 65535:
        raise ParameterError(f"--port: expected a TCP port from 0 to 65535, got {port!r}")
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    except (socket.gaierror, UnicodeError, TypeError) as exc:
        why = getattr(exc, "strerror", None) or str(exc)
        raise ParameterError(
            f"--host: expected an address of this machine or a name that resolves to one, got "
            f"{str(host)[:100]!r} ({why})"
        ) from None
    socks: list[socket.socket] = []
    seen = set()
    try:
        for family, kind, proto, _, addr in infos:
            if addr in seen:
                continue
            seen.add(addr)
            s = socket.socket(family, kind, proto)
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            if family == getattr(socket, "AF_INET6", None):
                s.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_V6ONLY, 1)
            if socks and port == 0:
                addr = (addr[0], socks[0].getsockname()[1], *addr[2:])
            try:
                s.bind(addr)
            except OSError as exc:
                s.close()
                if socks and exc.errno in (errno.EADDRNOTAVAIL, errno.EAFNOSUPPORT):
                    continue  # "localhost" on a machine without IPv6: its IPv4 address serves
                raise _bind_error(exc, host, port) from None
            socks.append(s)
    except BaseException:
        for s in socks:
            s.close()
        raise
    return socks


def check_listen(host: str, port: int, tls_cert: str | None = None, tls_key: str | None = None) -> None:
    """What :func:`serve` checks before it starts (:func:`check_tls`, :func:`bind`), for a caller that
    wants the answer before it starts a cluster; the port is bound and released again.

    >>> check_listen("127.0.0.1", 0)
    >>> check_listen("127.0.0.1", 70000)
    Traceback (most recent call last):
    hevr.errors.ParameterError: --port: expected a TCP port from 0 to 65535, got 70000
    """
    check_tls(tls_cert, tls_key)
    for s in bind(host, port):
        s.close()


def _bind_error(exc: OSError, host: str, port: int) -> ParameterError:
    if exc.errno == errno.EADDRINUSE:
        return ParameterError(f"--port: expected a free port, got {port} (in use on {host})")
    if exc.errno == errno.EACCES:
        return ParameterError(
            f"--port: expected a port this user may listen on, got {port} (permission denied; "
            f"ports below 1024 need privileges)"
        )
    if exc.errno == errno.EADDRNOTAVAIL:
        return ParameterError(f"--host: expected an address of this machine, got {host!r} (not one of its addresses)")
    return ParameterError(
        f"--host/--port: expected an address and port to listen on, got {host}:{port} ({exc.strerror or exc})"
    )


def _room_for(deadlines: Deadlines) -> Deadlines:
    """``deadlines`` with at most as many connections as the open-files limit leaves room for (the
    soft limit raised towards the hard one first)."""
    if sys.platform == "win32":  # pragma: no cover - no open-files limit
        return deadlines
    need = deadlines.connections + 256  # the stores, the cluster's sockets, the log
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft != resource.RLIM_INFINITY and soft < need:
        want = need if hard == resource.RLIM_INFINITY else min(need, hard)
        try:
            resource.setrlimit(resource.RLIMIT_NOFILE, (want, hard))
            soft = want
        except (ValueError, OSError):  # not allowed here
            pass
        if soft < need:
            fit = max(16, soft - 256)
            log.warning(
                "serve: %d open files allowed: at most %d connections (not %d); raise 'ulimit -n'",
                soft,
                fit,
                deadlines.connections,
            )
            deadlines = dataclasses.replace(deadlines, connections=fit, per_address=min(deadlines.per_address, fit))
    return deadlines


if SERVE_EXTRA:

    class _Server(uvicorn.Server):
        """uvicorn's server on sockets bound beforehand (:func:`bind`), with TLS in the guarded
        protocol (:func:`~hevr.serve.guard.over_tls`: bounds from the TCP accept, a handshake deadline)."""

        def __init__(
            self, config: Any, sockets: list[socket.socket], handshake: float, protocol: type[GuardedH11Protocol]
        ) -> None:
            super().__init__(config)
            self.bound, self.handshake, self.protocol_class = sockets, handshake, protocol

        async def startup(self, sockets: Any = None) -> None:
            await self.lifespan.startup()
            if self.lifespan.should_exit:
                raise RuntimeError("hevr serve: the application did not start (its log says why)")
            loop, config = asyncio.get_running_loop(), self.config

            def protocol(_loop: Any = None) -> asyncio.BaseProtocol:
                app = self.protocol_class(  # config.http_protocol_class: the guarded protocol (serve)
                    config=config, server_state=self.server_state, app_state=self.lifespan.state, _loop=_loop
                )
                return app if config.ssl is None else over_tls(app, config.ssl, self.handshake)

            self.servers = []  # TLS in the protocol (over_tls): a connection counts from its TCP accept
            for sock in self.bound:
                self.servers.append(await loop.create_server(protocol, sock=sock, backlog=config.backlog))
            self.started = True

        async def shutdown(self, sockets: Any = None) -> None:
            """Stop: no more connections, idle ones closed, then the application's shutdown at once
            (its running renders are cancelled, and their requests answer 503) while the answers in
            flight are written; a request still running after :data:`GRACE` s more than that
            shutdown took (at most :data:`LIFESPAN_STOP` s) is cancelled. uvicorn's own order waits
            for the requests before the application hears of the shutdown, so a render's client got
            no answer and Ctrl-C waited on the render. A second Ctrl-C stops at once."""
            for server in self.servers:
                server.close()
            for connection in list(self.server_state.connections):
                connection.shutdown()
            app_stop = asyncio.ensure_future(asyncio.wait_for(self.lifespan.shutdown(), LIFESPAN_STOP))
            clock = asyncio.get_running_loop().time
            t0, app_done = clock(), None
            while self.server_state.tasks and not self.force_exit:
                if app_done is None and app_stop.done():
                    app_done = clock()
                if clock() - (t0 + LIFESPAN_STOP if app_done is None else app_done) >= GRACE:
                    break
                await asyncio.sleep(0.05)
            if self.server_state.tasks:
                log.warning("serve: stopping; %d request(s) still running cancelled", len(self.server_state.tasks))
                for task in list(self.server_state.tasks):
                    task.cancel()
            if self.force_exit:
                app_stop.cancel()
            try:
                await app_stop
            except asyncio.TimeoutError:
                log.warning("serve: the application's shutdown took over %g s; stopping without it", LIFESPAN_STOP)
            except asyncio.CancelledError:
                pass


def serve(
    stores: dict[str, EncryptedVolume],
    *,
    host: str = "127.0.0.1",
    port: int = 8750,
    client: Any = None,
    tokens: Any = None,
    tls_cert: str | None = None,
    tls_key: str | None = None,
    max_concurrent: int = 4,
    backend: str | None = None,
    on_ready: Callable[[str], None] | None = None,
    deadlines: Deadlines | None = None,
) -> None:
    """Serve ``stores`` (name or store id -> opened store: :func:`open_stores`,
    :func:`~hevr.serve.app.create_app`) until interrupted (uvicorn; TLS with ``tls_cert`` and ``tls_key``).
    ``on_ready(url)`` is called once the socket listens. Every connection keeps ``deadlines``
    (default: :meth:`Deadlines.from_config`; :mod:`hevr.serve.guard`). The TLS files, the host and
    the port are checked before anything starts (:func:`check_tls`, :func:`bind`)."""
    if not SERVE_EXTRA:
        raise MissingDependencyError(
            "hevr serve needs the 'serve' extra (Starlette, uvicorn): pip install 'hevr[serve]'"
        )
    check_tls(tls_cert, tls_key)
    deadlines = _room_for(Deadlines.from_config() if deadlines is None else deadlines)
    sockets = bind(host, port)
    try:
        app = create_app(stores, client=client, tokens=tokens, max_concurrent=max_concurrent, backend=backend)
        protocol, _ = guarded_protocol(deadlines)
        # ws="none": no upgrade takes a connection out of the guard; proxy_headers=False: the TCP peer,
        # never X-Forwarded-For (uvicorn's default reads it from 127.0.0.1 and ::1: any local user's)
        config = uvicorn.Config(
            app,
            host=host,
            port=port,
            log_level="warning",
            access_log=False,
            http=protocol,
            ws="none",
            proxy_headers=False,
            ssl_certfile=tls_cert,
            ssl_keyfile=tls_key,
            # uvicorn annotates int; it hands the seconds to loop.call_later, which takes a float
            timeout_keep_alive=deadlines.idle,  # type: ignore[arg-type]
            limit_concurrency=None,
            h11_max_incomplete_event_size=64 * 1024,
        )
        server = _Server(config, sockets, deadlines.handshake, protocol)
    except BaseException:
        for s in sockets:
            s.close()
        raise
    scheme = "https" if tls_cert else "http"
    bound = sockets[0].getsockname()[1]

    async def main() -> None:
        task = asyncio.create_task(startup(on_ready)) if on_ready is not None else None
        await server.serve()
        if task is not None:
            task.cancel()

    async def startup(ready: Callable[[str], None]) -> None:
        while not server.started:  # pragma: no branch - polled until the socket listens
            await asyncio.sleep(0.02)
        ready(f"{scheme}://{host if ':' not in host else f'[{host}]'}:{bound}")

    asyncio.run(main())
